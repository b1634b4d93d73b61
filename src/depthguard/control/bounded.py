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

from depthguard.control.otg import OtgState

__all__ = ["enforce_velocity_bounds", "braking_step"]

_ROUNDING = 1e-12  # a planned velocity this far beyond a bound is rounding: clipped, not reported


def _constant_jerk(state: OtgState, a_new: np.ndarray, dt: float) -> OtgState:
    """Integrate one period with the jerk ``(a_new - a) / dt`` constant over it (exact)."""
    p, v, a = state
    v_new = v + 0.5 * (a + a_new) * dt
    p_new = p + v * dt + a * (dt * dt / 2.0) + (a_new - a) * (dt * dt / 6.0)
    return OtgState(p_new, v_new, a_new)


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
    v_plan = planned.velocity
    over = v_plan > hi + _ROUNDING
    under = v_plan < lo - _ROUNDING
    if not (np.any(over) or np.any(under)):
        v = np.minimum(np.maximum(v_plan, lo), hi)
        return OtgState(planned.position, v, planned.acceleration), False
    v0 = state.velocity
    a0 = np.minimum(np.maximum(state.acceleration, -a_max), a_max)
    a_lo = np.maximum(a0 - j_max * dt, -a_max)  # the accelerations reachable within the jerk limit
    a_hi = np.minimum(a0 + j_max * dt, a_max)
    hit_hi = 2.0 * (hi - v0) / dt - a0  # the a_new whose constant-jerk step lands on hi (or lo)
    hit_lo = 2.0 * (lo - v0) / dt - a0
    a_up = np.minimum(np.minimum(hit_hi, 0.0), a_hi)  # upper bound crossed: land on it, a_new <= 0
    a_dn = np.maximum(np.maximum(hit_lo, 0.0), a_lo)  # lower bound crossed: land on it, a_new >= 0
    ok_up = a_up >= a_lo
    ok_dn = a_dn <= a_hi
    fix = (over & ok_up) | (under & ok_dn)
    step = _constant_jerk(state, np.where(over, a_up, a_dn), dt)
    fix &= (step.velocity <= hi + _ROUNDING) & (step.velocity >= lo - _ROUNDING)
    wins = (over | under) & ~fix
    pos = np.where(fix, step.position, planned.position)
    vel = np.where(fix, step.velocity, v_plan)
    acc = np.where(fix, step.acceleration, planned.acceleration)
    if np.any(wins):  # no jerk-limited step stays within the bound: the bound wins
        v_bound = np.minimum(np.maximum(v_plan, lo), hi)
        pos = np.where(wins, state.position + 0.5 * (v0 + v_bound) * dt, pos)
        vel = np.where(wins, v_bound, vel)
        # the acceleration keeps to its jerk limit, braking as hard as it may (and not pushing on)
        acc = np.where(wins, np.where(over, np.minimum(a_lo, 0.0), np.maximum(a_hi, 0.0)), acc)
    vel = np.minimum(np.maximum(vel, lo), hi)
    return OtgState(pos, vel, acc), bool(np.any(wins))


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
