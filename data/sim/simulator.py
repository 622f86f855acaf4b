"""Live simulation: the scenario's scene, moved by ship motion and ray cast into frames.

`Simulation` is a FrameSource, so the pipeline consumes it exactly like a recording.
Every random draw takes a seed derived from the scenario seed, the sensor and the frame
number, so a frame is the same whatever order frames are generated in.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from boomtip.data.frames import BODIES, TRUTH_COLUMNS, Frame, FrameSource, MruLog, SourceMeta, Truth
from boomtip.data.sim.motion import BodyStates, ShipMotion
from boomtip.data.sim.raycast import RayCaster
from boomtip.data.scenario import Mount, Scenario
from boomtip.data.sim.scene import Body, build_bodies, feeder_deck_plane_body
from boomtip.data.sim.sensors import FaceLookup, lidar_measure, lidar_pattern, radar_measure, radar_pattern
from boomtip.data.sim.truth import relative_heave, tip_states

SENSOR_IDS = {"lidar": 1, "radar": 2, "mru": 3}


def mount_matrix(m: Mount) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", m.rpy_deg, degrees=True).as_matrix()
    T[:3, 3] = m.xyz_m
    return T


def frame_times(rate_hz: float, duration_s: float) -> np.ndarray:
    n = int(np.floor(duration_s * rate_hz + 1e-9))
    return np.arange(n) / rate_hz


class World:
    """Bodies, their motion, and the mount chain crane -> boom tip -> sensor."""

    def __init__(self, scenario: Scenario, bodies: list[Body] | None = None) -> None:
        s = scenario
        self.scenario = s
        self.bodies = bodies if bodies is not None else build_bodies(s)
        self.caster = RayCaster(self.bodies)
        self.faces = FaceLookup.from_bodies(self.bodies)
        self.crane_motion = ShipMotion(s.crane.motion, s.crane.irregular, (0.0, 0.0, 0.0), seed=s.seed * 7 + 11)
        self.feeder_motion = ShipMotion(s.feeder.motion, s.feeder.irregular, s.feeder.geometry.position_m, seed=s.seed * 7 + 13)
        self.T_crane_boomtip = np.eye(4)
        self.T_crane_boomtip[:3, 3] = s.crane.geometry.boom_tip_m
        self.T_boomtip_sensor = {"lidar": mount_matrix(s.lidar.mount), "radar": mount_matrix(s.radar.mount)}
        self.deck_plane_body = feeder_deck_plane_body(s)
        self.sea_index = next((i for i, b in enumerate(self.bodies) if b.name == "sea"), None)

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


class Simulation(FrameSource):
    """A scenario simulated in memory, frame by frame."""

    def __init__(self, scenario: Scenario, world: World | None = None) -> None:
        self.scenario = scenario
        self.world = world or World(scenario)
        w = self.world
        self.meta = SourceMeta(scenario, w.T_crane_boomtip, dict(w.T_boomtip_sensor), w.deck_plane_body)
        self.lidar_pattern = lidar_pattern(scenario.lidar)
        self.radar_pattern = radar_pattern(scenario.radar)
        self._schedule = self._frame_schedule()
        self.mru = self._mru_log()
        self.truth = self._truth()

    # -- schedule ------------------------------------------------------------------------
    def _frame_schedule(self) -> list[tuple[float, str, int]]:
        s = self.scenario
        items = []
        for sensor, cfg in (("lidar", s.lidar), ("radar", s.radar)):
            if cfg.enabled:
                items += [(float(t), sensor, i) for i, t in enumerate(frame_times(cfg.rate_hz, s.duration_s))]
        return sorted(items)

    def __len__(self) -> int:
        return len(self._schedule)

    def __iter__(self) -> Iterator[Frame]:
        for t, sensor, i in self._schedule:
            yield self.lidar_frame(i, t) if sensor == "lidar" else self.radar_frame(i, t)

    def _rng(self, sensor: str, index: int) -> np.random.Generator:
        return np.random.default_rng([self.scenario.seed, SENSOR_IDS[sensor], index])

    # -- sensors -------------------------------------------------------------------------
    def _scene_poses(self, times: np.ndarray, sensor: str):
        """Sensor pose (R (M,3,3), p (M,3)) and every body's pose (lists of (M,3,3), (M,3),
        and per-body axis scales or None) at the given times."""
        w = self.world
        states = w.body_states(times)
        R_ws, p_ws = w.sensor_pose(states[0], sensor)
        Rs, ps = w.poses(states, len(times))
        return R_ws, p_ws, Rs, ps, None

    def lidar_frame(self, index: int, t_s: float) -> Frame:
        return self._lidar_frame_from(index, t_s, self._scene_poses, self._sensor_fixed_hits("lidar"))

    def _sensor_fixed_hits(self, sensor: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
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

    def _lidar_frame_from(self, index: int, t_s: float, scene_poses, fixed_hits=None) -> Frame:
        cfg, pat, w = self.scenario.lidar, self.lidar_pattern, self.world
        if cfg.motion_during_sweep:
            times = t_s + pat.column_time_s
            pose_index = pat.column
        else:
            times = np.array([t_s])
            pose_index = None
        R_ws, p_ws, Rs, ps, scales = scene_poses(times, "lidar")
        if pose_index is None:
            dirs_w = pat.dirs_sensor @ R_ws[0].T
            origins_w = p_ws[0]
        else:
            dirs_w = np.einsum("kij,kj->ki", R_ws[pose_index], pat.dirs_sensor)
            origins_w = p_ws[pose_index]
        hits = w.caster.cast(origins_w, dirs_w, Rs, ps, pose_index, scales, fixed_hits)
        points, fields = lidar_measure(
            cfg, hits, pat, dirs_w, w.faces, w.sea_index, self.scenario.sea.clutter_probability, self._rng("lidar", index)
        )
        return Frame("lidar", index, t_s, points, fields)

    def radar_frame(self, index: int, t_s: float) -> Frame:
        cfg, pat, w = self.scenario.radar, self.radar_pattern, self.world
        states = w.body_states(np.array([t_s]))
        R_ws, p_ws = w.sensor_pose(states[0], "radar")
        dirs_w = pat.dirs_sensor @ R_ws[0].T
        origins_w = np.broadcast_to(p_ws[0], dirs_w.shape)
        Rs, ps = w.poses(states, 1)
        hits = w.caster.cast(origins_w, dirs_w, Rs, ps)
        range_rate = self._range_rate(hits, dirs_w, origins_w, states)
        points, fields = radar_measure(
            cfg, hits, pat, range_rate, w.faces, w.sea_index, self.scenario.sea.clutter_probability, self._rng("radar", index)
        )
        return Frame("radar", index, t_s, points, fields)

    def _range_rate(self, hits, dirs_w, origins_w, states) -> np.ndarray:
        """d(range)/dt of each hit: the beam projection of the hit point's velocity relative
        to the sensor, with both ships' translation and rotation."""
        crane = states[0]
        v_sensor = crane.point_velocity(origins_w[:1], 0)[0]
        rr = np.zeros(len(dirs_w))
        ok = hits.hit
        p_hit = origins_w + dirs_w * np.where(ok, hits.range_m, 0.0)[:, None]
        for b, st in enumerate(states):
            m = ok & (hits.body == b)
            if not m.any():
                continue
            v_hit = np.zeros((m.sum(), 3)) if st is None else st.point_velocity(p_hit[m], 0)
            rr[m] = np.einsum("ij,ij->i", dirs_w[m], v_hit - v_sensor)
        return rr

    # -- MRU and truth -------------------------------------------------------------------
    def _mru_log(self) -> MruLog:
        cfg = self.scenario.mru
        t = frame_times(cfg.rate_hz, self.scenario.duration_s + 1.0 / cfg.rate_hz)
        st = self.world.crane_motion.states(t)
        rng = self._rng("mru", 0)
        rpy = st.rpy_rad + np.deg2rad(cfg.angle_noise_deg) * rng.standard_normal(st.rpy_rad.shape)
        rate = st.rpy_rate_radps + np.deg2rad(cfg.rate_noise_degps) * rng.standard_normal(st.rpy_rad.shape)
        return MruLog(t, rpy, rate, max_gap_s=max(0.1, 5.0 / cfg.rate_hz))

    def _truth(self) -> Truth:
        s = self.scenario
        t = frame_times(s.truth_rate_hz, s.duration_s + 1.0 / s.truth_rate_hz)
        crane = self.world.crane_motion.states(t)
        feeder = self.world.feeder_motion.states(t)
        p_tip, v_tip = tip_states(crane, np.asarray(s.crane.geometry.boom_tip_m))
        D, D_dot = relative_heave(p_tip, v_tip, self.world.deck_plane_body, feeder)
        cols: dict[str, np.ndarray] = {"t": t, "D": D, "D_dot": D_dot}
        for name, st in zip(BODIES, (crane, feeder)):
            for i, ax in enumerate("xyz"):
                cols[f"{name}_{ax}"] = st.position_m[:, i]
                cols[f"{name}_v{ax}"] = st.velocity_mps[:, i]
                cols[f"{name}_w{ax}"] = st.omega_radps[:, i]
            for i, ang in enumerate(("roll", "pitch", "yaw")):
                cols[f"{name}_{ang}"] = st.rpy_rad[:, i]
        return Truth({k: cols[k] for k in TRUTH_COLUMNS})
