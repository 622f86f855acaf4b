"""Whether a filter's covariance is honest, without truth: the normalised innovations squared
(NIS) of its updates, per measurement stream. A consistent filter's innovations are white with
the covariance it predicts, so a stream's NIS summed over n updates of d degrees of freedom is
chi-square with n d degrees of freedom. Beyond the interval, the filter's sigmas say more than
it knows (too large) or much less (too small)."""

from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv

__all__ = ["FLAG_PROBABILITY", "WINDOW_S", "Innovations", "consistent_rows", "stream_consistency",
           "consistency_block", "flagged_notes"]

WINDOW_S = 10.0  # a stream is also judged over each window of this length, not only over the run
FLAG_PROBABILITY = 0.999  # a consistent stream's NIS sum stays under this quantile (and over its complement)
BEYOND_PROBABILITY = 0.99  # `beyond_99`: the share of single updates beyond this quantile


def chi2_quantile(p: float | np.ndarray, dof: float | np.ndarray) -> np.ndarray:
    """The chi-square quantile 2 P^-1(dof/2, p), vectorised (scipy.special's, not scipy.stats')."""
    return 2.0 * gammaincinv(0.5 * np.asarray(dof, dtype=float), p)


# an update's row: time, NIS, degrees of freedom, noise scale
_T, _NIS, _DOF, _SCALE = range(4)
_FIRST_ROWS = 256  # a stream's first array; it doubles as it fills


class Innovations:
    """Every update's NIS, per stream (the measurement's method): time, NIS, degrees of freedom,
    and the factor the filter had widened the stream's stated covariance by (noise_matching).
    Kept as one float64 array per stream (32 bytes an update; a tuple of Python numbers would
    be five times that, and a long run has hundreds of thousands of updates)."""

    def __init__(self) -> None:
        self._rows: dict[str, np.ndarray] = {}
        self._n: dict[str, int] = {}

    def add(self, stream: str, t_s: float, nis: float, dof: int, noise_scale: float = 1.0) -> None:
        if not (np.isfinite(nis) and np.isfinite(t_s) and dof > 0):
            return
        rows, n = self._rows.get(stream), self._n.get(stream, 0)
        if rows is None or n == len(rows):
            grown = np.empty((max(_FIRST_ROWS, 2 * n), 4))
            if rows is not None:
                grown[:n] = rows
            self._rows[stream] = rows = grown
        rows[n] = (t_s, nis, dof, noise_scale)
        self._n[stream] = n + 1

    @property
    def streams(self) -> list[str]:
        return sorted(self._rows)

    def count(self, stream: str) -> int:
        return self._n.get(stream, 0)

    def arrays(self, stream: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Time, NIS, degrees of freedom and noise scale, in time order."""
        a = self._rows.get(stream, np.zeros((0, 4)))[:self.count(stream)]
        a = a[np.argsort(a[:, _T], kind="stable")]
        return a[:, _T], a[:, _NIS], a[:, _DOF], a[:, _SCALE]

    def only(self, streams) -> "Innovations":
        """These streams' rows alone."""
        out = Innovations()
        for s in self._rows:
            if s in streams:
                out._rows[s], out._n[s] = self._rows[s][:self._n[s]].copy(), self._n[s]
        return out

    @staticmethod
    def merged(parts: list["Innovations"], until_s: float = float("inf")) -> "Innovations":
        """The rows of several filters' innovations per stream, those before until_s."""
        out = Innovations()
        for s in sorted({s for p in parts for s in p._rows}):
            rows = np.concatenate([p._rows[s][:p._n[s]] for p in parts if s in p._rows])
            rows = rows[rows[:, _T] < until_s]
            if len(rows):  # a stream with nothing before until_s is no stream of it
                out._rows[s], out._n[s] = rows, len(rows)
        return out

    def __getstate__(self) -> dict:
        """Pickled (a solution's filter run in another process) without the arrays' unused rows."""
        return {"_rows": {s: a[:self._n[s]].copy() for s, a in self._rows.items()}, "_n": dict(self._n)}


def _window_sums(t_s: np.ndarray, nis: np.ndarray, dof: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """NIS and degrees of freedom summed over consecutive windows of window_s from the first update."""
    k = np.floor((t_s - t_s[0]) / window_s).astype(int)
    return np.bincount(k, nis), np.bincount(k, dof)


def _bounds(d: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """The chi-square quantiles alpha and 1 - alpha of d degrees of freedom (0 and inf where d = 0)."""
    have = d > 0
    lo = np.where(have, chi2_quantile(alpha, np.maximum(d, 1)), 0.0)
    hi = np.where(have, chi2_quantile(1.0 - alpha, np.maximum(d, 1)), np.inf)
    return lo, hi


def stream_consistency(t_s: np.ndarray, nis: np.ndarray, dof: np.ndarray, window_s: float = WINDOW_S,
                       probability: float = FLAG_PROBABILITY) -> dict:
    """One stream's consistency: the mean NIS per update (`nis_mean`, `nis_dof` degrees of
    freedom each on average), the share of updates beyond their chi-square 99 % bound
    (`beyond_99`), and `flagged`: the run's NIS sum, or any window's, above its chi-square
    quantile at `probability`, Bonferroni-corrected for the number of windows tested (so a
    consistent stream is flagged in about 1 - probability of runs): the filter's sigmas are
    too small for what it sees. Below the lower quantile the filter is `underconfident`: its
    sigmas are larger than its errors, which is safe and not flagged."""
    if len(nis) == 0:
        return {"updates": 0, "flagged": False, "underconfident": False}
    ws, wd = _window_sums(t_s, nis, dof, window_s)
    tests_s, tests_d = np.r_[nis.sum(), ws], np.r_[dof.sum(), wd]
    lo, hi = _bounds(tests_d, (1.0 - probability) / len(tests_s))
    over, under = tests_s > hi, tests_s < lo
    res = {"nis_mean": round(float(nis.mean()), 4), "nis_dof": round(float(dof.mean()), 3),
           "nis_per_dof": round(float(nis.sum() / dof.sum()), 4),
           "beyond_99": round(float(np.mean(nis > chi2_quantile(BEYOND_PROBABILITY, dof))), 4),
           "updates": int(len(nis)), "windows": int(len(ws)), "flagged": bool(over.any()),
           "underconfident": bool(under.any())}
    if over.any():
        worst = int(np.argmax(np.where(over, tests_s / np.maximum(tests_d, 1), -1.0)))
        res["worst_nis_per_dof"] = round(float(tests_s[worst] / tests_d[worst]), 4)
        res["flagged_from_s"] = round(float(t_s[0] + (worst - 1) * window_s if worst else t_s[0]), 3)
    return res


def consistency_block(innovations: Innovations, window_s: float = WINDOW_S) -> dict[str, dict]:
    """stream_consistency of every stream, with how far the filter widened its stated noise
    (`noise_scale_max`, `noise_scale_last`: factors on its variance)."""
    block = {}
    for s in innovations.streams:
        t, nis, dof, scales = innovations.arrays(s)
        block[s] = stream_consistency(t, nis, dof, window_s=window_s)
        if len(scales):
            block[s]["noise_scale_max"] = round(float(scales.max()), 3)
            block[s]["noise_scale_last"] = round(float(scales[-1]), 3)
    return block


def consistent_rows(t_out: np.ndarray, innovations: Innovations, window_s: float = WINDOW_S,
                    probability: float = FLAG_PROBABILITY, both_sides: bool = False) -> np.ndarray:
    """Per output time: whether every stream's NIS over the trailing window_s of acquisition
    time stays under its chi-square quantile at `probability` (only an overconfident filter
    fails; with both_sides also above the lower quantile). The NIS are the filter's settled
    ones (after any out-of-sequence replay), so a row may count a measurement that arrived
    after it by the sensor's latency. True where no update falls in the window."""
    ok = np.ones(len(t_out), dtype=bool)
    alpha = 1.0 - probability
    for stream in innovations.streams:
        t, nis, dof, _ = innovations.arrays(stream)
        cs, cd = np.r_[0.0, np.cumsum(nis)], np.r_[0.0, np.cumsum(dof)]
        hi_i = np.searchsorted(t, t_out, side="right")
        lo_i = np.searchsorted(t, t_out - window_s, side="right")
        s, d = cs[hi_i] - cs[lo_i], cd[hi_i] - cd[lo_i]
        lo, hi = _bounds(d, alpha)
        ok &= (s <= hi) & ((s >= lo) | (not both_sides))
    return ok


def flagged_notes(block: dict[str, dict], who: str) -> list[str]:
    """A note for each flagged stream whose innovations are larger than its covariance predicts."""
    return [f"{who}: the {stream} updates' innovations are {v['worst_nis_per_dof']:.1f} times what the filter's "
            f"covariance predicts from t = {v['flagged_from_s']:g} s (NIS per degree of freedom, 1 when consistent): "
            "its sigmas are too small there" for stream, v in block.items() if v.get("flagged")]
