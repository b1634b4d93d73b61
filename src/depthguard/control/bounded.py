"""Keeping every cycle's joint command within that cycle's velocity bounds (the bound wins).

Ruckig (velocity mode) plans a jerk-limited motion towards a target velocity, but it knows nothing of the
bounds: from a state that is still accelerating it overshoots its target (from ``v = 1.95``, ``a = 10``
towards 2.0 with ``j = 500`` it peaks at ``v + a^2 / (2 j) = 2.05`` rad/s), and a bound that shrinks
from one cycle to the next (an obstacle came closer, a joint nears its position limit) can leave the
planned velocity above the new bound. :func:`enforce_velocity_bounds` is the last stage of every cycle:

1. if the planned velocity of a joint lies within ``[lo, hi]`` (to 1e-12), it is kept;
2. otherwise the joint takes the constant-jerk step that lands on the bound it crossed, if one exists
   within the jerk and acceleration limits and ends with an acceleration that does not push further
   out (``a_new <= 0`` at the upper bound); limits hold, nothing is reported;
3. otherwise no jerk-limited step can stay within the bound (it shrank faster than the jerk limit can
   follow): the velocity is set to the bound, which breaks the acceleration or jerk limit in this
   cycle, and the acceleration brakes as hard as the jerk limit allows (but not beyond 0 towards the
   bound), so that the following cycles can follow a bound that keeps shrinking. The bound wins, and
   the cycle reports it (``limited``).

So ``lo <= qdot_cmd <= hi`` holds in every cycle (exactly), and the acceleration and jerk limits hold in
every cycle that does not report ``limited``.

Bad input never gives a non-finite command and is always reported (``limited``): a NaN bound reads as 0 (no
motion that way) and bounds with ``lo > hi`` as the single value between them nearest 0; a non-finite state
velocity or acceleration reads as 0 (as in :func:`braking_step`); a joint whose planned state is not finite
takes the braking step instead. The command then lies within the bounds as read.

:func:`braking_step` is a jerk-limited stop that needs no Ruckig: the fallback when Ruckig fails.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.control.otg import OtgState

__all__ = ["enforce_velocity_bounds", "enforce_bounds_kernel", "braking_step"]

_ROUNDING = 1e-12  # a planned velocity this far beyond a bound is rounding: clipped, not reported


@njit(cache=True, nogil=True, inline="always")
def _brake_one(p: float, v: float, a: float, a_max: float, j_max: float, dt: float) -> tuple[float, float, float]:
    """:func:`braking_step` for one joint with a finite state: position (rad), velocity (rad/s) and
    acceleration (rad/s^2) after one period ``dt`` (s). The one implementation of the stop: the bound
    enforcement uses it for a joint without a plan, :func:`braking_step` for every joint."""
    a = min(max(a, -a_max), a_max)
    a_des = -min(a_max, np.sqrt(2.0 * j_max * abs(v)))
    if v < 0.0:
        a_des = -a_des
    elif v == 0.0:
        a_des = 0.0
    a_new = min(max(min(max(a_des, a - j_max * dt), a + j_max * dt), -a_max), a_max)
    v_new = v + 0.5 * (a + a_new) * dt
    if v == 0.0 or (v_new < 0.0 < v) or (v < 0.0 < v_new):  # it would reverse: it stops at 0
        return p + 0.5 * v * dt, 0.0, min(max(0.0, a - j_max * dt), a + j_max * dt)
    return p + v * dt + a * (dt * dt / 2.0) + (a_new - a) * (dt * dt / 6.0), v_new, a_new


@njit(cache=True, nogil=True)
def _braking_kernel(p: np.ndarray, v: np.ndarray, a: np.ndarray, a_max: np.ndarray, j_max: np.ndarray, dt: float):
    """:func:`_brake_one` over float64 C-contiguous (n,) arrays of finite states: new (p, v, a)."""
    n = p.shape[0]
    po, vo, ao = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        po[i], vo[i], ao[i] = _brake_one(p[i], v[i], a[i], a_max[i], j_max[i], dt)
    return po, vo, ao


@njit(cache=True, nogil=True, inline="always")
def _sane_bounds(lo: float, hi: float) -> tuple[float, float, bool]:
    """The bounds of one joint as used (rad/s) and whether they were unusable: a NaN bound reads as 0 (no
    motion that way); where then ``lo > hi``, both become the value between them nearest 0."""
    if lo <= hi:
        return lo, hi, False
    lo = lo if lo == lo else 0.0
    hi = hi if hi == hi else 0.0
    if lo > hi:
        lo = hi = min(max(0.0, hi), lo)
    return lo, hi, True


@njit(cache=True, nogil=True)
def enforce_bounds_kernel(
    p0: np.ndarray, v0: np.ndarray, a0_in: np.ndarray, pp: np.ndarray, vp: np.ndarray, ap: np.ndarray,
    lo: np.ndarray, hi: np.ndarray, a_max: np.ndarray, j_max: np.ndarray, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:  # fmt: skip
    """:func:`enforce_velocity_bounds` on float64 C-contiguous (n,) arrays (state p0, v0, a0; planned
    pp, vp, ap): steps 1-3 of the module docstring per joint, and its rules for bad input. Returns position,
    velocity, acceleration, limited."""
    n = p0.shape[0]
    p, v, a = np.empty(n), np.empty(n), np.empty(n)
    limited = False
    for i in range(n):
        lo_i, hi_i, bad = _sane_bounds(lo[i], hi[i])
        vs = v0[i] if np.isfinite(v0[i]) else 0.0  # (a non-finite state entry reads as 0, as in braking_step)
        a0 = a0_in[i] if np.isfinite(a0_in[i]) else 0.0
        bad = bad or vs != v0[i] or a0 != a0_in[i] or not np.isfinite(p0[i])
        pi, vi, ai = pp[i], vp[i], ap[i]
        if not (np.isfinite(pi) and np.isfinite(vi) and np.isfinite(ai)):  # no plan: the braking step
            pi, vi, ai = _brake_one(p0[i], vs, a0, a_max[i], j_max[i], dt)
            bad = True
        over = vi > hi_i + _ROUNDING
        under = vi < lo_i - _ROUNDING
        if over or under:
            a0 = min(max(a0, -a_max[i]), a_max[i])
            a_lo = max(a0 - j_max[i] * dt, -a_max[i])  # accelerations reachable within the jerk limit
            a_hi = min(a0 + j_max[i] * dt, a_max[i])
            if over:  # land on hi with a_new <= 0 (the constant-jerk step: v0 + (a0 + a_new) dt / 2)
                a_new = min(2.0 * (hi_i - vs) / dt - a0, 0.0, a_hi)
                ok = a_new >= a_lo
            else:  # land on lo with a_new >= 0
                a_new = max(2.0 * (lo_i - vs) / dt - a0, 0.0, a_lo)
                ok = a_new <= a_hi
            v_new = vs + 0.5 * (a0 + a_new) * dt
            if ok and lo_i - _ROUNDING <= v_new <= hi_i + _ROUNDING:
                pi = p0[i] + vs * dt + a0 * (dt * dt / 2.0) + (a_new - a0) * (dt * dt / 6.0)
                vi, ai = v_new, a_new
            else:  # no jerk-limited step stays within the bound: the bound wins
                vb = hi_i if over else lo_i
                pi = p0[i] + 0.5 * (vs + vb) * dt
                vi = vb
                # the acceleration keeps to its jerk limit, braking as hard as it may (not pushing on)
                ai = min(a_lo, 0.0) if over else max(a_hi, 0.0)
                limited = True
        p[i], v[i], a[i] = pi, min(max(vi, lo_i), hi_i), ai
        limited = limited or bad
    return p, v, a, limited


def enforce_velocity_bounds(
    state: OtgState,
    planned: OtgState,
    lo: np.ndarray,
    hi: np.ndarray,
    a_max: np.ndarray,
    j_max: np.ndarray,
    dt: float,
) -> tuple[OtgState, bool]:
    """The planned next state, corrected so that its velocity lies within ``[lo, hi]`` (module docstring).

    Args:
        state: the state at the start of the cycle (position rad, velocity rad/s, acceleration rad/s^2).
        planned: the state that Ruckig (or :func:`braking_step`) planned for the end of the cycle.
        lo, hi: (n,) the cycle's velocity bounds, rad/s, ``lo <= hi`` (otherwise: the module docstring).
        a_max, j_max: (n,) acceleration (rad/s^2) and jerk (rad/s^3) limits; dt: period, s.
    Returns:
        the new state with ``lo <= velocity <= hi`` exactly, and ``limited``: True when a bound had to
        win over the acceleration or jerk limit in this cycle, or the input was bad (module docstring).
    """
    f = np.ascontiguousarray
    p, v, a, limited = enforce_bounds_kernel(
        f(state.position, np.float64), f(state.velocity, np.float64), f(state.acceleration, np.float64),
        f(planned.position, np.float64), f(planned.velocity, np.float64), f(planned.acceleration, np.float64),
        f(lo, np.float64), f(hi, np.float64), f(a_max, np.float64), f(j_max, np.float64), float(dt),
    )  # fmt: skip
    return OtgState(p, v, a), bool(limited)


def braking_step(state: OtgState, a_max: np.ndarray, j_max: np.ndarray, dt: float) -> OtgState:
    """One period of a jerk-limited stop without Ruckig (the fallback when Ruckig fails).

    Each joint steers its acceleration, at most ``j_max`` per second, towards
    ``-sign(v) min(a_max, sqrt(2 j_max |v|))``: the deceleration from which ramping the acceleration
    back to 0 at ``j_max`` ends at ``v = 0``. A joint whose velocity would change sign stops at 0.
    Everything stays finite for finite inputs; non-finite state entries are treated as 0.
    """

    def finite(x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.nan_to_num(np.asarray(x, np.float64), nan=0.0, posinf=0.0, neginf=0.0))

    n = len(state.velocity)
    a_m = np.ascontiguousarray(np.broadcast_to(np.asarray(a_max, np.float64), (n,)))
    j_m = np.ascontiguousarray(np.broadcast_to(np.asarray(j_max, np.float64), (n,)))
    return OtgState(*_braking_kernel(finite(state.position), finite(state.velocity), finite(state.acceleration),
                                     a_m, j_m, float(dt)))  # fmt: skip
