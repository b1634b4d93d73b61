"""One cycle's jerk-limited step of the controller (stage 5 of :mod:`depthguard.control.cycle`): Ruckig towards
the planned target velocity, the fallback braking step if it fails, the cycle's joint bounds enforced on it, and
in an evading protective stop the phase-synchronized step where the time-optimal one would bring the end
effector nearer its obstacle."""

from __future__ import annotations

import numpy as np

from depthguard.control.bounded import braking_step, enforce_bounds_kernel
from depthguard.control.otg import JointOtg, OtgState

__all__ = ["generate"]


def generate(
    j: JointOtg,
    otg: OtgState,
    target: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    away: np.ndarray | None = None,
) -> tuple[OtgState, bool, bool]:
    """Ruckig towards ``target`` (or the fallback braking step if it fails), kept within ``[lo, hi]``.

    ``away`` (n,): in an evading protective stop, ``J_eeᵀ n``, the joint-space gradient of the end
    effector's distance to its obstacle (``n`` its repulsive direction). Each joint reaches its target on
    its own time-optimal profile, so on the way the joint velocities are not proportional to the target's
    and the end effector can move towards the obstacle although the target moves it away (up to 4.9 mm
    from rest, found by a property test). When this cycle's step would do so, the phase-synchronized step
    (:meth:`JointOtg.advance <depthguard.control.otg.JointOtg.advance>`) is taken instead if it approaches
    less. Its joints accelerate and brake more gently, never harder, so its stop is never shorter; the
    joint bounds are enforced on it in the same way.

    ``j``: the controller's generator (``AvoidanceController.otg``). Returns the new state, whether Ruckig
    succeeded, and whether a bound won over the jerk limit.
    """
    planned, code = j.advance(otg, target)
    ok = code >= 0
    if not ok:
        planned = braking_step(otg, j.a_max, j.j_max, j.dt)
    p, v, a, limited = _enforce(j, otg, planned, lo, hi)
    if away is not None and ok:
        nearer = float(away @ (p - otg.position))
        if nearer < 0.0:  # the time-optimal step moves the end effector towards its obstacle
            synced, code_s = j.advance(otg, target, synchronized=True)
            if code_s >= 0:
                ps, vs, as_, limited_s = _enforce(j, otg, synced, lo, hi)
                if float(away @ (ps - otg.position)) > nearer:
                    p, v, a, limited = ps, vs, as_, limited_s
    return OtgState(p, v, a), ok, bool(limited)


def _enforce(j: JointOtg, otg: OtgState, planned: OtgState, lo: np.ndarray, hi: np.ndarray):
    """:func:`~depthguard.control.bounded.enforce_bounds_kernel` on the step from ``otg`` to ``planned``."""
    return enforce_bounds_kernel(
        otg.position, otg.velocity, otg.acceleration, planned.position, planned.velocity,
        planned.acceleration, lo, hi, j.a_max, j.j_max, j.dt,
    )  # fmt: skip
