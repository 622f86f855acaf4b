"""The hook chain's outputs: per-frame rows and estimates as CSV, the KPIs against the truth
(only when there is one), and report.md with document 002's Tables 6.1/6.4 layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.data.frames import Truth
from boomtip.data.io.atomic import atomic_text_file, atomic_write_bytes
from boomtip.fusion.hook_run import HookFilterRun
from boomtip.tools.report.hook_rows import COLUMNS, FrameRows
from boomtip.tools.report.hook_store import P, EstimateStore
from boomtip.tools.report.kpis import consistency_table
from boomtip.tools.report.plots import TRUTH_STYLE, legend, plot_link, plot_path, save

PLOT_EVERY = 4  # the report's plots take every 4th estimator sample (50 Hz): a 700 s run is 140,000 samples
# and at most about this many points per line: a plotted line's memory grows with its points, and
# a long run's lines at every 4th sample would add a hundred MB to the run's peak
PLOT_MAX_POINTS = 5_000

WARMUP_S = 5.0
ROWS_CHUNK = 2048  # hook_measurements.csv rows formatted at a time
CHI2_3_95 = 7.8147  # chi-square, 3 degrees of freedom, 95 %
# Document 002, Tables 6.1/6.3 (flexible model, EKF, LiDAR = truth + noise) and 6.4.
DOC002 = {  # Table 6.1, flexible internal model, EKF
    "hook-1": {"pos_cm": (1.811, 2.001, 1.667), "vel_cms": (0.633, 1.049, 2.883)},
    "hook-2": {"pos_cm": (1.832, 1.996, 1.690), "vel_cms": (0.640, 1.067, 2.951)},
    "hook-3": {"pos_cm": (2.005, 2.093, 1.817), "vel_cms": (1.007, 0.843, 2.683)},
    "hook-4": {"pos_cm": (2.292, 2.246, 3.576), "vel_cms": (1.251, 1.268, 5.517)},
}
DOC002_RUNTIME_PCT = "2.4-4.0 % (flexible EKF 3.3-3.8 %)"


def estimator_kpis(run: HookFilterRun, store: EstimateStore, truth: Truth) -> dict:
    """The estimator's errors against the truth, read from its stored samples a chunk at a time.
    The sums over the samples run in sample order, row after row, as numpy's mean over axis 0 of
    the whole series does: the same figures to the last bit."""
    # Runs shorter than the warm-up are scored over all their samples (and say so).
    t_from = WARMUP_S if store.n and store.t_last >= WARMUP_S else store.t_first
    n = 0
    sums = np.zeros((4, 3))  # squared errors: position, velocity, relative position, relative velocity
    peak = np.zeros((2, 3))  # largest |error|: position, velocity
    nees_parts = [np.zeros(0)]
    for c in store.chunks():
        keep = (c.t >= t_from) & (c.t <= truth.end_s)  # scored only where the truth is
        if not keep.any():
            continue
        t = c.t[keep]
        ref_p = np.column_stack([truth.at(f"hook_{a}", t) for a in "xyz"])
        ref_v = np.column_stack([truth.at(f"hook_v{a}", t) for a in "xyz"])
        ep, ev = c.p_hook[keep] - ref_p, c.v_hook[keep] - ref_v
        # Consistency on the ray-cast chain: NEES of the hook relative to the tip (the filter's own
        # 3x3 covariance of p_rel); a consistent filter averages 3, 95 % of samples below 7.81.
        ref_rel = np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
        e_rel = c.p_rel[keep] - ref_rel
        ev_rel = c.v_rel[keep] - np.column_stack([truth.at(f"hook_rel_v{a}", t) for a in "xyz"])
        nees_parts.append(np.einsum("ni,ni->n", e_rel, np.linalg.solve(c.cov_p[keep], e_rel[..., None])[..., 0]))
        for k, e in enumerate((ep, ev, e_rel, ev_rel)):
            sums[k] = np.concatenate([sums[k][None], e**2]).sum(axis=0)  # sequential: the running sum first
        peak = np.maximum(peak, [np.abs(ep).max(axis=0), np.abs(ev).max(axis=0)])
        n += len(t)
    nees = np.concatenate(nees_parts)
    rms = np.sqrt(sums / n) if n else np.full((4, 3), np.nan)
    return {
        "rmse_pos_m": rms[0].tolist(),
        "rmse_vel_mps": rms[1].tolist(),
        "max_pos_m": (peak[0] if n else np.full(3, np.nan)).tolist(),
        "max_vel_mps": (peak[1] if n else np.full(3, np.nan)).tolist(),
        # relative to the boom tip (what the LiDAR sees): the rest of the world-frame error is
        # the tip's own position, estimated from the encoders and the MRU
        "rmse_rel_pos_m": rms[2].tolist(),
        "rmse_rel_vel_mps": rms[3].tolist(),
        "evaluated_from_s": t_from,
        "nees_pos_mean": float(np.mean(nees)) if n else float("nan"),
        "nees_pos_within_95": float(np.mean(nees < CHI2_3_95)) if n else float("nan"),
        "runtime_fraction": run.realtime_fraction,
        "lidar_accepted": run.n_lidar_accepted,
        "lidar_rejected": run.n_lidar_rejected,
        "rope_accepted": run.n_rope_accepted,
        "rope_rejected": run.n_rope_rejected,
    }


SIGMA_EVERY = 10  # the median sigma of a path from every 10th sample (a 700 s run's is 14,000 of them)


def estimated_path(store: EstimateStore) -> dict:
    """Without truth, the hook's path as the estimator had it: its extent per axis (world
    frame), its top speed, the median sigma of its position relative to the tip and its last
    position, read from the stored samples a chunk at a time."""
    if store.n == 0:
        return {"samples": 0}
    lo, hi, top = np.full(3, np.inf), np.full(3, -np.inf), 0.0
    sigmas, last = [], None
    for c in store.chunks():
        lo, hi = np.minimum(lo, c.p_hook.min(axis=0)), np.maximum(hi, c.p_hook.max(axis=0))
        top = max(top, float(np.linalg.norm(c.v_hook, axis=1).max()))
        sigmas.append(np.sqrt(np.diagonal(c.cov_p, axis1=1, axis2=2))[::SIGMA_EVERY])
        last = (float(c.t[-1]), c.p_hook[-1])
    r = lambda v: [round(float(x), 4) for x in v]  # noqa: E731
    return {"samples": store.n, "min_m": r(lo), "max_m": r(hi), "top_speed_mps": round(top, 4),
            "median_sigma_rel_m": r(np.median(np.concatenate(sigmas), axis=0)), "last_t_s": last[0], "last_m": r(last[1])}


def segmentation_kpis(rows: FrameRows, truth: Truth) -> dict:
    """Precision and recall of the block's points over the frames with the hook in view, and
    the fixes' reference-point RMSE (model fits and sparse fixes apart)."""
    in_view = rows["hook_points_true"] > 0
    prec, rec = rows["precision"][in_view], rows["recall"][in_view]
    prec, rec = prec[np.isfinite(prec)], rec[np.isfinite(rec)]
    seg = {"precision": float(np.mean(prec)) if len(prec) else float("nan"),
           "recall": float(np.mean(rec)) if len(rec) else float("nan"), "frames_in_view": int(np.count_nonzero(in_view))}
    status, t_all, det_all = rows["status"], rows["t"], rows.xyz()
    for key, fixes in (("rmse_m", status == "ok"), ("sparse_rmse_m", status == "sparse")):
        if fixes.any():
            t, det = t_all[fixes], det_all[fixes]
            ref = np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
            sq = (det - ref) ** 2
            n = np.count_nonzero(np.isfinite(sq), axis=0)  # the truth may not cover every fix
            seg[key] = np.where(n > 0, np.sqrt(np.nansum(sq, axis=0) / np.maximum(n, 1)), np.nan).tolist()
    return seg


def rope_kpis(rows: FrameRows, truth) -> dict:
    """How often the rope was fitted, and (with a truth) its error: the angle between the fitted
    and the true direction tip -> hook, and that angle times the rope length per axis (what it
    means at the hook, the number comparable with a block fix's error)."""
    fits = rows["rope_status"] == "ok"
    n_fits = int(np.count_nonzero(fits))
    out = {
        "found_fraction": n_fits / max(len(rows), 1),
        "accepted_fraction": int(np.count_nonzero(rows["rope_accepted"][fits])) / max(n_fits, 1),
        "points_median": float(np.median(rows["rope_points"][fits])) if n_fits else 0.0,
        # what the points say the radius is, against the configured one the fit assumes
        "radius_median_m": float(np.median(rows["rope_radius_m"][fits])) if n_fits else float("nan"),
    }
    if truth is not None and n_fits:
        t = rows["t"][fits]
        u = rows.xyz("rope_u")[fits]
        ref = np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
        covered = np.all(np.isfinite(ref), axis=1)  # the truth may not cover every fit
        u, ref = u[covered], ref[covered]
        length = np.linalg.norm(ref, axis=1, keepdims=True)
        e = u - ref / length
        out["rmse_angle_mrad"] = float(1e3 * np.sqrt(np.mean(np.einsum("ij,ij->i", e, e))))
        out["rmse_at_hook_m"] = np.sqrt(np.mean((length * e) ** 2, axis=0)).tolist()
        prec = rows["rope_precision"][fits]
        prec = prec[np.isfinite(prec)]
        out["precision"] = float(np.mean(prec)) if len(prec) else float("nan")
    return out


def write_rows(path: Path, rows: FrameRows) -> None:
    """hook_measurements.csv: a row per LiDAR frame (empty for NaN), written ROWS_CHUNK rows at a
    time (a 700 s run's 14,000 rows as Python strings all at once would be about 35 MB)."""
    columns = {c: rows[c] for c in COLUMNS}
    with atomic_text_file(path) as fh:
        fh.write(",".join(COLUMNS) + "\n")
        for a in range(0, len(rows), ROWS_CHUNK):
            cols = []
            for c, v in columns.items():
                v = v[a:a + ROWS_CHUNK]
                if c in ("status", "rope_status"):
                    cols.append(['"' + s.replace('"', "'") + '"' for s in v])
                elif v.dtype == np.float64:
                    cols.append([f"{x:.6g}" if np.isfinite(x) else "" for x in v.tolist()])
                else:
                    cols.append([str(x) for x in v.tolist()])
            fh.write("".join(",".join(r) + "\n" for r in zip(*cols)))


def write_estimates(path: Path, stores: dict[str, EstimateStore]) -> None:
    """hook_estimates.csv, one estimator after the other, written a chunk of samples at a time."""
    with atomic_text_file(path) as fh:
        fh.write("t,estimator,x,y,z,vx,vy,vz,rel_x,rel_y,rel_z,rel_vx,rel_vy,rel_vz\n")
        for name, store in stores.items():
            for c in store.chunks():
                fh.write("".join(f"{row[0]:.4f},{name}," + ",".join(f"{x:.5f}" for x in row[1:]) + "\n"
                                 for row in c.block[:, :13]))


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


def write_hook_estimates_report(out: Path, kpis: dict) -> None:
    """report.md of a recording without truth: what was found and estimated, not how well."""
    hook = kpis["hook"]
    seg = hook["segmentation"]
    lines = [f"# boomtip hook report: {kpis['scenario']} ({kpis['duration_s']:g} s, no truth)", "",
             *[f"**Warning:** {w}" for w in kpis.get("warnings", [])], "",
             "No truth came with this recording: this report says what was estimated, not how well.", "",
             f"Hook found by the block model in {100 * seg['found_fraction']:.1f} % and by the sparse fix in "
             f"{100 * seg.get('sparse_fraction', 0.0):.1f} % of {seg['frames']} frames, {seg['apt_ms']:.1f} ms per frame.",
             "", rope_summary(hook["rope"]) if "rope" in hook else "", "",
             "## The hook's path as estimated (world frame)", "",
             "| estimator | x range [m] | y range [m] | z range [m] | top speed [m/s] | median sigma relative to the tip x/y/z [cm] | last position [m] |",
             "|---|---|---|---|---|---|---|"]
    for name, e in hook.get("estimated", {}).items():
        if not e.get("samples"):
            lines.append(f"| {name} | no estimate | | | | | |")
            continue
        rng = [f"{a:.2f} to {b:.2f}" for a, b in zip(e["min_m"], e["max_m"])]
        sig = " / ".join(f"{100 * x:.2f}" for x in e["median_sigma_rel_m"])
        last = ", ".join(f"{x:.2f}" for x in e["last_m"])
        lines.append(f"| {name} | {' | '.join(rng)} | {e['top_speed_mps']:.2f} | {sig} | {last} at {e['last_t_s']:.1f} s |")
    lines += ["", *consistency_table(kpis)]
    atomic_write_bytes(out / "report.md", ("\n".join(lines) + "\n").encode())


def write_hook_report(out: Path, kpis: dict, program: str | None, runs: dict[str, HookFilterRun],
                      stores: dict[str, EstimateStore], truth: Truth, rows) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hook = kpis["hook"]
    doc = DOC002.get(program or "")
    lines = [
        f"# boomtip hook report: {kpis['scenario']} (program {program or '-'}, seed {kpis['seed']}, {kpis['duration_s']:g} s)",
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
        *consistency_table(kpis),
        plot_link(plot_path(out, "hook_trajectory")),
        plot_link(plot_path(out, "hook_errors")),
        "",
    ]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    # the truth at the estimates' plotting rate too
    step = max(PLOT_EVERY, -(-max((st.n for st in stores.values()), default=0) // PLOT_MAX_POINTS))
    every = slice(None, None, step)
    tt = truth.t_s[every]

    def truth_plotted(name: str) -> np.ndarray:
        # a copy: a plotted view would keep the whole column (a 700 s run's 140,000 samples)
        return truth.columns[name][every].copy()

    ax[0].plot(truth_plotted("hook_x"), truth_plotted("hook_y"), label="truth", **TRUTH_STYLE)
    best = "ekf_flexible" if "ekf_flexible" in runs else next(iter(runs))
    t_best, p = stores[best].columns(P, step)
    ax[0].plot(p[:, 0], p[:, 1], "r", lw=1, label=runs[best].kind + " " + runs[best].model)
    ax[0].set_xlabel("x [m]")
    ax[0].set_ylabel("y [m]")
    ax[0].set_aspect("equal", adjustable="datalim")
    legend(ax[0])
    ax[0].set_title("hook path seen from above (world)")
    ax[1].plot(tt, truth_plotted("hook_z"), label="truth z", **TRUTH_STYLE)
    ax[1].plot(t_best, p[:, 2], "r", lw=1, label="estimate z")
    ok = rows["status"] == "ok"
    if ok.any():
        t_ok = rows["t"][ok]
        tip_z = truth.at("tip_z", t_ok)
        ax[1].plot(t_ok, tip_z + rows["z"][ok], ".", ms=2, color="tab:blue", label="LiDAR detections")
    ax[1].set_xlabel("t [s] from the recording's start")
    ax[1].set_ylabel("z [m]")
    legend(ax[1])
    ax[1].set_title("hook height")
    save(fig, plot_path(out, "hook_trajectory"))
    fig, ax = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    for name, run in runs.items():
        t, pv = stores[name].columns(slice(P.start, P.start + 6), step)
        p, v = pv[:, :3], pv[:, 3:]
        ref = np.column_stack([truth.at(f"hook_{a}", t) for a in "xyz"])
        refv = np.column_stack([truth.at(f"hook_v{a}", t) for a in "xyz"])
        # Colour by internal model, line style by estimator: EKF and UKF nearly coincide.
        style = {"color": "tab:green" if run.model == "flexible" else "tab:red", "ls": "-" if run.kind == "ekf" else "--",
                 "lw": 0.9 if run.kind == "ekf" else 1.2}
        ax[0].plot(t, 100 * np.linalg.norm(p - ref, axis=1), label=name, **style)
        ax[1].plot(t, 100 * np.linalg.norm(v - refv, axis=1), label=name, **style)
    ax[0].set_ylabel("|position error| [cm]")
    ax[1].set_ylabel("|velocity error| [cm/s]")
    ax[1].set_xlabel("t [s] from the recording's start")
    for a in ax:
        a.axvspan(0, WARMUP_S, color="0.9", label=f"first {WARMUP_S:g} s: not scored")
        legend(a, fontsize=8)
        a.set_yscale("log")
    ax[0].set_title("hook errors (world frame)")
    save(fig, plot_path(out, "hook_errors"))
