"""The crane truth's DOP853 integration as it goes (data/sim/crane_truth.py): the records a chunk at
a time, keeping only the solver's step in progress, so a long run's truth needs no whole-run arrays."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["dop853_chunks"]


def rhs_and_pieces(prm, flex, joints, vessel, duration_s, accel):
    """The state's derivative (a, a', b, b', f, f') for scipy, and the intervals between the
    inputs' breakpoints (acceleration steps) that it is integrated over one at a time."""
    sin, cos = math.sin, math.cos

    def rhs(t, y):
        J = joints.evaluate(t)
        V = vessel.evaluate(t)
        a, ad, b, bd, f, fd = y
        add, bdd, fdd = accel(sin, cos, prm, flex, a, ad, b, bd, *J, *V, f, fd)
        return [ad, add, bd, bdd, fd, fdd]

    def rhs_in_time(t, y):  # the accelerations depend on time beyond the inputs (gusts)
        J = joints.evaluate(t)
        V = vessel.evaluate(t)
        a, ad, b, bd, f, fd = y
        add, bdd, fdd = accel(sin, cos, prm, flex, a, ad, b, bd, *J, *V, f, fd, t=t)
        return [ad, add, bd, bdd, fd, fdd]

    bps = getattr(joints, "breakpoints", lambda: [])()
    edges = sorted({0.0, duration_s, *[t for t in bps if 0.0 < t < duration_s]})
    return rhs_in_time if getattr(accel, "time_varying", False) else rhs, [(t0, t1) for t0, t1 in zip(edges[:-1], edges[1:]) if t1 - t0 >= 1e-12]


def dop853_chunks(prm, flex, joints, vessel, y0, duration_s, t_rec, rtol, accel, chunk_n):
    """crane_truth's ``_dop853`` as it goes: (first record index, (m, 6) states) for ``chunk_n`` records at a
    time, keeping only the step in progress (not the whole run's dense output). The same solver
    steps as ``solve_ivp`` takes on each piece, and each record read from the interpolant of the
    same step as ``solve_ivp``'s dense output picks (the one ending at or after it): the same
    numbers to the last bit. A record on a breakpoint belongs to the later piece, as in
    :func:`_dop853`."""
    from scipy.integrate import DOP853

    rhs, pieces = rhs_and_pieces(prm, flex, joints, vessel, duration_s, accel)
    # each record's piece: the last one that holds it
    owner = np.full(len(t_rec), -1)
    for k, (t0, t1) in enumerate(pieces):
        owner[np.searchsorted(t_rec, t0, "left"):np.searchsorted(t_rec, t1, "right")] = k
    buf = np.empty((chunk_n, 6))
    n_buf, first = 0, 0
    y = np.asarray(y0, float)
    for k, (t0, t1) in enumerate(pieces):
        todo = np.flatnonzero(owner == k)
        solver = DOP853(rhs, t0, y, t1, rtol=rtol, atol=rtol * 1e-3)
        j = 0
        while True:
            solver.step()
            if solver.status == "failed":
                raise RuntimeError("DOP853 failed")
            done = solver.status == "finished"
            # the records up to this step's end (all that are left after the last step)
            j_end = len(todo) if done else int(np.searchsorted(t_rec[todo], solver.t, "right"))
            if j_end > j:
                interp = solver.dense_output()
                while j < j_end:
                    take = min(j_end - j, chunk_n - n_buf)
                    idx = todo[j:j + take]
                    if n_buf == 0:
                        first = int(idx[0])
                    buf[n_buf:n_buf + take] = interp(t_rec[idx]).T
                    n_buf += take
                    j += take
                    if n_buf == chunk_n:
                        yield first, buf.copy()
                        n_buf = 0
            if done:
                break
        y = solver.y
    if n_buf:
        yield first, buf[:n_buf].copy()
