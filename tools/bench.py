"""Benchmarks. Each measures boomtip and a baseline on the same input in the same run and
reports the ratio, so the figure does not depend on the machine's speed."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from data.scenario import Scenario


def bench_raycast(scenario: Scenario, frames: int = 20, simulate_s: float = 60.0) -> dict:
    """Simulated LiDAR frames per second (moving bodies) vs the straightforward trimesh route:
    pose the meshes, concatenate them, `ray.intersects_first` with embreex, per frame."""
    import trimesh

    from data.recording import write_recording
    from data.simulator import Simulation

    sim = Simulation(scenario)
    w = sim.world
    times = np.arange(frames) / scenario.lidar.rate_hz
    meshes = [b.trimesh() for b in w.bodies]

    # boomtip: the simulator's own LiDAR frame (cast + sensor model).
    sim.lidar_frame(0, 0.0)  # warm-up
    t0 = time.perf_counter()
    ours = [sim.lidar_frame(i, float(t)) for i, t in enumerate(times)]
    ours_s = time.perf_counter() - t0

    # Baseline: rebuild the posed scene each frame and cast with trimesh + embreex.
    pat = sim.lidar_pattern
    base_ranges = []
    t0 = time.perf_counter()
    for t in times:
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
        base_ranges.append(r)
    base_s = time.perf_counter() - t0

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
        "ratio": base_s / ours_s,
        "hit_agreement": float(np.mean(agree)),
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
