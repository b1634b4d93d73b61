"""Ruckig velocity-mode generator: every limit holds; position limits are enforced by our bounds."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ruckig")

from depthguard.control.otg import JointOtg, OtgState, position_limited_velocity_bounds  # noqa: E402

DT = 0.001


def _check_limits(states: list[OtgState], v_max: np.ndarray, a_max: np.ndarray, j_max: np.ndarray) -> None:
    v = np.array([s.velocity for s in states])
    a = np.array([s.acceleration for s in states])
    assert np.all(np.abs(v) <= v_max + 1e-9)
    assert np.all(np.abs(a) <= a_max + 1e-9)
    jerk = np.diff(a, axis=0) / DT  # independent of Ruckig's own jerk output
    assert np.all(np.abs(jerk) <= j_max * (1 + 1e-6) + 1e-6)
    # positions integrate the velocities (trapezoid bound), no jumps
    p = np.array([s.position for s in states])
    assert np.all(np.abs(np.diff(p, axis=0)) <= v_max * DT + 1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_output_stays_within_every_limit_under_abrupt_targets(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 7
    v_max = rng.uniform(1.0, 3.0, n)
    a_max = rng.uniform(5.0, 15.0, n)
    j_max = rng.uniform(100.0, 1000.0, n)
    otg = JointOtg(n, DT, a_max, j_max)
    s = OtgState(np.zeros(n), np.zeros(n), np.zeros(n))
    states = [s]
    target = np.zeros(n)
    for k in range(3000):
        if k % 37 == 0:  # jump the target anywhere inside the velocity bounds
            target = rng.uniform(-v_max, v_max)
        s, _, code = otg.step(s, target)
        assert code >= 0
        states.append(s)
    _check_limits(states, v_max, a_max, j_max)


@pytest.mark.parametrize("sync", ["time", "phase", "none"])
def test_reaches_the_target_velocity(sync: str) -> None:
    otg = JointOtg(3, DT, 10.0, 500.0, synchronization=sync)
    s = OtgState(np.zeros(3), np.zeros(3), np.zeros(3))
    for _ in range(1000):
        s, _, _ = otg.step(s, np.array([1.0, -0.5, 0.2]))
    np.testing.assert_allclose(s.velocity, [1.0, -0.5, 0.2], atol=1e-9)


def test_a_synchronized_step_moves_along_the_target_and_leaves_the_setting_as_it_was() -> None:
    """``advance(..., synchronized=True)`` from rest: every joint's velocity is the same fraction of its
    target (a straight line in joint-velocity space), where the time-optimal joints are not; the next plain
    call is again the time-optimal one, as from a fresh generator."""
    target = np.array([1.0, -0.05, 0.3])
    rest = OtgState(np.zeros(3), np.zeros(3), np.zeros(3))
    otg = JointOtg(3, DT, 10.0, 500.0)
    s = rest
    for _ in range(30):
        s, code = otg.advance(s, target, synchronized=True)
        assert code >= 0
        frac = s.velocity / target
        np.testing.assert_allclose(frac, frac[0], rtol=1e-6)
        assert 0.0 < frac[0] < 1.0
    plain, _ = otg.advance(rest, target)
    fresh, _ = JointOtg(3, DT, 10.0, 500.0).advance(rest, target)
    np.testing.assert_array_equal(plain.velocity, fresh.velocity)
    frac = plain.velocity / target
    assert frac.max() > 2.0 * frac.min()  # (time-optimal: the small target is nearer to being reached)


def test_position_limits_hold_when_driving_into_them() -> None:
    n = 2
    q_min, q_max = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    v_max, a_max, j_max = np.array([2.0, 2.0]), np.array([10.0, 10.0]), np.array([500.0, 500.0])
    otg = JointOtg(n, DT, a_max, j_max)
    s = OtgState(np.zeros(n), np.zeros(n), np.zeros(n))
    states = [s]
    for _ in range(3000):
        lo, hi = position_limited_velocity_bounds(s.position, q_min, q_max, a_max, j_max, 2 * DT, 0.02)
        desired = np.array([v_max[0], -v_max[1]])  # joint 0 up, joint 1 down, at full speed
        s, _, _ = otg.step(s, np.clip(desired, np.maximum(lo, -v_max), np.minimum(hi, v_max)))
        states.append(s)
    p = np.array([x.position for x in states])
    assert p[:, 0].max() <= q_max[0] and p[:, 1].min() >= q_min[1]
    assert p[-1, 0] > q_max[0] - 0.1 and p[-1, 1] < q_min[1] + 0.1  # it does get close
    _check_limits(states, v_max, a_max, j_max)


def _segment(p: float, v: float, a: float, jerk: float, t: float) -> tuple[float, float, float]:
    """Exact motion under constant jerk for t seconds."""
    return p + v * t + a * t * t / 2 + jerk * t**3 / 6, v + a * t + jerk * t * t / 2, a + jerk * t


def _stopping_distance(v: float, a_lim: float, j_lim: float) -> float:
    """Independent reference: distance of the time-optimal jerk-limited stop from speed v > 0 at zero
    acceleration (jerk -j to the peak deceleration, hold it, jerk +j back to 0 as v reaches 0), by exact
    integration of its constant-jerk segments. Peak deceleration min(a, sqrt(j v))."""
    a_p = min(a_lim, np.sqrt(j_lim * v))
    t_hold = max(v - a_p * a_p / j_lim, 0.0) / a_p if a_p > 0 else 0.0
    p, vv, a = _segment(0.0, v, 0.0, -j_lim, a_p / j_lim)
    p, vv, a = _segment(p, vv, a, 0.0, t_hold)
    p, vv, a = _segment(p, vv, a, j_lim, a_p / j_lim)
    assert abs(vv) <= 1e-9 * max(1.0, v) and abs(a) <= 1e-9
    return p


@pytest.mark.parametrize("latency", [0.0, 0.002, 0.01])
@pytest.mark.parametrize("margin", [0.0, 0.02])
def test_braking_bound_is_the_exact_jerk_limited_stopping_speed(latency: float, margin: float) -> None:
    """With brake_fraction 1 the bound v_b(d) travels ``latency * v_b`` and then stops exactly at the
    margin when the profile reaches the acceleration limit (v_b >= a^2/j), and before it otherwise; a
    slightly faster joint would overrun it. Checked against an independent integration of the profile."""
    a_max, j_max = np.array([10.0]), np.array([500.0])
    q_max = 1.0
    for d in np.geomspace(1e-4, 2.0, 40):
        q = np.array([q_max - margin - d])
        lo, hi = position_limited_velocity_bounds(
            q, np.array([-5.0]), np.array([q_max]), a_max, j_max, latency, margin, brake_fraction=1.0
        )
        v = float(hi[0])
        assert v > 0.0 and lo[0] < 0.0
        travel = latency * v + _stopping_distance(v, 10.0, 500.0)
        assert travel <= d * (1 + 1e-9)  # never past q_max - margin
        if v >= 10.0**2 / 500.0:  # trapezoidal profile: the bound is exact, not conservative
            assert travel == pytest.approx(d, rel=1e-9)
            assert latency * v * 1.001 + _stopping_distance(v * 1.001, 10.0, 500.0) > d
        # (triangular profile, v < a^2/j: v^2/(2a) + v a/(2j) >= v sqrt(v/j) by AM-GM, so conservative)


@pytest.mark.parametrize("brake_fraction", [0.5, 1.0])
def test_ruckig_braking_from_the_bound_stops_within_the_margin(brake_fraction: float) -> None:
    """Ruckig's own braking (full limits, from zero acceleration) from v_b stops at or before
    q_max - margin; with brake_fraction 1 it stops right at it (no hidden slack)."""
    a_max, j_max, margin = np.array([10.0]), np.array([500.0]), 0.02
    otg = JointOtg(1, DT, a_max, j_max)
    for d in (0.0005, 0.01, 0.05, 0.3, 1.0):
        q = np.array([1.0 - margin - d])
        _, hi = position_limited_velocity_bounds(
            q, np.array([-1.0]), np.array([1.0]), a_max, j_max, 0.0, margin, brake_fraction
        )
        s = OtgState(q.copy(), hi.copy(), np.zeros(1))
        for _ in range(2000):
            s, _, _ = otg.step(s, np.zeros(1))
        assert abs(s.velocity[0]) < 1e-12
        assert s.position[0] <= 1.0 - margin + 1e-9
        if brake_fraction == 1.0 and hi[0] >= 10.0**2 / 500.0:
            assert s.position[0] == pytest.approx(1.0 - margin, abs=1e-6)


def test_bounds_contain_zero_and_vanish_beyond_the_limits() -> None:
    q = np.array([-2.0, 0.0, 2.0])
    lo, hi = position_limited_velocity_bounds(q, -np.ones(3), np.ones(3), np.full(3, 10.0), np.full(3, 500.0), 0.002)
    assert np.all(lo <= 0) and np.all(hi >= 0)
    assert lo[0] == 0.0 and hi[2] == 0.0  # beyond a limit: only motion back inside
    assert hi[0] > 0 and lo[2] < 0


def test_bad_configuration_raises() -> None:
    with pytest.raises(ValueError, match="a_max"):
        JointOtg(2, DT, 0.0, 1.0)
    with pytest.raises(ValueError, match="synchronization"):
        JointOtg(2, DT, 1.0, 1.0, synchronization="x")
    with pytest.raises(ValueError, match="dt"):
        JointOtg(2, 0.0, 1.0, 1.0)


def test_joint_velocity_bounds_match_the_numpy_formula() -> None:
    from depthguard.control.otg import joint_velocity_bounds

    rng = np.random.default_rng(5)
    n = 7
    for _ in range(50):
        q_min, q_max = -rng.uniform(1.0, 3.0, n), rng.uniform(1.0, 3.0, n)
        q = rng.uniform(q_min - 0.1, q_max + 0.1)
        v = rng.uniform(-3.0, 3.0, n)
        v_max, a_max, j_max = rng.uniform(1, 3, n), rng.uniform(5, 15, n), rng.uniform(100, 1000, n)
        ahead, latency, margin = 0.04, 0.002, 0.02
        lo, hi, lo_s, hi_s = joint_velocity_bounds(q, v, q_min, q_max, v_max, a_max, j_max, latency, margin, ahead)
        lo_p, hi_p = position_limited_velocity_bounds(q, q_min, q_max, a_max, j_max, latency, margin)
        np.testing.assert_allclose(lo, np.minimum(np.maximum(-v_max, lo_p), 0.0), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(hi, np.maximum(np.minimum(v_max, hi_p), 0.0), rtol=1e-12, atol=1e-15)
        lo_a, _ = position_limited_velocity_bounds(
            q + np.minimum(v, 0) * ahead, q_min, q_max, a_max, j_max, latency, margin
        )
        _, hi_a = position_limited_velocity_bounds(
            q + np.maximum(v, 0) * ahead, q_min, q_max, a_max, j_max, latency, margin
        )
        np.testing.assert_allclose(lo_s, np.maximum(lo, lo_a), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(hi_s, np.minimum(hi, hi_a), rtol=1e-12, atol=1e-15)
        assert np.all(lo <= lo_s) and np.all(lo_s <= 0) and np.all(0 <= hi_s) and np.all(hi_s <= hi)
