"""The crane's equations of motion for many states at once (the UKF's 2n+1 sigma points),
generated from the trace of :func:`boomtip.data.crane_model.pendulum_accelerations_core`.

On arrays of 43 sigma points each of the core's ~250 scalar operations is one numpy call, and
its cost is the call, not the arithmetic. The trace (fusion/models/autodiff.py: the crane
parameters folded in, common subexpressions shared) splits the operations in two:

* those of the inputs only (slew, luff, hoist, roll, pitch and their rates: the tip's
  kinematics), evaluated once per step for the step's input times together (RK4: t, t + h/2,
  t + h on one array of 3 x 43 columns, instead of once per stage, 4 times; the midpoint rule:
  t, t + h/2);
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
from boomtip.fusion.models.autodiff import Tape, TraceNode, ancestors, node_expression
from boomtip.fusion.models.crane_pendulum import CHAINS, IA, IAD, IB, IBD, IF, IFD, state_size
from boomtip.fusion.models.jacobian import constant_part

__all__ = ["split_accelerations", "rk4_sigma_points", "midpoint_sigma_points", "midpoint_linearised_sigma_points"]

_SWAY = (IA, IAD, IB, IBD, IF, IFD)


def _generate(prm: tuple, flex: bool) -> tuple[Callable, Callable] | None:
    """(inputs_part(u) -> list of arrays, sway_part(a, a', b, b', f, f', *inputs_part) ->
    (a'', b''[, nu_f''])); u are the 15 input arrays (state indices 4..18). None when the core
    is not traceable."""
    n = state_size(flex)
    n_acc = 3 if flex else 2
    try:
        tape = Tape()
        xs = tape.inputs(n)
        outs = list(pendulum_accelerations_core(tape.sin, tape.cos, prm, flex, *xs[:19],
                                                *((xs[IF], xs[IFD]) if flex else (0.0, 0.0)))[:n_acc])
    except Exception:  # not traceable: the caller uses the core itself
        return None
    if not all(isinstance(o, TraceNode) for o in outs):
        return None
    nodes = tape.nodes
    live = ancestors(outs)
    sway = set(i for i in _SWAY if i < n)
    for nd in nodes[n:]:
        if any(isinstance(a, TraceNode) and a.id in sway for a in nd.args):
            sway.add(nd.id)
    uses = [0] * len(nodes)
    for nd in nodes:
        if nd.id in live:
            for a in nd.args:
                if isinstance(a, TraceNode):
                    uses[a.id] += 1
    # input-only values the sway part reads: the inputs part's results
    handed = sorted({a.id for nd in nodes if nd.id in live and nd.id in sway
                     for a in nd.args if isinstance(a, TraceNode) and a.id not in sway})
    for o in outs:  # (an output of the inputs only would be handed over too)
        if o.id not in sway and o.id not in handed:
            handed.append(o.id)
    handed_set = set(handed)

    # a constant operand as a named 0-d array: numpy takes ~2x as long for an operation with a
    # Python float as with an array (its scalar conversion), and the product is the same
    consts: dict[str, str] = {}

    def const(v):
        return consts.setdefault(repr(v), f"_c{len(consts)}")

    def emit(lines, expr, depth, nd, keep):
        a = nd.args
        e = node_expression(nd.op, [expr[x.id] if isinstance(x, TraceNode) else const(x) for x in a])
        d = 1 + max((depth[x.id] for x in a if isinstance(x, TraceNode)), default=0)
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
    ns = {"_sin": np.sin, "_cos": np.cos, **{name: np.array(float(v)) for v, name in consts.items()}}
    exec(compile("\n".join(lines), "<generated crane accelerations, batched>", "exec"), ns)
    return ns["_inputs"], ns["_sway"]


_SPLIT: dict[tuple, tuple[Callable, Callable] | None] = {}


def split_accelerations(prm: tuple, flex: bool) -> tuple[Callable, Callable] | None:
    """Cached :func:`_generate` (None: the core is not traceable)."""
    key = (prm, flex)
    if key not in _SPLIT:
        _SPLIT[key] = _generate(prm, flex)
    return _SPLIT[key]


def _inputs_at(inputs_part, X: np.ndarray, taus: tuple[float, ...]) -> np.ndarray:
    """The inputs part for the states X (n, N) at the times t + tau (taus[0] = 0), all times in
    one call on T x N columns: the handed values (T, H, N)."""
    N = X.shape[1]
    C = X[CHAINS].reshape(5, 3, N)  # per chain (q, q', q'')
    q, qd, qdd = C[:, 0], C[:, 1], C[:, 2]
    U = np.empty((5, 3, len(taus), N))  # (chains, derivatives, times, N)
    U[:, :, 0] = C
    for j, tau in enumerate(taus[1:], 1):  # :func:`~.crane_pendulum.kin_at`'s operations
        U[:, 0, j] = q + qd * tau + qdd * (0.5 * tau * tau)
        U[:, 1, j] = qd + qdd * tau
        U[:, 2, j] = qdd
    # one array of the handed values: each time's share is then a (H, N) view whose rows unpack
    # into the sway part in C (cheaper than a Python list of per-time slices)
    K = np.array(inputs_part(U.reshape(15, len(taus) * N)))
    return K.reshape(len(K), len(taus), N).transpose(1, 0, 2)


def _sway_evaluator(sway_part, flex: bool) -> Callable:
    """acc(Y, V, k) -> (a'', b''[, nu_f'']) as one (m, N) array, for positions Y = (a, b[, nu_f])
    and rates V (m, N) and the handed values k (H, N)."""
    if flex:
        def acc(Y, V, k):
            y0, y1, y2 = Y
            v0, v1, v2 = V
            return np.array(sway_part(y0, v0, y1, v1, y2, v2, *k))
    else:
        def acc(Y, V, k):
            y0, y1 = Y
            v0, v1 = V
            return np.array(sway_part(y0, v0, y1, v1, *k))
    return acc


def _end_state(X: np.ndarray, h: float, Y1: np.ndarray, V1: np.ndarray) -> np.ndarray:
    """The state after a step h: positions Y1 and rates V1 (m, N) of the sway (and deflection),
    the kinematic chains extrapolated exactly (constant acceleration)."""
    n, N = X.shape
    C = X[CHAINS].reshape(5, 3, N)
    q, qd, qdd = C[:, 0], C[:, 1], C[:, 2]
    out = np.empty((n, N))
    out[IA:IB + 1:2], out[IAD:IBD + 1:2] = Y1[:2], V1[:2]  # (a, b) at 0, 2; their rates at 1, 3
    if len(Y1) == 3:
        out[IF], out[IFD] = Y1[2], V1[2]
    Co = out[4:19].reshape(5, 3, N)
    Co[:, 0] = q + qd * h + qdd * (0.5 * h * h)
    Co[:, 1] = qd + qdd * h
    Co[:, 2] = qdd
    return out


def _positions_rates(X: np.ndarray, flex: bool) -> tuple[np.ndarray, np.ndarray]:
    return (X[[IA, IB, IF]], X[[IAD, IBD, IFD]]) if flex else (X[[IA, IB]], X[[IAD, IBD]])


def rk4_sigma_points(prm: tuple, flex: bool, X: np.ndarray, h: float) -> np.ndarray | None:
    """One RK4 step of the states X (n, N) -> (n, N): the same operations as
    :func:`~boomtip.fusion.models.crane_pendulum.rk4_batch` with the tip's kinematics evaluated
    once for the step's three input times. None when the core is not traceable."""
    split = split_accelerations(prm, flex)
    if split is None:
        return None
    inputs_part, sway_part = split
    h2 = 0.5 * h
    k0, k1, k2 = _inputs_at(inputs_part, X, (0.0, h2, h))
    acc = _sway_evaluator(sway_part, flex)
    Y, V = _positions_rates(X, flex)
    a1 = acc(Y, V, k0)
    Y2, V2 = Y + h2 * V, V + h2 * a1
    a2 = acc(Y2, V2, k1)
    Y3, V3 = Y + h2 * V2, V + h2 * a2
    a3 = acc(Y3, V3, k1)
    Y4, V4 = Y + h * V3, V + h * a3
    a4 = acc(Y4, V4, k2)
    h6 = h / 6.0
    return _end_state(X, h, Y + h6 * (V + 2 * V2 + 2 * V3 + V4), V + h6 * (a1 + 2 * a2 + 2 * a3 + a4))


def midpoint_sigma_points(prm: tuple, flex: bool, X: np.ndarray, h: float) -> np.ndarray | None:
    """One explicit midpoint step (second-order Runge-Kutta, two evaluations of the model
    instead of RK4's four) of the states X (n, N) -> (n, N): the same operations as
    :func:`~boomtip.fusion.models.crane_pendulum.midpoint_batch`. None when the core is not
    traceable."""
    split = split_accelerations(prm, flex)
    if split is None:
        return None
    inputs_part, sway_part = split
    h2 = 0.5 * h
    k0, k1 = _inputs_at(inputs_part, X, (0.0, h2))
    acc = _sway_evaluator(sway_part, flex)
    Y, V = _positions_rates(X, flex)
    a1 = acc(Y, V, k0)
    Ym, Vm = Y + h2 * V, V + h2 * a1
    a2 = acc(Ym, Vm, k1)
    return _end_state(X, h, Y + h * Vm, V + h * a2)


_HALF_STEP: dict[tuple, np.ndarray] = {}


def _half_step_matrix(n: int, flex: bool, h: float) -> np.ndarray:
    """M (n, n): the midpoint's displacement X(t + h/2) - X(t) = M X of the linear rows (the
    chains' constant-acceleration extrapolation, the sway angles' rates); the accelerations'
    rows are zero (their share is h/2 times the model's accelerations)."""
    key = (n, flex, round(h, 12))
    M = _HALF_STEP.get(key)
    if M is None:
        A0 = constant_part(n, flex)
        M = _HALF_STEP[key] = (0.5 * h) * A0 + (0.125 * h * h) * (A0 @ A0)
        if len(_HALF_STEP) > 64:
            _HALF_STEP.clear()
    return M


def midpoint_linearised_sigma_points(prm: tuple, flex: bool, X: np.ndarray, h: float, J: np.ndarray,
                                     core: bool = False) -> np.ndarray:
    """:func:`midpoint_sigma_points` with the second stage's accelerations linearised about the
    first's: a2 = a1 + J (X(t + h/2) - X(t)), J (m, n) the accelerations' rows of the model's
    Jacobian at the sigma points' mean. One evaluation of the model per step instead of two:
    the midpoint's accelerations differ from the exact second stage by the model's curvature
    over the half step's displacement and over the sigma points' spread (with Simulink's alpha
    = 1e-3 a two-hundredth of a standard deviation). The first stage by the generated model, or
    by the crane model's core on arrays (``core``, or the core not traceable): the same bits."""
    split = None if core else split_accelerations(prm, flex)
    n = X.shape[0]
    h2 = 0.5 * h
    rows = [IAD, IBD, IFD] if flex else [IAD, IBD]
    Y, V = _positions_rates(X, flex)
    if split is not None:
        inputs_part, sway_part = split
        a1 = _sway_evaluator(sway_part, flex)(Y, V, inputs_part(X[CHAINS]))
    else:
        f, fd = (Y[2], V[2]) if flex else (0.0, 0.0)
        a1 = np.array(pendulum_accelerations_core(np.sin, np.cos, prm, flex, Y[0], V[0], Y[1], V[1], *X[CHAINS],
                                                  f, fd)[: len(rows)])
    # a2 = a1 + J (M X + h/2 E a1) with E the accelerations' rows: (I + h/2 J E) a1 + (J M) X
    C = J[:, rows] * h2
    C[np.diag_indices(len(rows))] += 1.0
    a2 = C @ a1
    a2 += (J @ _half_step_matrix(n, flex, h)) @ X
    Vm = V + h2 * a1
    return _end_state(X, h, Y + h * Vm, V + h * a2)
