"""The continuous Jacobian ``A = df/dx`` of the hook filter's process model (the EKF's
linearisation): the kinematic chains' constant part plus the rows of a'', b''[, nu_f''].

``"autodiff"`` (reverse-mode algorithmic differentiation, :mod:`.autodiff`) and
``"complex_step"`` are exact to machine precision (they agree to ~1e-15; autodiff is ~5x
cheaper); ``"numeric"`` uses central differences (benchmark variant).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from boomtip.data.crane_model import pendulum_accelerations_core
from boomtip.fusion.models.autodiff import accel_jacobian
from boomtip.fusion.models.crane_pendulum import CHAINS, IA, IAD, IB, IBD, IF, IFD, KIN_CHAINS, state_size

__all__ = ["constant_part", "continuous_jacobian", "jacobian_and_accelerations"]

_CS_H = 1e-30  # complex step


@cache
def constant_part(n: int, flex: bool) -> np.ndarray:
    """The Jacobian's state-independent rows (the chains, the angles' rates); read-only."""
    A0 = np.zeros((n, n))
    for i in (IA, IB):
        A0[i, i + 1] = 1.0
    for i in KIN_CHAINS:
        A0[i, i + 1] = 1.0
        A0[i + 1, i + 2] = 1.0
    if flex:
        A0[IF, IFD] = 1.0
    A0.flags.writeable = False
    return A0


@cache
def _complex_step(n: int) -> np.ndarray:
    step = 1j * _CS_H * np.eye(n)
    step.flags.writeable = False
    return step


@cache
def _rows(flex: bool) -> np.ndarray:
    r = np.array((IAD, IBD, IFD) if flex else (IAD, IBD), np.intp)
    r.flags.writeable = False
    return r


def jacobian_and_accelerations(prm: tuple, flex: bool, x: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(A (n, n), the accelerations (a'', b''[, nu_f'']) of the model) at the state x: with
    ``"autodiff"`` both from one generated call (its forward sweep is the model's arithmetic)."""
    n = state_size(flex)
    jac = accel_jacobian(prm, flex) if method == "autodiff" else None
    if jac is None:
        xl = x.tolist()
        f, fd = (xl[IF], xl[IFD]) if flex else (0.0, 0.0)
        acc = pendulum_accelerations_core(math.sin, math.cos, prm, flex, *xl[:19], f, fd)
        return continuous_jacobian(prm, flex, x, method), np.array(acc[:3] if flex else acc[:2])
    rows = _rows(flex)
    k = len(rows)
    out = np.array(jac(x.tolist()))
    A = constant_part(n, flex).copy()
    A[rows] = out[: k * n].reshape(k, n)
    return A, out[k * n:]


def continuous_jacobian(prm: tuple, flex: bool, x: np.ndarray, method: str) -> np.ndarray:
    """A (n, n) at the state x; ``prm`` is ``CraneParams.as_tuple()``."""
    n = state_size(flex)
    A = constant_part(n, flex).copy()
    rows = (IAD, IBD, IFD) if flex else (IAD, IBD)
    if method == "autodiff":
        jac = accel_jacobian(prm, flex)
        if jac is not None:
            A[list(rows)] = np.array(jac(x.tolist())[: len(rows) * n]).reshape(len(rows), n)
            return A
        method = "complex_step"  # the core not traceable
    if method == "complex_step":
        X = x[:, None] + _complex_step(n)
        f, fd = (X[IF], X[IFD]) if flex else (0.0, 0.0)
        acc = pendulum_accelerations_core(np.sin, np.cos, prm, flex, X[0], X[1], X[2], X[3], *X[CHAINS], f, fd)
        for r, v in zip(rows, acc):
            A[r] = v.imag / _CS_H
    elif method == "numeric":
        xl = x.tolist()
        sin, cos = math.sin, math.cos

        def acc_at(xx):
            f, fd = (xx[IF], xx[IFD]) if flex else (0.0, 0.0)
            return pendulum_accelerations_core(sin, cos, prm, flex, *xx[0:19], f, fd)

        for k in range(n):
            eps = 1e-6 * max(1.0, abs(xl[k]))
            xp = list(xl)
            xm = list(xl)
            xp[k] += eps
            xm[k] -= eps
            ap, am = acc_at(xp), acc_at(xm)
            for r, vp, vm in zip(rows, ap, am):
                A[r, k] = (vp - vm) / (2 * eps)
    else:
        raise ValueError(method)
    return A
