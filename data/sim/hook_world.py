"""The hook scene (document 002): a crane vessel whose boom, rope and lower block move with
the crane's joints and the pendulum, seen by a spinning LiDAR at the boom tip.

The crane and hook truth is integrated once (data/sim/crane_truth.py, DOP853) over the whole run,
a chunk at a time; the tracks the frames, the logs and the truth table need go to temporary files
as they come, and are read back a window at a time: a run's memory does not grow with its length. The vessel's waves are the scenario's
`crane.motion.roll` and `crane.motion.pitch` about the vessel origin, as in data/motion.py.

Frames: the boom-tip frame has its origin at the tip and the axes of the vessel slewed by
nu + nu_f (it turns with the boom, stays level in luff); sensors mount on it with
`<sensor>.mount`. Hook positions relative to the tip are in world axes, which is what the
perception reports and the filter's LiDAR model h(x) = l u(a, b) predicts.
"""

from __future__ import annotations

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.data.sim.crane_programmes import HOOK_SCENARIOS
from boomtip.data.sim.crane_truth import crane_truth_chunks
from boomtip.data.sim.vessel_waves import CallableVesselMotion
from boomtip.data.frames import Frame, MruLog, Truth
from boomtip.data.block_model import lower_block_parts, rope_mesh
from boomtip.data.sim.run import SimulatedRun
from boomtip.data.sim.scene import Body, Label, Part, box, cylinder, lattice_boom, lofted_hull
from boomtip.data.sim.simulator import SENSOR_IDS, SimScene, Simulation, frame_times
from boomtip.data.sim.stored import TRUTH_CHUNK
from boomtip.data.stored_truth import StoredTruth, TrackFiles

BOOM_SHORT_OF_TIP_M = 2.0  # the lattice stops short of the tip: the sensors hang in free space
# the crane truth's tracks kept (on disk): the frames' poses (_scene_poses), the encoders and the truth table
RATE_STEP_S = 0.0025  # the radar's velocities by central differences over +-this (the truth's tracks: 200 Hz or more)
ENCODER_STREAM_ID = SENSOR_IDS["mru"] + 10  # the encoders' noise stream (after the sensors' ids)
KEPT_TRACKS = ("roll", "pitch", "nu", "mu", "l", "nu_f", "a", "b", "p_tip_world", "p_hook_world", "v_hook_world",
               "p_hook_rel_tip", "v_hook_rel_tip")


def crane_params(s: SimulatedRun) -> CraneParams:
    """The crane as it really is: the installation's nominal parameters times the world's
    mismatch factors (geometry as surveyed); in the lift, the load's true mass on the hook."""
    c, mm = s.installation.crane, s.world.mismatch
    load_kg = s.world.lift.mass_kg() if s.world.lift.enabled else 0.0
    return CraneParams(
        m=c.dynamics.hook_mass_kg * mm.hook_mass + load_kg, m_b=c.dynamics.boom_mass_kg * mm.boom_mass, L=c.geometry.boom_length_m, b=c.geometry.boom_foot_offset_m,
        h=c.geometry.boom_foot_height_m, c=c.geometry.crane_base_m, k_f=c.dynamics.boom_stiffness_nm_per_rad * mm.boom_stiffness,
        c_f=c.dynamics.boom_damping * mm.boom_damping, flexible=s.world.hook.flexible,
    )


def _hook_vessel(s: SimulatedRun) -> Body:
    """The crane vessel: hull, deck, accommodation, pedestal and crane house (no boom: the
    boom is its own moving body), and cargo on deck for the hook to pass over."""
    g = s.world.crane.geometry
    deck_z = g.freeboard_m
    hull, is_deck = lofted_hull(g.length_m, g.beam_m, -g.draft_m, deck_z, bow_length_m=0.15 * g.length_m, n_stations=90)
    cx, cy, cz = s.installation.crane.geometry.crane_base_m
    x_acc = -0.38 * g.length_m  # accommodation aft, out of the way of the boom
    parts = [
        Part(hull, Label.CRANE_HULL, 0.25, face_label=np.where(is_deck, int(Label.CRANE_DECK), int(Label.CRANE_HULL))),
        Part(box([x_acc, 0, deck_z + 10], [24, 0.8 * g.beam_m, 20]), Label.CRANE_STRUCTURE, 0.6),
        Part(cylinder(6.0, s.installation.crane.geometry.boom_foot_height_m, [cx, cy, cz + s.installation.crane.geometry.boom_foot_height_m / 2]), Label.CRANE_STRUCTURE, 0.5),
    ]
    if s.world.hook.deck_cargo:
        for x, y in ((-10.0, 8.0), (5.0, -10.0), (20.0, 10.0), (80.0, 0.0)):
            parts.append(Part(box([x, y, deck_z + 1.3], [12.2, 2.44, 2.6]), Label.CARGO, 0.4))
        parts.append(Part(cylinder(3.0, 9.0, [-40.0, -8.0, deck_z + 4.5]), Label.CARGO, 0.55))
    return Body.from_parts("crane", parts)


def hook_bodies(s: SimulatedRun) -> list[Body]:
    L = s.installation.crane.geometry.boom_length_m
    boom = lattice_boom([0.0, 0.0, 0.0], [L - BOOM_SHORT_OF_TIP_M, 0.0, 0.0], 6.0, 2.0, panels=48, member=0.5)
    return [
        _hook_vessel(s),
        Body.from_parts("boom", [Part(boom, Label.CRANE_STRUCTURE, 0.5)]),
        Body.from_parts("block", lower_block_parts(s.installation.crane.block_height_m)),
        Body.from_parts("rope", [Part(rope_mesh(s.installation.crane.rope_radius_m), Label.ROPE, 0.3)]),
    ]


def rot_z(theta) -> np.ndarray:
    """Rotation(s) about z by theta (any shape): (..., 3, 3)."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _ry(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 2], R[..., 2, 0], R[..., 2, 2], R[..., 1, 1] = c, s, -s, c, 1.0
    return R


def hanging_rotation(u: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Block frames (M,3,3): z along -u (up the rope), x along the heading projected."""
    z = -u / np.linalg.norm(u, axis=-1, keepdims=True)
    x = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)], -1)
    x = x - np.sum(x * z, axis=-1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


class HookSimulation(Simulation):
    """A hook scenario simulated in memory: LiDAR frames, MRU and encoder logs, hook truth."""

    def __init__(self, scenario: SimulatedRun) -> None:
        if not (scenario.world.hook.enabled or scenario.world.lift.enabled):
            raise ValueError(f"scenario '{scenario.name}': world.hook.enabled is false; use Simulation")
        self.params = crane_params(scenario)
        world = SimScene(scenario, self._bodies(scenario))
        joints = self._joints(scenario)
        bank = world.crane_motion.bank  # DOF order: surge sway heave roll pitch yaw

        def dof(i):
            return lambda t: (bank.eval(np.atleast_1d(t))[:, i].reshape(np.shape(t)),
                              bank.eval(np.atleast_1d(t), 1)[:, i].reshape(np.shape(t)),
                              bank.eval(np.atleast_1d(t), 2)[:, i].reshape(np.shape(t)))

        self._tracks = TrackFiles()
        t_crane = []
        for crane in crane_truth_chunks(
            self.params, joints, CallableVesselMotion(dof(3), dof(4)),
            duration_s=scenario.duration_s + 0.5, record_rate_hz=max(scenario.world.truth_rate_hz, 200.0),
            # richer than the filter's model: an elastic reeving and the wind on block and load
            rope_ea_n=scenario.world.mismatch.rope_ea_n, wind_mps=scenario.world.mismatch.wind_mps,
            drag_area_m2=scenario.world.hook.drag_area_m2,
            gust_seed=scenario.seed if scenario.world.mismatch.wind_gusts else None,
        ):
            t_crane.append(crane.t)
            for name in KEPT_TRACKS:
                self._tracks.append(name, getattr(crane, name))
        self._t_crane = np.concatenate(t_crane)
        super().__init__(scenario, world)
        self.encoders = self._encoder_log()

    def _bodies(self, scenario: SimulatedRun) -> list[Body]:
        return hook_bodies(scenario)

    def _joints(self, scenario: SimulatedRun):
        return HOOK_SCENARIOS[scenario.world.hook.program](self.params).joints

    def _vessel_translation(self, times: np.ndarray) -> np.ndarray:
        """The crane vessel's surge, sway and heave (M,3): none in the hook scene, whose vessel
        turns about its origin (document 002)."""
        return np.zeros((len(times), 3))

    def _hook_rel_tip(self, times: np.ndarray) -> np.ndarray:
        """The hook's reference point relative to the tip, world axes (M,3)."""
        return self._interp("p_hook_rel_tip", times)

    # The MRU and encoder logs on disk too, each read back whole when asked for: a chain copies
    # what it needs once, and no second copy stays for the whole run (700 s: 10 MB).
    @property
    def mru(self) -> MruLog:
        return MruLog(*(self._logs.read(f"mru_{k}") for k in ("t", "rpy", "rate")), max_gap_s=self._mru_max_gap_s)

    @mru.setter
    def mru(self, log: MruLog) -> None:
        # at set-up, and again when processing screens it (before any worker reads the files)
        for k, v in (("t", log.t_s), ("rpy", log.rpy_rad), ("rate", log.rpy_rate_radps)):
            self._log_files().replace(f"mru_{k}", v)
        self._mru_max_gap_s = log.max_gap_s

    @property
    def encoders(self) -> dict[str, np.ndarray]:
        return {k: self._logs.read(f"encoders_{k}") for k in self._encoder_keys}

    @encoders.setter
    def encoders(self, log: dict[str, np.ndarray]) -> None:
        if hasattr(self, "_encoder_keys"):
            raise AttributeError("a hook simulation's encoder log is made once, at set-up")
        for k, v in log.items():
            self._log_files().append(f"encoders_{k}", v)
        self._encoder_keys = tuple(log)

    def _log_files(self) -> TrackFiles:
        if not hasattr(self, "_logs"):
            self._logs = TrackFiles()
        return self._logs

    # -- poses from the crane truth ------------------------------------------------------
    def _interp(self, name: str, t: np.ndarray) -> np.ndarray:
        return self._tracks.interp(name, t, self._t_crane)

    def _scene_poses(self, times: np.ndarray, sensor: str):
        roll, pitch = self._interp("roll", times), self._interp("pitch", times)
        nu, mu, nu_f = self._interp("nu", times), self._interp("mu", times), self._interp("nu_f", times)
        R_v = _ry(pitch) @ _rx(roll)  # R = Rz(yaw) Ry(pitch) Rx(roll) with yaw = 0
        base = np.asarray(self.params.c)
        foot_v = base + self.params.b * np.stack([np.cos(nu), np.sin(nu), np.zeros_like(nu)], -1) + [0, 0, self.params.h]
        R_tipframe = R_v @ rot_z(nu + nu_f)
        R_boom = R_tipframe @ _ry(-mu)
        shift = self._vessel_translation(times)
        p_tip = self._interp("p_tip_world", times) + shift
        r_hook = self._hook_rel_tip(times)
        p_hook = p_tip + r_hook
        R_block = hanging_rotation(r_hook, nu + nu_f)
        l = np.linalg.norm(r_hook, axis=-1)
        m = len(times)
        Rs = [R_v, R_boom, R_block, R_block]
        ps = [shift, np.einsum("nij,nj->ni", R_v, foot_v) + shift, p_hook, p_hook]
        scales = [None, None, None, np.stack([np.ones(m), np.ones(m), l], -1)]
        T_ts = self.world.T_boomtip_sensor[sensor]
        R_ws = R_tipframe @ T_ts[:3, :3]
        p_ws = p_tip + np.einsum("nij,j->ni", R_tipframe, T_ts[:3, 3])
        return R_ws, p_ws, Rs, ps, scales

    def lidar_frame(self, index: int, t_s: float) -> Frame:
        return self._lidar_frame_from(index, t_s, self._scene_poses)

    def _radar_hits(self, t_s: float):
        """As in Simulation, with the bodies' and the sensor's velocities by central differences of
        their poses over +-RATE_STEP_S: the crane's truth is a table, not a closed form. Every hit
        point keeps its place in its body (scaled: the rope's length) from t - step to t + step."""
        R_ws, p_ws, Rs, ps, scales = self._scene_poses(t_s + np.array([-RATE_STEP_S, 0.0, RATE_STEP_S]), "radar")
        dirs_w = self.radar_pattern.dirs_sensor @ R_ws[1].T
        origins_w = np.broadcast_to(p_ws[1], dirs_w.shape)
        hits = self.world.caster.cast(origins_w, dirs_w, [R[1:2] for R in Rs], [p[1:2] for p in ps],
                                      scale_body=[None if sc is None else sc[1:2] for sc in scales])
        scales = [np.ones((3, 3)) if sc is None else np.asarray(sc) for sc in scales]
        v_sensor = (p_ws[2] - p_ws[0]) / (2 * RATE_STEP_S)
        p_hit = origins_w + dirs_w * np.where(hits.hit, hits.range_m, 0.0)[:, None]
        v_hit = np.broadcast_to(v_sensor, dirs_w.shape).copy()
        for b in np.unique(hits.body[hits.hit]):
            m = hits.hit & (hits.body == b)
            local = ((p_hit[m] - ps[b][1]) @ Rs[b][1]) / scales[b][1]  # the body's own frame
            ends = [ps[b][k] + (local * scales[b][k]) @ Rs[b][k].T for k in (0, 2)]
            v_hit[m] = (ends[1] - ends[0]) / (2 * RATE_STEP_S)
        return R_ws[1], origins_w, dirs_w, hits, p_hit, v_hit, v_sensor

    # -- logs ----------------------------------------------------------------------------
    def _encoder_log(self) -> dict[str, np.ndarray]:
        """The encoders as they are: specified noise plus the world's unstated biases."""
        cfg, bias = self.scenario.installation.encoders, self.scenario.world.mismatch.encoder_bias_deg
        t = frame_times(cfg.rate_hz, self.scenario.duration_s + 1.0 / cfg.rate_hz)
        rng = np.random.default_rng([self.scenario.seed, ENCODER_STREAM_ID, 0])
        n = len(t)
        ang = np.deg2rad(cfg.angle_noise_deg)
        return {
            "t": t,
            "slew": self._interp("nu", t) + np.deg2rad(bias.slew) + ang * rng.standard_normal(n),
            "luff": self._interp("mu", t) + np.deg2rad(bias.luff) + ang * rng.standard_normal(n),
            "hoist": self._interp("l", t) + cfg.hoist_noise_m * rng.standard_normal(n),
        }

    def _truth(self) -> Truth:
        """The truth table at the truth rate, made a chunk of rows at a time into files of its own.
        The hook's and the tip's world positions are in the frame the hook chain estimates them
        in: turning with the vessel's roll and pitch about its origin, not moving with its surge,
        sway and heave (an MRU measures no translation; see `_vessel_translation`)."""
        s = self.scenario
        t = frame_times(s.world.truth_rate_hz, s.duration_s + 1.0 / s.world.truth_rate_hz)
        files = TrackFiles()
        for a in range(0, len(t), TRUTH_CHUNK):
            tc = t[a:a + TRUTH_CHUNK]
            for prefix, name in (("hook_", "p_hook_world"), ("hook_v", "v_hook_world"), ("hook_rel_", "p_hook_rel_tip"),
                                 ("hook_rel_v", "v_hook_rel_tip"), ("tip_", "p_tip_world")):
                v = self._interp(name, tc)
                for k, ax in enumerate("xyz"):
                    files.append(f"{prefix}{ax}", v[:, k])
            for col, name in (("slew", "nu"), ("luff", "mu"), ("hoist", "l"), ("boom_deflection", "nu_f"),
                              ("sway_a", "a"), ("sway_b", "b"), ("crane_roll", "roll"), ("crane_pitch", "pitch")):
                files.append(col, self._interp(name, tc))
        return StoredTruth(t, files)


def _rx(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2], R[..., 0, 0] = c, -s, s, c, 1.0
    return R
