"""Repulsive vectors from distances (ICRA'12 §IV, eqs. 6-9; RA-L'16 eq. 11).

The magnitude profile (eq. 7, read as in ``docs/conventions.md``) is
``v(D) = Vmax / (1 + exp((D * 2/ρ - 1) α))``: about ``Vmax`` at ``D = 0`` and about 0 at ``D = ρ``
(Fig. 4: Vmax = 3 m/s, ρ = 0.4 m, α = 6).
"""

from __future__ import annotations

import numpy as np

from depthguard.depthspace import PointDistances

__all__ = ["magnitude", "risk", "repulsive_vectors"]


def _check_profile(rho: float, alpha: float) -> None:
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
    if not (np.isfinite(alpha) and alpha > 0):
        raise ValueError(f"alpha must be a positive shape factor, got {alpha!r}")


def risk(distance: np.ndarray | float, rho: float, alpha: float) -> np.ndarray:
    """Collision risk ``f(D) = 1 / (1 + exp((D 2/ρ - 1) α))`` in [0, 1] (ICRA'12 eq. 12); 0 for D = inf.

    A NaN distance (unknown) is given risk 1, the value at contact: when in doubt, the robot slows."""
    _check_profile(rho, alpha)
    d = np.asarray(distance, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        f = 1.0 / (1.0 + np.exp((d * 2.0 / rho - 1.0) * alpha))
    return np.where(np.isnan(d), 1.0, f)


def magnitude(distance: np.ndarray | float, vmax: float, rho: float, alpha: float) -> np.ndarray:
    """Repulsive magnitude ``v(D) = Vmax f(D)`` in m/s (ICRA'12 eq. 7); 0 where D = inf (nothing within ρ)."""
    if not (np.isfinite(vmax) and vmax >= 0):
        raise ValueError(f"vmax must be a non-negative speed in m/s, got {vmax!r}")
    return vmax * risk(distance, rho, alpha)


def repulsive_vectors(distances: PointDistances, vmax: float, rho: float, alpha: float) -> np.ndarray:
    """Repulsive velocities ``V_R`` (N, 3) in the world frame, m/s.

    ``V_R = v(D_min) * direction`` where ``direction`` is the one the query produced: the nearest
    obstacle's (``V_min``, eq. 8), the normalised v-weighted sum (``V_all``, eq. 9) or the mean of unit
    vectors (hybrid, RA-L'16 eq. 11). Zero where nothing lies within ρ.
    """
    mag = magnitude(distances.distance, vmax, rho, alpha)
    found = np.isfinite(distances.distance)
    return np.where(found[:, None], mag[:, None] * np.nan_to_num(distances.direction), 0.0)
