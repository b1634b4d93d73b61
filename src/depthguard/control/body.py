"""Collision avoidance for the robot body: joint-velocity bounds from Cartesian constraints.

ICRA'12 §V-C, eqs. 12-14. For each body control point C with distance ``D`` (from its sphere surface,
m) to the nearest obstacle and the repulsive unit direction ``n = D/||D||`` (from the obstacle towards
the point, see docs/conventions.md):

* risk (eq. 12, as read in docs/conventions.md): ``f(D) = 1 / (1 + exp((D 2/rho - 1) alpha))``, about 1 at contact
  and about 0 at ``rho``;
* influence (eq. 13): ``s = J_C^T n f(D)``; ``s_i > 0`` means that a positive velocity of joint i moves
  C along n, away from the obstacle, so the *negative* direction of joint i moves C towards it;
* bounds (eq. 14): the joint motion towards the obstacle is limited to ``V_max,i (1 - f(D))``:
  ``s_i > 0 -> qdot_min,i = -V_max,i (1 - f)``, ``s_i < 0 -> qdot_max,i = V_max,i (1 - f)``.
  The paper writes eq. 14 with the opposite sign because its D points from the point to the obstacle;
  with our repulsive convention this is the reading under which motion towards the obstacle slows
  down (tests/test_controller.py checks it). Motion away from the obstacle keeps its full bound.

For each joint the most restrictive bound over all points is taken. Two additions to the paper:

* joints that cannot move the point along n (``|J_C^T n|_i <= influence_eps``, e.g. joints after C in
  the chain) are not restricted by that point (the paper's ``s_i >= 0`` would also cap them);
* at or below ``contact_distance`` the motion towards the obstacle is denied completely (bound 0):
  f(0) = 1/(1 + e^-alpha) < 1, so eq. 14 alone would still allow ``V_max (1 - f(0))`` at contact.

Points with ``D = inf`` (nothing within rho) impose nothing. When in doubt the bounds tighten: a negative
``D`` (penetration) denies the motion towards the obstacle as contact does, and a direction that is zero or
of a norm outside ``[1e-150, 1e150]`` (unknown: which way is towards?) bounds every joint that moves the
point (a column of ``J_C`` over ``influence_eps``) to ``V_max,i (1 - f)`` both ways. The compiled kernel
also takes a NaN distance as contact and a NaN ``J_C^T n`` as the unknown direction.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.repulsion import risk  # ICRA'12 eq. 12, shared with the distance stage
from depthguard.validation import real_array, real_number

__all__ = ["risk", "body_velocity_bounds", "body_bounds_inplace"]


@njit(cache=True, nogil=True)
def body_bounds_inplace(
    jac: np.ndarray,
    dist: np.ndarray,
    dirs: np.ndarray,
    use: np.ndarray,
    v_max: np.ndarray,
    rho: float,
    alpha: float,
    contact_distance: float,
    influence_eps: float,
    qmin: np.ndarray,
    qmax: np.ndarray,
) -> None:
    """:func:`body_velocity_bounds` for the real-time path: no validation, bounds tightened in place.

    Arrays float64, C-contiguous: jac (N, 3, n), dist (N,) (inf: none; NaN reads as contact), dirs (N, 3)
    (zero or non-finite: unknown, module docstring), use (N,) bool, v_max (n,); qmin/qmax (n,) are
    tightened in place; rho, alpha finite > 0, contact_distance and influence_eps finite >= 0.
    """
    N, _, n = jac.shape
    for k in range(N):
        if not use[k]:
            continue
        d = dist[k]
        if d >= rho:  # inf (nothing within rho) or beyond: nothing (a NaN goes on, as contact)
            continue
        if not d > contact_distance:  # contact, penetration (d < 0) or NaN: no motion towards it
            keep = 0.0
        else:
            f = 1.0 / (1.0 + np.exp((d * 2.0 / rho - 1.0) * alpha))
            keep = 1.0 - f
        dx, dy, dz = dirs[k, 0], dirs[k, 1], dirs[k, 2]
        nrm = np.sqrt(dx * dx + dy * dy + dz * dz)
        known = 1e-150 <= nrm <= 1e150  # (not zero, NaN, inf or so far from unit that J_C^T n is unreliable)
        thr = influence_eps * nrm  # (|J_C^T n| > eps |n|: the eps of a unit n)
        for i in range(n):
            g = jac[k, 0, i] * dx + jac[k, 1, i] * dy + jac[k, 2, i] * dz
            lower = upper = False
            if not known or g != g:  # the direction is unknown: both ways, for a joint that moves C at all
                c = np.sqrt(jac[k, 0, i] ** 2 + jac[k, 1, i] ** 2 + jac[k, 2, i] ** 2)
                lower = upper = not c <= influence_eps
            elif g > thr:  # negative qdot_i moves C towards the obstacle
                lower = True
            elif g < -thr:  # positive qdot_i moves C towards the obstacle
                upper = True
            if lower:
                b = -v_max[i] * keep
                if b > qmin[i]:
                    qmin[i] = b
            if upper:
                b = v_max[i] * keep
                if b < qmax[i]:
                    qmax[i] = b


def body_velocity_bounds(
    jacobians: np.ndarray,
    distances: np.ndarray,
    directions: np.ndarray,
    v_max: np.ndarray,
    rho: float,
    alpha: float,
    *,
    use: np.ndarray | None = None,
    contact_distance: float = 0.0,
    influence_eps: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint-velocity bounds reshaped by the body constraints (ICRA'12 eqs. 12-14).

    Args:
        jacobians: (N, 3, n) positional Jacobians of the control points.
        distances: (N,) distances from the sphere surfaces to the nearest obstacle, m (inf = none; below 0:
            penetration, treated as contact).
        directions: (N, 3) unit repulsive directions, from the obstacle towards the point; finite
            wherever the distance is finite (ignored where it is inf; zero: unknown, module docstring).
        v_max: (n,) original joint velocity bounds ``V_max,i`` (finite, > 0), rad/s.
        rho: distance of influence, m; alpha: steepness of the risk function (both finite, > 0).
        use: (N,) bool, points that take part (default all); the end effector is usually excluded
            because it is handled by the repulsive velocity (eqs. 10-11).
        contact_distance: at or below it the motion towards the obstacle is denied, m (finite, >= 0).
        influence_eps: ``|J_C^T n|_i`` below this (m/rad, finite >= 0) counts as no influence.
    Returns:
        ``(qdot_min, qdot_max)``, each (n,), with ``-v_max <= qdot_min <= 0 <= qdot_max <= v_max``.
    Raises:
        ValueError naming the argument: wrong shapes, non-finite Jacobians, NaN or -inf distances, bools or
        strings for numbers, a negative or non-finite contact_distance, ...
    """
    jac = real_array(jacobians, "jacobians", "an (N, 3, n) array")
    if jac.ndim != 3 or jac.shape[1] != 3:
        raise ValueError(f"jacobians must have shape (N, 3, n), got {jac.shape}")
    if not np.all(np.isfinite(jac)):  # (a NaN column would restrict nothing)
        raise ValueError("jacobians must be finite (no NaN or inf)")
    N, _, n = jac.shape
    dist = real_array(distances, "distances", f"an ({N},) array")
    dirs = real_array(directions, "directions", f"an ({N}, 3) array")
    vmax = real_array(v_max, "v_max", f"an ({n},) array")
    if dist.shape != (N,):
        raise ValueError(f"distances must have shape ({N},), got {dist.shape}")
    if dirs.shape != (N, 3):
        raise ValueError(f"directions must have shape ({N}, 3), got {dirs.shape}")
    if vmax.shape != (n,) or np.any(~(vmax > 0)) or not np.all(np.isfinite(vmax)):
        raise ValueError(f"v_max must be ({n},) positive numbers, got {v_max!r}")
    if np.any(np.isnan(dist)) or np.any(dist == -np.inf):
        raise ValueError("distances must be numbers of metres (inf for none, < 0 penetration), without NaN or -inf")
    bad = np.isfinite(dist) & ~np.all(np.isfinite(dirs), axis=1)
    if np.any(bad):
        raise ValueError(f"directions must be finite where the distance is finite (point {int(np.argmax(bad))} is not)")
    rho = real_number(rho, "rho", "a finite number of metres > 0")
    alpha = real_number(alpha, "alpha", "a finite number > 0")
    if not (rho > 0 and alpha > 0 and np.isfinite(rho) and np.isfinite(alpha)):
        raise ValueError(f"rho and alpha must be finite numbers > 0, got rho={rho}, alpha={alpha}")
    contact_distance = real_number(contact_distance, "contact_distance", "a finite number of metres >= 0")
    if not (np.isfinite(contact_distance) and contact_distance >= 0):  # (< 0: motion towards allowed at contact)
        raise ValueError(f"contact_distance must be a finite number of metres >= 0, got {contact_distance!r}")
    influence_eps = real_number(influence_eps, "influence_eps", "a finite number >= 0")
    if not (np.isfinite(influence_eps) and influence_eps >= 0):
        raise ValueError(f"influence_eps must be a finite number >= 0, got {influence_eps!r}")
    use_a = np.ones(N, dtype=np.bool_) if use is None else np.ascontiguousarray(use, dtype=np.bool_)
    if use_a.shape != (N,):  # (the kernel does not check bounds)
        raise ValueError(f"use must have shape ({N},), got {use_a.shape}")
    qmin, qmax = -vmax.copy(), vmax.copy()
    body_bounds_inplace(jac, dist, dirs, use_a, vmax, rho, alpha, contact_distance, influence_eps, qmin, qmax)
    return qmin, qmax
