"""report.md in document 000's Table 5.4 layout, with its published row beside ours, and plots."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np

from boomtip.data.frames import Truth
from boomtip.data.io.atomic import atomic_write_bytes
from boomtip.fusion.solutions import Estimates
from boomtip.perception.pipeline import Measurement
from boomtip.tools.report.kpis import WARMUP_S, consistency_table
from boomtip.tools.report.plots import TRUTH_STYLE, decimated, legend, plot_link, plot_path, save

# Document 000, Table 5.4 (after its Kalman filter) and its truth amplitudes (section 5.1.2).
DOC000 = {
    "deck_lidar": {"mae_D": 0.010, "max_D": 0.045, "mae_V": 0.048, "max_V": 0.225, "apt": 91.7},
    "deck_radar": {"mae_D": 0.018, "max_D": 0.128, "mae_V": 0.098, "max_V": 0.522, "apt": 34.8},
    "reflectors_lidar": {"mae_D": 0.013, "max_D": 0.088, "mae_V": 0.068, "max_V": 0.396, "apt": 1.9},
    "doppler_radar": {"mae_D": 0.159, "max_D": None, "mae_V": 0.018, "max_V": 0.057, "apt": 2.4},
}
DOC000_AMPLITUDE = {"D_m": 3.06, "D_dot_mps": 2.3}
COLORS = {"deck_lidar": "#1f77b4", "deck_radar": "#ff7f0e", "reflectors_lidar": "#2ca02c", "doppler_radar": "#9467bd", "fused": "#d62728",
          "doppler_radar_rot": "#17becf"}  # cyan: apart from doppler_radar's purple at a glance


def _fmt(v, pct_of=None, unit_mm=False) -> str:
    if v is None or not np.isfinite(v):
        return "-"
    s = f"{v * 1e3:.1f}" if unit_mm else f"{v:.3f}"
    if pct_of:
        s += f" ({100 * v / pct_of:.2f} %)"
    return s


def kpi_table(kpis: dict) -> str:
    amp = kpis.get("truth_max_amplitude", {})
    aD, aV = amp.get("D_m"), amp.get("D_dot_mps")
    lines = [
        "| solution | MAE D [mm] | max D [mm] | MAE D-dot [mm/s] | max D-dot [mm/s] | APT [ms] | doc 000: MAE D / max D [mm] | doc 000: MAE / max D-dot [mm/s] | doc 000 APT [ms] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, k in kpis.get("solutions", {}).items():
        d = DOC000.get(name)
        doc_d = f"{_fmt(d['mae_D'], DOC000_AMPLITUDE['D_m'], True)} / {_fmt(d['max_D'], None, True)}" if d else "not built"
        doc_v = f"{_fmt(d['mae_V'], DOC000_AMPLITUDE['D_dot_mps'], True)} / {_fmt(d['max_V'], None, True)}" if d else "not built"
        lines.append(
            f"| {name} | {_fmt(k['mae_D_m'], aD, True)} | {_fmt(k['max_D_m'], aD, True)} | {_fmt(k['mae_D_dot_mps'], aV, True)} | "
            f"{_fmt(k['max_D_dot_mps'], aV, True)} | {k['apt_ms']:.2f} | {doc_d} | {doc_v} | {d['apt'] if d else '-'} |"
        )
    return "\n".join(lines)


def estimated_tables(kpis: dict) -> str:
    """A run without truth: what each method measured and each solution estimated."""
    lines = ["| method | quantity | valid | min | median | max | median sigma | APT [ms] |", "|---|---|---|---|---|---|---|---|"]
    for m, k in kpis.get("measurements", {}).items():
        unit = "m" if k["quantity"] == "D" else "m/s"
        vals = [f"{k[c]:.3f} {unit}" if c in k else "-" for c in ("min", "median", "max_value")]
        vals.append(f"{1e3 * k['median_sigma']:.2f} m{unit}" if "median_sigma" in k else "-")
        lines.append(f"| {m} | {k['quantity']} | {100 * k['valid_fraction']:.1f} % | {' | '.join(vals)} | {k['apt_ms']:.2f} |")
    lines += ["", "| solution | D range [m] | max abs D-dot [m/s] | median sigma D [mm] | median sigma D-dot [mm/s] | "
              "last D [m] (3 sigma) | lost |", "|---|---|---|---|---|---|---|"]
    for n, e in kpis.get("estimated", {}).items():
        lost = f"{100 * e['lost_fraction']:.1f} %" if "lost_fraction" in e else "-"
        D = (f"{e['D_min_m']:.3f} to {e['D_max_m']:.3f}", f"{1e3 * e['median_sigma_D_m']:.2f}",
             f"{e['last_D_m']:.3f} ({3 * e['last_sigma_D_m']:.3f}) at {e['last_t_s']:.1f} s") if "D_min_m" in e else ("lost", "-", "-")
        V = (f"{e['D_dot_abs_max_mps']:.3f}", f"{1e3 * e['median_sigma_D_dot_mps']:.2f}") if "D_dot_abs_max_mps" in e else ("lost", "-")
        lines.append(f"| {n} | {D[0]} | {V[0]} | {D[1]} | {V[1]} | {D[2]} | {lost} |")
    return "\n".join(lines)


def measurement_table(kpis: dict) -> str:
    lines = ["| method | quantity | MAE | max | APT [ms] | valid |", "|---|---|---|---|---|---|"]
    for m, k in kpis.get("measurements", {}).items():
        unit = "mm" if k["quantity"] == "D" else "mm/s"
        lines.append(f"| {m} | {k['quantity']} | {_fmt(k.get('mae'), None, True)} {unit} | {_fmt(k.get('max'), None, True)} {unit} | "
                     f"{k['apt_ms']:.2f} | {100 * k['valid_fraction']:.1f} % |")
    return "\n".join(lines)


def write_report(out: Path, kpis: dict, estimates: dict[str, Estimates], truth: Truth, rows: Collection[Measurement]) -> None:
    plots = write_plots(out, estimates, truth, rows)
    amp = kpis.get("truth_max_amplitude", {})
    text = [
        f"# boomtip relative-heave report: {kpis['scenario']} (seed {kpis['seed']}, {kpis['duration_s']:.0f} s)",
        "",
        *[f"**Warning:** {w}" for w in kpis.get("warnings", [])],
        "",
        "Sources: " + "; ".join(f"{n}: D from {', '.join(v['D']) or 'none'}, D-dot from {', '.join(v['D_dot']) or 'D'}"
                                for n, v in kpis.get("sources", {}).items()),
        "",
        "## Solutions after the Kalman filter (document 000, Table 5.4 layout)",
        "",
        f"Errors against the closed-form truth, first {WARMUP_S:g} s excluded (filter convergence). Percentages are of the",
        f"truth's maximum amplitude: here {amp.get('D_m', float('nan')):.2f} m for D and {amp.get('D_dot_mps', float('nan')):.2f} m/s for D-dot",
        f"(document 000: {DOC000_AMPLITUDE['D_m']} m and {DOC000_AMPLITUDE['D_dot_mps']} m/s). APT is perception plus filter time per measurement cycle.",
        "",
        kpi_table(kpis),
        "",
        "## Raw measurements (before any filter)",
        "",
        measurement_table(kpis),
        "",
        *consistency_table(kpis),
        "## Plots",
        "",
        *[plot_link(p) for p in plots],
        "",
    ]
    atomic_write_bytes(out / "report.md", "\n".join(text).encode())


def write_plots(out: Path, estimates: dict[str, Estimates], truth: Truth, rows: Collection[Measurement]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for qi, (q, unit, scale) in enumerate((("D", "mm", 1e3), ("D_dot", "mm/s", 1e3))):
        fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(13, 7), sharex=True, gridspec_kw={"height_ratios": [1, 1.3]})
        ax1.axvspan(0, WARMUP_S, color="0.9", label=f"first {WARMUP_S:g} s: not scored")
        for name, e in estimates.items():
            c = COLORS.get(name)
            ax0.plot(*decimated(e.t_s, e.x[:, qi]), lw=1, color=c, label=name)
            err = (e.x[:, qi] - truth.at(q, e.t_s)) * scale
            ax1.plot(*decimated(e.t_s, err), lw=0.9, color=c, label=name)
        ax0.plot(*decimated(truth.t_s, truth.columns[q]), label="truth", **TRUTH_STYLE)
        ax0.set_ylabel(f"{q} [{'m' if q == 'D' else 'm/s'}]")
        legend(ax0, fontsize=8)
        ax0.set_title(f"{q}: estimates and the truth (dashed)")
        # Doppler-only D drifts by design; the limit follows the others so their errors stay readable.
        lim = _robust_limit([((e.x[:, qi] - truth.at(q, e.t_s)) * scale, e.t_s >= WARMUP_S) for n, e in estimates.items()
                             if not (q == "D" and n == "doppler_radar") or len(estimates) == 1])
        ax1.set_ylim(-lim, lim)
        ax1.axhline(0, color="black", lw=0.5)
        ax1.set_ylabel(f"error [{unit}]")
        ax1.set_xlabel("t [s] from the recording's start")
        legend(ax1, fontsize=8)
        ax1.set_title(f"{q} error (estimate - truth); y-axis clipped to the bulk of the scored errors"
                      + ("; doppler_radar's D drifts off-scale" if q == "D" and "doppler_radar" in estimates else ""))
        paths.append(save(fig, plot_path(out, f"heave_{q}")))
    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    for qi, (q, unit) in enumerate((("D", "mm"), ("D_dot", "mm/s"))):
        for name, e in estimates.items():
            keep = e.t_s >= WARMUP_S
            err = (e.x[keep, qi] - truth.at(q, e.t_s[keep])) * 1e3
            err = err[np.isfinite(err)]
            if name == "doppler_radar" and q == "D":
                continue  # drifts by design; it would swamp the others
            axes[qi].hist(err, bins=80, histtype="step", lw=1.5, color=COLORS.get(name), label=name)
        axes[qi].set_xlabel(f"{q} error [{unit}]")
        axes[qi].set_ylabel("estimates per bin [count]")
        axes[qi].set_title(f"{q} error histogram (t >= {WARMUP_S:g} s)")
    legend(axes[1], fontsize=8)
    paths.append(save(fig, plot_path(out, "error_histograms")))
    # Raw measurement errors per method.
    fig, ax = plt.subplots(2, 1, figsize=(13, 6), sharex=True)
    methods = sorted({r.method for r in rows})
    for m in methods:
        ok = [r for r in rows if r.method == m and r.ok]
        if not ok:
            continue
        t = np.array([r.t_s for r in ok])
        err = (np.array([r.value for r in ok]) - truth.at(ok[0].quantity, t)) * 1e3
        ax[0 if ok[0].quantity == "D" else 1].plot(t, err, ".", ms=2, label=m, color=COLORS.get(m))
    ax[0].set_ylabel("D error [mm]")
    ax[1].set_ylabel("D-dot error [mm/s]")
    ax[1].set_xlabel("t [s] from the recording's start")
    ax[0].set_title("Raw measurements minus truth (before filtering)")
    for a in ax:
        legend(a, fontsize=8, markerscale=6)
        a.axhline(0, color="black", lw=0.5)
    paths.append(save(fig, plot_path(out, "measurements")))
    return paths


def _robust_limit(errs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """A y-limit for the bulk of the scored errors: (errors, kept mask) per estimate."""
    if not errs:
        return 1.0
    vals = np.concatenate([np.abs(e[keep]) for e, keep in errs])
    vals = vals[np.isfinite(vals)]
    return float(np.percentile(vals, 99.5) * 1.2) if len(vals) else 1.0
