"""Evaluation of hook filter runs against the truth: per-axis RMSE and the world-frame boom tip
and hook from the filter's states (document 002 Table 6.1's metric)."""

from __future__ import annotations

import numpy as np

from boomtip.data.crane_model import CraneParams, JointStates, VesselState, hook_relative_kinematics, tip_kinematics
from boomtip.fusion.models.crane_pendulum import IA, IAD, IB, IBD, IF, IFD, IL, INU, IPITCH, IROLL

__all__ = ["rmse_per_axis", "world_hook_from_states"]


def rmse_per_axis(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((np.asarray(est) - np.asarray(ref)) ** 2, axis=0))


def world_hook_from_states(params: CraneParams, X: np.ndarray):
    """Boom-tip and hook position/velocity in the world frame from filter states X (N, n).

    Returns (p_tip, v_tip, p_hook, v_hook), each (N, 3).
    """
    X = np.atleast_2d(X)
    n = X.shape[1]
    J = JointStates(*(X[:, i] for i in range(INU, IL + 3)))
    V = VesselState(*(X[:, i] for i in range(IROLL, IPITCH + 3)))
    f = X[:, IF] if n > IF else 0.0
    fd = X[:, IFD] if n > IFD else 0.0
    p_tip, v_tip, _ = tip_kinematics(params, J, V, f, fd, 0.0)
    r, rd = hook_relative_kinematics(X[:, IL], X[:, IL + 1], X[:, IA], X[:, IAD], X[:, IB], X[:, IBD])
    return p_tip, v_tip, p_tip + r, v_tip + rd
