"""Jerk-limited on-line trajectory generation (ICRA'12 §V-B) with Ruckig in velocity mode.

Ruckig (Berscheid & Kröger, RSS 2021) computes, every control cycle, the time-optimal jerk-limited
motion from the current state (velocity, acceleration) to a target velocity, within per-joint
acceleration and jerk limits. In velocity mode it does not enforce joint *position* limits, so
:func:`position_limited_velocity_bounds` shrinks the velocity bounds near the position limits first,
to speeds from which the joint can still brake in time:

``v_b(d) = a (-(a/(2j) + T) + sqrt((a/(2j) + T)^2 + 2 d / a))``, the largest v with
``v^2/(2a) + v a/(2j) + v T <= d``: the braking distance from zero acceleration under acceleration limit
a and jerk limit j, plus T seconds of latency at speed v. The braking term is exact when the stop reaches
the acceleration limit (``v >= a^2/j``) and an upper bound otherwise (``v sqrt(v/j)``, by AM-GM);
tests/test_otg.py checks both against an independent integration of the jerk-limited profile. ``d`` is
the distance to the limit (less a margin) and a is a fraction ``brake_fraction`` of the acceleration
limit: the rest is a reserve. It does not cover an arbitrary acceleration towards the limit at the
moment braking starts; the controller keeps the acceleration towards a limit at or below 0 whenever
the velocity sits on this bound (:mod:`depthguard.control.bounded`) and plans a little ahead of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["OtgState", "JointOtg", "position_limited_velocity_bounds", "joint_velocity_bounds"]


def position_limited_velocity_bounds(
    q: np.ndarray,
    q_min: np.ndarray,
    q_max: np.ndarray,
    a_max: np.ndarray,
    j_max: np.ndarray,
    latency: float,
    margin: float = 0.0,
    brake_fraction: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity bounds (n,), (n,) from which every joint can stop before its position limits.

    Args:
        q: (n,) joint positions, rad; q_min, q_max: (n,) limits, rad (-inf / +inf: unbounded).
        a_max, j_max: (n,) acceleration (rad/s^2) and jerk (rad/s^3) limits.
        latency: seconds before braking starts (e.g. two control cycles).
        margin: stop this far (rad) inside the limits.
        brake_fraction: share of ``a_max`` assumed for braking, in (0, 1].
    Returns:
        ``(lo, hi)`` with ``lo <= 0 <= hi``: ``hi = v_b(q_max - margin - q)``,
        ``lo = -v_b(q - q_min - margin)``, 0 where the joint is at or beyond the (margin-reduced) limit,
        +-inf towards an infinite limit; never NaN. Where the bound is unknown (``q`` NaN or infinite; a NaN
        limit, ``a_max``, ``j_max``, ``latency`` or ``margin``; an infinite ``latency`` or ``a_max``) it is 0.
    Raises:
        ValueError: ``brake_fraction`` not in (0, 1].
    """
    if not 0.0 < brake_fraction <= 1.0:
        raise ValueError(f"brake_fraction must be a number in (0, 1], got {brake_fraction!r}")
    q = np.asarray(q, dtype=float)
    a = np.asarray(a_max, dtype=float) * brake_fraction
    with np.errstate(all="ignore"):
        c = a / (2.0 * np.asarray(j_max, dtype=float)) + latency
        known = np.isfinite(q) & (a > 0.0) & (c >= 0.0)

        def vb(d: np.ndarray) -> np.ndarray:
            # 2 d / (c + sqrt(c^2 + 2 d / a)) is v_b(d) without the cancellation of -c + sqrt(...); an
            # overflowing c^2 gives 0, not inf; d = inf (an unbounded joint) gives inf unless c is inf
            v = 2.0 * d / (c + np.sqrt(c * c + 2.0 * d / a))
            v = np.where(d == np.inf, np.where(c < np.inf, np.inf, 0.0), v)
            return np.where(known & (d > 0.0) & (v > 0.0), v, 0.0)

        return -vb(q - q_min - margin), vb(q_max - margin - q)


@njit(cache=True, nogil=True, inline="always")
def _braking_speed(d: float, a: float, c: float) -> float:
    """``v_b(d)`` of the module docstring for one joint (rad/s, >= 0): distance ``d`` (rad), braking
    acceleration ``a`` (rad/s^2), ``c = a / (2 j) + latency`` (s). Computed as ``2 d / (c + sqrt(c^2 + 2 d / a))``
    (no cancellation, an overflowing ``c^2`` gives 0); 0 for ``d <= 0`` and wherever an argument is NaN or
    out of range; inf for ``d = inf`` (an unbounded joint) with a finite ``c``."""
    if not (d > 0.0 and a > 0.0 and c >= 0.0):
        return 0.0
    if d == np.inf:
        return np.inf if c < np.inf else 0.0
    v = 2.0 * d / (c + np.sqrt(c * c + 2.0 * d / a))
    return v if v > 0.0 else 0.0


@njit(cache=True, nogil=True)
def joint_velocity_bounds(
    q: np.ndarray, v: np.ndarray, q_min: np.ndarray, q_max: np.ndarray, v_max: np.ndarray,
    a_max: np.ndarray, j_max: np.ndarray, latency: float, margin: float, ahead: float,
    brake_fraction: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The controller's joint-velocity bounds in one pass (float64 (n,) arrays, C-contiguous).

    ``lo, hi``: ``|qdot| <= v_max`` and :func:`position_limited_velocity_bounds` at ``q``;
    ``lo_s, hi_s``: the same with the position-limit bounds evaluated ``ahead`` (s) later along the
    velocity ``v`` (for planning: braking towards a limit then starts while the jerk limit can still
    follow the shrinking bound), so ``lo <= lo_s <= 0 <= hi_s <= hi``, never NaN. A joint whose ``q`` or
    ``v`` is not finite gets 0 for all four (no motion), as does the side of a NaN limit or of NaN
    parameters (``q_min``/``q_max`` may be -inf/+inf: an unbounded joint). tests/test_otg.py and
    tests/test_motion_guarantees.py check the result against :func:`position_limited_velocity_bounds`.
    """
    n = q.shape[0]
    lo, hi = np.zeros(n), np.zeros(n)
    lo_s, hi_s = np.zeros(n), np.zeros(n)
    for i in range(n):
        if not (np.isfinite(q[i]) and np.isfinite(v[i])):  # an unknown state: no motion (bounds 0)
            continue
        a = a_max[i] * brake_fraction
        c = a / (2.0 * j_max[i]) + latency
        vm = v_max[i] if v_max[i] > 0.0 else 0.0  # (NaN: 0)
        up = max(v[i], 0.0) * ahead
        dn = min(v[i], 0.0) * ahead
        hi[i] = min(vm, _braking_speed(q_max[i] - margin - q[i], a, c))
        lo[i] = -min(vm, _braking_speed(q[i] - q_min[i] - margin, a, c))
        hi_s[i] = min(hi[i], _braking_speed(q_max[i] - margin - q[i] - up, a, c))
        lo_s[i] = max(lo[i], -_braking_speed(q[i] + dn - q_min[i] - margin, a, c))
    return lo, hi, lo_s, hi_s


class OtgState(NamedTuple):
    """Motion state that the trajectory generator carries from one cycle to the next.

    Attributes:
        position: (n,) rad; velocity: (n,) rad/s; acceleration: (n,) rad/s^2.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclass
class JointOtg:
    """Ruckig in velocity mode for n joints with cycle time ``dt`` (s).

    ``synchronization``: "none" (each joint time-optimal, the default), "time" or "phase".
    ``v_max``: (n,) joint velocity limits, rad/s, passed to Ruckig as ``max_velocity``. Ruckig's velocity
    mode does not use it (nor any bound): its output can overshoot the target velocity when it starts
    from a non-zero acceleration, so the controller keeps each cycle's command within that cycle's
    bounds afterwards (:mod:`depthguard.control.bounded`).

    ``step`` is a function of its arguments (the Ruckig object only caches the last trajectory).
    ``n`` must be an integer >= 1, ``dt`` and every ``a_max``, ``j_max``, ``v_max`` finite and > 0 (a number
    or an (n,) array): anything else is refused at construction with a ValueError naming the field.
    """

    n: int
    dt: float
    a_max: np.ndarray
    j_max: np.ndarray
    synchronization: str = "none"
    v_max: np.ndarray | None = None

    def __post_init__(self) -> None:
        import ruckig

        self._ruckig = ruckig
        if isinstance(self.n, bool) or not isinstance(self.n, int | np.integer) or self.n < 1:
            raise ValueError(f"n must be an integer >= 1 (the number of joints), got {self.n!r}")
        self.n = int(self.n)
        self.a_max = _per_joint("a_max", self.a_max, self.n, "rad/s^2")
        self.j_max = _per_joint("j_max", self.j_max, self.n, "rad/s^3")
        try:
            dt = float(self.dt)
        except (TypeError, ValueError):
            dt = math.nan
        if not 0.0 < dt < math.inf:
            raise ValueError(f"dt must be a finite number of seconds > 0, got {self.dt!r}")
        self.dt = dt
        sync = {
            "time": ruckig.Synchronization.Time,
            "phase": ruckig.Synchronization.Phase,
            "none": ruckig.Synchronization.No,
        }
        if self.synchronization not in sync:
            raise ValueError(f"synchronization must be one of {sorted(sync)}, got {self.synchronization!r}")
        self._otg = ruckig.Ruckig(self.n, self.dt)
        self._inp = ruckig.InputParameter(self.n)
        self._out = ruckig.OutputParameter(self.n)
        self._inp.control_interface = ruckig.ControlInterface.Velocity
        self._sync = sync[self.synchronization]
        self._inp.synchronization = self._sync
        if self.v_max is None:
            self._inp.max_velocity = [1e9] * self.n  # not used in velocity mode
        else:
            self.v_max = _per_joint("v_max", self.v_max, self.n, "rad/s")
            self._inp.max_velocity = self.v_max.tolist()
        self._neg_a_max = -self.a_max
        self._inp.max_acceleration = self.a_max.tolist()
        self._inp.max_jerk = self.j_max.tolist()
        self._inp.target_acceleration = [0.0] * self.n

    def step(self, state: OtgState, target_velocity: np.ndarray) -> tuple[OtgState, np.ndarray, int]:
        """Advance one cycle towards ``target_velocity`` (n,).

        Returns:
            the new state, the jerk (n,) applied, and Ruckig's result code (``ruckig.Result``:
            0 Working, 1 Finished, negative = error). On error the state is returned unchanged: a state or
            target that is not finite or not of length n, and any exception inside Ruckig, is reported as
            -1 (Error); this never raises.
        """
        new, code = self.advance(state, target_velocity)
        if code < 0:
            return state, np.zeros(self.n), code
        return new, np.array(self._out.new_jerk), code

    def advance(self, state: OtgState, target_velocity: np.ndarray, synchronized: bool = False) -> tuple[OtgState, int]:
        """:meth:`step` without the jerk: the new state and Ruckig's result code (the state unchanged on
        error). ``synchronized``: this one step phase-synchronized (all joints on proportional profiles,
        so that the joint velocity moves along a straight line to the target; Ruckig falls back to time
        synchronization where the current motion makes that impossible), whatever ``synchronization`` is."""
        inp, out = self._inp, self._out
        if synchronized:
            inp.synchronization = self._ruckig.Synchronization.Phase
        try:
            p, v = state.position.tolist(), state.velocity.tolist()
            a, t = state.acceleration.tolist(), np.asarray(target_velocity, dtype=float).tolist()
            # Ruckig's velocity mode checks neither the position nor the length of the target, and the
            # acceleration is clipped below: one finite sum per input refuses NaN/inf (and sums beyond float
            # range), 4 sums of n floats, about 0.2 us
            n = self.n
            if not (len(p) == len(v) == len(a) == len(t) == n and _finite(sum(p) + sum(v) + sum(a) + sum(t))):
                raise ValueError("state and target must be finite (n,) arrays")
            inp.current_position, inp.current_velocity = p, v
            inp.current_acceleration = np.minimum(np.maximum(state.acceleration, self._neg_a_max), self.a_max).tolist()
            inp.target_velocity = t
            res = self._otg.update(inp, out)
            code = int(res)
        except Exception:  # noqa: BLE001 - the real-time path reports, it does not raise
            code = -1
        finally:
            if synchronized:
                inp.synchronization = self._sync
        if code < 0:
            return state, code
        return OtgState(np.array(out.new_position), np.array(out.new_velocity), np.array(out.new_acceleration)), code


_finite = math.isfinite


def _per_joint(name: str, value, n: int, unit: str) -> np.ndarray:
    """``value`` (a number or an (n,) array) as a float (n,) array of finite numbers > 0; ValueError naming
    ``name`` otherwise."""
    expected = f"{name} must be a finite number > 0 ({unit}) or an ({n},) array of them"
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{expected}, got {value!r}") from None
    if arr.shape not in ((), (n,)):
        raise ValueError(f"{expected}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr) & (arr > 0.0)):
        raise ValueError(f"{expected}, got {arr.tolist()}")
    return np.broadcast_to(arr, (n,)).copy()
