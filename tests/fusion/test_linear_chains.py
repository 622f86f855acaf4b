"""The linear part of the hook filter's process model (fusion/models/linear_chains.py)."""

from __future__ import annotations

import numpy as np

from boomtip.fusion.models.crane_pendulum import IL, IMU, INU, IPITCH, IROLL, KIN_CHAINS, kin_at
from boomtip.fusion.models.linear_chains import accumulated_noise, sample_rows


def test_a_sample_before_the_state_is_the_chains_extrapolation_back():
    """A chain state measured tau before the state's time: H(tau) applied to the state tau later
    (the chains extrapolated with constant acceleration) gives the earlier value."""
    rng = np.random.default_rng(1)
    x_then = rng.normal(0, 1, 21)
    tau = 0.02
    x_now = x_then.copy()
    x_now[4:19] = kin_at(x_then, tau)
    idx = [IROLL, IPITCH, IROLL + 1, IPITCH + 1, INU, IMU, IL, IL + 2]
    H = sample_rows(idx, tau, 21)
    np.testing.assert_allclose(H @ x_now, x_then[idx], rtol=0, atol=1e-14)
    np.testing.assert_array_equal(sample_rows(idx, 0.0, 21), np.eye(21)[idx])
    assert all(any(0 <= i - c < 3 for c in KIN_CHAINS) for i in idx)


def test_accumulated_noise_is_the_stepwise_propagation():
    """m steps of P -> F P F^T + Q equal F^m P F^mT plus the accumulated noise."""
    rng = np.random.default_rng(2)
    n, m = 6, 5
    F = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    B = rng.normal(size=(n, n))
    Q = B @ B.T
    C = rng.normal(size=(n, n))
    P = C @ C.T
    stepwise = P
    for _ in range(m):
        stepwise = F @ stepwise @ F.T + Q
    Fm = np.linalg.matrix_power(F, m)
    Qm = accumulated_noise(Q, F, m)
    np.testing.assert_allclose(Fm @ P @ Fm.T + Qm, stepwise, rtol=1e-12)
    np.testing.assert_array_equal(Qm, Qm.T)
    np.testing.assert_array_equal(accumulated_noise(Q, F, 1), 0.5 * (Q + Q.T))
