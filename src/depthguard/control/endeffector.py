"""End-effector collision avoidance (ICRA'12 §V-A, eqs. 7, 10, 11) with damped least squares.

* repulsive velocity (eq. 7, as read in docs/conventions.md): ``V_R = v(D) n`` with
  ``v(D) = V_max / (1 + exp((D 2/rho - 1) alpha))`` and ``n`` the unit direction from the obstacle to
  the end effector (docs/conventions.md); ``V_R = 0`` for ``D = inf``;
* commanded task velocity (eq. 10): ``xdot_c = xdot_d + V_R(P_EE)``;
* joint velocity (eq. 11): ``qdot = J^#(q) xdot_c``. Near singularities ``J^#`` is replaced by damped
  least squares ``J^T (J J^T + lambda^2 I)^-1`` with the damping of Maciejewski & Klein / Chiaverini:
  ``lambda^2 = (1 - (sigma_min/eps)^2) lambda_max^2`` when the smallest singular value ``sigma_min`` is
  below ``eps``, else 0.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from depthguard.control.linalg import _jacobi_svd, _mtv
from depthguard.validation import real_array, real_number

__all__ = [
    "repulsive_velocity", "repulsive_velocity_kernel", "commanded_task_velocity", "dls_damping", "dls_inverse",
    "dls_apply",
]  # fmt: skip


def repulsive_velocity(distance: float, direction: np.ndarray, v_max: float, rho: float, alpha: float) -> np.ndarray:
    """Repulsive velocity vector ``V_R`` (3,) in m/s (ICRA'12 eq. 7); zero for ``distance >= rho``
    (nothing within the region of surveillance, as a query's ``inf``: a distance that a longer-range query
    found beyond ρ, e.g. for speed and separation monitoring, does not repel).

    Args:
        distance: D from the control sphere's surface to the obstacle, m (>= 0, inf = none).
        direction: (3,) unit vector from the obstacle towards the point (any finite length is normalised; a
            zero direction gives no repulsion: which way is away is not known).
        v_max: largest repulsive speed, m/s (finite, >= 0); rho: m; alpha: steepness (both finite, > 0).
    Raises:
        ValueError naming the argument: a NaN distance, a direction of another shape or not finite (where it
        is used: ``distance < rho``), a non-finite or non-positive parameter, a bool or string for a number.
    """
    d = real_number(distance, "distance", "a number of metres (inf = none)")
    v_max = real_number(v_max, "v_max", "a finite speed >= 0")
    rho = real_number(rho, "rho", "a finite number > 0")
    alpha = real_number(alpha, "alpha", "a finite number > 0")
    if math.isnan(d):  # (``not d < rho`` would silently turn the repulsion off)
        raise ValueError("distance must be a number of metres (inf = none), got NaN")
    if not (math.isfinite(v_max) and v_max >= 0):
        raise ValueError(f"v_max must be a finite speed >= 0, got {v_max!r}")
    if not (math.isfinite(rho) and rho > 0 and math.isfinite(alpha) and alpha > 0):
        raise ValueError(f"rho and alpha must be finite numbers > 0, got rho={rho!r}, alpha={alpha!r}")
    if not d < rho:  # (the direction is not looked at)
        return np.zeros(3)
    dvec = real_array(direction, "direction", "a (3,) array")
    if dvec.shape != (3,):
        raise ValueError(f"direction must have shape (3,), got {dvec.shape}")
    if not (math.isfinite(dvec[0]) and math.isfinite(dvec[1]) and math.isfinite(dvec[2])):
        raise ValueError(f"direction must be finite where the distance is below rho, got {dvec!r}")
    return repulsive_velocity_kernel(d, dvec, v_max, rho, alpha)


@njit(cache=True, nogil=True)
def repulsive_velocity_kernel(d: float, direction: np.ndarray, v_max: float, rho: float, alpha: float) -> np.ndarray:
    """:func:`repulsive_velocity` for compiled callers (float64 ``direction`` (3,)); returns a new (3,) array."""
    out = np.zeros(3)
    if not d < rho:  # inf, or beyond the region of surveillance
        return out
    x = (d * 2.0 / rho - 1.0) * alpha
    mag = 0.0 if x > 700.0 else v_max / (1.0 + math.exp(x))  # (exp overflows past 709: the speed is 0 there)
    dx, dy, dz = direction[0], direction[1], direction[2]
    nrm2 = dx * dx + dy * dy + dz * dz
    if not 1e-280 < nrm2 < 1e280:  # the squares under- or overflow: the direction scaled to its largest entry
        big = max(abs(dx), abs(dy), abs(dz))
        if not 0.0 < big < np.inf:  # zero (no direction: no repulsion) or not finite
            return out
        dx, dy, dz = dx / big, dy / big, dz / big
        nrm2 = dx * dx + dy * dy + dz * dz
    nrm = math.sqrt(nrm2)
    k = mag / nrm
    out[0], out[1], out[2] = k * dx, k * dy, k * dz
    return out


def commanded_task_velocity(xdot_d: np.ndarray, v_repulsive: np.ndarray) -> np.ndarray:
    """ICRA'12 eq. 10: ``xdot_c = xdot_d + V_R(P_EE)``; with a 6-D task V_R adds to the linear part."""
    xc = np.array(xdot_d, dtype=float)
    xc[:3] += v_repulsive
    return xc


@njit(cache=True, nogil=True)
def _dls_damping(J: np.ndarray, eps: float, lambda_max: float) -> float:
    if J.shape[0] > J.shape[1]:
        smin = 0.0
    else:  # the smallest singular value (Jacobi: accurate, and no LAPACK call at these sizes)
        smin = np.inf
        for s in _jacobi_svd(J)[2]:
            smin = min(smin, s)
    if smin >= eps:
        return 0.0
    return lambda_max * np.sqrt(1.0 - (smin / eps) ** 2)


def _matrix(J: object) -> np.ndarray:
    """``J`` as a finite float64 C-contiguous (m, n) array (m, n >= 1), else ValueError naming J."""
    if type(J) is np.ndarray and J.dtype == np.float64 and J.ndim == 2 and J.flags.c_contiguous:
        a = J  # (the control cycle's case: no copy)
    else:
        a = real_array(J, "J", "an (m, n) matrix")
    if a.ndim != 2 or a.size == 0:
        raise ValueError(f"J must be an (m, n) matrix with m, n >= 1, got shape {a.shape}")
    if not (math.isfinite(a.sum()) or np.all(np.isfinite(a))):  # (a finite sum: every entry is finite)
        raise ValueError("J must be finite (no NaN or inf)")
    return a


def _nonneg(x: object, name: str) -> float:
    v = real_number(x, name, "a finite number >= 0")
    if not 0.0 <= v < math.inf:
        raise ValueError(f"{name} must be a finite number >= 0, got {x!r}")
    return v


def dls_damping(J: np.ndarray, eps: float = 0.02, lambda_max: float = 0.05) -> float:
    """Damping factor lambda in [0, lambda_max] for J (m, n): 0 unless the smallest singular value is below
    eps. Raises ValueError naming the argument: J not a finite matrix, eps or lambda_max not finite >= 0."""
    eps_f, lam_f = _nonneg(eps, "eps"), _nonneg(lambda_max, "lambda_max")
    return float(_dls_damping(_matrix(J), eps_f, lam_f))


def dls_inverse(J: np.ndarray, damping: float) -> np.ndarray:
    """(n, m) damped least-squares inverse ``J^T (J J^T + damping^2 I)^-1`` (the pseudo-inverse at 0).
    Raises ValueError naming the argument: J not a finite matrix, damping not a finite number >= 0."""
    J, damping = _matrix(J), _nonneg(damping, "damping")
    if damping == 0.0:
        return np.linalg.pinv(J)
    m = J.shape[0]
    return J.T @ np.linalg.inv(J @ J.T + damping**2 * np.eye(m))


@njit(cache=True, nogil=True)
def _dls_apply(J: np.ndarray, damping: float, x: np.ndarray) -> np.ndarray:
    """``J^T (J J^T + (damping^2 + 1e-12) I)^-1 x`` by a Cholesky factorisation written out (the matrix is
    symmetric positive definite; m is 3 or 6, where LAPACK's call costs more than the arithmetic)."""
    m, n = J.shape
    L = np.zeros((m, m))
    reg = damping * damping + 1e-12
    for i in range(m):
        for j in range(i + 1):
            a = reg if i == j else 0.0
            for k in range(n):
                a += J[i, k] * J[j, k]
            for k in range(j):
                a -= L[i, k] * L[j, k]
            L[i, j] = np.sqrt(max(a, 1e-300)) if i == j else a / L[j, j]
    y = np.empty(m)
    for i in range(m):  # L y = x
        a = x[i]
        for k in range(i):
            a -= L[i, k] * y[k]
        y[i] = a / L[i, i]
    for i in range(m - 1, -1, -1):  # L^T z = y
        a = y[i]
        for k in range(i + 1, m):
            a -= L[k, i] * y[k]
        y[i] = a / L[i, i]
    return _mtv(J, y)


def dls_apply(J: np.ndarray, damping: float, x: np.ndarray) -> np.ndarray:
    """(n,) ``J^T (J J^T + (damping^2 + 1e-12) I)^-1 x`` for J (m, n) and x (m,): the damped least-squares
    joint velocity of task velocity x (the 1e-12 keeps a rank-deficient J solvable at zero damping).
    Raises ValueError naming the argument: J not a finite matrix, x not finite (m,), damping not finite >= 0."""
    J = _matrix(J)
    xv = real_array(x, "x", f"a ({J.shape[0]},) array")
    if xv.shape != (J.shape[0],) or not np.all(np.isfinite(xv)):  # (the kernel would read past a short x)
        raise ValueError(f"x must be a finite ({J.shape[0]},) array, got {x!r}")
    return _dls_apply(J, _nonneg(damping, "damping"), xv)
