"""Wave spectra: pure functions shared by the simulator's irregular seas and the heave
filters' sea-state prior (a forecast's Hs and Tp)."""

from __future__ import annotations

import numpy as np


def jonswap(omega: np.ndarray, hs_m: float, tp_s: float, gamma: float) -> np.ndarray:
    """JONSWAP wave-elevation spectrum S(w) in m^2 s/rad, scaled so that 4 sqrt(m0) = Hs."""
    wp = 2 * np.pi / tp_s
    sigma = np.where(omega <= wp, 0.07, 0.09)
    shape = omega**-5 * np.exp(-1.25 * (wp / omega) ** 4) * gamma ** np.exp(-((omega - wp) ** 2) / (2 * sigma**2 * wp**2))
    dw = np.gradient(omega)
    m0 = np.sum(shape * dw)
    return shape * (hs_m / 4) ** 2 / m0
