"""The touchdown forecast: the wave part run forward by its AR model, the hoist held at its rate."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.lift_forecast import touchdown_forecasts

T = np.arange(0.0, 90.0, 0.05)


def waves(t):
    return 0.8 * np.sin(2 * np.pi * t / 9.0) + 0.3 * np.sin(2 * np.pi * t / 7.0 + 1.0)


def waves_rate(t):
    return 0.8 * 2 * np.pi / 9.0 * np.cos(2 * np.pi * t / 9.0) + 0.3 * 2 * np.pi / 7.0 * np.cos(2 * np.pi * t / 7.0 + 1.0)


def test_a_narrow_band_sea_and_a_steady_hoist_are_forecast_to_millimetres_per_second():
    hoist = 0.1 * T  # paying out 10 cm/s
    C = 10.0 - hoist + waves(T)
    f = touchdown_forecasts(T, C, hoist, horizon_s=8.0, history_s=40.0)
    k = int(np.argmin(np.abs(f.lead_s - 2.0)))
    target = f.t_issue + f.lead_s[k]
    inside = target < T[-1]
    assert np.sqrt(np.mean((f.relative_vz_mps[inside, k] - (waves_rate(target) - 0.1)[inside]) ** 2)) < 0.01
    assert np.sqrt(np.mean((f.clearance_m[inside, k] - (10.0 - 0.1 * target + waves(target))[inside]) ** 2)) < 0.01
    assert f.clearance_m.shape == (len(f.t_issue), len(f.lead_s)) and f.lead_s[-1] == pytest.approx(8.0)


def test_a_forecast_uses_only_what_came_before_it():
    hoist = np.zeros_like(T)
    C = 5.0 + waves(T)
    a = touchdown_forecasts(T, C, hoist, 8.0, 40.0)
    late = C.copy()
    late[T > 60.0] += 3.0  # the future changes
    b = touchdown_forecasts(T, late, hoist, 8.0, 40.0)
    before = a.t_issue < 60.0 - 0.2
    assert np.array_equal(a.clearance_m[before], b.clearance_m[before])


def test_nothing_after_a_gap_reaches_a_forecast_issued_before_its_end_and_none_is_issued_in_it():
    hoist = np.zeros_like(T)
    C = 5.0 + waves(T)
    C[(T > 33.0) & (T < 40.0)] = np.nan
    a = touchdown_forecasts(T, C, hoist, 8.0, 40.0)
    later = C.copy()
    later[T >= 40.0] += 3.0
    b = touchdown_forecasts(T, later, hoist, 8.0, 40.0)
    before = a.t_issue < 40.0
    assert np.array_equal(a.t_issue, b.t_issue) and np.array_equal(a.clearance_m[before], b.clearance_m[before])
    assert not np.any((a.t_issue > 33.5) & (a.t_issue < 40.0))


def test_gaps_and_nans_are_skipped_and_too_little_gives_no_forecast():
    C = 5.0 + waves(T)
    C[100:300] = np.nan
    f = touchdown_forecasts(T, C, np.zeros_like(T), 8.0, 40.0)
    assert len(f.t_issue) > 100 and np.all(np.isfinite(f.clearance_m))
    g = touchdown_forecasts(T[:3], C[:3], np.zeros(3), 8.0, 40.0)
    assert len(g.t_issue) == 0 and g.clearance_m.shape == (0, len(g.lead_s))
