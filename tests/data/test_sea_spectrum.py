"""The JONSWAP spectrum (data/sea_spectrum.py): scaled so that 4 sqrt(m0) = Hs on the grid it is
given, the Pierson-Moskowitz / Bretschneider shape for gamma = 1, its peak at 2 pi / Tp, and the
peak enhancement gamma^r with the standard widths (sigma 0.07 below the peak, 0.09 above)."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.sea_spectrum import jonswap

HS_M, TP_S = 2.5, 8.0
WP = 2 * np.pi / TP_S


def _m0(S: np.ndarray, omega: np.ndarray) -> float:
    """The zeroth moment with the spectrum's own quadrature weights."""
    return float(np.sum(S * np.gradient(omega)))


@pytest.mark.parametrize("gamma", [1.0, 3.3, 7.0])
def test_zeroth_moment_is_hs_squared_over_16_on_a_uniform_grid(gamma):
    w = np.linspace(0.3, 3.0, 541)
    S = jonswap(w, HS_M, TP_S, gamma)
    assert _m0(S, w) == pytest.approx(HS_M**2 / 16, rel=1e-12)
    assert 4 * np.sqrt(_m0(S, w)) == pytest.approx(HS_M, rel=1e-12)
    assert np.all(S > 0)


def test_zeroth_moment_holds_on_the_simulators_randomised_grid():
    """motion.py draws one frequency inside each of 64 bands between 0.4 and 3 peak frequencies."""
    rng = np.random.default_rng(4)
    edges = np.linspace(0.4 * WP, 3.0 * WP, 65)
    w = edges[:-1] + rng.random(64) * np.diff(edges)
    assert 4 * np.sqrt(_m0(jonswap(w, HS_M, TP_S, 3.3), w)) == pytest.approx(HS_M, rel=1e-12)


def test_the_spectrum_scales_with_hs_squared():
    w = np.linspace(0.3, 3.0, 100)
    assert np.allclose(jonswap(w, 2 * HS_M, TP_S, 3.3), 4 * jonswap(w, HS_M, TP_S, 3.3), rtol=1e-14, atol=0)


def test_gamma_one_is_the_bretschneider_spectrum_normalised_on_the_grid():
    """S(w) = 5/16 Hs^2 wp^4 w^-5 exp(-5/4 (wp/w)^4) integrates to Hs^2/16 over (0, inf). On a
    grid [a, b] the spectrum carries all of Hs^2/16 inside it, so it is the closed form times
    1 / (F(b) - F(a)), F(w) = exp(-B w^-4) (the share of the closed form's energy below w,
    B = 5/4 wp^4): here 1.86e-3 above it. What remains is the quadrature's error: the
    gradient weights' half-cell at each end, h (f(a) + f(b)) / 2, and the trapezoid rule's
    h^2/12 |f'(b) - f'(a)| (Euler-Maclaurin)."""
    B = 1.25 * WP**4
    w = np.linspace(0.2, 4.0, 3801)
    h = w[1] - w[0]
    S = jonswap(w, HS_M, TP_S, 1.0)
    closed = 5 / 16 * HS_M**2 * WP**4 * w**-5 * np.exp(-B * w**-4)
    ratio = S / closed
    # the same shape at every frequency, to the rounding of exp's argument (up to ~300 here)
    assert np.ptp(ratio) / ratio.mean() < 4 * np.finfo(float).eps * (1 + (B * w**-4).max())

    share = np.exp(-B * w[-1] ** -4) - np.exp(-B * w[0] ** -4)
    f = lambda x: x**-5 * np.exp(-B * x**-4)  # noqa: E731
    df = lambda x: (-5 * x**-6 + 4 * B * x**-10) * np.exp(-B * x**-4)  # noqa: E731
    m0_shape = share / (4 * B)
    quadrature = (h * (f(w[0]) + f(w[-1])) / 2 + h**2 / 12 * abs(df(w[-1]) - df(w[0]))) / m0_shape
    assert 1 / share - 1 > 1e-3  # the truncation is far above the tolerance: the test sees it
    assert abs(ratio[0] * share - 1) <= quadrature * (1 + 1e-6)


def test_the_peak_is_at_two_pi_over_tp():
    w = WP * (1 + np.arange(-500, 2001) / 1000)  # wp itself is on the grid (index 500)
    for gamma in (1.0, 3.3):
        S = jonswap(w, HS_M, TP_S, gamma)
        assert int(np.argmax(S)) == 500, gamma
    # a longer peak period moves the peak down in frequency with it
    assert w[int(np.argmax(jonswap(w, HS_M, TP_S * 1.25, 3.3)))] == pytest.approx(WP / 1.25, abs=WP / 1000)


def test_peak_enhancement_is_gamma_to_the_standard_gaussian():
    """JONSWAP / PM = C gamma^r(w), r = exp(-(w - wp)^2 / (2 sigma^2 wp^2)), sigma 0.07 up to the
    peak and 0.09 above it; C (the two normalisations) cancels against w = 3 wp, where r < 1e-100."""
    gamma = 3.3
    w = WP * np.linspace(0.7, 3.0, 461)
    ratio = jonswap(w, HS_M, TP_S, gamma) / jonswap(w, HS_M, TP_S, 1.0)
    r = np.log(ratio / ratio[-1]) / np.log(gamma)
    sigma = np.where(w <= WP, 0.07, 0.09)
    expected = np.exp(-((w - WP) ** 2) / (2 * sigma**2 * WP**2))
    assert np.allclose(r, expected, rtol=0, atol=1e-12)
    assert r.max() == pytest.approx(1.0, abs=1e-12)  # the full factor gamma at the peak
