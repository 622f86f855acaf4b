"""Live simulation: the scenario's scene, moved by ship motion and ray cast into frames.

`Simulation` is a FrameSource, so the pipeline consumes it exactly like a recording.
Every random draw takes a seed derived from the scenario seed, the sensor and the frame
number, so a frame is the same whatever order frames are generated in.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from boomtip.data.frames import BODIES, TRUTH_COLUMNS, Frame, FrameSource, MruLog, SourceMeta, Truth
from boomtip.data.sim.footprint import cast_footprints
from boomtip.data.poses import rpy_matrices
from boomtip.data.sim.motion import BodyStates, ShiftedSines, ShipMotion
from boomtip.data.sim.raycast import RayCaster
from boomtip.data.sim.run import SimulatedRun
from boomtip.data.sim.stored import TRUTH_CHUNK, FrameSchedule
from boomtip.data.stored_truth import StoredTruth, TrackFiles
from boomtip.data.sim.world import in_windows, mru_faults, true_lidar, true_radar, true_T_boomtip_sensor
from boomtip.data.sim.scene import Body, build_bodies, feeder_deck_plane_body
from boomtip.data.sim.sensors import FaceLookup, lidar_measure, lidar_pattern, multipath_ghosts, radar_measure, radar_pattern
from boomtip.data.sim.truth import relative_heave, tip_states

SENSOR_IDS = {"lidar": 1, "radar": 2, "mru": 3, "feeder_mru": 4}
# the run's seed s gives each ship's irregular sea its own stream: s * 7 + 11 (crane), s * 7 + 13 (feeder)
MOTION_SEED_FACTOR, CRANE_MOTION_SEED_SALT, FEEDER_MOTION_SEED_SALT = 7, 11, 13

# numpy's SeedSequence (a pool of 4 uint32 words) and PCG64's seeding, for `FrameRng`
_SS_INIT_A, _SS_MULT_A, _SS_INIT_B, _SS_MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_SS_MIX_L, _SS_MIX_R = 0xCA01F9DD, 0x4973F715
_PCG64_MULT = 0x2360ED051FC65DA44385DF649FCCF645
_M32, _M128 = (1 << 32) - 1, (1 << 128) - 1


def seed_sequence_words(entropy: np.ndarray) -> np.ndarray:
    """`SeedSequence(entropy[:, j]).generate_state(4, np.uint64)` for every column j of (W, N)
    uint32 entropy at once: (4, N) uint64. Written out (numpy's hash, uint32 arithmetic modulo
    2^32) because SeedSequence takes one entropy per call, several us of numpy calls each."""
    u = np.uint32
    h = _SS_INIT_A

    def hashmix(v: np.ndarray) -> np.ndarray:
        nonlocal h
        v = v ^ u(h)
        h = (h * _SS_MULT_A) & _M32
        v = v * u(h)
        return v ^ (v >> u(16))

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        r = u(_SS_MIX_L) * x - u(_SS_MIX_R) * y
        return r ^ (r >> u(16))

    pool = [hashmix(entropy[i] if i < len(entropy) else np.zeros(entropy.shape[1], u)) for i in range(4)]
    for src in range(4):
        for dst in range(4):
            if src != dst:
                pool[dst] = mix(pool[dst], hashmix(pool[src]))
    for src in range(4, len(entropy)):
        for dst in range(4):
            pool[dst] = mix(pool[dst], hashmix(entropy[src]))
    h, words = _SS_INIT_B, []
    for i in range(8):
        v = pool[i % 4] ^ u(h)
        h = (h * _SS_MULT_B) & _M32
        v = v * u(h)
        words.append(v ^ (v >> u(16)))
    w = np.array(words, dtype=np.uint64)
    return w[0::2] | (w[1::2] << np.uint64(32))  # little-endian pairs, as generate_state's uint64 view


class FrameRng:
    """`np.random.default_rng([seed, sensor_id, index])` frame after frame, at a third of the
    cost: the seeds' hash for a block of indices at once (`seed_sequence_words`) and one kept
    PCG64 put in the state its seeding gives. The generator returned is the same object each
    call: valid until the next."""

    BLOCK = 4096

    def __init__(self, seed: int, sensor_id: int) -> None:
        self.seed, self.sensor_id = seed, sensor_id
        self._words: dict[int, np.ndarray] = {}  # block -> (4, BLOCK) uint64
        self._bitgen = np.random.PCG64(0)
        self._gen = np.random.Generator(self._bitgen)

    def __call__(self, index: int) -> np.random.Generator:
        if not (0 <= self.seed < 2**32 and 0 <= self.sensor_id < 2**32 and 0 <= index < 2**32):
            return np.random.default_rng([self.seed, self.sensor_id, index])  # words of more than 32 bits
        block, j = divmod(index, self.BLOCK)
        words = self._words.get(block)
        if words is None:
            idx = np.arange(block * self.BLOCK, min((block + 1) * self.BLOCK, 2**32), dtype=np.uint32)
            entropy = np.stack([np.full(len(idx), self.seed, np.uint32), np.full(len(idx), self.sensor_id, np.uint32), idx])
            words = self._words[block] = seed_sequence_words(entropy)
        s0, s1, q0, q1 = words[:, j].tolist()
        # PCG64's seeding: state 0 and inc = 2 seq + 1, a step, state += the seed, a step.
        inc = ((((q0 << 64) | q1) << 1) | 1) & _M128
        state = ((inc + ((s0 << 64) | s1)) * _PCG64_MULT + inc) & _M128
        self._bitgen.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc}, "has_uint32": 0, "uinteger": 0}
        return self._gen


def frame_times(rate_hz: float, duration_s: float) -> np.ndarray:
    n = int(np.floor(duration_s * rate_hz + 1e-9))
    return np.arange(n) / rate_hz


class SimScene:
    """Bodies, their motion, and the TRUE mount chain crane -> boom tip -> sensor (the
    installation's surveyed mounts rotated by the world's mount errors)."""

    def __init__(self, scenario: SimulatedRun, bodies: list[Body] | None = None) -> None:
        s = scenario
        w, inst = s.world, s.installation
        self.scenario = s
        self.bodies = bodies if bodies is not None else build_bodies(s)
        self.caster = RayCaster(self.bodies)
        self.faces = FaceLookup.from_bodies(self.bodies)
        self.crane_motion = ShipMotion(w.crane.motion, w.crane.irregular, (0.0, 0.0, 0.0),
                                       seed=s.seed * MOTION_SEED_FACTOR + CRANE_MOTION_SEED_SALT)
        self.feeder_motion = ShipMotion(w.feeder.motion, w.feeder.irregular, w.feeder.geometry.position_m,
                                        seed=s.seed * MOTION_SEED_FACTOR + FEEDER_MOTION_SEED_SALT)
        self.T_crane_boomtip = inst.T_crane_boomtip()
        self.lidar = true_lidar(inst.lidar, w)
        self.radar = true_radar(inst.radar, w)
        mm = w.mismatch
        self.T_boomtip_sensor = {"lidar": true_T_boomtip_sensor(inst.lidar.mount, mm.lidar_mount_rpy_deg),
                                 "radar": true_T_boomtip_sensor(inst.radar.mount, mm.radar_mount_rpy_deg)}
        self.deck_plane_body = feeder_deck_plane_body(s)
        self.sea_index = next((i for i, b in enumerate(self.bodies) if b.name == "sea"), None)
        self._shifted: dict[str, ShiftedSines] = {}  # per ship, for the last offsets asked for

    def body_states(self, t_s: np.ndarray) -> list[BodyStates | None]:
        out: list[BodyStates | None] = []
        for b in self.bodies:
            if b.name == "crane":
                out.append(self.crane_motion.states(t_s))
            elif b.name == "feeder":
                out.append(self.feeder_motion.states(t_s))
            else:
                out.append(None)  # static in the world
        return out

    def body_poses(self, t_s: np.ndarray, offsets_s: np.ndarray | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Every body's rotation (M,3,3) and position (M,3) at the times: `poses(body_states(t))`
        without the velocities, which casting does not need. With `offsets_s` (C,), at the one
        time t_s[0] plus each offset (a sweep's columns, M = C), by `ShiftedSines`."""
        motions = {"crane": self.crane_motion, "feeder": self.feeder_motion}
        m = len(t_s) if offsets_s is None else len(offsets_s)
        Rs, ps = [], []
        for b in self.bodies:
            motion = motions.get(b.name)
            if motion is None:  # static in the world
                Rs.append(np.broadcast_to(np.eye(3), (m, 3, 3)))
                ps.append(np.zeros((m, 3)))
            else:
                if offsets_s is None:
                    q = motion.bank.at(float(t_s[0])) if m == 1 else motion.bank.eval(t_s)
                else:
                    shifted = self._shifted.get(b.name)
                    if shifted is None or shifted.offsets_s is not offsets_s:
                        shifted = self._shifted[b.name] = ShiftedSines(motion.bank, offsets_s)
                    q = shifted.eval(float(t_s[0]))
                Rs.append(rpy_matrices(q[:, 3:]))
                ps.append(motion.rest_position_m + q[:, :3])
        return Rs, ps

    def poses(self, states: list[BodyStates | None], m: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
        Rs, ps = [], []
        for st in states:
            if st is None:
                Rs.append(np.broadcast_to(np.eye(3), (m, 3, 3)))
                ps.append(np.zeros((m, 3)))
            else:
                Rs.append(st.R)
                ps.append(st.position_m)
        return Rs, ps

    def sensor_pose(self, crane: BodyStates, sensor: str) -> tuple[np.ndarray, np.ndarray]:
        """World rotation (M,3,3) and position (M,3) of a sensor."""
        T_cs = self.T_crane_boomtip @ self.T_boomtip_sensor[sensor]
        R_wc = crane.R
        return R_wc @ T_cs[:3, :3], R_wc @ T_cs[:3, 3] + crane.position_m


def source_meta(scenario: SimulatedRun) -> SourceMeta:
    """What a simulated source tells processing: the installation and the scenario's own
    processing settings; the full scenario only as provenance."""
    return SourceMeta(
        installation=scenario.installation,
        duration_s=scenario.duration_s,
        name=scenario.name,
        processing=scenario.processing_settings(),
        provenance=scenario.model_dump(mode="json"),
    )


class Simulation(FrameSource):
    """A scenario simulated in memory, frame by frame."""

    def __init__(self, scenario: SimulatedRun, world: SimScene | None = None) -> None:
        self.scenario = scenario
        self.world = world or SimScene(scenario)
        self.meta = source_meta(scenario)
        self.lidar_pattern = lidar_pattern(self.world.lidar)
        self.radar_pattern = radar_pattern(self.world.radar)
        mm = scenario.world.mismatch
        self.clock_offset_s = {"lidar": mm.lidar_clock_offset_s, "radar": mm.radar_clock_offset_s}
        self._T_crane_sensor: dict[str, np.ndarray] = {}
        self._schedule = self._frame_schedule()
        self.mru = self._mru_log()
        self.feeder_mru = self._feeder_mru_log() if scenario.world.feeder.mru.enabled else None
        self.truth = self._truth()

    # -- schedule ------------------------------------------------------------------------
    def _frame_schedule(self) -> FrameSchedule:
        """(time stamp, sensor, index): each sensor fires on the ticks of its own clock, which
        runs `clock_offset_s` ahead of true time (the frame is cast at stamp - offset)."""
        s = self.scenario
        items = []
        for sensor in s.installation.sensors():
            rate = getattr(s.installation, sensor).rate_hz
            t = frame_times(rate, s.duration_s)
            out = in_windows(t, getattr(s.world, sensor).outages_s)  # the sensor gives nothing then
            items += [(float(tk), sensor, i) for i, tk in enumerate(t) if not out[i]]
        return FrameSchedule(sorted(items))

    def __len__(self) -> int:
        return len(self._schedule)

    def __iter__(self) -> Iterator[Frame]:
        for t, sensor, i in self._schedule:
            t_true = t - self.clock_offset_s[sensor]
            frame = self.lidar_frame(i, t_true) if sensor == "lidar" else self.radar_frame(i, t_true)
            frame.t_s = t
            yield frame

    def _rng(self, sensor: str, index: int) -> np.random.Generator:
        """`default_rng([seed, sensor id, index])`; the LiDAR's, every frame, from a `FrameRng`
        (valid until the next LiDAR frame). Words below 2^32 go in as one uint32 array, the
        entropy the list becomes anyway, which skips converting each int."""
        if sensor == "lidar":
            frame_rng = self.__dict__.get("_lidar_rng")
            if frame_rng is None:
                frame_rng = self._lidar_rng = FrameRng(self.scenario.seed, SENSOR_IDS["lidar"])
            return frame_rng(index)
        words = (self.scenario.seed, SENSOR_IDS[sensor], index)
        if all(0 <= x < 2**32 for x in words):
            return np.random.Generator(np.random.PCG64(np.random.SeedSequence(np.array(words, dtype=np.uint32))))
        return np.random.default_rng(list(words))

    # -- sensors -------------------------------------------------------------------------
    def _scene_poses(self, times: np.ndarray, sensor: str, offsets_s: np.ndarray | None = None):
        """Sensor pose (R (M,3,3), p (M,3)) and every body's pose (lists of (M,3,3), (M,3),
        and per-body axis scales or None) at the given times (with `offsets_s`, at times[0]
        plus each offset)."""
        w = self.world
        Rs, ps = w.body_poses(times, offsets_s)
        T_cs = self._T_crane_sensor.get(sensor)  # the sensor rides on the crane vessel (body 0)
        if T_cs is None:
            T_cs = self._T_crane_sensor[sensor] = w.T_crane_boomtip @ w.T_boomtip_sensor[sensor]
        R_crane = Rs[0].reshape(-1, 3)  # (M*3,3): one product, not M small ones
        return (R_crane @ T_cs[:3, :3]).reshape(-1, 3, 3), (R_crane @ T_cs[:3, 3]).reshape(-1, 3) + ps[0], Rs, ps, None

    def bodies_about_tip(self, t_s: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        """For display: each body's rotation (M,3,3), position (M,3) relative to the true boom
        tip in world axes, and its per-axis scale (M,3) or None, at the times."""
        R_ws, p_ws, Rs, ps, scales = self._scene_poses(np.asarray(t_s, float), "lidar")
        T_ts = self.world.T_boomtip_sensor["lidar"]
        p_tip = p_ws + R_ws @ (-T_ts[:3, :3].T @ T_ts[:3, 3])
        scales = scales or [None] * len(Rs)
        return {b.name: (R, p - p_tip, s) for b, R, p, s in zip(self.world.bodies, Rs, ps, scales)}

    def lidar_frame(self, index: int, t_s: float) -> Frame:
        return self._lidar_frame_from(index, t_s, self._scene_poses, self._sensor_fixed_hits("lidar"))

    def _sensor_fixed_hits(self, sensor: str) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The crane vessel carries the sensors (boom tip on the crane body), so the pattern's
        rays are fixed in the crane's frame and so are their hits on it: cast them once."""
        cache = self.__dict__.setdefault("_fixed_hits", {})
        if sensor not in cache:
            crane = next((i for i, b in enumerate(self.world.bodies) if b.name == "crane"), None)
            if crane is None:
                cache[sensor] = {}
            else:
                T_cs = self.world.T_crane_boomtip @ self.world.T_boomtip_sensor[sensor]
                pat = self.lidar_pattern if sensor == "lidar" else self.radar_pattern
                cache[sensor] = {crane: self.world.caster.cast_in_body_frame(crane, T_cs[:3, 3], pat.dirs_sensor @ T_cs[:3, :3].T)}
        return cache[sensor]

    def _lidar_hits(self, t_s: float, scene_poses, fixed_hits=None):
        """The LiDAR's hits at true time t_s and the sensor's world pose (R (M,3,3), p (M,3)):
        M = 1, or one pose per column when the scene moves during the sweep; and, with a diverging
        beam, the dual mode's second returns (see `cast_footprints`) or None."""
        w, pat = self.world, self.lidar_pattern
        if w.lidar.motion_during_sweep and getattr(scene_poses, "__func__", None) is Simulation._scene_poses:
            # The ships' closed-form motion: the columns' poses as offsets from t_s.
            R_ws, p_ws, Rs, ps, scales = scene_poses(np.array([t_s]), "lidar", pat.column_time_s)
        else:
            times = t_s + pat.column_time_s if w.lidar.motion_during_sweep else np.array([t_s])
            R_ws, p_ws, Rs, ps, scales = scene_poses(times, "lidar")
        hits = w.caster.cast_fans(pat.fans, R_ws, p_ws, Rs, ps, scales, fixed_hits)
        second = None
        if w.lidar.beam_divergence_mrad > 0:  # the edge rays' footprints mixed; dual: their second returns
            hits, second = cast_footprints(
                w.caster, w.faces, pat.fans, hits, R_ws, p_ws, Rs, ps, scales, w.lidar.beam_divergence_mrad,
                w.lidar.return_separation_m, w.lidar.returns, w.lidar.retro_gain, w.lidar.pattern == "spinning")
        return hits, R_ws, p_ws, second

    def _lidar_frame_from(self, index: int, t_s: float, scene_poses, fixed_hits=None) -> Frame:
        w = self.world
        cfg, pat = w.lidar, self.lidar_pattern
        hits, R_ws, p_ws, second = self._lidar_hits(t_s, scene_poses, fixed_hits)
        sea = self.scenario.world.sea
        dirs_w = origin_z = None
        if sea.spray.probability > 0:  # only the spray needs the rays in world axes
            if len(R_ws) == 1:
                dirs_w, origin_z = pat.dirs_sensor @ R_ws[0].T, p_ws[0, 2]
            else:
                dirs_w, origin_z = np.einsum("kij,kj->ki", R_ws[pat.column], pat.dirs_sensor), p_ws[pat.column, 2]
        points, fields = lidar_measure(
            cfg, hits, pat, dirs_w, w.faces, w.sea_index, sea.clutter_probability, self._rng("lidar", index),
            spray=sea.spray, origin_z_world=origin_z, second_returns=second,
        )
        return Frame("lidar", index, t_s, points, fields)

    def radar_frame(self, index: int, t_s: float) -> Frame:
        w, cfg = self.world, self.world.radar
        R_ws, origins_w, dirs_w, hits, p_hit, v_hit, v_sensor = self._radar_hits(t_s)
        rng, ghosts = self._rng("radar", index), None
        if cfg.multipath_probability > 0:
            echoes = hits.hit & (hits.body != (-1 if w.sea_index is None else w.sea_index)) & (hits.range_m <= cfg.max_range_m)
            ghosts = multipath_ghosts(cfg, p_hit, v_hit, echoes, origins_w[0], v_sensor, R_ws, rng)
        points, fields = radar_measure(cfg, hits, self.radar_pattern, np.einsum("ij,ij->i", dirs_w, v_hit - v_sensor), w.faces,
                                       w.sea_index, self.scenario.world.sea.clutter_probability, rng, ghosts)
        return Frame("radar", index, t_s, points, fields)

    def _radar_hits(self, t_s: float):
        """The radar's rays at true time t_s: the sensor's rotation (3,3), the rays' origins and directions
        (K,3, world), their hits, the hit points and velocities and the sensor's velocity."""
        w = self.world
        states = w.body_states(np.array([t_s]))
        R_ws, p_ws = w.sensor_pose(states[0], "radar")
        dirs_w = self.radar_pattern.dirs_sensor @ R_ws[0].T
        origins_w = np.broadcast_to(p_ws[0], dirs_w.shape)
        hits = w.caster.cast(origins_w, dirs_w, *w.poses(states, 1))
        p_hit, v_hit, v_sensor = self._hit_motion(hits, dirs_w, origins_w, states)
        return R_ws[0], origins_w, dirs_w, hits, p_hit, v_hit, v_sensor

    def _hit_motion(self, hits, dirs_w, origins_w, states) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The hit points (world), their velocities (the sensor's where a beam met nothing: no
        range rate) and the sensor's, with both ships' translation and rotation."""
        crane = states[0]
        v_sensor = crane.point_velocity(origins_w[:1], 0)[0]
        ok = hits.hit
        p_hit = origins_w + dirs_w * np.where(ok, hits.range_m, 0.0)[:, None]
        v_hit = np.broadcast_to(v_sensor, dirs_w.shape).copy()
        for b, st in enumerate(states):
            m = ok & (hits.body == b)
            if m.any():
                v_hit[m] = 0.0 if st is None else st.point_velocity(p_hit[m], 0)
        return p_hit, v_hit, v_sensor

    # -- MRU and truth -------------------------------------------------------------------
    def _mru_log(self) -> MruLog:
        """The MRU as it really is: its specified noise, plus the world's unstated bias and lag
        (a sample stamped t holds the attitude of t - lag). The vessel's states are evaluated
        TRUTH_CHUNK samples at a time: all at once, a long run's would raise its peak memory."""
        cfg, mm = self.scenario.installation.mru, self.scenario.world.mismatch
        t = frame_times(cfg.rate_hz, self.scenario.duration_s + 1.0 / cfg.rate_hz)
        rpy, rate = np.empty((len(t), 3)), np.empty((len(t), 3))
        for a in range(0, len(t), TRUTH_CHUNK):
            st = self.world.crane_motion.states(t[a:a + TRUTH_CHUNK] - mm.mru_lag_s)
            rpy[a:a + TRUTH_CHUNK], rate[a:a + TRUTH_CHUNK] = st.rpy_rad, st.rpy_rate_radps
        rng = self._rng("mru", 0)
        rpy += np.deg2rad(mm.mru_bias_deg)
        rpy += np.deg2rad(cfg.angle_noise_deg) * rng.standard_normal(rpy.shape)
        rate += np.deg2rad(cfg.rate_noise_degps) * rng.standard_normal(rate.shape)
        real = self.scenario.world.mru
        rpy, rate = mru_faults(t, rpy, rate, real.glitches_s, np.deg2rad(real.glitch_rpy_deg), real.frozen_s)
        keep = ~in_windows(t, real.outages_s)
        return MruLog(t[keep], rpy[keep], rate[keep], max_gap_s=max(0.1, 5.0 / cfg.rate_hz))

    def _feeder_mru_log(self) -> MruLog:
        """The feeder's MRU: its body's attitude in its own heading frame (the world's, the
        feeder lying at heading 0), with the installation's stated noise and the world's
        unstated bias (the yaw's: the two heading references' offset) and lag."""
        cfg, real = self.scenario.installation.feeder_mru, self.scenario.world.feeder.mru
        t = frame_times(cfg.rate_hz, self.scenario.duration_s + 1.0 / cfg.rate_hz)
        st = self.world.feeder_motion.states(t - real.lag_s)
        rng = self._rng("feeder_mru", 0)
        rpy = st.rpy_rad + np.deg2rad(real.bias_deg) + np.deg2rad(cfg.angle_noise_deg) * rng.standard_normal(st.rpy_rad.shape)
        rate = st.rpy_rate_radps + np.deg2rad(cfg.rate_noise_degps) * rng.standard_normal(st.rpy_rad.shape)
        keep = ~in_windows(t, real.outages_s)
        return MruLog(t[keep], rpy[keep], rate[keep], max_gap_s=max(0.1, 5.0 / cfg.rate_hz))

    def _truth(self) -> Truth:
        """The truth table at the truth rate, made TRUTH_CHUNK rows at a time into files of its own."""
        s = self.scenario
        t = frame_times(s.world.truth_rate_hz, s.duration_s + 1.0 / s.world.truth_rate_hz)
        files, boom_tip_m = TrackFiles(), np.asarray(s.installation.crane.geometry.boom_tip_m)
        for a in range(0, len(t), TRUTH_CHUNK):
            crane = self.world.crane_motion.states(t[a:a + TRUTH_CHUNK])
            feeder = self.world.feeder_motion.states(t[a:a + TRUTH_CHUNK])
            p_tip, v_tip = tip_states(crane, boom_tip_m)
            D, D_dot = relative_heave(p_tip, v_tip, self.world.deck_plane_body, feeder)
            for col, v in (("D", D), ("D_dot", D_dot)):
                files.append(col, v)
            for name, st in zip(BODIES, (crane, feeder)):
                for i, ax in enumerate("xyz"):
                    files.append(f"{name}_{ax}", st.position_m[:, i])
                    files.append(f"{name}_v{ax}", st.velocity_mps[:, i])
                    files.append(f"{name}_w{ax}", st.omega_radps[:, i])
                for i, ang in enumerate(("roll", "pitch", "yaw")):
                    files.append(f"{name}_{ang}", st.rpy_rad[:, i])
        return StoredTruth(t, files, TRUTH_COLUMNS)
