"""The protective buffer: spring pseudo-energy of robot-mounted proximity sensors (SAPHARI D4.1.1 §5.1).

Each sensor k carries a spring of rest length ``r_k``. With ``d_k`` the measured distance of the nearest
obstacle point along the sensor's direction ``v_dk``:

* eq. 5.1  ``eps_k = 1/2 (d_k - r_k)^2`` if ``d_k <= r_k``, else 0;
* eq. 5.2  ``sigma = sum_k eps_k``;
* eqs. 5.6-5.7  ``J_o = d sigma / d q = sum_k -(d_k - r_k) v_dk^T J_sk`` over the compressed springs,
  with ``J_sk = d p_sk / d q`` (3, n) the positional Jacobian of the sensor point: with the obstacle point
  ``p_ok`` fixed, ``d_k = ||p_ok - p_sk(q)||`` and ``d d_k / d q = -v_dk^T J_sk``.

Pure numpy; distances in m, ``inf`` = nothing in range (no energy). A NaN distance is treated as 0
(an obstacle at the sensor: maximum energy), never as free space.
"""

from __future__ import annotations

import numpy as np

__all__ = ["spring_energy", "total_energy", "energy_gradient"]


def _clean(d: np.ndarray) -> np.ndarray:
    d = np.asarray(d, float)
    return np.where(np.isnan(d), 0.0, np.maximum(d, 0.0))


def spring_energy(distances: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """eq. 5.1: (N,) pseudo-energies, m^2, for (N,) ``distances`` and rest lengths ``rest`` (m, > 0)."""
    d = _clean(distances)
    r = np.broadcast_to(np.asarray(rest, float), d.shape)
    return np.where(d <= r, 0.5 * (d - r) ** 2, 0.0)


def total_energy(distances: np.ndarray, rest: np.ndarray) -> float:
    """eq. 5.2: total pseudo-energy sigma, m^2."""
    return float(np.sum(spring_energy(distances, rest)))


def energy_gradient(
    distances: np.ndarray, rest: np.ndarray, directions: np.ndarray, jacobians: np.ndarray
) -> np.ndarray:
    """eqs. 5.6-5.7: (n,) gradient ``J_o`` of sigma with respect to q.

    Args:
        distances: (N,) d_k, m.  rest: (N,) or scalar r_k, m.
        directions: (N, 3) unit v_dk, world frame (from the sensor towards the obstacle point).
        jacobians: (N, 3, n) positional Jacobians J_sk of the sensor points, world frame.
    """
    d = _clean(distances)
    r = np.broadcast_to(np.asarray(rest, float), d.shape)
    v, J = np.asarray(directions, float), np.asarray(jacobians, float)
    if d.ndim != 1 or v.shape != (d.size, 3) or J.ndim != 3 or J.shape[:2] != (d.size, 3):
        raise ValueError(
            f"energy_gradient: distances (N,), directions (N, 3) and jacobians (N, 3, n) expected, got "
            f"{d.shape}, {v.shape}, {J.shape}"
        )
    w = np.where(d <= r, -(d - r), 0.0)  # (N,)  -(d_k - r_k) >= 0 when compressed
    vJ = np.einsum("ki,kin->kn", v, J)
    return w @ vJ
