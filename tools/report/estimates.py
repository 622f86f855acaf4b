"""report.md for a run without truth (a real recording): what was estimated. D and D-dot per
solution with their sigma, each method's valid fraction, time and the reasons for its invalid
frames, and the gaps in each stream."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from boomtip.data.frames import MruLog
from boomtip.data.io.atomic import atomic_write_bytes
from boomtip.fusion.solutions import Estimates
from boomtip.perception.pipeline import SENSOR_OF, Measurement
from boomtip.tools.report.heave import COLORS
from boomtip.tools.report.kpis import consistency_table
from boomtip.tools.report.plots import PLOTS_DIR, decimated, legend, plot_link, plot_path, save

EPOCH_LIKE_S = 1e8  # a clock beyond this (1973) counts seconds since the epoch; below, a sensor's own


def stream_gaps(t_s: np.ndarray, nominal_dt_s: float, factor: float = 1.5) -> list[tuple[float, float]]:
    """Intervals between consecutive samples longer than factor x the nominal period."""
    t = np.sort(np.asarray(t_s, dtype=float))
    if len(t) < 2:
        return []
    d = np.diff(t)
    idx = np.flatnonzero(d > factor * nominal_dt_s)
    return [(float(t[i]), float(t[i + 1])) for i in idx]


def method_table(rows: Collection[Measurement]) -> list[str]:
    lines = ["| method | frames | valid | APT [ms] | why not valid (frames) |", "|---|---|---|---|---|"]
    for m in sorted({r.method for r in rows}):
        mine = [r for r in rows if r.method == m]
        bad = Counter(r.status.split(":")[0][:80] for r in mine if not r.ok)
        why = "; ".join(f"{k} ({v})" for k, v in bad.most_common(4)) or "-"
        lines.append(f"| {m} | {len(mine)} | {100 * sum(r.ok for r in mine) / len(mine):.1f} % | "
                     f"{np.mean([r.time_ms for r in mine]):.2f} | {why} |")
    return lines


def _clock(origin_s: float) -> str:
    """A source clock's value as people read it: UTC for an epoch clock, else seconds."""
    if origin_s > EPOCH_LIKE_S:
        return datetime.fromtimestamp(origin_s, timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return f"{origin_s:.6f} s on the source's clock"


def time_base(kpis: dict) -> list[str]:
    """The report's line on what t = 0 is, for a recording on a clock of its own."""
    origin = kpis.get("t_origin_s")
    if not origin:
        return []
    epoch = f" ({origin:.6f} s since the epoch)" if origin > EPOCH_LIKE_S else ""
    return [f"Times count from the recording's first stamp: t = 0 s is {_clock(origin)}{epoch}.", ""]


def write_estimates_report(out: Path, kpis: dict, estimates: dict[str, Estimates], rows: Collection[Measurement],
                           mru: MruLog | None, rates_hz: dict[str, float]) -> list[str]:
    """report.md of a recording without truth. mru: None when the installation logs no attitude
    (`attitude: level`)."""
    lines = [f"# boomtip relative-heave report: {kpis['scenario']} ({kpis['duration_s']:.0f} s, no truth)", "",
             *[f"**Warning:** {w}" for w in kpis.get("warnings", [])], "",
             "No truth came with this recording: this report says what was estimated, not how well.", "",
             *time_base(kpis),
             "## Solutions", "", "Lost: the share of the estimates after the first seconds whose sigma or value no "
             "measurement holds (estimates.csv's status says why, row by row); the range and sigmas are of the rest.", "",
             "| solution | D from | D-dot from | D range [m] | median sigma D [mm] | median sigma D-dot [mm/s] | lost |",
             "|---|---|---|---|---|---|---|"]
    for name, e in estimates.items():
        ok = np.isfinite(e.x[:, 0]) & (~e.lost.D if e.lost is not None else True)
        src = kpis.get("sources", {}).get(name, {})
        lost = (kpis.get("estimated") or {}).get(name, {}).get("lost_fraction")
        lost = "-" if lost is None else f"{100 * lost:.1f} %"
        head = f"| {name} | {', '.join(src.get('D', [])) or '-'} | {', '.join(src.get('D_dot', [])) or 'D'} | "
        if not ok.any():
            if np.isfinite(e.x[:, 0]).any():
                lines.append(head + f"lost throughout | | | {lost} |")
            continue
        lines.append(head + f"{np.min(e.x[ok, 0]):.3f} to {np.max(e.x[ok, 0]):.3f} | {1e3 * np.sqrt(np.median(e.var[ok, 0])):.2f} | "
                     f"{1e3 * np.sqrt(np.median(e.var[ok, 1])):.2f} | {lost} |")
    lines += ["", *consistency_table(kpis), "## Measurements", "", *method_table(rows), "", "## Gaps in the streams", ""]
    streams = {s: np.array(sorted({r.t_s for r in rows if SENSOR_OF[r.method] == s})) for s in ("lidar", "radar")}
    for s, t in streams.items():
        if len(t):
            gaps = stream_gaps(t, 1.0 / rates_hz[s])
            lines.append(f"- {s}: {len(t)} frames, {len(gaps)} gaps" + "".join(f"; {a:.2f}-{b:.2f} s" for a, b in gaps[:10]))
    if mru is None:
        lines.append("- MRU: none (`attitude: level`: the boom tip is taken as level)")
    else:
        gaps = stream_gaps(mru.t_s, float(np.median(np.diff(mru.t_s))) if len(mru.t_s) > 1 else 1.0)
        lines.append(f"- MRU: {len(mru.t_s)} samples, {len(gaps)} gaps" + "".join(f"; {a:.2f}-{b:.2f} s" for a, b in gaps[:10]))
    plot = _plot(out, estimates, kpis.get("t_origin_s"))
    lines += ["", plot_link(plot), ""]
    atomic_write_bytes(out / "report.md", "\n".join(lines).encode())
    return ["report.md", PLOTS_DIR]


def _plot(out: Path, estimates: dict[str, Estimates], t_origin_s: float | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(13, 7), sharex=True)
    for qi, label in enumerate(("D [m]", "D-dot [m/s]")):
        for name, e in estimates.items():
            if name == "doppler_radar" and qi == 0:
                continue  # integrated D drifts by design
            c = COLORS.get(name)
            ax[qi].plot(*decimated(e.t_s, e.x[:, qi]), lw=1, color=c, label=name)
            if name == "fused":
                s = 3 * np.sqrt(e.var[:, qi])
                ax[qi].fill_between(*decimated(e.t_s, e.x[:, qi] - s, e.x[:, qi] + s), color=c, alpha=0.2,
                                    label="fused +-3 sigma")
        ax[qi].set_ylabel(label)
        legend(ax[qi], fontsize=8)
    ax[1].set_xlabel("t [s] from the recording's start")
    ax[0].set_title("Estimates (no truth)" + (f"; the recording starts at {_clock(t_origin_s)}" if t_origin_s else ""))
    return save(fig, plot_path(out, "estimates"))
