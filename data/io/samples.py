"""Which samples of a logged stream (MRU, encoders) are bad, and why: a value that is not a
number or lies beyond physical bounds, a time that does not follow the log's own order, an
angle step no vessel makes (a glitch), angles frozen for a second in a log that moves (a
stuck sensor).

Bad references must not condemn good samples: a glitch in the first row, a stamp far in the
future, a glitch held for many samples. So times are judged by the log's longest increasing run
of stamps (one odd stamp cannot reorder the rest), and steps by the log's longest stretch
without an impossible step, from which the other stretches are joined on in both directions
when they continue it, and dropped when they do not.
"""

from __future__ import annotations

from bisect import bisect_left
from typing import Callable

import numpy as np

from boomtip.data.io.errors import RecordingError

__all__ = ["bad_samples", "drop_bad_samples", "STEP_FLOOR_RAD", "STEP_NOISE_SIGMAS"]

# A step is impossible beyond the column's rate bound times the time between the samples plus
# the log's own noise between two samples: STEP_NOISE_SIGMAS robust sigmas (from the median
# absolute deviation of its steps), and never less than STEP_FLOOR_RAD (a log quantised coarser
# than its noise, or one without noise).
STEP_NOISE_SIGMAS = 8.0
STEP_FLOOR_RAD = 0.005
STUCK_MIN_S = 1.0  # every value bit-identical this long, in a log that otherwise changes: a frozen sensor
STILL_LOG_SHARE = 0.5  # a log repeating more than half its samples is still or coarse, not frozen
MAX_GLITCH_S = 1.0  # a stretch longer than this is kept even when it does not continue its neighbours
MAD_TO_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation


def bad_samples(table: np.ndarray, names: list[str], time_column: str, bounds: dict[str, float],
                steps: dict[str, float]) -> dict[int, str]:
    """The bad rows of `table` (columns `names`) and why each is bad; good rows are absent.
    bounds: column -> largest magnitude; steps: angle column -> largest rate (per second)."""
    why: dict[int, str] = {}
    values = np.nan_to_num(table)
    for j, n in enumerate(names):
        for k in np.flatnonzero(~np.isfinite(table[:, j]) | (np.abs(values[:, j]) > bounds.get(n, np.inf))).tolist():
            if k not in why:
                v = float(table[k, j])
                limit = f"expected |{n}| <= {bounds[n]:g}" if np.isfinite(v) and n in bounds else "expected a finite number"
                why[k] = f"column '{n}' is {v!r} ({limit})"
    t = table[:, names.index(time_column)]
    ok = _rows_not_in(len(table), why)
    if len(ok) > 1 and np.any(np.diff(t[ok]) <= 0):
        in_order = ok[_longest_increasing(t[ok])]
        kept = np.zeros(len(table), dtype=bool)
        kept[in_order] = True
        for k in ok[~kept[ok]].tolist():
            j = int(np.searchsorted(in_order, k)) - 1  # the last kept sample before k
            if j >= 0 and t[k] <= t[in_order[j]]:
                why[k] = (f"time {float(t[k])!r} is not after the previous sample's {float(t[in_order[j]])!r}; "
                          "expected strictly increasing times")
            else:
                why[k] = f"time {float(t[k])!r} is after the samples that follow it; expected strictly increasing times"
        ok = in_order
    step_cols = [(names.index(n), rate) for n, rate in steps.items() if n in names]
    if len(ok) > 1 and step_cols:
        values = [j for j in range(len(names)) if names[j] != time_column]
        for k, reason in _stuck(table[ok], t[ok], values, names):
            why[int(ok[k])] = reason
        ok = _rows_not_in(len(table), why)
    if len(ok) > 1 and step_cols:
        for k, reason in _glitches(table[ok], t[ok], step_cols, names):
            why[int(ok[k])] = reason
    return why


def _rows_not_in(n: int, why: dict[int, str]) -> np.ndarray:
    good = np.ones(n, dtype=bool)
    good[list(why)] = False
    return np.flatnonzero(good)


def _stuck(table: np.ndarray, t: np.ndarray, cols: list[int], names: list[str]) -> list[tuple[int, str]]:
    """(row, why) of the samples of a frozen sensor: every value (angles and rates) bit-identical
    to the sample before for STUCK_MIN_S or longer, in a log whose values otherwise change from
    sample to sample. A log that mostly repeats itself (a level rig's, a vessel at a quay read
    in coarse steps) is what it is: no sample of it is called frozen. The run's first sample is
    kept."""
    same = np.all(np.diff(table[:, cols], axis=0) == 0.0, axis=1)
    if not same.any() or np.mean(same) > STILL_LOG_SHARE:
        return []
    edges = np.diff(np.concatenate([[0], same.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # rows [s+1, e] repeat row s
    out: list[tuple[int, str]] = []
    for s, e in zip(starts, ends):
        held_s = float(t[e] - t[s])
        if held_s >= STUCK_MIN_S:
            reason = (f"columns {', '.join(repr(names[j]) for j in cols)} unchanged for {held_s:.3g} s from "
                      f"t = {float(t[s]):.3f} s (a frozen sensor: expected its noise at least)")
            out.extend((k, reason) for k in range(s + 1, e + 1))
    return out


def drop_bad_samples(table: np.ndarray, names: list[str], where: str, unit: str, label: Callable[[int], str],
                     strict: bool, notes: list[str] | None, time_column: str = "t",
                     bounds: dict[str, float] | None = None, steps: dict[str, float] | None = None,
                     why: dict[int, str] | None = None) -> np.ndarray:
    """The good rows of a stream's `table`. A bad row (bad_samples, or a reason already in `why`)
    refuses the stream when `strict`, else is dropped and counted in `notes` with the `label`s
    of the first five (`unit` "line", label "12"; "message", "4 (t = ...)"); a stream of mostly bad rows is refused:
    that is no log. `where` names the stream (a file, a bag's topic) in every message."""
    why = {**bad_samples(table, names, time_column, bounds or {}, steps or {}), **(why or {})}
    if not why:
        return table
    rows = np.array(sorted(why))
    first = int(rows[0])
    if strict:
        raise RecordingError(f"{where}: {unit} {label(first)}: {why[first]}")
    if 2 * len(rows) > len(table):
        raise RecordingError(f"{where}: {len(rows)} of {len(table)} samples are bad (first: {unit} {label(first)}: "
                             f"{why[first]}); expected a log of mostly good samples")
    if notes is not None:
        shown = ", ".join(label(int(k)) for k in rows[:5])
        notes.append(f"{where}: dropped {len(rows)} of {len(table)} samples ({unit}s {shown}{', ...' if len(rows) > 5 else ''}): "
                     f"first {why[first]}")
    return np.delete(table, rows, axis=0)


def _longest_increasing(t: np.ndarray) -> np.ndarray:
    """Indices of a longest strictly increasing subsequence of t, keeping the earlier of two
    samples that compete (a late sample is the one dropped). Patience sorting (n log n) run
    backwards, on the longest decreasing run of the negated times."""
    tails: list[float] = []
    tail_index: list[int] = []
    parent = np.full(len(t), -1)
    for i in range(len(t) - 1, -1, -1):
        v = -float(t[i])
        p = bisect_left(tails, v)
        if p == len(tails):
            tails.append(v)
            tail_index.append(i)
        else:
            tails[p], tail_index[p] = v, i
        parent[i] = tail_index[p - 1] if p > 0 else -1
    out = []
    i = tail_index[-1]
    while i >= 0:
        out.append(i)
        i = parent[i]
    return np.array(out, dtype=int)


def _wrapped(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _tolerances(table: np.ndarray, step_cols: list[tuple[int, float]]) -> np.ndarray:
    """Per step column, the log's noise between two samples that a step may add to its bound."""
    tol = []
    for j, _ in step_cols:
        d = _wrapped(np.diff(table[:, j]))
        mad = float(np.median(np.abs(d - np.median(d))))
        tol.append(max(STEP_FLOOR_RAD, STEP_NOISE_SIGMAS * MAD_TO_SIGMA * mad))
    return np.array(tol)


def _excess(a: np.ndarray, b: np.ndarray, dt: float | np.ndarray, cols: np.ndarray, rates: np.ndarray,
            tol: np.ndarray) -> np.ndarray:
    """How far the steps from rows a to rows b exceed what a vessel can do in dt (> 0: a glitch)."""
    step = np.abs(_wrapped(b[..., cols] - a[..., cols]))
    return step - (rates * np.asarray(dt)[..., None] + tol)


def _glitches(table: np.ndarray, t: np.ndarray, step_cols: list[tuple[int, float]],
              names: list[str]) -> list[tuple[int, str]]:
    """(row, why) of the rows in stretches, none longer than MAX_GLITCH_S, that do not continue
    the log's longest good stretch (a step between two long stretches is a fact of the log, say a
    sensor's restart: neither side is dropped)."""
    cols = np.array([j for j, _ in step_cols])
    rates = np.array([r for _, r in step_cols])
    tol = _tolerances(table, step_cols)
    breaks = np.flatnonzero(np.any(_excess(table[:-1], table[1:], np.diff(t), cols, rates, tol) > 0, axis=1)) + 1
    if len(breaks) == 0:
        return []
    starts = np.concatenate([[0], breaks])
    ends = np.concatenate([breaks, [len(table)]])  # exclusive
    anchor = int(np.argmax(ends - starts))
    out: list[tuple[int, str]] = []

    def judge(ref: int, s: int, e: int, first: int) -> bool:
        """Does the stretch [s, e) continue from row ref (its nearest row being `first`)?"""
        exc = _excess(table[ref], table[first], abs(t[first] - t[ref]), cols, rates, tol)
        if np.all(exc <= 0) or t[e - 1] - t[s] > MAX_GLITCH_S:  # a long stretch is the log, whatever its step
            return True
        c = int(np.argmax(exc))
        step = float(abs(_wrapped(table[first, cols[c]] - table[ref, cols[c]])))
        reason = (f"column '{names[cols[c]]}' steps {step:.4g} in {abs(t[first] - t[ref]):.4g} s from the log's good "
                  f"samples (expected at most {rates[c]:g} per second and {tol[c]:.2g} of noise: a glitch)")
        out.extend((k, reason) for k in range(s, e))
        return False

    last = ends[anchor] - 1
    for s, e in zip(starts[anchor + 1:], ends[anchor + 1:]):
        if judge(last, s, e, s):
            last = e - 1
    first_good = starts[anchor]
    for s, e in zip(starts[:anchor][::-1], ends[:anchor][::-1]):
        if judge(first_good, s, e, e - 1):
            first_good = s
    return sorted(out)
