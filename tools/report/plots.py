"""What every report's plots share: one `plots/` folder linked from the report, legends beside
the data (never over it), and the truth drawn over the estimates, where it stays visible."""

from __future__ import annotations

import gc
from pathlib import Path

import numpy as np

__all__ = ["legend", "PLOTS_DIR", "plot_path", "plot_link", "link_in_report", "TRUTH_STYLE", "save", "decimated"]

PLOTS_DIR = "plots"
# dashed and on top: an estimate that follows the truth closely shows through its gaps
TRUTH_STYLE = {"color": "black", "lw": 1.2, "ls": (0, (4, 3)), "zorder": 10}
DPI = 90
# a series longer than twice this is drawn from its extremes in this many time bins: a plot is
# about 1200 pixels wide, so the line looks the same, and a long run's plots take no more memory
# or time than a short run's
DECIMATE_BINS = 4000


def legend(ax, outside: bool = True, **kwargs) -> None:
    """The axes' legend, beside the axes (outside: the default) or where asked, when it has
    anything labelled (an empty panel, e.g. no radar's D-dot, gets none: matplotlib would warn)."""
    if not ax.get_legend_handles_labels()[0]:
        return
    if outside:
        kwargs = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0, **kwargs}
        kwargs.pop("ncol", None)  # a column beside the axes
    ax.legend(**kwargs)


def plot_path(out: Path, name: str) -> Path:
    """OUT/plots/NAME.png, its folder made."""
    folder = Path(out) / PLOTS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{name}.png"


def plot_link(path: Path) -> str:
    """The Markdown image of a plot, relative to the report beside the plots folder."""
    return f"![{path.stem}]({PLOTS_DIR}/{path.name})"


def link_in_report(out: Path, title: str, path: Path) -> None:
    """A section `title` showing the plot at `path`, appended to OUT/report.md when there is one."""
    report = Path(out) / "report.md"
    if report.exists():
        with open(report, "a", encoding="utf-8") as fh:
            fh.write(f"\n## {title}\n\n{plot_link(path)}\n")


def save(fig, path: Path) -> Path:
    """Laid out (legends beside the axes included), written and closed."""
    import matplotlib.pyplot as plt

    if fig.get_layout_engine() is None:  # a figure may have its own (constrained)
        fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")  # the legends beside the axes kept whole
    plt.close(fig)
    gc.collect()  # a figure's artists are reference cycles: freed now, not after the next figures are drawn
    return path


def decimated(t, *ys, bins: int = DECIMATE_BINS) -> tuple[np.ndarray, ...]:
    """(t, *ys) thinned for a line or a band, all of the same length: in each of `bins` equal
    bins of t, the samples where each y is least and greatest, and the bin's first not-finite y
    (a gap stays a gap), in their order; a thinned series drops the rows whose t is not finite
    (matplotlib draws nothing there). A series of at most 2 x bins samples is returned as it is."""
    t = np.asarray(t, dtype=float)
    ys = tuple(np.asarray(y, dtype=float) for y in ys)
    if len(t) <= 2 * bins:
        return (t, *ys)
    ok = np.flatnonzero(np.isfinite(t))
    if len(ok) == 0:
        return (t[ok], *(y[ok] for y in ys))
    t0, span = float(t[ok].min()), float(np.ptp(t[ok])) or 1.0
    k = np.minimum(((t[ok] - t0) / span * bins).astype(np.int64), bins - 1)
    keep = []
    for y in ys:
        v = y[ok]
        finite = np.isfinite(v)
        order = np.lexsort((np.where(finite, v, np.inf), k))  # by bin, then by value, not-finite last
        starts = np.flatnonzero(np.r_[True, np.diff(k[order]) != 0])
        ends = np.r_[starts[1:], len(order)]
        n_finite = np.add.reduceat(finite[order].astype(np.int64), starts)
        keep += [order[starts], order[starts + np.maximum(n_finite - 1, 0)], order[np.minimum(starts + n_finite, ends - 1)]]
    rows = ok[np.unique(np.concatenate(keep))]
    return (t[rows], *(y[rows] for y in ys))
