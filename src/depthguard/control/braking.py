"""Jerk-limited braking: how far and how long each joint, and each control point, travels before it stops.

The controller stops with Ruckig in velocity mode, target velocity 0, no synchronization
(:mod:`depthguard.control.otg`): every joint follows its own time-optimal jerk-limited profile. From a
velocity ``v >= 0`` with acceleration ``a = 0`` that profile ramps the deceleration up at the jerk limit
``J``, holds ``A`` (if reached) and ramps it back down, symmetric in time, so

* ``|v| >= A^2/J``: ``T = |v|/A + A/J``, distance ``|v| T / 2``;
* ``|v| <  A^2/J``: ``T = 2 sqrt(|v|/J)``, distance ``|v| sqrt(|v|/J)``.

With an acceleration ``a`` that still speeds the joint up (same sign as ``v``), the profile first ramps
``a`` down to 0 at the jerk limit (time ``|a|/J``, velocity gain ``a^2/(2J)``) and then continues as above
from ``|v| + a^2/(2J)``: the two pieces join with the same jerk, so this is the time-optimal profile
itself. An acceleration that already brakes only shortens the stop; it is ignored (an upper bound).

A control point's path during the stop is bounded by the sum over joints of (its distance from the joint's
axis) x (the joint's travel). The distance from axis j changes only through the joints between j and the
point, each by at most its own lever x travel, and never exceeds the chain length from joint j to the
point: :func:`point_stopping_distance` uses the smaller of the two bounds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["JointStop", "stop_one", "joint_stopping", "chain_lengths", "point_stopping_distance"]


class JointStop(NamedTuple):
    """Per-joint jerk-limited stop.

    Attributes:
        time: (n,) stopping time, s.
        travel: (n,) unsigned joint travel until standstill, rad (or m).
    """

    time: np.ndarray
    travel: np.ndarray


@njit(cache=True, nogil=True, inline="always")
def _stop_from_rest_acc(speed: float, a_max: float, j_max: float) -> tuple[float, float]:
    """Time-optimal stop from speed >= 0 with zero acceleration: (time s, travel)."""
    if speed >= a_max * a_max / j_max:  # trapezoidal deceleration
        t = speed / a_max + a_max / j_max
    else:  # triangular
        t = 2.0 * np.sqrt(speed / j_max)
    return t, speed * t / 2.0


@njit(cache=True, nogil=True)
def stop_one(v: float, a: float, a_max: float, j_max: float) -> tuple[float, float]:
    """Stopping time (s) and unsigned path length (rad or m) of one joint from velocity ``v`` and
    acceleration ``a`` (module docstring); exact for Ruckig's time-optimal velocity-mode stop. A non-finite
    ``v`` or ``a`` (an unknown motion) gives ``(inf, inf)``: the only upper bound (NaN would compare False)."""
    if not (np.isfinite(v) and np.isfinite(a)):
        return np.inf, np.inf
    speed = abs(v)
    a = min(max(a, -a_max), a_max)
    if v < 0.0:
        a = -a  # from here on the joint moves in +: a > 0 speeds it up, a < 0 brakes
    if a >= 0.0 or v == 0.0:
        a = abs(a)
        t0 = a / j_max  # ramp the acceleration down to zero at the jerk limit, then brake from rest-acc
        d0 = speed * t0 + a * t0 * t0 / 2.0 - j_max * t0 * t0 * t0 / 6.0
        t1, d1 = _stop_from_rest_acc(speed + a * a / (2.0 * j_max), a_max, j_max)
        return t0 + t1, d0 + d1
    b = -a  # braking already
    overshoot = b * b / (2.0 * j_max) - speed
    if overshoot <= 0.0:
        # the tail of the stop from (speed + b^2/2J, 0) after its first ramp: total minus that ramp
        t_all, d_all = _stop_from_rest_acc(speed + b * b / (2.0 * j_max), a_max, j_max)
        t0 = b / j_max
        v_all = speed + b * b / (2.0 * j_max)
        d0 = v_all * t0 - j_max * t0 * t0 * t0 / 6.0
        return max(t_all - t0, 0.0), max(d_all - d0, 0.0)
    # the velocity crosses zero while the braking acceleration ramps back to zero (unavoidable)
    t0 = b / j_max
    ts = (b - np.sqrt(max(b * b - 2.0 * j_max * speed, 0.0))) / j_max  # zero crossing
    xs = speed * ts - b * ts * ts / 2.0 + j_max * ts * ts * ts / 6.0
    x0 = speed * t0 - b * t0 * t0 / 2.0 + j_max * t0 * t0 * t0 / 6.0
    t1, d1 = _stop_from_rest_acc(overshoot, a_max, j_max)
    return t0 + t1, xs + (xs - x0) + d1


def joint_stopping(v: np.ndarray, a: np.ndarray, a_max: np.ndarray, j_max: np.ndarray) -> JointStop:
    """Time and travel of the time-optimal jerk-limited stop of each joint (module docstring).

    Args:
        v: (n,) joint velocities, rad/s.
        a: (n,) joint accelerations, rad/s^2 (clipped to ``±a_max``).
        a_max, j_max: (n,) or scalar acceleration and jerk limits, > 0.
    Returns:
        :class:`JointStop` with (n,) arrays; exact for ``a`` of the same sign as ``v`` or zero, an upper
        bound otherwise.
    """
    v = np.asarray(v, dtype=float).ravel()
    a = np.broadcast_to(np.asarray(a, dtype=float), v.shape)
    A = np.broadcast_to(np.asarray(a_max, dtype=float), v.shape)
    J = np.broadcast_to(np.asarray(j_max, dtype=float), v.shape)
    out = np.array([stop_one(v[i], a[i], A[i], J[i]) for i in range(v.size)]).reshape(v.size, 2)
    return JointStop(out[:, 0].copy(), out[:, 1].copy())


def chain_lengths(model, joints: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N, n) upper bounds of the distance from each joint's origin to each control point, m.

    Args:
        model: a :class:`depthguard.robot.model.RobotModel` (pinocchio inside).
        joints: (N,) pinocchio joint index that carries each point.
        offsets: (N, 3) point in that joint's frame, m.
    Returns:
        ``L[k, c]`` = sum of the joint-placement translations from coordinate ``c``'s joint to point ``k``'s
        joint, plus the largest extension (``max(|q_min|, |q_max|)``, m) of each prismatic joint between
        them, plus ``|offset_k|`` (triangle inequality, any configuration within the limits); 0 where ``c``
        does not move ``k``. A prismatic coordinate ``c`` moves the point by its own travel (lever 1 m/m):
        its ``L[k, c]`` is at least 1, so that ``min(L, |J| + ...)`` never cuts its lever below 1 (a base on
        rails moved the points near its origin by its whole travel, while the bound took their tiny
        ``L``: 16 cm under the youBot's swept path, found by a property test).
    """
    pm = model.model
    N, n = len(joints), model.n_dof
    prismatic = [_is_prismatic(pm, j) for j in range(pm.njoints)]
    reach = [0.0] * pm.njoints  # a prismatic joint's largest extension from its placement, m
    for j in range(1, pm.njoints):
        if prismatic[j]:
            q0 = pm.idx_qs[j]
            reach[j] = float(max(abs(pm.lowerPositionLimit[q0]), abs(pm.upperPositionLimit[q0])))
    L = np.zeros((N, n))
    for k, (jk, off) in enumerate(zip(joints, offsets, strict=True)):
        chain = [int(j) for j in pm.supports[int(jk)] if j > 0]  # root .. jk
        for pos, j in enumerate(chain):
            length = float(np.linalg.norm(off))
            for i in chain[pos + 1 :]:
                length += float(np.linalg.norm(pm.jointPlacements[i].translation)) + reach[i]
            c0, nv = pm.idx_vs[j], pm.nvs[j]
            L[k, c0 : c0 + nv] = max(length, 1.0) if prismatic[j] else length
    return L


def _is_prismatic(pm, j: int) -> bool:
    """Joint ``j`` of the pinocchio model ``pm`` is prismatic (its one coordinate a length, m)."""
    return pm.joints[j].shortname() in ("JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned")


def point_stopping_distance(
    jacobians: np.ndarray, travel: np.ndarray, lengths: np.ndarray, prismatic: np.ndarray | None = None
) -> np.ndarray:
    """(N,) upper bound of the path length of every control point while the joints travel ``travel``.

    Args:
        jacobians: (N, 3, n) positional Jacobians at the current configuration, m/rad.
        travel: (n,) unsigned joint travels, rad (:func:`joint_stopping`).
        lengths: (N, n) chain lengths (:func:`chain_lengths`), m.
        prismatic: (n,) bool, prismatic coordinates (lever 1 whatever the configuration); default none.
    Returns:
        ``S[k] = sum_j lever_kj * travel_j`` with ``lever_kj = min(L_kj, |J_k[:, j]| + sum_{i after j} L_ki
        travel_i)``, m (a prismatic ``i`` moves the point by its travel itself: ``L_ki`` is 1 there).
    """
    lever0 = np.linalg.norm(jacobians, axis=1)  # (N, n): distance from each joint axis now
    moved = np.where(travel[None, :] > 0, lengths * travel[None, :], 0.0)  # (N, n): how far each joint moves it
    if prismatic is not None:  # (a prismatic joint moves the point by its travel, whatever its chain length)
        moved = np.where(np.asarray(prismatic, bool)[None, :], (lengths > 0) * travel[None, :], moved)
    # joints after j along the chain have higher indices: suffix sums of their displacements
    after = np.cumsum(moved[:, ::-1], axis=1)[:, ::-1] - moved
    lever = np.minimum(lengths, lever0 + after)
    if prismatic is not None:
        lever = np.where(np.asarray(prismatic, bool)[None, :], np.maximum(lever0, (lengths > 0) * 1.0), lever)
    return lever @ travel
