"""Gusts on the hook's wind: the offshore (NPD) gust spectrum's power, along the steady wind, and
what they do to the hanging hook."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from boomtip.data.crane_model import CraneParams
from boomtip.data.sim.crane_joints import CraneJointProfiles
from boomtip.data.sim.crane_truth import simulate_crane
from boomtip.data.sim.wind import GUST_BAND_HZ, GustyWind, npd_spectrum


def _static():
    return CraneJointProfiles.from_moves(0.3, math.radians(50.0), 80.0)


def test_the_npd_spectrum_at_its_reference_point_and_its_power():
    assert npd_spectrum(np.array([0.0]), 10.0, 10.0)[0] == pytest.approx(320.0)  # 320 (U0/10)^2 (z/10)^0.45 at f = 0
    assert npd_spectrum(np.array([0.0]), 20.0, 10.0)[0] == pytest.approx(4 * 320.0)
    # the standard's turbulence at 10 m/s and 10 m: a standard deviation of about 1 m/s (B(2.14, 1.42) / n / 172 x 320)
    variance, _ = quad(lambda f: npd_spectrum(np.array([f]), 10.0, 10.0)[0], 0, np.inf, limit=200)
    assert math.sqrt(variance) == pytest.approx(1.03, abs=0.05)


def test_gusts_carry_the_band_power_along_the_steady_wind():
    wind = GustyWind.draw((6.0, 8.0), seed=3, height_m=20.0)
    band, _ = quad(lambda f: npd_spectrum(np.array([f]), 10.0, 20.0)[0], *GUST_BAND_HZ, limit=400)
    assert 0.5 * np.sum(wind.amplitude_mps ** 2) == pytest.approx(band, rel=0.03)
    t = np.arange(0.0, 20000.0, 0.25)
    g = wind.gust_mps(t)
    assert abs(g.mean()) < 0.15 and g.std() == pytest.approx(math.sqrt(band), rel=0.15)
    wx, wy = wind(123.4)
    assert wy / wx == pytest.approx(8.0 / 6.0) and math.hypot(wx, wy) == pytest.approx(10.0 + wind.gust_mps(123.4))
    assert GustyWind.draw((6.0, 8.0), seed=3)(50.0) == wind(50.0)  # the seed's gusts
    assert GustyWind.draw((6.0, 8.0), seed=4)(50.0) != wind(50.0)
    assert GustyWind.draw((0.0, 0.0), seed=3)(50.0) == (0.0, 0.0)  # no wind, no gusts


def test_gusts_swing_the_hook_about_where_the_steady_wind_holds_it():
    P = CraneParams()  # document 002's 1000 t hook and load, 80 m of rope: a pendulum of 18 s
    kw = dict(wind_mps=(12.0, 0.0), drag_area_m2=20.0)
    steady = simulate_crane(P, _static(), None, 300.0, **kw)
    gusty = simulate_crane(P, _static(), None, 300.0, gust_seed=1, **kw)
    again = simulate_crane(P, _static(), None, 300.0, gust_seed=1, **kw)
    np.testing.assert_array_equal(gusty.p_hook_rel_tip, again.p_hook_rel_tip)
    late = steady.t > 100.0
    swing = gusty.p_hook_rel_tip[late, :2] - steady.p_hook_rel_tip[late, :2]
    # A gust of 1.3 m/s (sigma) on 12 m/s changes the drag by 2 x 1.3 / 12 of its 2.1 kN: 4 mm of
    # quasi-static sway, more where the gusts' power meets the pendulum's period.
    rms = np.sqrt(np.mean(swing ** 2, axis=0))
    assert 0.004 < rms[0] < 0.05 and rms[1] < 0.2 * rms[0]  # along the wind
    with pytest.raises(ValueError, match="dop853"):
        simulate_crane(P, _static(), None, 1.0, method="rk4", gust_seed=1, **kw)
