"""The feeder chain's outputs: feeder_estimates.csv, kpis.json's `feeder` block, the report's
section beside document 004's Tables 1-3, and its plot.

OUT/feeder_estimates.csv   t, x, y, z, roll, pitch, yaw, their rates, the 12 variances
                            (m, rad; the feeder frame in the heading frame at the boom tip)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from boomtip.data.frames import Truth
from boomtip.data.io.atomic import atomic_text_file
from boomtip.data.sim.world import in_windows  # the scored windows, from the world's provenance
from boomtip.fusion.models.relative_motion import deck_plane
from boomtip.fusion.feeder_estimator import FeederEstimate
from boomtip.fusion.feeder_frame import HISTORY_COLUMNS, UPDATE_EVERY_S, CausalEstimates
from boomtip.perception.feeder_merges import MergeRecord
from boomtip.tools.report.feeder_truth import (
    POSE,
    feeder_origin_body,
    feeder_pose_truth,
    feeder_twist_truth,
)
from boomtip.tools.report.kpis import WARMUP_S
from boomtip.tools.report.plots import decimated, legend, plot_link, plot_path, save

RATES = tuple(f"{a}_rate" for a in POSE)
COLUMNS = ("t",) + POSE + RATES + tuple(f"var_{a}" for a in POSE + RATES)
# Document 004, Tables 1-3 (lab rig at about 1:10): position RMS / max in mm, angles in deg.
DOC004 = {
    "T1 tracker + 2 MRUs": {"rms_mm": (1.22, 2.05, 2.26), "max_mm": (2.84, 3.38, 4.82), "rms_deg": (0.03, 0.11, 0.04), "max_deg": (0.07, 0.18, 0.11)},
    "T2 tracker off (MRUs only)": {"rms_mm": (9.17, 7.59, 18.63), "max_mm": (22.96, 13.69, 46.54), "rms_deg": (0.04, 0.10, 0.11), "max_deg": (0.09, 0.17, 0.24)},
    "T3 tracker back": {"rms_mm": (1.51, 1.32, 1.98), "max_mm": (9.96, 9.89, 7.40), "rms_deg": (0.06, 0.07, 0.05), "max_deg": (0.13, 0.14, 0.15)},
}


@dataclass
class FeederResult(FeederEstimate):
    """The feeder's estimate and what its pipeline reports of the run."""

    frame_ms: list[float] = field(default_factory=list)  # wall time per LiDAR frame (feeder stages, the deck stage it reuses, merge waits)
    stage_ms: dict[str, float] = field(default_factory=dict)  # the same by stage, summed over the run's LiDAR frames
    missing: list[tuple[float, str, str]] = field(default_factory=list)  # (t, sensor, why)
    model_points_map: np.ndarray | None = None  # the model's points, for the display
    merges: list[MergeRecord] = field(default_factory=list)  # the model's merges (inline, or beside the frames)


def write_feeder_estimates(path: Path, res: FeederResult | CausalEstimates) -> None:
    with atomic_text_file(path) as fh:  # row by row: a long run's table is never whole in memory
        fh.write(",".join(COLUMNS) + "\n")
        for t, p, r, v in zip(res.t_s, res.pose, res.rates, res.var):
            fh.write(f"{t:.4f}," + ",".join(f"{x:.7g}" for x in (*p, *r)) + "," + ",".join(f"{x:.4g}" for x in v) + "\n")


def write_feeder_online(out: Path, res: FeederResult) -> list[str]:
    """feeder_estimates_online.csv (the estimates as a live controller had them) and
    feeder_calibration.csv (the definition's history); nothing for a run without an estimate."""
    if res.online is None:
        return []
    write_feeder_estimates(out / "feeder_estimates_online.csv", res.online)
    with atomic_text_file(out / "feeder_calibration.csv") as fh:
        fh.write(",".join(HISTORY_COLUMNS) + "\n")
        for row in res.online.history:
            fh.write(f"{row[0]:.4f}," + ",".join(f"{x:.7g}" for x in row[1:]) + "\n")
    return ["feeder_estimates_online.csv", "feeder_calibration.csv"]


def truth_of(res: FeederResult, truth: Truth, p_tip_crane_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The truth's pose and twist at the estimates' times, with the estimator's definition."""
    origin = feeder_origin_body(truth, res.t_definition_s, p_tip_crane_m)
    return feeder_pose_truth(truth, res.t_s, origin, p_tip_crane_m), feeder_twist_truth(truth, res.t_s, origin, p_tip_crane_m)


def _figures(err_pose: np.ndarray, err_rate: np.ndarray, var: np.ndarray) -> dict:
    if len(err_pose) == 0:
        return {"samples": 0}
    rms = lambda e: np.sqrt(np.mean(e ** 2, axis=0))
    nees = np.einsum("ij,ij->i", err_pose ** 2, 1.0 / var[:, :6])
    return {
        "samples": len(err_pose),
        "rmse_pos_m": rms(err_pose[:, :3]).round(5).tolist(),
        "max_pos_m": np.abs(err_pose[:, :3]).max(axis=0).round(5).tolist(),
        "rmse_rpy_deg": np.degrees(rms(err_pose[:, 3:])).round(5).tolist(),
        "max_rpy_deg": np.degrees(np.abs(err_pose[:, 3:]).max(axis=0)).round(5).tolist(),
        "rmse_vel_mps": rms(err_rate[:, :3]).round(5).tolist(),
        "rmse_rpy_rate_degps": np.degrees(rms(err_rate[:, 3:])).round(5).tolist(),
        "nees_mean": round(float(nees.mean()), 3),  # 6 for an honest 6-DOF covariance
        "within_3sigma_pct": (100.0 * np.mean(np.abs(err_pose) <= 3.0 * np.sqrt(var[:, :6]), axis=0)).round(2).tolist(),
    }


def feeder_kpis(res: FeederResult, truth: Truth | None, p_tip_crane_m: np.ndarray, windows=(), heave_D: tuple | None = None,
                mru_windows=()) -> dict:
    """mru_windows: the crane MRU's outages alone, scored as `mru_outage` (fusion/feeder_estimator)."""
    apt = float(np.mean(res.frame_ms)) if res.frame_ms else float("nan")
    waits = [m.wait_s for m in res.merges]
    out: dict = {"apt_ms": round(apt, 3), "apt_ms_p95": round(float(np.percentile(res.frame_ms, 95)), 3) if res.frame_ms else None,
                 "apt_ms_max": round(float(np.max(res.frame_ms)), 3) if res.frame_ms else None,
                 # where a LiDAR frame's milliseconds go (means over the frames; they sum to apt_ms)
                 "apt_ms_by_stage": {k: round(v / len(res.frame_ms), 3) for k, v in res.stage_ms.items()} if res.frame_ms else {},
                 "merge_wait_ms": {"total": round(1e3 * sum(waits), 3), "max": round(1e3 * max(waits, default=0.0), 3)},
                 "model_merges": [{"frames": m.frames, "started_frame": m.started_frame, "taken_frame": m.taken_frame,
                                   "worker_s": round(m.worker_s, 3), "wait_s": round(m.wait_s, 3), "status": m.status}
                                  for m in res.merges],
                 "updates": res.counts, "missing": len(res.missing)}
    if res.tilt is not None:
        out["levelling_tilt_deg"] = {"about_x": round(math.degrees(res.tilt.rx_rad), 5), "about_y": round(math.degrees(res.tilt.ry_rad), 5),
                                     "sigma": round(math.degrees(res.tilt.sigma_rad), 5), "span_s": round(res.tilt.span_s, 2),
                                     "about_z": round(math.degrees(res.tilt.rz_rad), 5),
                                     "about_z_sigma": None if res.tilt.rz_sigma_rad is None else round(math.degrees(res.tilt.rz_sigma_rad), 5)}
    if res.centre_line is not None:
        out["centre_line"] = {"yaw_in_map_deg": round(math.degrees(res.centre_line[0]), 5), "frames": res.centre_line[1]}
    if res.feeder_mru is not None:
        out["feeder_mru"] = res.feeder_mru
    if res.notes:
        out["notes"] = res.notes
    if len(res.t_s) == 0:
        return out
    warm = res.t_s >= res.t_s[0] + WARMUP_S
    has_truth = truth is not None and {"feeder_x", "crane_x"} <= set(truth.columns)
    if heave_D is not None:
        side = D_side_by_side(res, heave_D, warm, truth.at("D", res.t_s) if has_truth else None)
        if side:
            out["D_side_by_side"] = side
    t_cal = res.online.calibrated_at_s if res.online is not None else math.nan
    online = {"calibrated_at_s": None if math.isnan(t_cal) else round(t_cal, 3), "update_every_s": UPDATE_EVERY_S}
    if not has_truth:
        if res.online is not None:
            out["online"] = online
        out["estimated"] = estimated_motion(res, warm)
        return out
    pose_t, rate_t = truth_of(res, truth, p_tip_crane_m)
    e_pose, e_rate = _errors(res, pose_t, rate_t)
    scored = warm & np.all(np.isfinite(pose_t), axis=1)
    inside, in_mru = in_windows(res.t_s, windows), in_windows(res.t_s, mru_windows)
    out.update(_figures(e_pose[scored], e_rate[scored], res.var[scored]))
    out["note"] = f"errors exclude the first {WARMUP_S:g} s after the first deck frame (filter convergence)"
    if windows:
        out["outage"] = _figures(e_pose[scored & inside], e_rate[scored & inside], res.var[scored & inside])
        out["outside_outage"] = _figures(e_pose[scored & ~inside], e_rate[scored & ~inside], res.var[scored & ~inside])
    if mru_windows:
        out["mru_outage"] = _figures(e_pose[scored & in_mru], e_rate[scored & in_mru], res.var[scored & in_mru])
    if res.online is None:
        return out
    o = res.online
    e_on, r_on = _errors(o, pose_t, rate_t)
    online.update(_figures(e_on[scored], r_on[scored], o.var[scored]))
    if windows:
        online["outage"] = _figures(e_on[scored & inside], r_on[scored & inside], o.var[scored & inside])
    # where the two differ: before the calibration applies (the survey's levelling), and after
    before = np.isnan(t_cal) | (res.t_s < t_cal)
    for name, part in (("until_calibrated", scored & before), ("once_calibrated", scored & ~before)):
        online[name] = {"online": _figures(e_on[part], r_on[part], o.var[part]),
                        "offline": _figures(e_pose[part], e_rate[part], res.var[part])}
    out["online"] = online
    return out


def estimated_motion(res: FeederResult, warm: np.ndarray) -> dict:
    """Without truth, what the feeder did as estimated (after the warm-up): each axis' range and
    standard deviation, and the median sigma the filter gave it."""
    ok = warm & np.all(np.isfinite(res.pose), axis=1)
    if not ok.any():
        return {"samples": 0}
    pose, sd = res.pose[ok].copy(), np.sqrt(res.var[ok, :6])
    pose[:, 3:], sd[:, 3:] = np.degrees(pose[:, 3:]), np.degrees(sd[:, 3:])
    r = lambda v: [round(float(x), 5) for x in v]  # noqa: E731
    return {"samples": int(ok.sum()), "axes": ["x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg"],
            "min": r(pose.min(axis=0)), "max": r(pose.max(axis=0)), "std": r(pose.std(axis=0)),
            "median_sigma": r(np.median(sd, axis=0))}


def estimated_motion_line(e: dict) -> str | None:
    """One line of the feeder's estimated motion (kpis' `feeder.estimated`), or None."""
    if not e or not e.get("samples"):
        return None
    mm = lambda k: " / ".join(f"{1000 * x:.0f}" for x in e[k][:3])  # noqa: E731
    dg = lambda k: " / ".join(f"{x:.2f}" for x in e[k][3:])  # noqa: E731
    return (f"Feeder motion as estimated (no truth): std x/y/z {mm('std')} mm, r/p/y {dg('std')} deg; "
            f"median sigma x/y/z {mm('median_sigma')} mm, r/p/y {dg('median_sigma')} deg")


def _errors(est: FeederResult | CausalEstimates, pose_t: np.ndarray, rate_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e_pose = est.pose - pose_t
    e_pose[:, 3:] = (e_pose[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    return e_pose, est.rates - rate_t


def D_side_by_side(res: FeederResult, heave_D: tuple, warm: np.ndarray, D_true: np.ndarray | None) -> dict:
    """The feeder's D (the deck below the tip) beside the heave chain's fused D: their RMS
    difference needs no truth; each one's error does."""
    t_h, D_h = heave_D
    D_f = feeder_D(res)
    D_fused = np.interp(res.t_s, t_h, D_h, left=np.nan, right=np.nan)
    ok = warm & np.isfinite(D_fused) & np.isfinite(D_f)
    if D_true is not None:
        ok &= np.isfinite(D_true)
    if not ok.any():
        return {}
    rms = lambda e: round(float(np.sqrt(np.mean(e ** 2))), 5)
    out = {"feeder_minus_fused_rms_m": rms(D_f[ok] - D_fused[ok])}
    if D_true is not None:
        out = {"feeder_rmse_m": rms(D_f[ok] - D_true[ok]), "heave_fused_rmse_m": rms(D_fused[ok] - D_true[ok]), **out}
    return out


def feeder_D(res: FeederResult) -> np.ndarray:
    """The vertical distance from the tip (the frame's origin) down to the deck, from the
    estimated pose: the deck is the feeder frame's z = 0 plane, n.(X - p) = 0, met by the
    vertical X = (0, 0, -D) at D = -(n.p) / n_z."""
    return np.array([-deck_plane(p)[2] for p in res.pose])  # the plane's height at the origin is -D


def report_section(kpis: dict, windows=()) -> str:
    f = kpis.get("feeder") or {}
    lines = ["", "## Feeder 6-DOF relative to the crane vessel (documents 003, 004)", ""]
    lines.append("The feeder frame (origin at the deck point below the boom tip at the first LiDAR frame, z the deck "
                 "normal, x the centre line) in the heading frame at the boom tip. boomtip is full scale; document 004's "
                 "lab figures are multiplied by 10 for positions (its own rule), angles unchanged.")
    lines.append("")
    if "rmse_pos_m" not in f:
        why = "No scored sample (the run is shorter than the warm-up, or the estimate never started)" \
            if f.get("samples") == 0 else "No feeder truth to score against"
        lines.append(f"{why}. APT {f.get('apt_ms', float('nan')):.2f} ms per LiDAR frame.")
        motion = estimated_motion_line(f.get("estimated"))
        if motion:
            lines += ["", motion + "."]
        lines += _D_side_by_side_lines(f)
        return "\n".join(lines) + "\n"
    lines.append("| period | position RMS x/y/z [mm] | position max [mm] | angle RMS r/p/y [deg] | angle max [deg] | NEES (6) |")
    lines.append("|---|---|---|---|---|---|")

    def row(name, b):
        if not b or not b.get("samples"):
            return
        mm = lambda v: " / ".join(f"{1000 * x:.1f}" for x in v)
        dg = lambda v: " / ".join(f"{x:.3f}" for x in v)
        lines.append(f"| {name} | {mm(b['rmse_pos_m'])} | {mm(b['max_pos_m'])} | {dg(b['rmse_rpy_deg'])} | {dg(b['max_rpy_deg'])} | {b['nees_mean']:.2f} |")

    row("boomtip, whole run", f)
    row("boomtip online, whole run (each row levelled and defined with what was known at its time)", f.get("online"))
    if windows:
        row("boomtip, inside the outage windows", f.get("outage"))
        row("boomtip, outside them", f.get("outside_outage"))
        row("boomtip, inside the crane MRU's gaps (its attitude predicted, fusion/feeder_estimator)", f.get("mru_outage"))
    for name, d in DOC004.items():
        lines.append(f"| 004 {name} (x10) | {' / '.join(f'{10 * x:.1f}' for x in d['rms_mm'])} | "
                     f"{' / '.join(f'{10 * x:.1f}' for x in d['max_mm'])} | {' / '.join(f'{x:.2f}' for x in d['rms_deg'])} | "
                     f"{' / '.join(f'{x:.2f}' for x in d['max_deg'])} | |")
    lines.append("")
    lines.append(f"APT {f['apt_ms']:.2f} ms per LiDAR frame, worst {f['apt_ms_max']:.1f} ms (the whole chain's wall time on "
                 f"its thread: its deck stage, static-return mask, registration, filter, and its waits for the model's merges). Velocity RMSE x/y/z {' / '.join(f'{1000 * v:.1f}' for v in f['rmse_vel_mps'])} mm/s.")
    if f.get("model_merges"):
        lines.append("The feeder's model merged at " + ", ".join(
            f"{m['frames']} frames ({m['worker_s']:.2f} s "
            + ("inline, in its frame's time)" if m["status"] == "ok" and m["taken_frame"] == m["started_frame"] else
               f"in a worker beside the frames, taken {m['taken_frame'] - m['started_frame']} frames later, "
               f"{1e3 * m['wait_s']:.0f} ms waited for)" if m["status"] == "ok" else f"not taken: {m['status']})")
            for m in f["model_merges"]) + ".")
    if "levelling_tilt_deg" in f:
        t = f["levelling_tilt_deg"]
        lines.append(f"Levelling calibration (LiDAR mount and MRU bias together, from the deck normal over {t['span_s']:.0f} s; "
                     f"the feeder's mean roll and pitch taken as zero): {t['about_x']:.4f} deg about x, {t['about_y']:.4f} deg "
                     f"about y (1-sigma {t['sigma']:.4f}). "
                     + (f"About the vertical, from the own hull's edge (taken as along the crane's heading): {t['about_z']:.4f} deg "
                        f"(1-sigma {t['about_z_sigma']:.4f})." if t.get("about_z_sigma") is not None
                        else "About the vertical: not calibrated (no straight edge of the own hull found)."))
    lines += _online_lines(f.get("online"))
    if "feeder_mru" in f:
        m = f["feeder_mru"]
        lines.append(f"Feeder MRU (004's second MRU) used: heading offset between its heading frame and the crane's "
                     f"{m['heading_offset_deg']:.3f} deg (1-sigma {m['heading_offset_sigma_deg']:.3f}), its yaw in the map "
                     f"{m['body_yaw_in_map_deg']:.3f} deg (1-sigma {m['body_yaw_sigma_deg']:.3f}), its tilt from the deck "
                     f"normal {m['body_tilt_deg'][0]:.4f} / {m['body_tilt_deg'][1]:.4f} deg; {m['gaps']} frames fell in its gaps.")
    lines += _D_side_by_side_lines(f)
    return "\n".join(lines) + "\n"


def _online_lines(o: dict | None) -> list[str]:
    """When the online estimate's calibration applied, and how it compares before and after."""
    if not o:
        return []
    if o.get("calibrated_at_s") is None:
        return ["Online (feeder_estimates_online.csv, feeder_calibration.csv): the levelling was not calibrated in this run; "
                "every row has the survey's tilt and its 1-sigma (and the own hull's heading once it is known)."]
    text = (f"Online (feeder_estimates_online.csv, the calibration's history in feeder_calibration.csv, recomputed every "
            f"{o['update_every_s']:g} s from the data up to then): the survey's tilt until {o['calibrated_at_s']:.1f} s, "
            "the calibration from then on; the own hull's heading from its first edges.")
    parts = [(name, o[key]) for name, key in (("before", "until_calibrated"), ("after", "once_calibrated"))
             if o.get(key, {}).get("online", {}).get("samples")]
    if parts:
        dg = lambda v: " / ".join(f"{x:.3f}" for x in v)
        text += " Angle RMS r/p/y online against offline " + "; ".join(
            f"{name}: {dg(b['online']['rmse_rpy_deg'])} against {dg(b['offline']['rmse_rpy_deg'])} deg" for name, b in parts) + "."
    return [text]


def _D_side_by_side_lines(f: dict) -> list[str]:
    d = f.get("D_side_by_side", {})
    if "feeder_rmse_m" in d:
        return [f"D from this estimate: RMSE {1000 * d['feeder_rmse_m']:.2f} mm; the heave chain's fused D: "
                f"{1000 * d['heave_fused_rmse_m']:.2f} mm; their difference {1000 * d['feeder_minus_fused_rms_m']:.2f} mm RMS."]
    if d:
        return ["", f"D from this estimate and the heave chain's fused D: {1000 * d['feeder_minus_fused_rms_m']:.2f} mm RMS apart (no truth)."]
    return []


FEEDER_PLOT = "feeder_pose"


def write_feeder_plot(out: Path, res: FeederResult, truth: Truth | None, p_tip_crane_m: np.ndarray) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if len(res.t_s) == 0:
        return None
    pose_t = truth_of(res, truth, p_tip_crane_m)[0] if truth is not None and "feeder_x" in truth.columns else None
    fig, axes = plt.subplots(6, 1, figsize=(10, 12), sharex=True)
    scale = [1000.0] * 3 + [180 / math.pi] * 3
    units = ["mm"] * 3 + ["deg"] * 3
    for i, ax in enumerate(axes):
        sig = 3 * np.sqrt(res.var[:, i]) * scale[i]
        if pose_t is not None:
            e = (res.pose[:, i] - pose_t[:, i]) * scale[i]
            ax.plot(*decimated(res.t_s, e), lw=0.8, label="error")
            ax.fill_between(*decimated(res.t_s, -sig, sig), alpha=0.2, label="3 sigma")
            ax.set_ylabel(f"{POSE[i]} err [{units[i]}]")
        else:
            ax.plot(*decimated(res.t_s, res.pose[:, i] * scale[i]), lw=0.8)
            ax.set_ylabel(f"{POSE[i]} [{units[i]}]")
        ax.grid(alpha=0.3)
    legend(axes[0])
    axes[-1].set_xlabel("t [s] from the recording's start")
    axes[0].set_title("The feeder's pose relative to the crane vessel: " + ("error (estimate - truth) and its 3 sigma"
                      if pose_t is not None else "as estimated (no truth)"))
    return save(fig, plot_path(out, FEEDER_PLOT))
