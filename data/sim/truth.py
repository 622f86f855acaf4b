"""Closed-form ground truth for relative heave.

With the feeder deck plane n.x + d = 0 in the world (unit n, n.e_z > 0) and the boom tip
p_t, the wire runs straight down along gravity and meets the deck at p_d = p_t - D e_z:

    D     = (n.p_t + d) / (n.e_z)
    D_dot = n.(p_t_dot - v(p_d)) / (n.e_z)

where v(x) = v_o + w x (x - o) is the feeder's rigid velocity field. The second line is the
exact derivative of the first (n_dot = w x n, and the deck point below the tip is fixed to
the body); tests check it against a fine finite difference of D.
"""

from __future__ import annotations

import numpy as np

from boomtip.data.sim.motion import BodyStates

E_Z = np.array([0.0, 0.0, 1.0])


def plane_to_world(plane_body: np.ndarray, states: BodyStates) -> np.ndarray:
    """A body-fixed plane [a,b,c,d] expressed in the world at each state: (T,4)."""
    n_w = states.rotation.apply(plane_body[:3])
    d_w = plane_body[3] - np.einsum("ij,ij->i", n_w, states.position_m)
    return np.hstack([n_w, d_w[:, None]])


def tip_states(crane: BodyStates, p_tip_crane_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boom-tip world position and velocity (T,3) from the crane vessel's states."""
    p = crane.rotation.apply(p_tip_crane_m) + crane.position_m
    v = crane.velocity_mps + np.cross(crane.omega_radps, p - crane.position_m)
    return p, v


def relative_heave(
    p_tip_world: np.ndarray, v_tip_world: np.ndarray, plane_body: np.ndarray, feeder: BodyStates
) -> tuple[np.ndarray, np.ndarray]:
    """D (m) and D_dot (m/s) at each state, both (T,)."""
    plane_w = plane_to_world(plane_body, feeder)
    n, d = plane_w[:, :3], plane_w[:, 3]
    n_z = n[:, 2]
    D = (np.einsum("ij,ij->i", n, p_tip_world) + d) / n_z
    p_d = p_tip_world - D[:, None] * E_Z
    v_pd = feeder.velocity_mps + np.cross(feeder.omega_radps, p_d - feeder.position_m)
    D_dot = np.einsum("ij,ij->i", n, v_tip_world - v_pd) / n_z
    return D, D_dot
