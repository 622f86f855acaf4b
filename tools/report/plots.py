"""What every report's plots share: one `plots/` folder linked from the report, legends beside
the data (never over it), and the truth drawn over the estimates, where it stays visible."""

from __future__ import annotations

from pathlib import Path

__all__ = ["legend", "PLOTS_DIR", "plot_path", "plot_link", "link_in_report", "TRUTH_STYLE", "save"]

PLOTS_DIR = "plots"
# dashed and on top: an estimate that follows the truth closely shows through its gaps
TRUTH_STYLE = {"color": "black", "lw": 1.2, "ls": (0, (4, 3)), "zorder": 10}
DPI = 90


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
    return path
