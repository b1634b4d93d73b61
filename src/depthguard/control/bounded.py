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

:func:`braking_step` is a jerk-limited stop that needs no Ruckig: the fallback when Ruckig fails.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.control.otg import OtgState

__all__ = ["enforce_velocity_bounds", "enforce_bounds_kernel", "braking_step"]

_ROUNDING = 1e-12  # a planned velocity this far beyond a bound is rounding: clipped, not reported


def _constant_jerk(state: OtgState, a_new: np.ndarray, dt: float) -> OtgState:
    """Integrate one period with the jerk ``(a_new - a) / dt`` constant over it (exact)."""
    p, v, a = state
    v_new = v + 0.5 * (a + a_new) * dt
    p_new = p + v * dt + a * (dt * dt / 2.0) + (a_new - a) * (dt * dt / 6.0)
    return OtgState(p_new, v_new, a_new)


@njit(cache=True, nogil=True)
def enforce_bounds_kernel(
    p0: np.ndarray, v0: np.ndarray, a0_in: np.ndarray, pp: np.ndarray, vp: np.ndarray, ap: np.ndarray,
    lo: np.ndarray, hi: np.ndarray, a_max: np.ndarray, j_max: np.ndarray, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:  # fmt: skip
    """:func:`enforce_velocity_bounds` on float64 C-contiguous (n,) arrays (state p0, v0, a0; planned
    pp, vp, ap): steps 1-3 of the module docstring per joint. Returns position, velocity, acceleration,
    limited."""
    n = p0.shape[0]
    p, v, a = pp.copy(), vp.copy(), ap.copy()
    limited = False
    for i in range(n):
        over = vp[i] > hi[i] + _ROUNDING
        under = vp[i] < lo[i] - _ROUNDING
        if over or under:
            a0 = min(max(a0_in[i], -a_max[i]), a_max[i])
            a_lo = max(a0 - j_max[i] * dt, -a_max[i])  # accelerations reachable within the jerk limit
            a_hi = min(a0 + j_max[i] * dt, a_max[i])
            if over:  # land on hi with a_new <= 0 (the constant-jerk step: v0 + (a0 + a_new) dt / 2)
                a_new = min(2.0 * (hi[i] - v0[i]) / dt - a0, 0.0, a_hi)
                ok = a_new >= a_lo
            else:  # land on lo with a_new >= 0
                a_new = max(2.0 * (lo[i] - v0[i]) / dt - a0, 0.0, a_lo)
                ok = a_new <= a_hi
            v_new = v0[i] + 0.5 * (a0 + a_new) * dt
            if ok and lo[i] - _ROUNDING <= v_new <= hi[i] + _ROUNDING:
                p[i] = p0[i] + v0[i] * dt + a0 * (dt * dt / 2.0) + (a_new - a0) * (dt * dt / 6.0)
                v[i], a[i] = v_new, a_new
            else:  # no jerk-limited step stays within the bound: the bound wins
                vb = hi[i] if over else lo[i]
                p[i] = p0[i] + 0.5 * (v0[i] + vb) * dt
                v[i] = vb
                # the acceleration keeps to its jerk limit, braking as hard as it may (not pushing on)
                a[i] = min(a_lo, 0.0) if over else max(a_hi, 0.0)
                limited = True
        v[i] = min(max(v[i], lo[i]), hi[i])
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
        lo, hi: (n,) the cycle's velocity bounds, rad/s, ``lo <= hi``.
        a_max, j_max: (n,) acceleration (rad/s^2) and jerk (rad/s^3) limits; dt: period, s.
    Returns:
        the new state with ``lo <= velocity <= hi`` exactly, and ``limited``: True when a bound had to
        win over the acceleration or jerk limit in this cycle.
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
    p = np.nan_to_num(state.position, nan=0.0, posinf=0.0, neginf=0.0)
    v = np.nan_to_num(state.velocity, nan=0.0, posinf=0.0, neginf=0.0)
    a = np.nan_to_num(state.acceleration, nan=0.0, posinf=0.0, neginf=0.0)
    a = np.minimum(np.maximum(a, -a_max), a_max)
    a_des = -np.sign(v) * np.minimum(a_max, np.sqrt(2.0 * j_max * np.abs(v)))
    a_new = np.minimum(np.maximum(a_des, a - j_max * dt), a + j_max * dt)
    a_new = np.minimum(np.maximum(a_new, -a_max), a_max)
    nxt = _constant_jerk(OtgState(p, v, a), a_new, dt)
    crossed = (np.sign(nxt.velocity) * np.sign(v) < 0) | (v == 0.0)
    if np.any(crossed):
        a_rest = np.minimum(np.maximum(0.0, a - j_max * dt), a + j_max * dt)
        vel = np.where(crossed, 0.0, nxt.velocity)
        pos = np.where(crossed, p + 0.5 * v * dt, nxt.position)
        acc = np.where(crossed, a_rest, nxt.acceleration)
        return OtgState(pos, vel, acc)
    return nxt
