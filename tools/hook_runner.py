"""Hook localisation over a frame source (document 002's chain, on ray-cast clouds).

Per LiDAR frame: level the cloud into the boom tip's world-axes frame with the tracking
filter's attitude (MRU and encoders filtered), fit the rope's direction (perception/rope),
segment the lower block and fit its model (perception/hook), then run the multi-rate EKF/UKF
(fusion/hook_filter) on the rope directions, the block fixes, the encoders and the MRU.
Outputs in OUT: hook_measurements.csv, hook_estimates.csv, the `hook` section of kpis.json,
and hook_report.md with document 002's Tables 6.1/6.4 layout and plots.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from boomtip.data.frames import FrameSource
from boomtip.data.sim.hook_world import crane_params, rot_z
from boomtip.data.io.pcd import atomic_write_bytes
from boomtip.data.meshes import Label
from boomtip.fusion.hook_filter import HookFilterRun, HookMeasurements, HookTracker, run_hook_filter, world_hook_from_states
from boomtip.perception.geometry import rpy_matrix
from boomtip.perception.hook import HookConfig, detect_hook, segmentation_scores
from boomtip.perception.rope import RopeConfig, RopeFix, fit_rope
from boomtip.perception.timing import StageTimes

WARMUP_S = 5.0
CHI2_3_95 = 7.8147  # chi-square, 3 degrees of freedom, 95 %
ESTIMATORS = ("ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid")
# Document 002, Tables 6.1/6.3 (flexible model, EKF, LiDAR = truth + noise) and 6.4.
DOC002 = {  # Table 6.1, flexible internal model, EKF
    "hook-1": {"pos_cm": (1.811, 2.001, 1.667), "vel_cms": (0.633, 1.049, 2.883)},
    "hook-2": {"pos_cm": (1.832, 1.996, 1.690), "vel_cms": (0.640, 1.067, 2.951)},
    "hook-3": {"pos_cm": (2.005, 2.093, 1.817), "vel_cms": (1.007, 0.843, 2.683)},
    "hook-4": {"pos_cm": (2.292, 2.246, 3.576), "vel_cms": (1.251, 1.268, 5.517)},
}
DOC002_RUNTIME_PCT = "2.4-4.0 % (flexible EKF 3.3-3.8 %)"


def angular_spacing_rad(lidar) -> float:
    """The LiDAR's coarser angular step (rad): points on a far target are this far apart."""
    if lidar.pattern == "spinning":
        return max(2 * np.pi / lidar.columns, np.deg2rad(lidar.channel_fov_deg) / max(lidar.channels - 1, 1))
    return np.deg2rad(max(lidar.res_h_deg, lidar.res_v_deg))


def detection_sigma_m(position_m: np.ndarray, n_points: int, lidar) -> float:
    """1-sigma per axis of a block fix. Across the beams, the block's position is fixed by its
    two edges, and each edge is only known to within one beam spacing s = r * dtheta (uniform:
    s / sqrt(12)); the points inside the outline do not sharpen the edges, so the two edges give
    s / sqrt(24) whatever the point count. Never better than the range noise. (The previous
    r dtheta / sqrt(12 n) treated every point as an independent edge sample and was 2-3x too
    small at 70-115 m: NEES 5.6 instead of 3 on hook-2.)"""
    r = float(np.linalg.norm(position_m))
    return float(max(lidar.range_noise_m, 0.005, r * angular_spacing_rad(lidar) / np.sqrt(24.0)))


def _sigma_across(cov_m2: np.ndarray) -> float:
    """Largest horizontal 1-sigma of a hook position covariance (m): across the rope."""
    return float(np.sqrt(max(np.linalg.eigvalsh(cov_m2[:2, :2])[-1], 0.0)))


def _rope_step(tracker: HookTracker, pts: np.ndarray, p_pred: np.ndarray, sigma_across_m: float, hoist_m: float,
               cfg: RopeConfig, rng: np.random.Generator, times: StageTimes, row: dict) -> RopeFix:
    """Fit the rope about the tracker's predicted direction, correct the tracker with it and fill
    the frame's rope columns."""
    range_m = float(np.linalg.norm(p_pred))
    rope = fit_rope(pts, p_pred / range_m, sigma_across_m / range_m, hoist_m, cfg, rng, times)
    row["rope_status"], row["rope_points"] = rope.status, rope.n_points
    if rope.ok:
        row["rope_ux"], row["rope_uy"], row["rope_uz"] = rope.direction
        row["rope_radius_m"] = rope.radius_m
        row["rope_sigma_across_m"] = hoist_m * math.sqrt(float(np.linalg.eigvalsh(rope.cov)[-1]))
        with times.stage("hook.track"):
            row["rope_accepted"] = tracker.correct_rope(rope.direction, rope.cov)
    return rope


def hook_measurements(source: FrameSource, cfg: HookConfig | None = None, progress=None, logger=None,
                      rope_cfg: RopeConfig | None = None) -> tuple[list[dict], HookMeasurements]:
    """Segment the hook in every LiDAR frame; return per-frame rows and the filter's streams.

    A tracking EKF (flexible model) runs beside the detector on the encoders, the MRU and the
    measurements so far. Per frame: its prediction levels the cloud and gates the rope; the
    rope's direction (perception.rope) corrects it; its estimate is then the block detector's
    prior, which is what lets a far block's 1-5 points be associated (sparse fixes) instead of
    dropped; the block's fix corrects it.
    """
    cfg = cfg or HookConfig()
    s = source.meta.scenario
    rope_cfg = rope_cfg or RopeConfig(radius_m=s.hook.rope_radius_m)
    enc = source.encoders
    m = source.mru
    enc_table = np.column_stack([enc["slew"], enc["luff"], enc["hoist"]])
    mru_table = np.column_stack([m.rpy_rad[:, 0], m.rpy_rad[:, 1], m.rpy_rate_radps[:, 0], m.rpy_rate_radps[:, 1]])
    tracker = HookTracker(enc["t"], enc_table, m.t_s, mru_table, params=crane_params(s))
    T_ts = source.meta.T_boomtip_sensor["lidar"]
    rows: list[dict] = []
    covs: list[np.ndarray] = []
    rope_dirs: list[np.ndarray] = []
    rope_covs: list[np.ndarray] = []
    last: tuple[float, np.ndarray] | None = None
    for frame in source:
        if progress:
            progress(1)
        if frame.sensor != "lidar":
            continue
        times = StageTimes()
        t = frame.t_s
        row = {"t": t, "x": np.nan, "y": np.nan, "z": np.nan, "sigma_x_m": np.nan, "sigma_y_m": np.nan,
               "sigma_z_m": np.nan, "n_points": 0, "fit_rms_m": np.nan, "precision": np.nan, "recall": np.nan,
               "hook_points_true": 0, "tracker_accepted": False, "pred_x": np.nan, "pred_y": np.nan, "pred_z": np.nan,
               "pred_sigma_across_m": np.nan, "rope_status": "", "rope_points": 0, "rope_ux": np.nan,
               "rope_uy": np.nan, "rope_uz": np.nan, "rope_sigma_across_m": np.nan, "rope_accepted": False,
               "rope_precision": np.nan, "rope_radius_m": np.nan}
        cov = np.full((3, 3), np.nan)
        rope: RopeFix | None = None
        if frame.error is not None:
            row["status"] = f"unreadable frame: {frame.error}"
        # (the MRU log must cover t, gaps included; the tracker's filtered attitude levels the frame)
        elif source.mru.attitude(t) is None or not (enc["t"][0] <= t <= enc["t"][-1]):
            row["status"] = f"no MRU attitude or encoder reading at t={t:.3f} s"
        else:
            with times.stage("hook.track"):
                p_pred, cov_pred = tracker.predict(t)
            with times.stage("hook.level"):
                # Level with the tracker's attitude (MRU and encoders filtered, boom deflection
                # included), not one raw sample: see HookTracker.tip_attitude.
                roll, pitch, heading = tracker.tip_attitude()
                hoist = float(np.interp(t, enc["t"], enc["hoist"]))
                R_tip = rpy_matrix(np.array([roll, pitch, 0.0])) @ rot_z(heading)
                pts = frame.points_sensor @ (R_tip @ T_ts[:3, :3]).T + R_tip @ T_ts[:3, 3]
            row["pred_x"], row["pred_y"], row["pred_z"] = p_pred
            row["pred_sigma_across_m"] = _sigma_across(cov_pred)
            if rope_cfg.enabled:
                rope = _rope_step(tracker, pts, p_pred, row["pred_sigma_across_m"], hoist, rope_cfg,
                                  np.random.default_rng([s.seed, 8, frame.index]), times, row)
                if rope.ok:
                    p_pred, cov_pred = tracker.estimate()
            # Prior: the tracker's estimate when it is certain enough to associate a sparse
            # block; else the last detection when recent (the hook moves < 1 m in 0.5 s), else
            # straight below the tip at the hoist length.
            sig_across = _sigma_across(cov_pred)
            tracked = bool(np.all(np.isfinite(p_pred)) and sig_across <= cfg.sparse_max_prior_sigma_m)
            if tracked:
                prior = p_pred
            else:
                prior = last[1] if last is not None and t - last[0] <= 0.5 else np.array([0.0, 0.0, -hoist])
            rng = np.random.default_rng([s.seed, 7, frame.index])
            det = detect_hook(pts, prior, hoist, cfg, rng, times, sensor_position_m=R_tip @ T_ts[:3, 3],
                              prior_cov_m2=cov_pred if tracked else None)
            if logger is not None:
                logger.log_frame(t, pts, det, prior, cfg.prior_radius_m, rope=rope, hoist_m=hoist)
            row["status"] = det.status
            row["n_points"] = det.n_points
            row["fit_rms_m"] = det.fit_rms_m
            if det.has_fix:
                if det.cov_m2 is not None:
                    cov = det.cov_m2
                else:
                    cov = np.eye(3) * detection_sigma_m(det.position_m, det.n_points, s.lidar) ** 2
                row["x"], row["y"], row["z"] = det.position_m
                row["sigma_x_m"], row["sigma_y_m"], row["sigma_z_m"] = np.sqrt(np.diag(cov))
                with times.stage("hook.track"):
                    row["tracker_accepted"] = tracker.correct(det.position_m, cov)
                last = (t, det.position_m)
            labels = frame.fields.get("label")
            if labels is not None:
                p, r = segmentation_scores(det.points_mask, labels)
                row["precision"], row["recall"] = p, r
                row["hook_points_true"] = int(np.count_nonzero(labels == Label.HOOK))
                if rope is not None and rope.ok:
                    row["rope_precision"] = float(np.mean(labels[rope.mask] == Label.ROPE))
        row["time_ms"] = times.total()
        rows.append(row)
        covs.append(cov)
        rope_ok = rope is not None and rope.ok
        rope_dirs.append(rope.direction if rope_ok else np.full(3, np.nan))
        rope_covs.append(rope.cov if rope_ok else np.full((3, 3), np.nan))
    lid_t = np.array([r["t"] for r in rows])
    lid_p = np.array([[r["x"], r["y"], r["z"]] for r in rows]).reshape(-1, 3)
    meas = HookMeasurements(
        t_lidar=lid_t, lidar_p_rel_tip_world=lid_p,
        t_encoders=enc["t"], encoders=enc_table, t_mru=m.t_s, mru=mru_table,
        lidar_cov_m2=np.array(covs).reshape(-1, 3, 3),
        rope_direction=np.array(rope_dirs).reshape(-1, 3), rope_cov=np.array(rope_covs).reshape(-1, 3, 3),
    )
    return rows, meas


def _errors(run: HookFilterRun, source: FrameSource, params) -> dict:
    truth = source.truth
    # Runs shorter than the warm-up are scored over all their samples (and say so).
    t_from = WARMUP_S if np.any(run.t >= WARMUP_S) else float(run.t[0])
    keep = run.t >= t_from
    t = run.t[keep]
    _, _, p_hook, v_hook = world_hook_from_states(params, run.x[keep])
    ref_p = np.column_stack([truth.at(f"hook_{a}", t) for a in "xyz"])
    ref_v = np.column_stack([truth.at(f"hook_v{a}", t) for a in "xyz"])
    ep, ev = p_hook - ref_p, v_hook - ref_v
    # Consistency on the ray-cast chain: NEES of the hook relative to the tip (the filter's own
    # 3x3 covariance of p_rel); a consistent filter averages 3, 95 % of samples below 7.81.
    ref_rel = np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
    e_rel = run.p_rel[keep] - ref_rel
    ev_rel = run.v_rel[keep] - np.column_stack([truth.at(f"hook_rel_v{a}", t) for a in "xyz"])
    nees = np.einsum("ni,ni->n", e_rel, np.linalg.solve(run.cov_p[keep], e_rel[..., None])[..., 0])
    return {
        "rmse_pos_m": np.sqrt(np.mean(ep**2, axis=0)).tolist(),
        "rmse_vel_mps": np.sqrt(np.mean(ev**2, axis=0)).tolist(),
        "max_pos_m": np.abs(ep).max(axis=0).tolist(),
        "max_vel_mps": np.abs(ev).max(axis=0).tolist(),
        # relative to the boom tip (what the LiDAR sees): the rest of the world-frame error is
        # the tip's own position, estimated from the encoders and the MRU
        "rmse_rel_pos_m": np.sqrt(np.mean(e_rel**2, axis=0)).tolist(),
        "rmse_rel_vel_mps": np.sqrt(np.mean(ev_rel**2, axis=0)).tolist(),
        "evaluated_from_s": t_from,
        "nees_pos_mean": float(np.mean(nees)),
        "nees_pos_within_95": float(np.mean(nees < CHI2_3_95)),
        "runtime_fraction": run.realtime_fraction,
        "lidar_accepted": run.n_lidar_accepted,
        "lidar_rejected": run.n_lidar_rejected,
        "rope_accepted": run.n_rope_accepted,
        "rope_rejected": run.n_rope_rejected,
    }


def _rope_kpis(rows: list[dict], truth) -> dict:
    """How often the rope was fitted, and (with a truth) its error: the angle between the fitted
    and the true direction tip -> hook, and that angle times the rope length per axis (what it
    means at the hook, the number comparable with a block fix's error)."""
    fits = [r for r in rows if r["rope_status"] == "ok"]
    out = {
        "found_fraction": len(fits) / max(len(rows), 1),
        "accepted_fraction": sum(bool(r["rope_accepted"]) for r in fits) / max(len(fits), 1),
        "points_median": float(np.median([r["rope_points"] for r in fits])) if fits else 0.0,
        # what the points say the radius is, against the configured one the fit assumes
        "radius_median_m": float(np.median([r["rope_radius_m"] for r in fits])) if fits else float("nan"),
    }
    if truth is not None and fits:
        t = np.array([r["t"] for r in fits])
        u = np.array([[r["rope_ux"], r["rope_uy"], r["rope_uz"]] for r in fits])
        ref = np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
        length = np.linalg.norm(ref, axis=1, keepdims=True)
        e = u - ref / length
        out["rmse_angle_mrad"] = float(1e3 * np.sqrt(np.mean(np.einsum("ij,ij->i", e, e))))
        out["rmse_at_hook_m"] = np.sqrt(np.mean((length * e) ** 2, axis=0)).tolist()
        prec = [r["rope_precision"] for r in fits if np.isfinite(r["rope_precision"])]
        out["precision"] = float(np.mean(prec)) if prec else float("nan")
    return out


def run_hook_into(source: FrameSource, out: Path, estimators: tuple[str, ...] = ESTIMATORS, progress=None,
                  rerun: bool = False) -> dict:
    s = source.meta.scenario
    params = crane_params(s)
    logger = None
    if rerun:
        from boomtip.tools.visualise import HookRerunLogger

        logger = HookRerunLogger(out / "boomtip.rrd", source)
    rows, meas = hook_measurements(source, progress=progress, logger=logger)
    _write_rows(out / "hook_measurements.csv", rows)
    runs: dict[str, HookFilterRun] = {}
    for name in estimators:
        kind, model = name.split("_")
        runs[name] = run_hook_filter(meas, kind, model, params.model_copy(update={"flexible": model == "flexible"}))
    _write_estimates(out / "hook_estimates.csv", runs, params)
    hook: dict = {"estimators_note": f"errors in the world frame, first {WARMUP_S:g} s excluded"}
    ok = [r for r in rows if r["status"] == "ok"]
    sparse = [r for r in rows if r["status"] == "sparse"]
    seg = {
        "found_fraction": len(ok) / max(len(rows), 1),
        "sparse_fraction": len(sparse) / max(len(rows), 1),
        "frames": len(rows),
        "apt_ms": float(np.mean([r["time_ms"] for r in rows])) if rows else float("nan"),
    }
    if source.truth is not None:
        for name, run in runs.items():
            hook[name] = _errors(run, source, params)
        in_view = [r for r in rows if r["hook_points_true"] > 0]
        prec = [r["precision"] for r in in_view if np.isfinite(r["precision"])]
        rec = [r["recall"] for r in in_view if np.isfinite(r["recall"])]
        seg["precision"] = float(np.mean(prec)) if prec else float("nan")
        seg["recall"] = float(np.mean(rec)) if rec else float("nan")
        seg["frames_in_view"] = len(in_view)
        for key, fixes in (("rmse_m", ok), ("sparse_rmse_m", sparse)):
            if fixes:
                t = np.array([r["t"] for r in fixes])
                det = np.array([[r["x"], r["y"], r["z"]] for r in fixes])
                ref = np.column_stack([source.truth.at(f"hook_rel_{a}", t) for a in "xyz"])
                seg[key] = np.sqrt(np.mean((det - ref) ** 2, axis=0)).tolist()
    hook["segmentation"] = seg
    hook["rope"] = _rope_kpis(rows, source.truth)
    if source.truth is not None and runs:
        write_hook_report(out, s, hook, runs, source, params, rows)
    if logger is not None:
        if runs:
            name = "ekf_flexible" if "ekf_flexible" in runs else next(iter(runs))
            run = runs[name]
            t_l = meas.t_lidar[(meas.t_lidar >= run.t[0]) & (meas.t_lidar <= run.t[-1])]
            p_est = np.column_stack([np.interp(t_l, run.t, run.p_rel[:, k]) for k in range(3)])
            p_true = None
            if source.truth is not None:
                p_true = np.column_stack([source.truth.at(f"hook_rel_{a}", t_l) for a in "xyz"])
            logger.log_hook_tracks(t_l, p_est, p_true, name)
        logger.close()
    return hook


def _write_rows(path: Path, rows: list[dict]) -> None:
    cols = ("t", "status", "x", "y", "z", "sigma_x_m", "sigma_y_m", "sigma_z_m", "n_points", "fit_rms_m", "precision",
            "recall", "hook_points_true", "tracker_accepted", "pred_x", "pred_y", "pred_z", "pred_sigma_across_m",
            "rope_status", "rope_points", "rope_ux", "rope_uy", "rope_uz", "rope_sigma_across_m", "rope_radius_m",
            "rope_accepted", "rope_precision", "time_ms")
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    for r in rows:
        vals = []
        for c in cols:
            v = r[c]
            if c in ("status", "rope_status"):
                vals.append('"' + str(v).replace('"', "'") + '"')
            elif isinstance(v, float):
                vals.append("" if not np.isfinite(v) else f"{v:.6g}")
            else:
                vals.append(str(v))
        buf.write(",".join(vals) + "\n")
    atomic_write_bytes(path, buf.getvalue().encode())


def _write_estimates(path: Path, runs: dict[str, HookFilterRun], params) -> None:
    buf = io.StringIO()
    buf.write("t,estimator,x,y,z,vx,vy,vz,rel_x,rel_y,rel_z,rel_vx,rel_vy,rel_vz\n")
    for name, run in runs.items():
        _, _, p, v = world_hook_from_states(params, run.x)
        table = np.column_stack([run.t, p, v, run.p_rel, run.v_rel])
        for row in table:
            buf.write(f"{row[0]:.4f},{name}," + ",".join(f"{x:.5f}" for x in row[1:]) + "\n")
    atomic_write_bytes(path, buf.getvalue().encode())


def rope_summary(rope: dict) -> str:
    """One line on the rope's direction (perception.rope) for the report and the CLI."""
    text = (f"Rope direction fitted in {100 * rope['found_fraction']:.1f} % of the frames "
            f"(median {rope['points_median']:.0f} points, radius from the points {1000 * rope['radius_median_m']:.1f} mm), "
            f"{100 * rope['accepted_fraction']:.1f} % of them accepted by the tracker")
    if "rmse_angle_mrad" in rope:
        text += (f"; angle RMSE {rope['rmse_angle_mrad']:.3f} mrad, "
                 f"{' / '.join(f'{100 * v:.1f}' for v in rope['rmse_at_hook_m'])} cm x/y/z at the hook, "
                 f"precision {rope['precision']:.4f}")
    return text + "."


def write_hook_report(out: Path, s, hook: dict, runs, source, params, rows) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    doc = DOC002.get(s.hook.program)
    lines = [
        f"# boomtip hook report: {s.name} (program {s.hook.program}, seed {s.seed}, {s.duration_s:g} s)",
        "",
        "## Estimators (document 002, Tables 6.1 and 6.4 layout)",
        "",
        f"Hook position and velocity in the world frame, first {WARMUP_S:g} s excluded. The LiDAR measurement is the hook",
        "segmented from the ray-cast cloud and fitted with the block model (document 002 used the truth plus noise).",
        "",
        "| estimator | RMSE pos x/y/z [cm] | RMSE vel x/y/z [cm/s] | max pos [cm] | max vel [cm/s] | runtime [% of real time] | NEES mean (3) / within 95 % | RMSE pos relative to the tip [cm] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in runs:
        k = hook[name]
        f = lambda v: " / ".join(f"{100 * x:.2f}" for x in v)  # noqa: E731
        lines.append(f"| {name} | {f(k['rmse_pos_m'])} | {f(k['rmse_vel_mps'])} | {f(k['max_pos_m'])} | {f(k['max_vel_mps'])} | "
                     f"{100 * k['runtime_fraction']:.2f} | {k['nees_pos_mean']:.2f} / {100 * k['nees_pos_within_95']:.0f} % | "
                     f"{f(k['rmse_rel_pos_m'])} |")
    if doc:
        lines.append(f"| document 002, EKF flexible | {' / '.join(f'{v:.2f}' for v in doc['pos_cm'])} | "
                     f"{' / '.join(f'{v:.2f}' for v in doc['vel_cms'])} | - | - | {DOC002_RUNTIME_PCT} | - | - |")
    seg = hook["segmentation"]
    lines += [
        "",
        "## Segmentation",
        "",
        f"Block model fitted in {100 * seg['found_fraction']:.1f} % of {seg['frames']} LiDAR frames, a sparse fix (a far block's "
        f"few points, associated by the tracking filter's prediction) in {100 * seg.get('sparse_fraction', 0.0):.1f} %; "
        f"precision {seg.get('precision', float('nan')):.4f}, "
        f"recall {seg.get('recall', float('nan')):.4f} over the {seg.get('frames_in_view', 0)} frames with the hook in view; "
        f"reference-point RMSE x/y/z {' / '.join(f'{100 * v:.1f}' for v in seg.get('rmse_m', [np.nan] * 3))} cm (model fits), "
        f"{' / '.join(f'{100 * v:.1f}' for v in seg.get('sparse_rmse_m', [np.nan] * 3))} cm (sparse fixes); "
        f"{seg['apt_ms']:.1f} ms per frame.",
        "",
        rope_summary(hook["rope"]),
        "",
        "![trajectory](hook_trajectory.png)",
        "![errors](hook_errors.png)",
        "",
    ]
    atomic_write_bytes(out / "hook_report.md", "\n".join(lines).encode())
    truth = source.truth
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    tt = truth.t_s
    ax[0].plot(truth.columns["hook_x"], truth.columns["hook_y"], "k", lw=2, label="truth")
    best = runs.get("ekf_flexible") or next(iter(runs.values()))
    _, _, p, _ = world_hook_from_states(params, best.x)
    ax[0].plot(p[:, 0], p[:, 1], "r", lw=1, label=best.kind + " " + best.model)
    ax[0].set_xlabel("x [m]")
    ax[0].set_ylabel("y [m]")
    ax[0].set_aspect("equal", adjustable="datalim")
    ax[0].legend()
    ax[0].set_title("hook path seen from above (world)")
    ax[1].plot(tt, truth.columns["hook_z"], "k", lw=2, label="truth z")
    ax[1].plot(best.t, p[:, 2], "r", lw=1, label="estimate z")
    ok = [r for r in rows if r["status"] == "ok"]
    if ok:
        t_ok = np.array([r["t"] for r in ok])
        tip_z = truth.at("tip_z", t_ok)
        ax[1].plot(t_ok, tip_z + np.array([r["z"] for r in ok]), ".", ms=2, color="tab:blue", label="LiDAR detections")
    ax[1].set_xlabel("t [s]")
    ax[1].set_ylabel("z [m]")
    ax[1].legend()
    ax[1].set_title("hook height")
    fig.tight_layout()
    fig.savefig(out / "hook_trajectory.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    for name, run in runs.items():
        _, _, p, v = world_hook_from_states(params, run.x)
        ref = np.column_stack([truth.at(f"hook_{a}", run.t) for a in "xyz"])
        refv = np.column_stack([truth.at(f"hook_v{a}", run.t) for a in "xyz"])
        # Colour by internal model, line style by estimator: EKF and UKF nearly coincide.
        style = {"color": "tab:green" if run.model == "flexible" else "tab:red", "ls": "-" if run.kind == "ekf" else "--",
                 "lw": 0.9 if run.kind == "ekf" else 1.2}
        ax[0].plot(run.t, 100 * np.linalg.norm(p - ref, axis=1), label=name, **style)
        ax[1].plot(run.t, 100 * np.linalg.norm(v - refv, axis=1), label=name, **style)
    ax[0].set_ylabel("|position error| [cm]")
    ax[1].set_ylabel("|velocity error| [cm/s]")
    ax[1].set_xlabel("t [s]")
    for a in ax:
        a.axvspan(0, WARMUP_S, color="0.9")
        a.legend(fontsize=8, ncol=4)
        a.set_yscale("log")
    ax[0].set_title("hook errors (world frame); grey: not scored")
    fig.tight_layout()
    fig.savefig(out / "hook_errors.png", dpi=90)
    plt.close(fig)
