"""The clearance's filters: C and h themselves while rates come, the wave parts without them."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.clearance_filters import RATES_SILENT_S, ClearanceFilters
from boomtip.fusion.heave_filter import HeaveFilterConfig

SOURCES = ("c", "h", "c_rate", "h_rate")


def _run(with_rates_until_s: float, duration_s: float = 20.0):
    """A load lowered at 0.3 m/s over a deck heaving 0.5 m at 9 s: heights at 20 Hz, rates
    (exact) until the given time; the rope paid out as the hoist says."""
    f = ClearanceFilters(HeaveFilterConfig(), SOURCES)
    w = 2 * np.pi / 9.0
    out = []
    for t in np.arange(0.0, duration_s, 0.05):
        l, l_dot = 50.0 + 0.3 * t, 0.3
        h = 8.0 - 0.3 * t + 0.5 * np.sin(w * t)
        h_dot = -0.3 + 0.5 * w * np.cos(w * t)
        if t < with_rates_until_s:
            f.add_rates(t, (h_dot, 0.01), (h_dot, 0.01))
        f.add_heights(t, (h, 0.005), (h, 0.005), (l, l_dot))
        (x, P), _ = f.estimates(t)
        o, o_dot = f.offset((l, l_dot))
        out.append((t, x[0] - o, x[1] - o_dot, h, h_dot, f.follow_rates))
    return f, np.array(out)


def test_with_rates_the_filters_follow_c_and_h_and_the_rates_hold():
    f, out = _run(with_rates_until_s=np.inf)
    assert f.follow_rates and f.restarts == 1  # the first frame had no rate yet
    late = out[:, 0] > 3.0
    assert np.abs(out[late, 1] - out[late, 3]).max() < 0.01 and np.abs(out[late, 2] - out[late, 4]).max() < 0.01
    sources = {s for filt in f.filters() for s in filt.innovations().streams}
    assert sources == set(SOURCES)


def test_when_the_rates_stop_the_filters_follow_the_wave_parts_again():
    f, out = _run(with_rates_until_s=10.0)
    assert not f.follow_rates and f.restarts == 2
    switched = out[~out[:, 5].astype(bool) & (out[:, 0] > 10.0)][0, 0]
    assert switched == pytest.approx(10.0 + RATES_SILENT_S, abs=0.06)
    late = out[:, 0] > switched + 4.0  # the wave part's filter settled: the hoist is no jerk to it
    assert np.abs(out[late, 1] - out[late, 3]).max() < 0.02
    assert len(f.retired) == 4  # the first spell's (no rates yet) and the rates' spell's


def test_without_a_radar_the_filters_never_follow_rates():
    f, out = _run(with_rates_until_s=-1.0)
    assert not f.follow_rates and f.restarts == 0 and not f.ever_followed_rates
