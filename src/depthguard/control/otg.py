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
        q: (n,) joint positions, rad; q_min, q_max: (n,) limits, rad.
        a_max, j_max: (n,) acceleration (rad/s^2) and jerk (rad/s^3) limits.
        latency: seconds before braking starts (e.g. two control cycles).
        margin: stop this far (rad) inside the limits.
        brake_fraction: share of ``a_max`` assumed for braking, in (0, 1].
    Returns:
        ``(lo, hi)`` with ``lo <= 0 <= hi``: ``hi = v_b(q_max - margin - q)``,
        ``lo = -v_b(q - q_min - margin)``, 0 where the joint is at or beyond the (margin-reduced) limit.
    """
    a = np.asarray(a_max, dtype=float) * brake_fraction
    c = a / (2.0 * np.asarray(j_max, dtype=float)) + latency

    def vb(d: np.ndarray) -> np.ndarray:
        d = np.maximum(d, 0.0)
        return a * (-c + np.sqrt(c * c + 2.0 * d / a))

    return -vb(q - q_min - margin), vb(q_max - margin - q)


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
    follow the shrinking bound), so ``lo <= lo_s <= 0 <= hi_s <= hi``. tests/test_otg.py checks the
    result against :func:`position_limited_velocity_bounds`.
    """
    n = q.shape[0]
    lo, hi = np.empty(n), np.empty(n)
    lo_s, hi_s = np.empty(n), np.empty(n)
    for i in range(n):
        a = a_max[i] * brake_fraction
        c = a / (2.0 * j_max[i]) + latency
        up = max(v[i], 0.0) * ahead
        dn = min(v[i], 0.0) * ahead
        d_hi = max(q_max[i] - margin - q[i], 0.0)
        d_lo = max(q[i] - q_min[i] - margin, 0.0)
        d_hi_s = max(q_max[i] - margin - q[i] - up, 0.0)
        d_lo_s = max(q[i] + dn - q_min[i] - margin, 0.0)
        hi[i] = max(min(v_max[i], a * (-c + np.sqrt(c * c + 2.0 * d_hi / a))), 0.0)
        lo[i] = min(max(-v_max[i], -a * (-c + np.sqrt(c * c + 2.0 * d_lo / a))), 0.0)
        hi_s[i] = min(hi[i], max(a * (-c + np.sqrt(c * c + 2.0 * d_hi_s / a)), 0.0))
        lo_s[i] = max(lo[i], min(-a * (-c + np.sqrt(c * c + 2.0 * d_lo_s / a)), 0.0))
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
        self.a_max = np.broadcast_to(np.asarray(self.a_max, dtype=float), (self.n,)).copy()
        self.j_max = np.broadcast_to(np.asarray(self.j_max, dtype=float), (self.n,)).copy()
        if not (np.all(self.a_max > 0) and np.all(self.j_max > 0)):
            raise ValueError("a_max and j_max must be > 0")
        if not self.dt > 0:
            raise ValueError(f"dt must be > 0, got {self.dt}")
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
            self.v_max = np.broadcast_to(np.asarray(self.v_max, dtype=float), (self.n,)).copy()
            if not np.all(self.v_max > 0):
                raise ValueError("v_max must be > 0")
            self._inp.max_velocity = self.v_max.tolist()
        self._neg_a_max = -self.a_max
        self._inp.max_acceleration = self.a_max.tolist()
        self._inp.max_jerk = self.j_max.tolist()
        self._inp.target_acceleration = [0.0] * self.n

    def step(self, state: OtgState, target_velocity: np.ndarray) -> tuple[OtgState, np.ndarray, int]:
        """Advance one cycle towards ``target_velocity`` (n,).

        Returns:
            the new state, the jerk (n,) applied, and Ruckig's result code (``ruckig.Result``:
            0 Working, 1 Finished, negative = error). On error the state is returned unchanged; an
            exception inside Ruckig (``RuckigError`` for non-finite input) is reported as -1 (Error).
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
            inp.current_position = state.position.tolist()
            inp.current_velocity = state.velocity.tolist()
            inp.current_acceleration = np.minimum(np.maximum(state.acceleration, self._neg_a_max), self.a_max).tolist()
            inp.target_velocity = np.asarray(target_velocity, dtype=float).tolist()
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
