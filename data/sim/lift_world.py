"""The lift: the hook scene's crane (vessel, boom, rope, block) working over the moving feeder,
a load hanging from the hook on slings, lowered and set down on the feeder's deck.

The crane and its pendulum are the hook scene's (data/sim/hook_world.py, document 002's model,
the load's mass on the hook) under `world.lift.program` (data/sim/lift_programme.py). Beyond the
hook scene, the crane vessel heaves, surges and sways as its waves say: the whole crane moves with
it, and the pendulum feels the vessel's roll and pitch as in document 002 (its heave only changes
the rope's tension, which the model does not carry).

The load hangs below the block, turning with it, until its lowest point first meets the deck
below it: from then on it lies flat on the deck at that spot and moves with the feeder, and the
block comes down no lower than the slings standing on the load (the rope goes slack).
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.frames import LIFT_TRUTH_COLUMNS, Truth
from boomtip.data.meshes import Label
from boomtip.data.sim.hook_world import HookSimulation, hanging_rotation, hook_bodies, rot_z
from boomtip.data.sim.lift_programme import LiftPlan
from boomtip.data.sim.load_mesh import load_parts
from boomtip.data.poses import matrices_rpy, rpy_matrices
from boomtip.data.sim.run import SimulatedRun
from boomtip.data.sim.scene import Body, feeder_vessel, sea_surface
from boomtip.data.sim.simulator import frame_times
from boomtip.data.sim.stored import TRUTH_CHUNK
from boomtip.data.stored_truth import StoredTruth



def height_above_deck(points_world: np.ndarray, R_feeder: np.ndarray, p_feeder: np.ndarray,
                      deck_z_body: float) -> np.ndarray:
    """Each point's height above the deck plane straight below it, for points (M,V,3) or (M,3)
    at M instants: the deck is the plane z = deck_z_body of the feeder's body frame, posed by
    R_feeder (M,3,3), p_feeder (M,3)."""
    n = R_feeder[:, :, 2]  # the deck's normal, world
    pts = points_world if points_world.ndim == 3 else points_world[:, None, :]
    h = (np.einsum("mvk,mk->mv", pts - p_feeder[:, None, :], n) - deck_z_body) / n[:, None, 2]
    return h if points_world.ndim == 3 else h[:, 0]


def clearance_to_deck(vertices_world: np.ndarray, centre_world: np.ndarray, R_feeder: np.ndarray, p_feeder: np.ndarray,
                      deck_z_body: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each instant, the load's clearance (its lowest vertex's height above the deck below
    it; vertices (M,V,3), world) and its landing point: its underside's centre (M,3) dropped
    straight onto the deck, in the feeder's body frame (x, y) and in the world: ((M,), (M,2), (M,3))."""
    clearance = height_above_deck(vertices_world, R_feeder, p_feeder, deck_z_body).min(axis=1)
    touch = centre_world - height_above_deck(centre_world, R_feeder, p_feeder, deck_z_body)[:, None] * np.array([0.0, 0.0, 1.0])
    return clearance, np.einsum("mji,mj->mi", R_feeder, touch - p_feeder)[:, :2], touch


def _gradient_apart(v: np.ndarray, dt_s: float, split: np.ndarray) -> np.ndarray:
    """np.gradient of v on either side of where the mask `split` turns on, each side alone."""
    out = np.zeros_like(v)
    for side in (~split, split):
        if np.count_nonzero(side) >= 2:
            out[side] = np.gradient(v[side], dt_s)
    return out


class LiftSimulation(HookSimulation):
    """A lift scenario simulated in memory: LiDAR frames, MRU and encoder logs, the hook's and
    the load's truth."""

    def __init__(self, scenario: SimulatedRun) -> None:
        lift = scenario.world.lift
        self.load_size_m = lift.size()
        self.below_hook_m = scenario.installation.crane.block_height_m + lift.sling_height_m + self.load_size_m[2]
        self._touchdown: tuple | None = None
        super().__init__(scenario)

    def _bodies(self, scenario: SimulatedRun) -> list[Body]:
        lift = scenario.world.lift
        parts = load_parts(lift.load, lift.size(), lift.sling_height_m)
        self.load_vertices_body = np.concatenate([p.mesh.vertices for p in parts if p.label == Label.LOAD])
        bodies = hook_bodies(scenario) + [Body.from_parts("load", parts), feeder_vessel(scenario)]
        if scenario.world.sea.clutter:
            bodies.append(sea_surface(scenario))
        return bodies

    def _joints(self, scenario: SimulatedRun):
        self.plan = LiftPlan(scenario, self.params)
        return self.plan.joints

    def _vessel_translation(self, times: np.ndarray) -> np.ndarray:
        return self.world.crane_motion.bank.eval(times)[:, :3]

    # -- the load ------------------------------------------------------------------------
    def _feeder_pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = self.world.feeder_motion.bank.eval(times)
        return rpy_matrices(q[:, 3:]), self.world.feeder_motion.rest_position_m + q[:, :3]

    def _hanging(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The hanging load's rotation and underside centre, and the hook's reference point (world)."""
        r_hook = self._interp("p_hook_rel_tip", times)
        p_hook = self._interp("p_tip_world", times) + self._vessel_translation(times) + r_hook
        R = hanging_rotation(r_hook, self._interp("nu", times) + self._interp("nu_f", times))
        return R, p_hook - self.below_hook_m * R[:, :, 2], p_hook

    def _clearance(self, R_load, p_load, R_f, p_f):
        v = p_load[:, None, :] + np.einsum("mij,vj->mvi", R_load, self.load_vertices_body)
        return clearance_to_deck(v, p_load, R_f, p_f, self.scenario.world.feeder.geometry.freeboard_m)

    def touchdown(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(t, R, p): when the load first meets the deck (inf: never), and its pose from then
        on in the feeder's body frame (lying flat where it met the deck, turned as it hung)."""
        if self._touchdown is None:
            self._touchdown = (math.inf, np.eye(3), np.zeros(3))
            s = self.scenario
            t = frame_times(s.world.truth_rate_hz, s.duration_s + 1.0)
            for a in range(0, len(t), TRUTH_CHUNK):
                tc = t[a:a + TRUTH_CHUNK]
                R, p, _ = self._hanging(tc)
                C, _, _ = self._clearance(R, p, *self._feeder_pose(tc))
                down = np.flatnonzero(C <= 0.0)
                if len(down):
                    k = down[0]
                    t_td = tc[k] if k == 0 else float(np.interp(0.0, [C[k], C[k - 1]], [tc[k], tc[k - 1]]))
                    R1, p1, _ = self._hanging(np.array([t_td]))
                    R_f, p_f = self._feeder_pose(np.array([t_td]))
                    R_rel = R_f[0].T @ R1[0]
                    p_rel = R_f[0].T @ (p1[0] - p_f[0])
                    p_rel[2] = s.world.feeder.geometry.freeboard_m
                    self._touchdown = (t_td, rot_z(math.atan2(R_rel[1, 0], R_rel[0, 0])), p_rel)
                    break
        return self._touchdown

    def load_pose(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The load's rotation (M,3,3) and underside centre (M,3), world: hanging, then landed."""
        R, p, _ = self._hanging(times)
        t_td, R_lf, p_lf = self.touchdown()
        landed = times >= t_td
        if landed.any():
            R_f, p_f = self._feeder_pose(times[landed])
            R[landed] = R_f @ R_lf
            p[landed] = p_f + R_f @ p_lf
        return R, p

    def _hook_rel_tip(self, times: np.ndarray) -> np.ndarray:
        """The hook's reference point relative to the tip; once the load has landed, no lower
        than the slings standing on it (the rope slack)."""
        r = self._interp("p_hook_rel_tip", times)
        t_td, _, _ = self.touchdown()
        landed = times >= t_td
        if landed.any():
            p_tip = self._interp("p_tip_world", times[landed]) + self._vessel_translation(times[landed])
            R, p = self.load_pose(times[landed])
            z_min = p[:, 2] + R[:, 2, 2] * self.below_hook_m - p_tip[:, 2]
            r[landed, 2] = np.maximum(r[landed, 2], z_min)
        return r

    def _scene_poses(self, times: np.ndarray, sensor: str):
        R_ws, p_ws, Rs, ps, scales = super()._scene_poses(times, sensor)
        R_load, p_load = self.load_pose(times)
        R_f, p_f = self._feeder_pose(times)
        m = len(times)
        Rs, ps, scales = Rs + [R_load, R_f], ps + [p_load, p_f], scales + [None, None]
        if len(self.world.bodies) > len(Rs):  # the sea, static in the world
            Rs, ps, scales = Rs + [np.broadcast_to(np.eye(3), (m, 3, 3))], ps + [np.zeros((m, 3))], scales + [None]
        return R_ws, p_ws, Rs, ps, scales

    # -- truth ---------------------------------------------------------------------------
    def _truth(self) -> Truth:
        """The hook scene's truth (the hook where the slack rope leaves it), and the load's."""
        hook_truth = super()._truth()
        t, files = hook_truth._t, hook_truth._files
        t_td, _, _ = self.touchdown()
        for a0 in range(0, len(t), TRUTH_CHUNK):
            tc = t[a0:a0 + TRUTH_CHUNK]
            R, p = self.load_pose(tc)
            pose_f = self._feeder_pose(tc)
            C, landing, touch = self._clearance(R, p, *pose_f)
            C = np.where(tc >= t_td, 0.0, C)
            centre = np.where(tc >= t_td, 0.0, height_above_deck(p, *pose_f, self.scenario.world.feeder.geometry.freeboard_m))
            tip = np.column_stack([files.read(f"tip_{a}", a0, a0 + len(tc)) for a in "xyz"]) + self._vessel_translation(tc)
            rel = touch[:, :2] - tip[:, :2]
            feeder_rel, feeder_rpy = pose_f[1] - tip, matrices_rpy(pose_f[0])  # the feeder's pose at the tip, world axes
            for name, v in (("clearance", C), ("centre_clearance", centre), ("landing_x", landing[:, 0]), ("landing_y", landing[:, 1]),
                            ("landing_rel_x", rel[:, 0]), ("landing_rel_y", rel[:, 1]),
                            ("feeder_rel_x", feeder_rel[:, 0]), ("feeder_rel_y", feeder_rel[:, 1]),
                            ("feeder_rel_z", feeder_rel[:, 2]), ("feeder_roll", feeder_rpy[:, 0]),
                            ("feeder_pitch", feeder_rpy[:, 1]), ("feeder_yaw", feeder_rpy[:, 2]),
                            ("load_x", p[:, 0]), ("load_y", p[:, 1]), ("load_z", p[:, 2]),
                            ("contact", (tc >= t_td).astype(float))):
                files.append(name, v)
        dt = 1.0 / self.scenario.world.truth_rate_hz
        landed = t >= t_td
        # rates on each side of the touchdown apart: the load lies down flat there (a step in
        # the centre's height), which a difference across it would make a spike
        files.replace("clearance_rate", _gradient_apart(files.read("clearance"), dt, landed))
        files.replace("relative_vz", _gradient_apart(files.read("centre_clearance"), dt, landed))
        if landed.any():  # the slack rope: the hook's reference point as the scene poses it
            r = self._hook_rel_tip(t)
            for k, a in enumerate("xyz"):
                tip = files.read(f"tip_{a}")
                for prefix, v in (("hook_rel_", r[:, k]), ("hook_", tip + r[:, k])):
                    pos, vel = files.read(f"{prefix}{a}"), files.read(f"{prefix}v{a}")
                    pos[landed], vel[landed] = v[landed], np.gradient(v, dt)[landed]
                    files.replace(f"{prefix}{a}", pos)
                    files.replace(f"{prefix}v{a}", vel)
        return StoredTruth(t, files, LIFT_TRUTH_COLUMNS)
