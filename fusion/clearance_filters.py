"""The clearance's two filters: C (the load's lowest point above the deck below it) and h (its
underside centre's), each the relative-heave filter's model (a value, its rate and acceleration).

Both fall as the hoist pays out rope l and swing with the waves. While a radar measures their
rates, the filters follow C and h themselves, hoist and all: the rates are measured, and the
hook tracker's l, differenced, would only add its jitter to them. Without rates (no radar, or
none from it for `RATES_SILENT_S`) they follow the wave parts C + l and h + l instead, smooth
narrow-band motions, so that heights alone need not follow the hoist's starts and stops as jerks.
At a change between the two the filters begin again (their states mean different things); the
filters of earlier spells are kept, so that every innovation is scored.
"""

from __future__ import annotations

import numpy as np

from boomtip.fusion.heave_filter import HeaveFilter, HeaveFilterConfig, Measurement

__all__ = ["ClearanceFilters", "RATES_SILENT_S"]

RATES_SILENT_S = 1.0  # no measured rate for this long: the filters follow the wave parts


class ClearanceFilters:
    def __init__(self, cfg: HeaveFilterConfig, sources: tuple[str, str, str, str]) -> None:
        """sources: the streams' names, the heights' (C, h) and the rates' (C-dot, h-dot)."""
        self.cfg, self.sources = cfg, sources
        self.clearance, self.height = HeaveFilter(cfg), HeaveFilter(cfg)
        self.follow_rates = False  # C and h themselves (rates measured), else C + l and h + l
        self.last_rate_s: float | None = None
        self.retired: list[HeaveFilter] = []
        self.restarts = 0

    def _mode(self, t_s: float) -> None:
        rates = self.last_rate_s is not None and t_s - self.last_rate_s <= RATES_SILENT_S
        if rates != self.follow_rates:
            self.retired += [self.clearance, self.height]
            self.clearance, self.height = HeaveFilter(self.cfg), HeaveFilter(self.cfg)
            self.follow_rates = rates
            self.restarts += 1

    def offset(self, hoist: tuple[float, float]) -> tuple[float, float]:
        """What the states hold beyond C and h, and its rate: l and its rate, or nothing."""
        return (0.0, 0.0) if self.follow_rates else hoist

    def add_heights(self, t_s: float, clearance: tuple[float, float], height: tuple[float, float],
                    hoist: tuple[float, float]) -> None:
        """A LiDAR frame's C and h (value, sigma) and the rope's length and rate then."""
        self._mode(t_s)
        l_m = self.offset(hoist)[0]
        self.clearance.add(Measurement(t_s, t_s, "D", clearance[0] + l_m, clearance[1], self.sources[0]))
        self.height.add(Measurement(t_s, t_s, "D", height[0] + l_m, height[1], self.sources[1]))

    def add_rates(self, t_s: float, clearance_rate: tuple[float, float], height_rate: tuple[float, float]) -> None:
        """A radar scan's C-dot and h-dot (value, sigma): into the filters while they follow C and h."""
        self.last_rate_s = t_s
        if self.follow_rates:
            self.clearance.add(Measurement(t_s, t_s, "D_dot", *clearance_rate, self.sources[2]))
            self.height.add(Measurement(t_s, t_s, "D_dot", *height_rate, self.sources[3]))

    def estimates(self, t_s: float) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """Both filters' (x, P) at t_s, in their states' terms (see offset)."""
        return self.clearance.estimate(t_s), self.height.estimate(t_s)

    def filters(self) -> list[HeaveFilter]:
        """Every filter of the run, the retired ones first: their innovations."""
        return [*self.retired, self.clearance, self.height]

    @property
    def ever_followed_rates(self) -> bool:
        return self.last_rate_s is not None
