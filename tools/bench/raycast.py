"""bench raycast: the simulated LiDAR frame against Open3D's raw cast of the same rays, with
the hits checked against the per-ray reference. Each measures boomtip and a baseline on the
same input in the same run and reports the ratio."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from boomtip.tools.config.scenario import Scenario


SPINNING_128x1024 = ["lidar.pattern=spinning", "lidar.channels=128", "lidar.columns=1024", "lidar.motion_during_sweep=true"]


def reference_lidar_hits(sim, t_s: float, fixed_hits=None):
    """The LiDAR's hits the straightforward way, without fans: every ray in world axes (its
    column's pose with motion during the sweep), moved into each body's frame ray by ray,
    every ray cast into every body (`RayCaster.cast`)."""
    w, pat = sim.world, sim.lidar_pattern
    if w.lidar.motion_during_sweep:
        times, pose_index = t_s + pat.column_time_s, pat.column
    else:
        times, pose_index = np.array([t_s]), None
    R_ws, p_ws, Rs, ps, scales = sim._scene_poses(times, "lidar")
    if pose_index is None:
        dirs_w, origins_w = pat.dirs_sensor @ R_ws[0].T, p_ws[0]
    else:
        dirs_w, origins_w = np.einsum("kij,kj->ki", R_ws[pose_index], pat.dirs_sensor), p_ws[pose_index]
    return w.caster.cast(origins_w, dirs_w, Rs, ps, pose_index, scales, fixed_hits)


def hits_difference(a, b, tol_m: float = 1e-4) -> dict:
    """Rays whose hits differ: another body or face, a hit against a miss, or ranges apart by more than tol_m."""
    both = np.isfinite(a.range_m) & np.isfinite(b.range_m)
    differ = (a.body != b.body) | (a.face != b.face) | (np.isfinite(a.range_m) != np.isfinite(b.range_m))
    gap = np.abs(a.range_m[both] - b.range_m[both])
    differ[both] |= gap > tol_m
    return {"rays": len(differ), "different": int(differ.sum()), "max_range_diff_m": float(gap.max(initial=0.0))}


def raw_cast_efficiency(scenario: Scenario, frames: int, repeats: int = 30) -> dict:
    """Simulated LiDAR frames (cast and sensor model) per second against Open3D's raw
    `cast_rays` of the same world rays into one static scene holding every body posed at the
    frame's instant (the cast alone: the scene is built and committed untimed). Per frame the
    two run alternately `repeats` times and the fastest of each counts: on a busy machine a
    frame is often interrupted, the longer (single-threaded) one more often, and the fastest
    of many runs is the one that was not. The hits are checked against `reference_lidar_hits`."""
    import open3d as o3d

    from boomtip.data.sim.simulator import Simulation

    sim = Simulation(scenario)
    w, pat = sim.world, sim.lidar_pattern
    fixed = sim._sensor_fixed_hits("lidar")
    sim.lidar_frame(0, 0.0)  # warm-up
    ours_s = raw_s = 0.0
    diff = {"rays": 0, "different": 0, "max_range_diff_m": 0.0}
    for i in range(frames):
        t = i / scenario.installation.lidar.rate_hz
        # The same rays in world axes, and the scene posed at the frame's instant.
        times = t + pat.column_time_s if w.lidar.motion_during_sweep else np.array([t])
        R_ws, p_ws, _, _, _ = sim._scene_poses(times, "lidar")
        pose = pat.column if len(times) > 1 else np.zeros(len(pat.column), dtype=np.int64)
        rays = np.empty((len(pose), 6), dtype=np.float32)
        rays[:, :3] = p_ws[pose]
        rays[:, 3:] = np.einsum("kij,kj->ki", R_ws[pose], pat.dirs_sensor)
        _, _, Rs, ps, _ = sim._scene_poses(np.array([t]), "lidar")
        scene = o3d.t.geometry.RaycastingScene()
        for body, R, p in zip(w.bodies, Rs, ps):
            scene.add_triangles(o3d.core.Tensor((body.vertices @ R[0].T + p[0]).astype(np.float32)),
                                o3d.core.Tensor(body.triangles.astype(np.uint32)))
        rays_t = o3d.core.Tensor.from_numpy(rays)
        scene.cast_rays(rays_t)  # builds the scene
        best_ours = best_raw = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            sim.lidar_frame(i, t)
            t1 = time.perf_counter()
            scene.cast_rays(rays_t)
            t2 = time.perf_counter()
            best_ours, best_raw = min(best_ours, t1 - t0), min(best_raw, t2 - t1)
        ours_s += best_ours
        raw_s += best_raw
        d = hits_difference(sim._lidar_hits(t, sim._scene_poses, fixed)[0], reference_lidar_hits(sim, t, fixed))
        diff = {"rays": diff["rays"] + d["rays"], "different": diff["different"] + d["different"],
                "max_range_diff_m": max(diff["max_range_diff_m"], d["max_range_diff_m"])}
    return {
        "rays_per_frame": int(len(pat.dirs_sensor)),
        "motion_during_sweep": bool(w.lidar.motion_during_sweep),
        "boomtip_s": ours_s,
        "raw_cast_s": raw_s,
        "boomtip_fps": frames / ours_s,
        "raw_cast_fps": frames / raw_s,
        "efficiency": raw_s / ours_s,
        "hits_vs_reference": diff,
    }


def bench_raycast(scenario: Scenario, frames: int = 20, simulate_s: float = 60.0, spinning_frames: int = 10,
                  repeats: int = 30) -> dict:
    """Simulated LiDAR frames per second (moving bodies) against Open3D's raw cast of the same
    rays (`raw_cast_efficiency`), on the scenario's LiDAR and on a 128 x 1024 spinning one with
    the scene moving during the sweep; and against the straightforward trimesh route: pose the
    meshes, concatenate them, `ray.intersects_first` with embreex, per frame."""
    import trimesh

    from boomtip.data.io.recording import write_recording
    from boomtip.tools.config.scenario import apply_overrides, scenario_from_dict
    from boomtip.data.sim.simulator import Simulation

    load_start = os.getloadavg()[0]  # the raw cast uses both cores: the ratio depends on what else runs
    grid = raw_cast_efficiency(scenario, frames, repeats)
    spin_s = scenario_from_dict(apply_overrides(scenario.model_dump(mode="json"), SPINNING_128x1024)[0])
    spinning = raw_cast_efficiency(spin_s, spinning_frames, repeats)

    sim = Simulation(scenario)
    w = sim.world
    times = np.arange(frames) / scenario.installation.lidar.rate_hz
    meshes = [b.trimesh() for b in w.bodies]

    # The two routes alternate frame by frame, so a slow spell of a shared machine hits both.
    pat = sim.lidar_pattern

    def baseline_frame(t: float) -> np.ndarray:
        """Pose the meshes, concatenate, cast with trimesh + embreex; ranges per ray."""
        states = w.body_states(np.array([t]))
        posed = []
        for m, st in zip(meshes, states):
            T = np.eye(4) if st is None else st.matrices()[0]
            posed.append(m.copy().apply_transform(T))
        scene = trimesh.util.concatenate(posed)
        R_ws, p_ws = w.sensor_pose(states[0], "lidar")
        dirs = pat.dirs_sensor @ R_ws[0].T
        origins = np.broadcast_to(p_ws[0], dirs.shape)
        tri = scene.ray.intersects_first(origins, dirs)
        # Range along each ray to the plane of the triangle it hit (vectorised).
        hit = tri >= 0
        v0 = scene.vertices[scene.faces[tri[hit], 0]]
        n = scene.face_normals[tri[hit]]
        r = np.full(len(dirs), np.inf)
        r[hit] = np.einsum("ij,ij->i", v0 - origins[hit], n) / np.einsum("ij,ij->i", dirs[hit], n)
        return r

    sim.lidar_frame(0, 0.0)  # warm-up both
    baseline_frame(0.0)
    ours, base_ranges = [], []
    ours_s = base_s = 0.0
    for i, t in enumerate(times):
        t0 = time.perf_counter()
        ours.append(sim.lidar_frame(i, float(t)))
        t1 = time.perf_counter()
        base_ranges.append(baseline_frame(float(t)))
        t2 = time.perf_counter()
        ours_s += t1 - t0
        base_s += t2 - t1

    # Same frames: compare the ideal ranges ray by ray (noise-free cast from our caster).
    agree = []
    for t, r_base in zip(times, base_ranges):
        states = w.body_states(np.array([t]))
        R_ws, p_ws = w.sensor_pose(states[0], "lidar")
        dirs = pat.dirs_sensor @ R_ws[0].T
        Rs, ps = w.poses(states, 1)
        hits = w.caster.cast(np.broadcast_to(p_ws[0], dirs.shape), dirs, Rs, ps)
        both = np.isfinite(hits.range_m) & np.isfinite(r_base)
        same_hit = np.isfinite(hits.range_m) == np.isfinite(r_base)
        agree.append(np.mean(same_hit) * np.mean(np.abs(hits.range_m[both] - r_base[both]) < 1e-3))
    result = {
        "frames": frames,
        "triangles": int(sum(len(b.triangles) for b in w.bodies)),
        "rays_per_frame": int(len(pat.dirs_sensor)),
        "points_per_frame": float(np.mean([len(f) for f in ours])),
        "boomtip_s": ours_s,
        "baseline_trimesh_s": base_s,
        "boomtip_fps": frames / ours_s,
        "baseline_fps": frames / base_s,
        "ratio_trimesh": base_s / ours_s,
        "hit_agreement": float(np.mean(agree)),
        "repeats": repeats,
        "grid": grid,
        "spinning": spinning,
        "efficiency_grid": grid["efficiency"],
        "efficiency_spinning": spinning["efficiency"],
        # The target's figure: the smaller of the two efficiencies.
        "ratio": min(grid["efficiency"], spinning["efficiency"]),
        "load_average_1min": [load_start, os.getloadavg()[0]],  # at the start and at the end of the timings
    }
    if simulate_s > 0:
        s = scenario.model_copy(update={"duration_s": simulate_s})
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            write_recording(Simulation(s), Path(tmp) / "rec")
            wall = time.perf_counter() - t0
        result["simulate_duration_s"] = simulate_s
        result["simulate_wall_s"] = wall
        result["simulate_realtime_factor"] = simulate_s / wall
    return result
