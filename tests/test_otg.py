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


@pytest.mark.parametrize("d", [0.0, 0.001, 0.05, 0.3, 1.0])
def test_braking_bound_lets_the_joint_stop_in_time(d: float) -> None:
    a_max, j_max = np.array([10.0]), np.array([500.0])
    q = np.array([1.0 - d])
    _, hi = position_limited_velocity_bounds(q, np.array([-1.0]), np.array([1.0]), a_max, j_max, 0.0)
    assert hi[0] >= 0.0
    # brake from hi with Ruckig at the full limits: the stop must come before q_max = 1
    otg = JointOtg(1, DT, a_max, j_max)
    s = OtgState(q.copy(), hi.copy(), np.zeros(1))
    for _ in range(2000):
        s, _, _ = otg.step(s, np.zeros(1))
    assert s.position[0] <= 1.0 + 1e-12
    assert abs(s.velocity[0]) < 1e-12


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
