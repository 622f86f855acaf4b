"""`boomtip bench feeder`: the feeder chain against plain kiss-icp odometry on the same frames.

Plain kiss-icp (its own pipeline, defaults, voxel max_range / 100) registers every LiDAR frame
in the sensor frame; its pose is the sensor's motion against the scene, so the feeder's pose is
its inverse. To put it in the heading frame at the tip it gets what the chain has (the same
levelling, from the MRU and the surveyed mount) and, as a favour it cannot give itself, the
true feeder pose at its first frame as the anchor. Both are scored against the same truth, with
the same feeder frame. The ratio is kiss-icp's error over the chain's, per axis: above 1 the
chain is better.
"""

from __future__ import annotations

import time

import numpy as np


def plain_kiss_icp():
    """kiss-icp's own pipeline as a user starts it: its defaults, the voxel max_range / 100, no
    deskew (boomtip's frames carry no per-point times it reads)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    cfg = KISSConfig()
    cfg.mapping.voxel_size = cfg.data.max_range / 100.0
    cfg.data.deskew = False
    return KissICP(cfg)


def bench_feeder(scenario: str = "sts-loaded", duration_s: float = 60.0, overrides: list[str] | None = None) -> dict:
    from boomtip.tools.config.scenario import load_scenario
    from boomtip.data.sim.sources import simulation_for
    from boomtip.perception.feeder import FeederPerception
    from boomtip.data.poses import inverse, pose_matrix, pose_vector
    from boomtip.tools.report.feeder import WARMUP_S, feeder_kpis
    from boomtip.tools.report.feeder_truth import feeder_origin_body, feeder_pose_truth
    from boomtip.tools.chains.chain import ChainError
    from boomtip.tools.chains.runner import build_chain, processing_for
    from boomtip.tools.chains.ship import ShipChain
    if duration_s <= WARMUP_S + 1.0:
        raise ChainError(f"--duration {duration_s:g}: expected more than {WARMUP_S + 1.0:g} s (the first {WARMUP_S:g} s "
                         "are the filter's warm-up and are not scored)")
    s = load_scenario(scenario, [f"duration_s={duration_s}", *(overrides or [])])
    sim = simulation_for(s)
    chain = build_chain(sim, processing_for(sim))
    if not isinstance(chain, ShipChain):
        raise ChainError(f"{scenario}: the feeder chain does not run here (no LiDAR, or a hook scenario)")
    kiss = plain_kiss_icp()
    perception = FeederPerception(sim.meta.installation)
    kiss_t, kiss_T, kiss_ms, chain_wall = [], [], [], 0.0
    for frame in sim:
        t0 = time.perf_counter()
        chain.process(frame)
        chain_wall += time.perf_counter() - t0
        if frame.sensor != "lidar" or frame.error is not None or len(frame) == 0:
            continue
        pts = frame.points_sensor[np.all(np.isfinite(frame.points_sensor), axis=1)]
        t0 = time.perf_counter()
        kiss.register_frame(pts, np.zeros(len(pts)))
        kiss_ms.append((time.perf_counter() - t0) * 1e3)
        att = chain.estimator.mru.attitude(frame.t_s)
        if att is None:
            continue
        R_ls, t_ls = perception.sensor_in_level("lidar", att[0])
        T_ls = np.eye(4)
        T_ls[:3, :3], T_ls[:3, 3] = R_ls, t_ls
        kiss_t.append(frame.t_s)
        kiss_T.append((T_ls, kiss.last_pose.copy()))
    result = chain.finish()
    fres = result.feeder
    p_tip = sim.meta.installation.T_crane_boomtip()[:3, 3]
    kp = feeder_kpis(fres, sim.truth, p_tip)
    if "rmse_pos_m" not in kp or not kiss_T:
        raise ChainError(f"{scenario}: no feeder estimate to score after the {WARMUP_S:g} s warm-up "
                         f"({len(fres.missing)} frames missing; first reason: {fres.missing[0][2] if fres.missing else 'none'})")
    # kiss-icp's feeder pose: level <- sensor(t) <- sensor(0) <- feeder, anchored on the truth at its first frame
    t_k = np.array(kiss_t)
    truth_k = feeder_pose_truth(sim.truth, t_k, feeder_origin_body(sim.truth, fres.t_definition_s, p_tip), p_tip)
    T_ls0, P0 = kiss_T[0]
    T_sensor0_feeder = inverse(T_ls0) @ pose_matrix(*truth_k[0])
    kiss_pose = np.array([pose_vector(T_ls @ inverse(P) @ P0 @ T_sensor0_feeder) for T_ls, P in kiss_T])
    # the chain's pose at the same times
    e_kiss = kiss_pose - truth_k
    e_kiss[:, 3:] = (e_kiss[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    scored = t_k >= fres.t_s[0] + 5.0 if len(fres.t_s) else t_k >= 5.0
    rms = lambda e: np.sqrt(np.mean(e ** 2, axis=0))
    kiss_pos, kiss_rpy = rms(e_kiss[scored, :3]), np.degrees(rms(e_kiss[scored, 3:]))
    chain_pos, chain_rpy = np.array(kp["rmse_pos_m"]), np.array(kp["rmse_rpy_deg"])
    lidar_frames = len(kiss_ms)
    return {
        "scenario": scenario, "duration_s": duration_s, "lidar_frames": lidar_frames,
        "chain": {"rmse_pos_m": chain_pos.tolist(), "rmse_rpy_deg": chain_rpy.tolist(), "max_pos_m": kp["max_pos_m"],
                  "max_rpy_deg": kp["max_rpy_deg"], "rmse_vel_mps": kp["rmse_vel_mps"], "nees_mean": kp["nees_mean"],
                  "ms_per_lidar_frame": kp["apt_ms"], "ms_worst_lidar_frame": kp["apt_ms_max"],
                  "ms_per_lidar_frame_by_stage": kp["apt_ms_by_stage"],
                  "merge_wait_ms": kp["merge_wait_ms"], "model_merges": kp["model_merges"],
                  "wall_s_all_frames": round(chain_wall, 3)},
        "kiss_icp": {"rmse_pos_m": kiss_pos.round(5).tolist(), "rmse_rpy_deg": kiss_rpy.round(5).tolist(),
                     "max_pos_m": np.abs(e_kiss[scored, :3]).max(axis=0).round(5).tolist(),
                     "ms_per_lidar_frame": round(float(np.mean(kiss_ms)), 3)},
        "ratio_pos": (kiss_pos / chain_pos).round(2).tolist(),
        "ratio_rpy": (kiss_rpy / chain_rpy).round(2).tolist(),
        "ratio": round(float(min(np.min(kiss_pos / chain_pos), np.min(kiss_rpy / chain_rpy))), 3),
        "ratio_note": "kiss-icp RMSE / chain RMSE, the smallest over the six axes (above 1: the chain is better on every axis)",
    }
