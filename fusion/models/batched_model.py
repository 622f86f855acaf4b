"""The crane's equations of motion for many states at once (the UKF's 2n+1 sigma points),
generated from the trace of :func:`boomtip.data.crane_model.pendulum_accelerations_core`.

On arrays of 43 sigma points each of the core's ~250 scalar operations is one numpy call, and
its cost is the call, not the arithmetic. The trace (fusion/models/autodiff.py: the crane
parameters folded in, common subexpressions shared) splits the operations in two:

* those of the inputs only (slew, luff, hoist, roll, pitch and their rates: the tip's
  kinematics), evaluated once per RK4 step for the step's three input times together (t,
  t + h/2, t + h) on one array of 3 x 43 columns, instead of once per RK4 stage (4 times);
* those of the sway and deflection states (a, a', b, b'[, nu_f, nu_f']), evaluated per stage.

Both are compiled to straight-line numpy code (a value used once is inlined into its consumer's
expression). The operations, their order and operands are the core's, so the result is the
core's on arrays to the last bit. numpy has no expression compiler; numba and the like are not
among the project's dependencies, hence the generated Python.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from boomtip.data.crane_model import pendulum_accelerations_core
from boomtip.fusion.models.autodiff import _Tape, _TraceNode, ancestors
from boomtip.fusion.models.crane_pendulum import IA, IAD, IB, IBD, IF, IFD

__all__ = ["split_accelerations", "rk4_sigma_points"]

_SWAY = (IA, IAD, IB, IBD, IF, IFD)


def _generate(prm: tuple, flex: bool) -> tuple[Callable, Callable] | None:
    """(inputs_part(u) -> list of arrays, sway_part(a, a', b, b', f, f', *inputs_part) ->
    (a'', b''[, nu_f''])); u are the 15 input arrays (state indices 4..18). None when the core
    is not traceable."""
    n = 21 if flex else 19
    n_acc = 3 if flex else 2
    try:
        tape = _Tape()
        xs = tape.inputs(n)
        outs = list(pendulum_accelerations_core(tape.sin, tape.cos, prm, flex, *xs[:19],
                                                *((xs[IF], xs[IFD]) if flex else (0.0, 0.0)))[:n_acc])
    except Exception:  # not traceable: the caller uses the core itself
        return None
    if not all(isinstance(o, _TraceNode) for o in outs):
        return None
    nodes = tape.nodes
    live = ancestors(outs)
    sway = set(i for i in _SWAY if i < n)
    for nd in nodes[n:]:
        if any(isinstance(a, _TraceNode) and a.id in sway for a in nd.args):
            sway.add(nd.id)
    uses = [0] * len(nodes)
    for nd in nodes:
        if nd.id in live:
            for a in nd.args:
                if isinstance(a, _TraceNode):
                    uses[a.id] += 1
    # input-only values the sway part reads: the inputs part's results
    handed = sorted({a.id for nd in nodes if nd.id in live and nd.id in sway
                     for a in nd.args if isinstance(a, _TraceNode) and a.id not in sway})
    for o in outs:  # (an output of the inputs only would be handed over too)
        if o.id not in sway and o.id not in handed:
            handed.append(o.id)
    handed_set = set(handed)

    def emit(lines, expr, depth, nd, keep):
        a = nd.args
        ref = [expr[x.id] if isinstance(x, _TraceNode) else repr(x) for x in a]
        if nd.op == "neg":
            e = f"(-{ref[0]})"
        elif nd.op in ("sin", "cos"):
            e = f"{nd.op}({ref[0]})"
        else:
            e = f"({ref[0]} {nd.op} {ref[1]})"
        d = 1 + max((depth[x.id] for x in a if isinstance(x, _TraceNode)), default=0)
        if keep or uses[nd.id] > 1 or d > 40:
            lines.append(f"    v{nd.id} = {e}")
            e, d = f"v{nd.id}", 0
        expr[nd.id], depth[nd.id] = e, d

    kin = list(range(4, 19))
    lines = ["def _inputs(u):", "    sin = _sin; cos = _cos", "    " + "".join(f"v{k}, " for k in kin) + "= u"]
    expr = {k: f"v{k}" for k in kin}
    depth = dict.fromkeys(kin, 0)
    for nd in nodes[n:]:
        if nd.id in live and nd.id not in sway:
            emit(lines, expr, depth, nd, nd.id in handed_set)
    lines.append("    return [" + "".join(f"v{k}, " for k in handed) + "]")
    sway_in = [i for i in _SWAY if i < n]
    lines += [f"def _sway({', '.join(f'v{k}' for k in sway_in + handed)}):", "    sin = _sin; cos = _cos"]
    expr = {k: f"v{k}" for k in sway_in + handed}
    depth = dict.fromkeys(sway_in + handed, 0)
    for nd in nodes[n:]:
        if nd.id in live and nd.id in sway:
            emit(lines, expr, depth, nd, False)
    lines.append("    return " + ", ".join(expr[o.id] for o in outs))
    ns = {"_sin": np.sin, "_cos": np.cos}
    exec(compile("\n".join(lines), "<generated crane accelerations, batched>", "exec"), ns)
    return ns["_inputs"], ns["_sway"]


_SPLIT: dict[tuple, tuple[Callable, Callable] | None] = {}


def split_accelerations(prm: tuple, flex: bool) -> tuple[Callable, Callable] | None:
    """Cached :func:`_generate` (None: the core is not traceable)."""
    key = (prm, flex)
    if key not in _SPLIT:
        _SPLIT[key] = _generate(prm, flex)
    return _SPLIT[key]


def rk4_sigma_points(prm: tuple, flex: bool, X: np.ndarray, h: float) -> np.ndarray | None:
    """One RK4 step of the states X (n, N) -> (n, N): the same operations as
    :func:`~boomtip.fusion.models.crane_pendulum.rk4_batch` with the tip's kinematics evaluated
    once for the step's three input times. None when the core is not traceable."""
    split = split_accelerations(prm, flex)
    if split is None:
        return None
    inputs_part, sway_part = split
    n, N = X.shape
    h2 = 0.5 * h
    t1 = 0.5 * h2 * h2
    t2 = 0.5 * h * h
    C = X[4:19].reshape(5, 3, N)  # per chain (q, q', q'')
    q, qd, qdd = C[:, 0], C[:, 1], C[:, 2]
    # the inputs at t, t + h/2 and t + h side by side: U (5 chains, 3 derivatives, 3 times, N)
    U = np.empty((5, 3, 3, N))
    U[:, :, 0] = C
    U[:, 0, 1] = q + qd * h2 + qdd * t1
    U[:, 1, 1] = qd + qdd * h2
    U[:, 0, 2] = q + qd * h + qdd * t2
    U[:, 1, 2] = qd + qdd * h
    U[:, 2, 1] = qdd
    U[:, 2, 2] = qdd
    # each time's share of the inputs part as 1-D views (cheaper to pass than the rows of a
    # 2-D array unpacked into the call)
    K = inputs_part(U.reshape(15, 3 * N))
    k0, k1, k2 = ([v[j * N:(j + 1) * N] for v in K] for j in range(3))
    if flex:
        Y, V = X[[IA, IB, IF]], X[[IAD, IBD, IFD]]  # positions (a, b, nu_f), rates

        def acc(Yi, Vi, k):
            y0, y1, y2 = Yi
            v0, v1, v2 = Vi
            return np.array(sway_part(y0, v0, y1, v1, y2, v2, *k))
    else:
        Y, V = X[[IA, IB]], X[[IAD, IBD]]

        def acc(Yi, Vi, k):
            y0, y1 = Yi
            v0, v1 = Vi
            return np.array(sway_part(y0, v0, y1, v1, *k))

    a1 = acc(Y, V, k0)
    Y2, V2 = Y + h2 * V, V + h2 * a1
    a2 = acc(Y2, V2, k1)
    Y3, V3 = Y + h2 * V2, V + h2 * a2
    a3 = acc(Y3, V3, k1)
    Y4, V4 = Y + h * V3, V + h * a3
    a4 = acc(Y4, V4, k2)
    h6 = h / 6.0
    out = np.empty((n, N))
    m = len(Y)
    out[[IA, IB, IF][:m]] = Y + h6 * (V + 2 * V2 + 2 * V3 + V4)
    out[[IAD, IBD, IFD][:m]] = V + h6 * (a1 + 2 * a2 + 2 * a3 + a4)
    out[4:19] = U[:, :, 2].reshape(15, N)
    return out


