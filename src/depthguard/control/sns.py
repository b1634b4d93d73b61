"""Saturation in the Null Space (SNS) at the velocity level.

F. Flacco, A. De Luca, O. Khatib, "Motion control of redundant robots under joint constraints:
Saturation in the Null Space", ICRA 2012, Algorithm 1 (and its task-scaling procedure, Algorithm 2).

Given a task Jacobian ``J`` (m, n), a desired task velocity ``xdot`` (m,) and box bounds on the joint
velocities, SNS finds ``qdot`` with ``qmin <= qdot <= qmax`` and ``J qdot = s xdot``, keeping the task
scale ``s`` at 1 whenever it can and otherwise as large as its greedy search finds:

1. ``qdot = qdot_N + (J W)^# (xdot - J qdot_N)``, with ``W`` the diagonal 0/1 selection of the joints
   not yet saturated and ``qdot_N`` the saturated joints' velocities (at their bounds).
2. If some joint leaves its bounds, compute the largest task scale that the free joints allow
   (``qdot(s) = s a + b`` with ``a = (J W)^# xdot``), remember the best scale seen so far, saturate the
   most critical joint at the bound it hits and repeat.
3. If the free joints can no longer realise the task (``rank(J W) < m``), fall back to the best scaled
   solution found.

The solver proper is :func:`sns_velocity_raw`; its output is tested against the bounds and against
``scipy.optimize.linprog`` *before* any clipping. :func:`sns_velocity_unchecked` adds a final guard on
top: it returns ``qdot = 0`` with ``s = 0`` if the solver ever left a bound violated by more than 1e-9
(or produced NaN, or was given non-finite input), and clips rounding below that tolerance, so the bounds
always hold; zero is feasible when ``qmin <= 0 <= qmax``, which :func:`sns_velocity` requires (otherwise
the velocity nearest to zero within the bounds is returned).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from depthguard.control.linalg import _mv
from depthguard.control.sns_kernels import _ray_exit, _sns_greedy, _violates, _zonotope_point
from depthguard.validation import real_array

__all__ = ["sns_velocity", "sns_velocity_raw", "sns_velocity_unchecked"]


@njit(cache=True, nogil=True)
def sns_velocity_raw(
    J: np.ndarray, xdot: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, damping: float = 0.0
) -> tuple[np.ndarray, float]:
    """The SNS solver proper, without input validation and without the final guard and clip.

    Runs SNS Algorithm 1. Its greedy saturation may scale a task more than needed, so when it scales
    (s < 1) the exact largest feasible scale s* is computed from the facets of the zonotope
    ``{J qdot : qmin <= qdot <= qmax}``; if s* is larger, SNS is re-run on the feasible task
    ``s* xdot`` and, should it still scale, an exact point of the zonotope is constructed
    (:func:`_zonotope_point`). ``damping`` > 0 replaces the pseudo-inverse by damped least squares near
    singularities; then ``J qdot = s xdot`` holds only approximately, while the bounds still hold.
    A ``J`` whose largest entry is below 2^-10 or above 2^10 is first scaled, with ``xdot`` and
    ``damping``, by the power of 2 that brings it into [0.5, 1): the same task, exactly, out of reach of
    the SVD's absolute thresholds and of overflow.

    Arrays must be float64 and C-contiguous: J (m, n), xdot (m,), qmin/qmax (n,). Returns ``(qdot, s)``
    with ``qdot`` within the bounds up to rounding (tests check 1e-9 on this output, before any clip).
    """
    m, n = J.shape
    big = 0.0
    for i in range(m):
        for j in range(n):
            big = max(big, abs(J[i, j]))
    if 0.0 < big < np.inf and not 2.0**-10 <= big <= 2.0**10:  # (see the docstring)
        c = math.ldexp(1.0, -math.frexp(big)[1])
        J, xdot, damping = J * c, xdot * c, damping * c
    qdot, s = _sns_greedy(J, xdot, qmin, qmax, damping)
    if _violates(qdot, qmin, qmax, 1e-9):  # rounding in the greedy search: try the exact path
        qdot, s = np.zeros(n), 0.0
    if s >= 1.0 or m > n:
        return qdot, s
    t, _ = _ray_exit(J, np.zeros(m), xdot, qmin, qmax)
    s_opt = min(t, 1.0)
    if s_opt <= s + 1e-9:
        return qdot, s
    target = s_opt * xdot
    q2, s2 = _sns_greedy(J, target, qmin, qmax, damping)
    if s2 >= 1.0 and not _violates(q2, qmin, qmax, 1e-9):
        return q2, s_opt
    lo = np.maximum(qmin, -1e9)
    hi = np.minimum(qmax, 1e9)
    q3 = _zonotope_point(J, target, lo, hi)
    err = np.sqrt(np.sum((_mv(J, q3) - target) ** 2))
    if _violates(q3, qmin, qmax, 1e-9) or err > 1e-8 * (1.0 + np.sqrt(np.sum(xdot * xdot))):
        return qdot, s
    return q3, s_opt


@njit(cache=True, nogil=True)
def _stand_still(qmin: np.ndarray, qmax: np.ndarray) -> np.ndarray:
    """The velocity nearest to zero within the bounds, per joint (0 where there is no finite one)."""
    q = np.zeros(qmin.shape[0])
    for i in range(q.shape[0]):
        if qmin[i] <= qmax[i] and qmin[i] < np.inf and qmax[i] > -np.inf:
            q[i] = min(max(0.0, qmin[i]), qmax[i])
    return q


@njit(cache=True, nogil=True)
def sns_velocity_unchecked(
    J: np.ndarray, xdot: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, damping: float = 0.0
) -> tuple[np.ndarray, float]:
    """SNS for the real-time path: :func:`sns_velocity_raw` plus the final guard (module docstring).

    Arrays must be float64, C-contiguous. The result is within ``[qmin, qmax]`` exactly: a solver
    output off by more than 1e-9 (or not finite) is replaced by the velocity nearest to zero within the bounds
    with ``s = 0`` (``qdot = 0`` when ``qmin <= 0 <= qmax``, as :func:`sns_velocity` requires; only then
    does ``J qdot = s xdot`` hold for it), smaller rounding is clipped. So is any non-finite ``J``,
    ``xdot`` or ``damping``, NaN bound, or box without a finite velocity (``qmin > qmax``, ``qmin = inf``
    or ``qmax = -inf``: those joints get 0, which no velocity could respect).
    """
    bad = not np.isfinite(damping)
    for i in range(J.shape[0]):
        bad = bad or not np.isfinite(xdot[i])
        for j in range(J.shape[1]):
            bad = bad or not np.isfinite(J[i, j])
    for j in range(J.shape[1]):
        bad = bad or not (qmin[j] <= qmax[j] and qmin[j] < np.inf and qmax[j] > -np.inf)
    if bad:
        return _stand_still(qmin, qmax), 0.0
    qdot, s = sns_velocity_raw(J, xdot, qmin, qmax, damping)
    bad = _violates(qdot, qmin, qmax, 1e-9) or not np.isfinite(s)
    for j in range(qdot.shape[0]):  # (an unbounded joint may take an overflowing solution: -inf in (-inf, inf))
        bad = bad or not np.isfinite(qdot[j])
    if bad:
        return _stand_still(qmin, qmax), 0.0
    return np.minimum(np.maximum(qdot, qmin), qmax), s


def sns_velocity(
    J: np.ndarray, xdot: np.ndarray, qdot_min: np.ndarray, qdot_max: np.ndarray
) -> tuple[np.ndarray, float]:
    """Joint velocities for a task under joint-velocity bounds by Saturation in the Null Space.

    Args:
        J: (m, n) task Jacobian.
        xdot: (m,) desired task velocity.
        qdot_min, qdot_max: (n,) joint velocity bounds (``-inf``/``inf`` allowed). They must satisfy
            ``qdot_min <= 0 <= qdot_max``: standing still must be feasible, so that a solution that
            respects the bounds always exists (with scale 0 in the worst case). Bounds that exclude
            zero raise ``ValueError``; shrink them to include zero first.
    Returns:
        ``(qdot, scale)``: ``qdot`` (n,) within the bounds, and the task scale in [0, 1] with
        ``J qdot = scale * xdot`` up to rounding when ``J`` has full row rank (at any magnitude of ``J``);
        otherwise ``J qdot = scale * J J^# xdot``, the part of ``xdot`` that ``J`` can realise. ``scale == 1``
        whenever the plain pseudo-inverse solution ``J^# xdot`` is within the bounds, in which case it is
        that solution.
    Raises:
        ValueError: naming the argument that is not an array of real numbers (bools, strings and complex
            numbers are refused) of the shape above, or is not finite, or bounds as described.
    """
    J = real_array(J, "J", "a 2-D (m, n) array")
    if J.ndim != 2 or J.shape[0] < 1 or J.shape[1] < 1:
        raise ValueError(f"J must be a 2-D (m, n) array, got shape {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError("J must be finite (no NaN or inf)")
    m, n = J.shape
    xdot = real_array(xdot, "xdot", f"a ({m},) array")
    if xdot.shape != (m,):
        raise ValueError(f"xdot must have shape ({m},) to match J {J.shape}, got {np.shape(xdot)}")
    if not np.all(np.isfinite(xdot)):
        raise ValueError("xdot must be finite (no NaN or inf)")
    bounds = []
    for name, v in (("qdot_min", qdot_min), ("qdot_max", qdot_max)):
        arr = real_array(v, name, f"a ({n},) array")
        if arr.shape != (n,):
            raise ValueError(f"{name} must have shape ({n},) to match J {J.shape}, got {arr.shape}")
        if np.any(np.isnan(arr)):
            raise ValueError(f"{name} must not contain NaN")
        bounds.append(arr)
    qmin, qmax = bounds
    if np.any(qmin > qmax):
        i = int(np.argmax(qmin > qmax))
        raise ValueError(f"qdot_min must be <= qdot_max; joint {i}: {qmin[i]} > {qmax[i]}")
    if np.any(qmin > 0) or np.any(qmax < 0):
        i = int(np.argmax((qmin > 0) | (qmax < 0)))
        raise ValueError(
            f"the bounds must contain zero (qdot_min <= 0 <= qdot_max) so that stopping is feasible; "
            f"joint {i} has [{qmin[i]}, {qmax[i]}]"
        )
    qdot, scale = sns_velocity_unchecked(J, xdot, qmin, qmax, 0.0)
    return qdot, float(scale)
