"""The lift chain's outputs: the clearance per frame (measured and filtered) and the touchdown
forecasts as CSV, the KPIs against the truth (when there is one), and report.md's lift section
with a plot of C and its forecasts.

Scored where the issue asks: the clearance over the samples whose true clearance lies between 0
and 10 m before touchdown; the forecast's rate 2 s ahead over the issues whose target instant
lies there too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from boomtip.data.frames import Truth
from boomtip.data.io.atomic import atomic_text_file
from boomtip.data.poses import rpy_matrices
from boomtip.fusion.consistency import Innovations, consistency_block
from boomtip.fusion.heave_filter import HeaveFilter
from boomtip.fusion.lift_forecast import TouchdownForecasts
from boomtip.perception.lift import LoadClearance
from boomtip.tools.report.plots import TRUTH_STYLE, decimated, legend, plot_link, plot_path, save

SCORED_CLEARANCE_M = (0.0, 10.0)  # the last 10 m of the lowering, before touchdown
PLOTTED_FORECAST_EVERY = 8  # of the forecasts' issues (every 0.5 s): one in 4 s drawn
FORECAST_LEAD_SCORED_S = 2.0
COLUMNS = ("t", "status", "deck", "estimate", "clearance_meas_m", "sigma_meas_m", "lowest_x_m", "lowest_y_m", "lowest_z_m",
           "deck_z_m", "centre_x_m", "centre_y_m", "height_meas_m", "landing_x_m", "landing_y_m", "landing_z_m",
           "landing_sigma_m", "deck_landing_x_m", "deck_landing_y_m", "deck_landing_z_m", "deck_landing_sigma_m", "deck_frame_s",
           "n_load", "n_deck", "clearance_m", "clearance_rate_mps", "sigma_m", "sigma_rate_mps", "height_m",
           "relative_vz_mps", "sigma_relative_vz_mps", "hoist_m")


# the frame's measurement status; its deck's source (lidar, or why the feeder's predicted pose gave it); the
# estimate's: ok, lost, no clearance yet, landed
TEXT_COLUMNS = ("status", "deck", "estimate")


def observation_row(obs: LoadClearance) -> dict:
    deck = "" if not obs.ok else "lidar" if obs.deck_hidden is None else f"predicted ({obs.deck_hidden})"
    return {"status": obs.status, "deck": deck, "clearance_meas_m": obs.clearance_m, "sigma_meas_m": obs.sigma_m,
            "lowest_x_m": obs.lowest_point_m[0], "lowest_y_m": obs.lowest_point_m[1], "lowest_z_m": obs.lowest_point_m[2],
            "deck_z_m": obs.deck_z_m, "centre_x_m": obs.landing_m[0], "centre_y_m": obs.landing_m[1],
            "height_meas_m": obs.centre_clearance_m,
            "landing_z_m": obs.landing_m[2], "n_load": obs.n_load, "n_deck": obs.n_deck}


def landed_row(obs: LoadClearance | None, landed_s: float, hoist_m: float) -> dict:
    """A frame after the load has landed: the filters stopped; the clearance as measured."""
    return {"estimate": f"landed at {landed_s:.2f} s", "clearance_m": obs.clearance_m if obs is not None else math.nan,
            "sigma_m": obs.sigma_m if obs is not None else math.nan, "hoist_m": hoist_m}


def landing_row(landing_xy: np.ndarray, var_m2: float) -> dict:
    return {"landing_x_m": float(landing_xy[0]), "landing_y_m": float(landing_xy[1]), "landing_sigma_m": math.sqrt(var_m2)}


def deck_landing_row(landing_deck: np.ndarray, sigma_m: float, key_t_s: float) -> dict:
    """The landing point in the feeder's deck frame (the levelled frame at `key_t_s`, carried with the feeder)."""
    return {"deck_landing_x_m": float(landing_deck[0]), "deck_landing_y_m": float(landing_deck[1]),
            "deck_landing_z_m": float(landing_deck[2]), "deck_landing_sigma_m": sigma_m, "deck_frame_s": key_t_s}


def estimate_row(clearance: tuple[np.ndarray, np.ndarray], height: tuple[np.ndarray, np.ndarray],
                 offset: tuple[float, float], hoist_m: float, lost_sigma_m: float) -> dict:
    """C, h and their rates from the filters' states C + o, h + o (x, P each) less the offset o
    and its rate (the rope's length and rate when the filters follow the wave parts, else 0);
    left empty, with the reason, when C's sigma exceeds `lost_sigma_m`."""
    offset_m, offset_rate_mps = offset
    (x, P), (xh, Ph) = clearance, height
    sigma = float(math.sqrt(max(P[0, 0], 0.0)))
    if not sigma <= lost_sigma_m:  # NaN too: no clearance measured yet
        return {"estimate": "lost" if math.isfinite(x[0]) else "no clearance yet", "sigma_m": sigma, "hoist_m": hoist_m}
    return {"estimate": "ok", "clearance_m": float(x[0]) - offset_m, "clearance_rate_mps": float(x[1]) - offset_rate_mps,
            "sigma_m": sigma, "sigma_rate_mps": float(math.sqrt(max(P[1, 1], 0.0))),
            "height_m": float(xh[0]) - offset_m, "relative_vz_mps": float(xh[1]) - offset_rate_mps,
            "sigma_relative_vz_mps": float(math.sqrt(max(Ph[1, 1], 0.0))), "hoist_m": hoist_m}


def as_columns(rows: list[dict]) -> dict[str, np.ndarray]:
    out = {}
    for c in COLUMNS:
        if c in TEXT_COLUMNS:
            out[c] = np.array([r.get(c, "") for r in rows], dtype=object)
        else:
            out[c] = np.array([r.get(c, math.nan) for r in rows], dtype=float)
    return out


def write_estimates(path: Path, cols: dict[str, np.ndarray]) -> None:
    """lift_estimates.csv: a row per LiDAR frame; lengths in metres, the lowest point and the
    deck's height in the levelled frame at the boom tip; `status` the frame's measurement's,
    `estimate` the filtered one's (ok, lost: its sigma beyond processing.lift.lost_sigma_m)."""
    with atomic_text_file(path) as fh:
        fh.write(",".join(COLUMNS) + "\n")
        for k in range(len(cols["t"])):
            fh.write(",".join(str(cols[c][k]) if c in TEXT_COLUMNS else f"{cols[c][k]:.6g}" for c in COLUMNS) + "\n")


def write_forecasts(path: Path, f: TouchdownForecasts) -> None:
    """lift_forecast.csv: a row per issue and lead: the forecast clearance, height and relative
    vertical velocity, and their 1-sigma."""
    with atomic_text_file(path) as fh:
        fh.write("t_issue,lead_s,clearance_m,height_m,relative_vz_mps,sigma_m,sigma_relative_vz_mps\n")
        for i, t in enumerate(f.t_issue):
            for k, lead in enumerate(f.lead_s):
                fh.write(f"{t:.3f},{lead:.2f},{f.clearance_m[i, k]:.5g},{f.height_m[i, k]:.5g},{f.relative_vz_mps[i, k]:.5g},"
                         f"{f.sigma_m[i, k]:.4g},{f.sigma_rate_mps[i, k]:.4g}\n")


class TruthUntil(Truth):
    """A truth that ends at `end_s` (NaN beyond): the hook's figures in a lift are scored while
    the rope holds the load; once it has landed, the rope is slack and the hoist no longer says
    where the hook is."""

    def __init__(self, truth: Truth, end_s: float) -> None:  # noqa: D107 (no dataclass fields of its own)
        self._truth, self._end_s = truth, end_s

    @property
    def columns(self):
        return self._truth.columns

    def at(self, name: str, t_s: np.ndarray) -> np.ndarray:
        v = self._truth.at(name, t_s)
        return v if name == "t" else np.where(np.asarray(t_s) <= self._end_s, v, np.nan)

    @property
    def end_s(self) -> float:
        return min(self._end_s, self._truth.end_s)


def until_touchdown(truth: Truth | None) -> Truth | None:
    """The truth up to the load's first contact (all of it when there is none)."""
    if truth is None or "contact" not in truth.columns:
        return truth
    t_td = touchdown_time(truth)
    return truth if t_td is None else TruthUntil(truth, t_td)


def _innovations(filters: list[HeaveFilter], until_s: float | None) -> Innovations:
    """The filters' innovations while the load hung (until it was found landed, if it was: the
    landing itself is a step no smooth model follows)."""
    return Innovations.merged([filt.innovations() for filt in filters], math.inf if until_s is None else until_s)


def _scored(truth: Truth, t: np.ndarray) -> np.ndarray:
    C = truth.at("clearance", t)
    lo, hi = SCORED_CLEARANCE_M
    return np.isfinite(C) & (C > lo) & (C <= hi) & (truth.at("contact", t) < 0.5)


def _rms(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2))) if len(e) else math.nan


def lift_kpis(rows: dict[str, np.ndarray], f: TouchdownForecasts, truth: Truth | None,
              filters: list[HeaveFilter], landed_s: float | None) -> dict:
    t, status = rows["t"], rows["status"]
    n = len(t)
    k: dict = {"frames": n, "clearance_found_fraction": float(np.mean(status == "ok")) if n else 0.0,
               "lost_fraction": float(np.mean(rows["estimate"] == "lost")) if n else 0.0,
               # frames whose deck about the load was hidden, taken from the feeder's predicted pose
               "deck_predicted_frames": int(sum(d.startswith("predicted") for d in rows["deck"])),
               "landed_detected_s": landed_s,
               "statuses": {s: int(np.count_nonzero(status == s)) for s in sorted(set(status.tolist()))},
               "consistency": consistency_block(_innovations(filters, landed_s))}
    if truth is None or "clearance" not in truth.columns:
        k["note"] = "no truth: the clearance and its forecast are in lift_estimates.csv and lift_forecast.csv"
        return k
    scored = _scored(truth, t)
    m = scored & (rows["estimate"] == "ok")  # the lost ones are counted apart, not scored
    C_true, rate_true = truth.at("clearance", t), truth.at("clearance_rate", t)
    err, err_meas = rows["clearance_m"] - C_true, rows["clearance_meas_m"] - C_true

    def within(e: np.ndarray, sigma: np.ndarray) -> float:
        return float(np.mean(np.abs(e[m]) <= 3.0 * sigma[m])) if m.any() else math.nan

    k["clearance"] = {"rmse_m": _rms(err[m]), "max_abs_m": float(np.nanmax(np.abs(err[m]))) if m.any() else math.nan,
                      "measured_rmse_m": _rms(err_meas[scored]), "within_3sigma": within(err, rows["sigma_m"]),
                      "samples": int(np.count_nonzero(m)),
                      "lost_fraction": float(np.mean(rows["estimate"][scored] == "lost")) if scored.any() else math.nan,
                      "landed_early_fraction": float(np.mean([e.startswith("landed") for e in rows["estimate"][scored]]))
                      if scored.any() else math.nan,
                      "scored": f"true clearance in ({SCORED_CLEARANCE_M[0]:g}, {SCORED_CLEARANCE_M[1]:g}] m before touchdown"}
    k["clearance_rate"] = {"rmse_mps": _rms((rows["clearance_rate_mps"] - rate_true)[m])}
    err_v = rows["relative_vz_mps"] - truth.at("relative_vz", t)
    k["relative_velocity"] = {"rmse_mps": _rms(err_v[m]), "within_3sigma": within(err_v, rows["sigma_relative_vz_mps"]),
                              "what": "the underside centre's vertical velocity relative to the deck below it"}
    # the landing point (the underside's centre dropped onto the deck) relative to the tip, world axes
    land_true = np.column_stack([truth.at("landing_rel_x", t), truth.at("landing_rel_y", t)])
    land_err = np.hypot(rows["landing_x_m"] - land_true[:, 0], rows["landing_y_m"] - land_true[:, 1])
    centre_err = np.hypot(rows["centre_x_m"] - land_true[:, 0], rows["centre_y_m"] - land_true[:, 1])
    both_within = (np.maximum(np.abs(rows["landing_x_m"] - land_true[:, 0]), np.abs(rows["landing_y_m"] - land_true[:, 1]))
                   <= 3.0 * rows["landing_sigma_m"])
    placed = m & np.isfinite(land_err)  # the rows with a landing point (a frame that measured the load)
    k["landing_point"] = {**_deck_landing_kpis(rows, truth, m),
                          "tip_rmse_m": _rms(land_err[m]), "tip_measured_rmse_m": _rms(centre_err[m]),
                          "tip_within_3sigma": float(np.mean(both_within[placed])) if placed.any() else math.nan,
                          "tip_frame": "relative to the boom tip, world axes"}
    k["touchdown_s"] = touchdown_time(truth)
    k["forecast"] = _forecast_kpis(f, truth)
    return k


def _deck_landing_kpis(rows: dict[str, np.ndarray], truth: Truth, m: np.ndarray) -> dict:
    """The landing point in the deck frame against the truth's in the feeder's body frame: the
    deck frame is the levelled frame at its keyframe's instant, which the truth's feeder pose
    relative to the tip then carries into the body frame."""
    key = rows["deck_frame_s"]
    ok = m & np.isfinite(key) & np.isfinite(rows["deck_landing_x_m"])
    frame = "the feeder's deck frame (the levelled frame at its keyframe, fixed to the feeder)"
    if not ok.any() or "feeder_rel_x" not in truth.columns:
        return {"rmse_m": math.nan, "placed_fraction": float(np.mean(ok[m])) if m.any() else math.nan, "frame": frame}
    t_key = key[ok]
    rel = np.column_stack([truth.at(f"feeder_rel_{a}", t_key) for a in "xyz"])
    R_f = rpy_matrices(np.column_stack([truth.at(f"feeder_{a}", t_key) for a in ("roll", "pitch", "yaw")]))
    p_deck = np.column_stack([rows[f"deck_landing_{a}_m"][ok] for a in "xyz"])
    p_body = np.einsum("mji,mj->mi", R_f, p_deck - rel)
    e = p_body[:, :2] - np.column_stack([truth.at("landing_x", rows["t"][ok]), truth.at("landing_y", rows["t"][ok])])
    return {"rmse_m": _rms(np.hypot(e[:, 0], e[:, 1])), "rmse_xy_m": [_rms(e[:, 0]), _rms(e[:, 1])],
            "within_3sigma": float(np.mean(np.max(np.abs(e), axis=1) <= 3.0 * rows["deck_landing_sigma_m"][ok])),
            "placed_fraction": float(np.count_nonzero(ok) / np.count_nonzero(m)), "keyframes": int(len(np.unique(t_key))),
            "frame": frame}


def radar_kpis(statuses: dict[str, int], times_ms: list[float], filter_restarts: int) -> dict:
    """The radar scans' share that gave the clearance's rate, why the others did not, their time,
    and how often the filters began again between following C and h and the wave parts."""
    n = sum(statuses.values())
    return {"scans": n, "rate_fraction": statuses.get("ok", 0) / n if n else 0.0, "statuses": dict(sorted(statuses.items())),
            "time_ms": float(np.median(times_ms)) if times_ms else math.nan, "filter_restarts": filter_restarts}


def touchdown_time(truth: Truth) -> float | None:
    c, t = truth.columns["contact"], truth.columns["t"]
    hit = np.flatnonzero(np.asarray(c) > 0.5)
    return float(t[hit[0]]) if len(hit) else None


def _forecast_kpis(f: TouchdownForecasts, truth: Truth) -> dict:
    if not len(f.t_issue):
        return {"issues": 0}
    j = int(np.argmin(np.abs(f.lead_s - FORECAST_LEAD_SCORED_S)))
    target = f.t_issue + f.lead_s[j]
    m = _scored(truth, target)
    # The forecast holds the hoist at its rate at the issue (the operator's next command is not
    # the sea's to forecast): its truth is the relative velocity with the hoist's later changes
    # taken out. Beside it, against the truth as it came.
    t_h = np.asarray(truth.columns["t"])
    hoist_rate = np.gradient(np.asarray(truth.columns["hoist"]), t_h)
    changes = np.interp(target, t_h, hoist_rate) - np.interp(f.t_issue, t_h, hoist_rate)
    v_true = truth.at("relative_vz", target)
    err, err_raw = f.relative_vz_mps[:, j] - (v_true + changes), f.relative_vz_mps[:, j] - v_true
    err_c = f.clearance_m[:, j] - truth.at("clearance", target)
    return {"rmse_mps_at_2s": _rms(err[m]), "rmse_mps_at_2s_with_hoist_changes": _rms(err_raw[m]),
            "clearance_rmse_m_at_2s": _rms(err_c[m]),
            "rate_within_2sigma_at_2s": float(np.mean(np.abs(err[m]) <= 2.0 * f.sigma_rate_mps[m, j])) if m.any() else math.nan,
            "issues_scored": int(np.count_nonzero(m)), "horizon_s": float(f.lead_s[-1]),
            "scored": "the relative vertical velocity with the hoist held at its rate at the issue"}


def write_lift_report(out: Path, kpis: dict, result, truth: Truth | None) -> list[str]:
    """report.md's lift section (appended) and plots/lift_clearance.png."""
    lines = ["", "## The lift: clearance, landing point and touchdown forecast", ""]
    k = kpis
    lines.append(f"Clearance found in {100 * k['clearance_found_fraction']:.1f} % of {k['frames']} LiDAR frames.")
    if "clearance" in k:
        c, f = k["clearance"], k["forecast"]
        lines += ["", "| quantity | RMSE | notes |", "|---|---|---|",
                  f"| clearance C | {100 * c['rmse_m']:.2f} cm | max {100 * c['max_abs_m']:.2f} cm, measured per frame "
                  f"{100 * c['measured_rmse_m']:.2f} cm, {100 * c['within_3sigma']:.1f} % within 3 sigma |",
                  f"| clearance rate | {100 * k['clearance_rate']['rmse_mps']:.2f} cm/s | the lowest point's, tilting included |",
                  f"| relative vertical velocity | {100 * k['relative_velocity']['rmse_mps']:.2f} cm/s | the underside centre's |",
                  f"| landing point | {100 * k['landing_point']['rmse_m']:.2f} cm | {k['landing_point']['frame']} |",
                  f"| landing point relative to the tip | {100 * k['landing_point']['tip_rmse_m']:.2f} cm | "
                  "world axes |",
                  f"| relative vertical velocity 2 s ahead | {100 * f.get('rmse_mps_at_2s', math.nan):.2f} cm/s | "
                  f"{f.get('issues_scored', 0)} issues |",
                  "", f"Scored: {c['scored']}; touchdown at {k['touchdown_s']} s."]
    names = []
    plot = _plot(out, result, truth)
    if plot is not None:
        lines += ["", plot_link(plot)]
        names.append("plots")
    with open(out / "report.md", "a", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return ["report.md"] + names


def _plot(out: Path, result, truth: Truth | None):
    import matplotlib.pyplot as plt

    rows, f = result.rows, result.forecasts
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    t = rows["t"]
    ax[0].plot(*decimated(t, rows["clearance_m"]), lw=1, label="C (filtered; measured once landed)")
    ax[1].plot(*decimated(t, rows["clearance_rate_mps"]), lw=1, label="C rate (filtered)")
    if truth is not None and "clearance" in truth.columns:
        ax[0].plot(*decimated(t, truth.at("clearance", t)), **TRUTH_STYLE)
        ax[1].plot(*decimated(t, truth.at("clearance_rate", t)), **TRUTH_STYLE)
    for i in range(0, len(f.t_issue), PLOTTED_FORECAST_EVERY):  # a forecast's path every few seconds
        ax[0].plot(f.t_issue[i] + f.lead_s, f.clearance_m[i], color="tab:orange", lw=0.6, alpha=0.7)
    ax[0].set_ylabel("clearance (m)")
    ax[1].set_ylabel("rate (m/s)")
    ax[1].set_xlabel("t (s)")
    legend(ax[0])
    path = plot_path(out, "lift_clearance")
    save(fig, path)
    return path
