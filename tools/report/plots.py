"""What every report's plots share."""

from __future__ import annotations

__all__ = ["legend"]


def legend(ax, **kwargs) -> None:
    """The axes' legend, when it has anything labelled (an empty panel, e.g. no radar's D-dot,
    gets none: matplotlib would warn)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)
