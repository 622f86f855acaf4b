"""KPIs of document 000 (5.1.2): MAE, max absolute error, RMSE and APT, against the truth."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from boomtip.data.frames import Truth
from boomtip.fusion.solutions import Estimates
from boomtip.perception.pipeline import METHODS, Measurement

WARMUP_S = 5.0  # solutions: the first seconds are filter convergence and are not scored


def error_stats(err: np.ndarray) -> dict[str, float]:
    err = err[np.isfinite(err)]
    if len(err) == 0:
        return {"mae": float("nan"), "max": float("nan"), "rmse": float("nan"), "n": 0}
    a = np.abs(err)
    return {"mae": float(a.mean()), "max": float(a.max()), "rmse": float(np.sqrt(np.mean(err**2))), "n": int(len(err))}


def measurement_kpis(rows: Collection[Measurement], truth: Truth | None) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for m in METHODS:
        mine = [r for r in rows if r.method == m]
        if not mine:
            continue
        ok = [r for r in mine if r.ok]
        entry = {
            "quantity": mine[0].quantity,
            "apt_ms": float(np.mean([r.time_ms for r in mine])),
            "valid_fraction": len(ok) / len(mine),
            "frames": len(mine),
        }
        if truth is not None:
            t = np.array([r.t_s for r in ok])
            v = np.array([r.value for r in ok])
            stats = error_stats(v - truth.at(mine[0].quantity, t)) if len(ok) else error_stats(np.zeros(0))
            entry.update({"mae": stats["mae"], "max": stats["max"], "rmse": stats["rmse"]})
        elif ok:  # no truth: what was measured, and how sure each measurement said it was
            v = np.array([r.value for r in ok])
            entry.update({"min": float(v.min()), "median": float(np.median(v)), "max_value": float(v.max()),
                          "median_sigma": float(np.median([r.sigma for r in ok]))})
        out[m] = entry
    return out


def lost_kpis(est: Estimates, keep: np.ndarray) -> dict:
    """How much of the kept span the solution's D was lost (fusion.solutions.lost_estimates),
    from when and why first, and how much its D-dot was."""
    if est.lost is None:
        return {}
    have = keep & np.isfinite(est.x[:, 0])
    lost = have & est.lost.D
    out: dict = {"lost_fraction": float(lost.sum() / have.sum()) if have.any() else 0.0,
                 "lost_D_dot_fraction": float((have & est.lost.D_dot).sum() / have.sum()) if have.any() else 0.0}
    if lost.any():
        k = int(np.flatnonzero(lost)[0])
        out.update({"first_lost_t_s": float(est.t_s[k]), "first_lost_reason": str(est.lost.why[k])})
    return out


def estimated_kpis(est: Estimates) -> dict:
    """A solution without truth: the range of D where its D was not lost and of D-dot where its
    D-dot was not (a Doppler-only solution's D-dot stands without its D), the median sigmas, the
    last D, and how much of the run after the warm-up it was lost, so a run says what it found
    even when nothing can score it."""
    have = np.isfinite(est.x[:, 0]) & np.isfinite(est.var[:, 0])
    keep = est.t_s >= (est.t_s[0] if len(est.t_s) else 0.0) + WARMUP_S
    lost = lost_kpis(est, keep)
    ok_D = have & ~est.lost.D if est.lost is not None else have
    ok_V = have & ~est.lost.D_dot if est.lost is not None else have
    out: dict = {"estimates": int((ok_D | ok_V).sum())}
    if ok_D.any():
        D, sd = est.x[ok_D, 0], np.sqrt(est.var[ok_D, 0])
        out.update({"D_min_m": float(D.min()), "D_max_m": float(D.max()), "median_sigma_D_m": float(np.median(sd)),
                    "last_t_s": float(est.t_s[ok_D][-1]), "last_D_m": float(D[-1]), "last_sigma_D_m": float(sd[-1])})
    if ok_V.any():
        out.update({"D_dot_abs_max_mps": float(np.abs(est.x[ok_V, 1]).max()),
                    "median_sigma_D_dot_mps": float(np.median(np.sqrt(est.var[ok_V, 1])))})
    return {**out, **lost}


def consistency(est: Estimates, truth: Truth, keep: np.ndarray) -> dict:
    """Errors of D and D-dot over the kept samples, and the fraction of D errors within the
    filter's own 3 sigma (0.997 for an honest Gaussian)."""
    t = est.t_s[keep]
    eD = est.x[keep, 0] - truth.at("D", t)
    d = error_stats(eD)
    v = error_stats(est.x[keep, 1] - truth.at("D_dot", t))
    ok = np.isfinite(eD) & np.isfinite(est.var[keep, 0])
    within = float(np.mean(np.abs(eD[ok]) <= 3 * np.sqrt(est.var[keep, 0][ok]))) if ok.any() else float("nan")
    return {"mae_D_m": d["mae"], "max_D_m": d["max"], "rmse_D_m": d["rmse"], "mae_D_dot_mps": v["mae"],
            "max_D_dot_mps": v["max"], "rmse_D_dot_mps": v["rmse"], "within_3sigma_D": within, "samples": d["n"]}


def solution_kpis(est: Estimates, truth: Truth, rows: Collection[Measurement], methods: tuple[str, ...],
                  windows: list[tuple[float, float]] = ()) -> dict:
    keep = est.t_s >= (est.t_s[0] if len(est.t_s) else 0.0) + WARMUP_S  # from the source's first time stamp
    errors = consistency(est, truth, keep)
    used = [r for r in rows if r.method in methods]
    cycles = len({(r.t_s, r.method.split("_")[-1]) for r in used}) or 1
    perception_ms = sum(r.time_ms for r in used)
    out = {
        **errors,
        "apt_ms": (perception_ms + est.filter_ms) / cycles,
        "filter_ms_per_cycle": est.filter_ms / cycles,
        "measurements": est.inputs,
        "filter_status": est.statuses,
        **lost_kpis(est, keep),
    }
    if windows:  # the same figures over the samples inside the sensors' outages
        inside = np.zeros(len(est.t_s), bool)
        for a, b in windows:
            inside |= (est.t_s >= a) & (est.t_s < b)
        out["outage"] = consistency(est, truth, keep & inside)
    if est.lost is not None and (keep & est.lost.D).any():  # what a controller that heeds "lost" was given
        out["not_lost"] = consistency(est, truth, keep & ~est.lost.D)
    return out


def truth_amplitudes(truth: Truth) -> dict[str, float]:
    """Maximum amplitude of the truth about its mean (document 000's % reference)."""
    D, V = truth.columns["D"], truth.columns["D_dot"]
    return {"D_m": float(np.max(np.abs(D - D.mean()))), "D_dot_mps": float(np.max(np.abs(V - V.mean())))}


def consistency_table(kpis: dict) -> list[str]:
    """report.md's consistency section: per solution and stream, what its innovations say of
    its covariance (kpis' `consistency`), with no truth needed."""
    blocks = kpis.get("consistency") or {}
    if not blocks:
        return []
    lines = ["## Consistency (no truth needed)", "",
             "Each stream's normalised innovations squared (NIS): 1 per degree of freedom when the filter's covariance and "
             "the installation's stated noise are honest. **flagged**: the run's or a 10 s window's NIS beyond its "
             "chi-square 99.9 % bound (the sigmas are too small there); *underconfident*: below it (the sigmas are larger "
             "than the errors, which is safe). Widened: the largest factor the filter put on the stream's stated variance "
             "to match its innovations. The heave chain's estimates.csv marks each row by the same test over the trailing 10 s "
             "(`consistent`).", "",
             "| solution | stream | updates | NIS per dof | beyond 99 % | widened | verdict |", "|---|---|---|---|---|---|---|"]
    for solution, block in blocks.items():
        for stream, v in block.items():
            if not v.get("updates"):
                continue
            verdict = "**flagged**" if v["flagged"] else "*underconfident*" if v.get("underconfident") else "consistent"
            lines.append(f"| {solution} | {stream} | {v['updates']} | {v['nis_per_dof']:.2f} | {100 * v['beyond_99']:.1f} % | "
                         f"{v.get('noise_scale_max', 1.0):.1f}x | {verdict} |")
    return lines + [""]
