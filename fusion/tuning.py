"""Process noise of the heave filters without an oracle: from a sea state, never from the
simulated world.

The filters' white-jerk PSD q follows the relative heave's spectrum. With no forecast, the
default is the worst sea the crane works in (Hs 4 m, a steep Tp of 7 s): too large a q only
costs a little smoothing (the filter's bandwidth grows as q^(1/6)), too small a q lags a
rough sea by centimetres. A user with a forecast gives `processing.sea_state` and gets the q
of that sea.
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.sea_spectrum import jonswap
from boomtip.fusion.heave_filter import jerk_psd_from_sea_state

WORKING_LIMIT_HS_M = 4.0
WORKING_LIMIT_TP_S = 7.0


def relative_heave_jerk_psd(hs_m: float, tp_s: float, gamma: float = 3.3) -> float:
    """White-jerk PSD q [m^2/s^5] for the relative heave in a JONSWAP sea.

    Both vessels are taken to follow the wave elevation one to one and independently (the
    relative heave's spectrum is twice the wave's): an upper bound for ships longer than the
    waves, whose response falls below one at short periods. The rule is
    `heave_filter.jerk_psd_from_sea_state`'s (q_k = A_k^2 w_k^5 / 2 per component) over the
    spectrum from 0.4 to 3 times the peak frequency, beyond which ships do not respond.
    """
    if not (math.isfinite(hs_m) and math.isfinite(tp_s)) or hs_m <= 0 or tp_s <= 0:
        raise ValueError(f"a sea state needs hs_m > 0 and tp_s > 0, got {hs_m!r}, {tp_s!r}")
    wp = 2 * np.pi / tp_s
    edges = np.linspace(0.4 * wp, 3.0 * wp, 65)
    w = (edges[:-1] + edges[1:]) / 2
    amplitude_D = np.sqrt(4.0 * jonswap(w, hs_m, tp_s, gamma) * np.diff(edges))  # sqrt(2 S_D dw), S_D = 2 S
    return jerk_psd_from_sea_state(zip(amplitude_D, 2 * np.pi / w))


def default_jerk_psd() -> float:
    """q for the working limit, Hs 4 m at Tp 7 s: holds for any sea up to it."""
    return relative_heave_jerk_psd(WORKING_LIMIT_HS_M, WORKING_LIMIT_TP_S)
