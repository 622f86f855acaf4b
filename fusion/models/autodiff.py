"""Exact Jacobian of the crane's equations of motion by reverse-mode algorithmic differentiation.

:func:`boomtip.data.crane_model.pendulum_accelerations_core` is straight-line float code.  It is
traced once per (params, model) into a list of elementary operations (the crane parameters
folded in, common subexpressions shared) and compiled to one Python function: the forward
sweep and one reverse (adjoint) sweep per output (a'', b''[, nu_f'']).  The derivatives are
exact to machine precision like the complex step (they agree to ~1e-15; checked when built) at
~1/5 of its cost (no 21-column complex numpy arithmetic).  If the core ever stops being
traceable (branches on values, other functions), :func:`accel_jacobian` returns None and the
caller uses the complex step.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from boomtip.data.crane_model import pendulum_accelerations_core
from boomtip.fusion.models.crane_pendulum import IF, IFD

__all__ = ["accel_jacobian"]


class TraceNode:
    """A traced value: the arithmetic operators record the operation on the tape; float-only
    sub-expressions (the crane parameters) are evaluated by Python, as in the real call."""

    __slots__ = ("tape", "op", "args", "id")

    def __init__(self, tape: "Tape", op: str, args: tuple) -> None:
        self.tape, self.op, self.args = tape, op, args
        self.id = len(tape.nodes)

    def _bin(self, op, other, swap=False):
        o = other if isinstance(other, TraceNode) else Tape.const(other)
        return self.tape.node(op, (o, self) if swap else (self, o))

    def __add__(self, o):
        return self._bin("+", o)

    def __radd__(self, o):
        return self._bin("+", o, True)

    def __sub__(self, o):
        return self._bin("-", o)

    def __rsub__(self, o):
        return self._bin("-", o, True)

    def __mul__(self, o):
        return self._bin("*", o)

    def __rmul__(self, o):
        return self._bin("*", o, True)

    def __truediv__(self, o):
        return self._bin("/", o)

    def __rtruediv__(self, o):
        return self._bin("/", o, True)

    def __neg__(self):
        return self.tape.node("neg", (self,))

    def __pos__(self):
        return self

    def __bool__(self):  # a data-dependent branch cannot be traced
        raise TypeError("cannot trace a branch on a traced value")


class Tape:
    def __init__(self) -> None:
        self.nodes: list[TraceNode] = []
        self._index: dict[tuple, TraceNode] = {}

    @staticmethod
    def const(v) -> float:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            return float(v)
        raise TypeError("cannot trace this operand")

    def node(self, op: str, args: tuple) -> TraceNode:
        key = (op,) + tuple(a.id if isinstance(a, TraceNode) else repr(a) for a in args)
        nd = self._index.get(key)  # the same operation on the same operands: reuse it
        if nd is None:
            nd = self._index[key] = TraceNode(self, op, args)
            self.nodes.append(nd)
        return nd

    def inputs(self, k: int) -> list[TraceNode]:
        return [self.node("in", (float(i),)) for i in range(k)]

    def sin(self, v):
        return self.node("sin", (v,)) if isinstance(v, TraceNode) else math.sin(v)

    def cos(self, v):
        return self.node("cos", (v,)) if isinstance(v, TraceNode) else math.cos(v)



def ancestors(roots) -> set[int]:
    """The ids of every traced node the roots depend on (themselves included)."""
    seen: set[int] = set()
    stack = list(roots)
    while stack:
        nd = stack.pop()
        if nd.id not in seen:
            seen.add(nd.id)
            stack.extend(a for a in nd.args if isinstance(a, TraceNode))
    return seen


def node_expression(op: str, refs: list[str]) -> str:
    """A traced node as Python source, from its arguments' source (the generated models' one
    rule for every operation)."""
    if op == "neg":
        return f"(-{refs[0]})"
    if op in ("sin", "cos"):
        return f"{op}({refs[0]})"
    return f"({refs[0]} {op} {refs[1]})"


def _compile_jacobian(tape: Tape, n_in: int, outs: list):
    """Python source for ``jac(x) -> [d outs[r] / d x_k for r for k < n_in]``, compiled:
    the forward sweep (values used once are inlined into their consumer's expression) and
    one reverse sweep per output (an adjoint reached by a single path is passed on as an
    expression, others are summed in one statement)."""
    nodes = tape.nodes
    live = ancestors(outs)
    sin_of = {nd.args[0].id: nd for nd in nodes if nd.op == "sin" and nd.id in live}
    cos_of = {nd.args[0].id: nd for nd in nodes if nd.op == "cos" and nd.id in live}
    # forward values stored in locals: used more than once, or needed by the reverse sweeps
    uses = [0] * len(nodes)
    for nd in nodes:
        if nd.id in live:
            for a in nd.args:
                if isinstance(a, TraceNode):
                    uses[a.id] += 1
                    if nd.op in ("*", "/"):
                        uses[a.id] += 2
            if nd.op == "/":
                uses[nd.id] += 2
            elif nd.op in ("sin", "cos"):
                partner = (cos_of if nd.op == "sin" else sin_of).get(nd.args[0].id)
                if partner is not None:
                    uses[partner.id] += 2
    expr: dict[int, str] = {}
    depth: dict[int, int] = {}

    def ref(a):
        return expr[a.id] if isinstance(a, TraceNode) else repr(a)

    lines = ["def _jac(x):", "    sin = _sin; cos = _cos",
             "    " + "".join(f"v{k}, " for k in range(n_in)) + "= x"]
    for k in range(n_in):
        expr[k], depth[k] = f"v{k}", 0
    for nd in nodes[n_in:]:
        if nd.id not in live:
            continue
        a = nd.args
        e = node_expression(nd.op, [ref(x) for x in a])
        d = 1 + max((depth[x.id] for x in a if isinstance(x, TraceNode)), default=0)
        if uses[nd.id] > 1 or d > 40:
            lines.append(f"    v{nd.id} = {e}")
            e, d = f"v{nd.id}", 0
        expr[nd.id], depth[nd.id] = e, d
    dname: dict[int, str] = {}  # derivative of the sin / cos nodes
    for nd in nodes[n_in:]:
        if nd.id in live and nd.op in ("sin", "cos"):
            partner = (cos_of if nd.op == "sin" else sin_of).get(nd.args[0].id)
            if nd.op == "sin":
                if partner is None:
                    lines.append(f"    d{nd.id} = cos({ref(nd.args[0])})")
                dname[nd.id] = f"v{partner.id}" if partner is not None else f"d{nd.id}"
            else:
                lines.append(f"    d{nd.id} = -{f'v{partner.id}' if partner is not None else f'sin({ref(nd.args[0])})'}")
                dname[nd.id] = f"d{nd.id}"
    lines.append("    jac = []")
    for out in outs:
        need = ancestors([out])
        # contributions to each adjoint: (negated, text)
        contrib: dict[int, list[tuple[bool, str]]] = {out.id: [(False, "1.0")]}

        def total(terms):
            s = ("-" if terms[0][0] else "") + terms[0][1]
            for neg, t in terms[1:]:
                s += (" - " if neg else " + ") + t
            return s

        for nd in reversed(nodes[n_in:out.id + 1]):
            terms = contrib.pop(nd.id, None)
            if nd.id not in need or terms is None:
                continue
            node_args = [a for a in nd.args if isinstance(a, TraceNode)]
            neg, g = terms[0]
            simple = len(terms) == 1 and (g.isidentifier() or g == "1.0" or (len(node_args) == 1 and len(g) < 200))
            if not simple:
                lines.append(f"    g{nd.id} = {total(terms)}")
                neg, g = False, f"g{nd.id}"
            gp = g if g.isidentifier() or g == "1.0" else f"({g})"
            a = nd.args

            def push(arg, n2, text):
                if isinstance(arg, TraceNode):
                    contrib.setdefault(arg.id, []).append((n2, text))

            if nd.op == "+":
                push(a[0], neg, g)
                push(a[1], neg, g)
            elif nd.op == "-":
                push(a[0], neg, g)
                push(a[1], not neg, g)
            elif nd.op == "neg":
                push(a[0], not neg, g)
            elif nd.op == "*":
                push(a[0], neg, f"{gp} * {ref(a[1])}")
                push(a[1], neg, f"{gp} * {ref(a[0])}")
            elif nd.op == "/":
                push(a[0], neg, f"{gp} / {ref(a[1])}")
                push(a[1], not neg, f"{gp} * v{nd.id} / {ref(a[1])}")
            else:  # sin / cos
                push(a[0], neg, f"{gp} * {dname[nd.id]}")
        row = [total(contrib[k]) if k in contrib else "0.0" for k in range(n_in)]
        lines.append("    jac += [" + ", ".join(row) + "]")
    # the outputs' values from the same forward sweep, after the rows: the EKF's affine mean
    # needs f(x0) where it takes A(x0)
    lines.append("    jac += [" + ", ".join(expr[out.id] for out in outs) + "]")
    lines.append("    return jac")
    ns = {"_sin": math.sin, "_cos": math.cos}
    exec(compile("\n".join(lines), "<generated crane accel jacobian>", "exec"), ns)
    return ns["_jac"]


def _build_accel_jacobian(prm: tuple, flex: bool) -> Callable | None:
    """``jac(x) -> [d out_r / d x_k] + [out_r]`` (r over a'', b''[, nu_f''], k over the
    state; then the outputs themselves) for
    :func:`~boomtip.data.crane_model.pendulum_accelerations_core`, generated by reverse-mode AD
    of its trace."""
    n = 21 if flex else 19
    n_acc = 3 if flex else 2
    try:
        tape = Tape()
        xs = tape.inputs(n)
        outs = pendulum_accelerations_core(tape.sin, tape.cos, prm, flex, *xs[:19],
                                           *((xs[IF], xs[IFD]) if flex else (0.0, 0.0)))[:n_acc]
        if not all(isinstance(o, TraceNode) for o in outs):
            return None
        jac = _compile_jacobian(tape, n, list(outs))
    except Exception:  # not traceable: the caller falls back to the complex step
        return None
    # check against the complex step at a generic state, row by row
    x = [0.05, -0.02, -0.04, 0.03, 0.7, 0.02, 0.003, 0.6, -0.01, 0.002, 50.0, -0.3, 0.05,
         0.01, 0.02, -0.03, -0.02, 0.01, 0.04, 0.002, -0.001][:n]
    X = np.array(x)[:, None] + 1j * 1e-30 * np.eye(n)
    ref = pendulum_accelerations_core(np.sin, np.cos, prm, flex, *X[:19], *((X[IF], X[IFD]) if flex else (0.0, 0.0)))
    ref = np.array([np.imag(v) / 1e-30 for v in ref[:n_acc]])
    got = jac(x)
    err = np.abs(np.reshape(got[: n_acc * n], (n_acc, n)) - ref)
    if not np.all(err <= 1e-9 * np.abs(ref).max(1, keepdims=True)):
        return None
    acc = pendulum_accelerations_core(math.sin, math.cos, prm, flex, *x[:19], *((x[IF], x[IFD]) if flex else (0.0, 0.0)))
    if got[n_acc * n:] != list(acc[:n_acc]):  # the forward sweep is the core's arithmetic
        return None
    return jac


_ACCEL_JACOBIANS: dict[tuple, Callable | None] = {}


def accel_jacobian(prm: tuple, flex: bool) -> Callable | None:
    """Cached :func:`_build_accel_jacobian` (None: the core is not traceable)."""
    key = (prm, flex)
    if key not in _ACCEL_JACOBIANS:
        _ACCEL_JACOBIANS[key] = _build_accel_jacobian(prm, flex)
    return _ACCEL_JACOBIANS[key]
