"""Speed and separation monitor: the ISO/TS 15066 formula, the speed scale, the stop latch."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.control.ssm import (
    MonitorState,
    SsmConfig,
    SsmMonitor,
    protective_separation,
    reaction_time,
)


def test_formula_each_term_zeroed_in_turn():
    """S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r, hand-computed, each term removed once."""
    base = dict(v_h=1.6, T_r=0.1, T_s=0.2, v_r=0.5, S_s=0.03, C=0.05, Z_d=0.04, Z_r=0.01)
    full = 1.6 * 0.3 + 0.5 * 0.1 + 0.03 + 0.05 + 0.04 + 0.01
    assert protective_separation(**base) == pytest.approx(full)
    for key, removed in [
        ("v_h", 1.6 * 0.3),
        ("v_r", 0.05),
        ("S_s", 0.03),
        ("C", 0.05),
        ("Z_d", 0.04),
        ("Z_r", 0.01),
    ]:
        assert protective_separation(**{**base, key: 0.0}) == pytest.approx(full - removed)
    assert protective_separation(**{**base, "T_s": 0.0}) == pytest.approx(full - 1.6 * 0.2)
    assert protective_separation(**{**base, "T_r": 0.0}) == pytest.approx(full - 1.6 * 0.1 - 0.05)


def test_reaction_time_sums_the_chain():
    """From the capture: the wait for the next frame (one period, or the data's age when a frame is late)
    + processing + communication + control period."""
    cfg = SsmConfig(camera_period=0.033, processing_latency=0.01, communication_latency=0.002, control_period=0.001)
    assert reaction_time(cfg) == pytest.approx(0.046)
    assert reaction_time(cfg, 0.02) == pytest.approx(0.046)  # the next frame is due 13 ms from now
    assert reaction_time(cfg, 0.05) == pytest.approx(0.063)  # late: the wait is at least the age


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="intrusion"):
        SsmConfig(intrusion=-0.1)
    with pytest.raises(ValueError, match="camera_period"):
        SsmConfig(camera_period=float("nan"))


def _one_point_monitor(cfg=None, lever=0.5):
    """One point on one prismatic-like joint: J = [lever] along x, chain length = lever."""
    jac = np.zeros((1, 3, 1))
    jac[0, 0, 0] = lever
    mon = SsmMonitor(np.array([[lever]]), np.array([10.0]), np.array([500.0]), cfg or SsmConfig())
    return mon, jac


def test_at_rest_the_protective_distance_is_the_iso_13855_case():
    """Robot at rest, nothing measured: S_p = 2.0 m/s * T_r + C + Z_d + Z_r (below 0.5 m, so K = 2000)."""
    cfg = SsmConfig()
    mon, jac = _one_point_monitor(cfg)
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([1.0]), np.array([[-1.0, 0, 0]]))
    T_r = reaction_time(cfg)
    assert out.s_p[0] == pytest.approx(2.0 * T_r + cfg.constant_terms)
    assert out.state == MonitorState.MONITOR_OK and out.scale == 1.0


def test_far_case_uses_1600_and_at_least_half_a_metre():
    """A fast approach pushes S_p over 0.5 m: ISO 13855 recomputes with 1.6 m/s, never below 0.5 m."""
    cfg = SsmConfig(camera_period=0.2)
    mon, jac = _one_point_monitor(cfg)
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([2.0]), np.array([[-1.0, 0, 0]]))
    T_r = reaction_time(cfg)
    expect = max(1.6 * T_r + cfg.constant_terms, 0.5)
    assert 2.0 * T_r + cfg.constant_terms > 0.5
    assert out.s_p[0] == pytest.approx(expect)


def test_only_the_speed_towards_the_obstacle_counts():
    """The point moves along +x; the obstacle lies along +y (direction -y... away from it): S_r = 0. Moving
    along +x towards an obstacle at +x (repulsive direction -x): S_r = v T_r."""
    cfg = SsmConfig()
    mon, jac = _one_point_monitor(cfg)
    qd = np.array([1.0])  # 0.5 m/s along +x
    side = mon.update(jac, np.zeros(1), np.zeros(1), qd, np.array([5.0]), np.array([[0.0, -1.0, 0]]))
    mon.reset()
    ahead = mon.update(jac, np.zeros(1), np.zeros(1), qd, np.array([5.0]), np.array([[-1.0, 0.0, 0]]))
    assert ahead.s_p[0] - side.s_p[0] == pytest.approx(0.5 * reaction_time(cfg))


def test_scale_is_the_largest_feasible():
    """The returned scale keeps S >= S_p; a slightly larger one would not."""
    cfg = SsmConfig()
    mon, jac = _one_point_monitor(cfg)
    d = np.array([0.35])
    dirs = np.array([[-1.0, 0, 0]])
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.array([3.0]), d, dirs)
    assert out.state == MonitorState.REDUCED and 0 < out.scale < 1
    assert out.margin[0] >= 0
    probe = SsmMonitor(mon.lengths, mon.a_max, mon.j_max, cfg)
    worse = probe.update(jac, np.zeros(1), np.zeros(1), np.array([3.0 * (out.scale + 2 / 4096)]), d, dirs)
    assert worse.scale < 1.0  # scaled nominal beyond the feasible one is cut again


def test_no_false_stop_when_nobody_is_within_reach():
    mon, jac = _one_point_monitor()
    for _ in range(20):
        out = mon.update(jac, np.array([1.0]), np.zeros(1), np.array([2.0]), np.array([np.inf]), np.zeros((1, 3)))
        assert out.state == MonitorState.MONITOR_OK and out.scale == 1.0


def test_nan_distance_stops():
    mon, jac = _one_point_monitor()
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([np.nan]), np.array([[np.nan] * 3]))
    assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=30))
def test_no_resume_while_a_person_stands_within_s_p(fracs):
    """After a stop, any sequence of separations below S_p(rest) + hysteresis keeps the robot stopped."""
    cfg = SsmConfig()
    mon, jac = _one_point_monitor(cfg)
    dirs = np.array([[-1.0, 0, 0]])
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([0.0]), dirs)
    assert out.state == MonitorState.PROTECTIVE_STOP
    rest = 2.0 * reaction_time(cfg) + cfg.constant_terms
    for f in fracs:
        d = f * (rest + cfg.hysteresis) * 0.999
        out = mon.update(jac, np.zeros(1), np.zeros(1), np.array([1.0]), np.array([d]), dirs)
        assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0
    out = mon.update(jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([rest + cfg.hysteresis + 0.01]), dirs)
    assert out.stop_ended and out.state == MonitorState.MONITOR_OK


@settings(max_examples=100, deadline=None)
@given(
    d=st.lists(st.one_of(st.floats(-1.0, 3.0), st.just(np.inf), st.just(np.nan)), min_size=3, max_size=3),
    qd=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
    qn=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
)
def test_monitor_output_is_consistent(d, qd, qn):
    """Whatever the inputs: scale in [0, 1]; when motion is allowed every finite margin is >= 0."""
    rng = np.random.default_rng(0)
    jac = rng.normal(size=(3, 3, 3)) * 0.3
    L = np.abs(jac).sum(axis=1) + 0.5
    mon = SsmMonitor(L, np.full(3, 10.0), np.full(3, 500.0))
    dirs = rng.normal(size=(3, 3))
    out = mon.update(jac, np.array(qd), np.zeros(3), np.array(qn), np.array(d), dirs)
    assert 0.0 <= out.scale <= 1.0
    if out.state != MonitorState.PROTECTIVE_STOP:
        m = out.margin[np.isfinite(out.margin)]
        assert np.all(m >= -1e-12)


def test_a_new_configuration_takes_effect_at_the_next_update():
    """The monitor caches its kernel parameters per configuration: assigning another one must not keep the
    old constants (C + Z_d + Z_r here) nor the old reaction time."""
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(3, 3, 3)) * 0.3
    L = np.abs(jac).sum(axis=1) + 0.5
    d, dirs = np.array([0.6, 0.9, np.inf]), rng.normal(size=(3, 3))
    qd, qn = np.array([0.3, -0.2, 0.1]), np.array([0.5, 0.4, -0.3])
    loose = SsmConfig(intrusion=0.0, sensor_uncertainty=0.0, robot_uncertainty=0.0)
    strict = SsmConfig(intrusion=0.2, camera_period=0.1)
    mon = SsmMonitor(L, np.full(3, 10.0), np.full(3, 500.0), loose)
    first = mon.update(jac, qd, np.zeros(3), qn, d, dirs)
    mon.config = strict
    second = mon.update(jac, qd, np.zeros(3), qn, d, dirs)
    fresh = SsmMonitor(L, np.full(3, 10.0), np.full(3, 500.0), strict).update(jac, qd, np.zeros(3), qn, d, dirs)
    np.testing.assert_array_equal(second.s_p, fresh.s_p)
    assert second.reaction_time == fresh.reaction_time == reaction_time(strict)
    assert np.all(second.s_p[:2] > first.s_p[:2] + 0.19)  # the 0.2 m intrusion distance is in
