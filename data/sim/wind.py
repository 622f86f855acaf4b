"""Gusty wind on the hook: the steady wind plus turbulence along its direction, drawn from the
NPD (Froya) gust spectrum of ISO 19901-1 and DNV-RP-C205 (3.3.3), the offshore standards' spectrum
of the longitudinal wind speed:

    S(f) = 320 (U0/10)^2 (z/10)^0.45 / (1 + f~^n)^(5 / 3n),  f~ = 172 f (z/10)^(2/3) (U0/10)^-0.75,  n = 0.468

(S in m^2/s^2 per Hz, U0 the mean speed in m/s, z the height above the sea in m). The gust is a sum
of sines at log-spaced frequencies, each of the power its band holds, with random phases: a smooth
function of time the ODE solver can take at any instant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GUST_HEIGHT_M = 20.0  # a hook's working height above the sea
GUST_BAND_HZ = (1e-3, 2.0)  # slower is a change of the mean; faster holds no power the hook feels
GUST_COMPONENTS = 96
NPD_EXPONENT = 0.468


def npd_spectrum(f_hz: np.ndarray, mean_mps: float, height_m: float = GUST_HEIGHT_M) -> np.ndarray:
    """The NPD gust spectrum S(f) (m^2/s^2 per Hz) of a mean wind `mean_mps` at `height_m`."""
    u, z = mean_mps / 10.0, height_m / 10.0
    f_tilde = 172.0 * np.asarray(f_hz, float) * z ** (2.0 / 3.0) * max(u, 1e-9) ** -0.75
    return 320.0 * u * u * z ** 0.45 / (1.0 + f_tilde ** NPD_EXPONENT) ** (5.0 / (3.0 * NPD_EXPONENT))


@dataclass(frozen=True)
class GustyWind:
    """The wind (world x, y; m/s) at time t: `steady_mps` plus a gust along its direction."""

    steady_mps: tuple[float, float]
    amplitude_mps: np.ndarray  # (N,)
    omega_radps: np.ndarray  # (N,)
    phase_rad: np.ndarray  # (N,)

    @classmethod
    def draw(cls, steady_mps: tuple[float, float], seed: int, height_m: float = GUST_HEIGHT_M) -> "GustyWind":
        edges = np.geomspace(*GUST_BAND_HZ, GUST_COMPONENTS + 1)
        f = np.sqrt(edges[:-1] * edges[1:])
        mean = float(np.hypot(*steady_mps))
        amplitude = np.sqrt(2.0 * npd_spectrum(f, mean, height_m) * np.diff(edges)) if mean > 0 else np.zeros(len(f))
        phase = np.random.default_rng([seed, 0x9057]).uniform(0.0, 2.0 * np.pi, len(f))
        return cls((float(steady_mps[0]), float(steady_mps[1])), amplitude, 2.0 * np.pi * f, phase)

    def gust_mps(self, t_s) -> np.ndarray:
        """The gust's speed along the steady wind at the times (m/s)."""
        t = np.asarray(t_s, float)
        return np.cos(np.multiply.outer(t, self.omega_radps) + self.phase_rad) @ self.amplitude_mps

    def __call__(self, t_s: float) -> tuple[float, float]:
        wx, wy = self.steady_mps
        speed = np.hypot(wx, wy)
        if speed <= 0:
            return wx, wy
        g = float(self.gust_mps(t_s)) / speed
        return wx * (1.0 + g), wy * (1.0 + g)
