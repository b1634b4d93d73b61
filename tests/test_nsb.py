"""Protective buffer (eqs. 5.1-5.2), its closed-form gradient (5.6-5.7) against finite differences, sensor
Jacobians against finite differences, the weighting functions (5.10-5.12) and the NSB combination (5.8)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.control.nsb import NSBConfig, NSBController, nsb_velocity, weight, weighted_pinv
from depthguard.robot.sensor_kinematics import SensorArray
from depthguard.robot.youbot import YOUBOT_Q0, YOUBOT_SENSORS, load_youbot
from depthguard.sensors.buffer import energy_gradient, spring_energy, total_energy


@pytest.fixture(scope="module")
def youbot():
    return load_youbot()


def test_spring_energy_eq_5_1():
    d = np.array([0.1, 0.3, 0.5, np.inf, np.nan])
    e = spring_energy(d, 0.3)
    assert e == pytest.approx([0.5 * 0.2**2, 0.0, 0.0, 0.0, 0.5 * 0.3**2])  # NaN -> obstacle at the sensor
    assert total_energy(d, 0.3) == pytest.approx(e.sum())


def _obstacle_distances(arr, q, obstacles):
    st_ = arr.evaluate(q)
    diff = obstacles - st_.positions
    d = np.linalg.norm(diff, axis=1)
    return d, diff / d[:, None], st_


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_energy_gradient_matches_finite_differences(youbot, seed):
    """sigma(q) with fixed obstacle points p_ok; eqs. 5.6-5.7 against central differences."""
    rng = np.random.default_rng(seed)
    arr = SensorArray(youbot, YOUBOT_SENSORS)
    q = YOUBOT_Q0 + rng.uniform(-0.4, 0.4, 8)
    st0 = arr.evaluate(q)
    # an obstacle point in front of every sensor, compressed springs of different lengths
    obst = st0.positions + st0.axes * rng.uniform(0.05, 0.25, (10, 1))
    rest = 0.3
    d, v, st_ = _obstacle_distances(arr, q, obst)
    g = energy_gradient(d, rest, v, st_.jacobians)
    h = 1e-6
    fd = np.zeros(8)
    for i in range(8):
        e = np.zeros(8)
        e[i] = h
        fd[i] = (
            total_energy(_obstacle_distances(arr, q + e, obst)[0], rest)
            - total_energy(_obstacle_distances(arr, q - e, obst)[0], rest)
        ) / (2 * h)
    assert np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(g, fd, atol=1e-7, rtol=1e-5)


def test_sensor_jacobians_match_finite_differences(youbot):
    arr = SensorArray(youbot, YOUBOT_SENSORS)
    q = YOUBOT_Q0 + 0.3
    st0 = arr.evaluate(q)
    h = 1e-6
    for i in range(8):
        e = np.zeros(8)
        e[i] = h
        fd = (arr.evaluate(q + e).positions - arr.evaluate(q - e).positions) / (2 * h)
        np.testing.assert_allclose(st0.jacobians[:, :, i], fd, atol=1e-7)
        fde = (arr.evaluate(q + e).ee_position - arr.evaluate(q - e).ee_position) / (2 * h)
        np.testing.assert_allclose(st0.ee_jacobian[:, i], fde, atol=1e-7)
    # base sensors do not move with the arm joints
    assert np.all(st0.jacobians[[0, 1, 2, 3, 7, 8]][:, :, 3:] == 0)


def test_weight_functions():
    f, K, dl = 0.25, 40.0, 0.1
    assert weight(0.2, "switch", f) == 1.0 and weight(0.3, "switch", f) == 0.0
    assert weight(f, "arctan", f, K) == pytest.approx(0.5)
    assert weight(f, "linear", f, delta=dl) == pytest.approx(0.5)
    assert weight(f - dl / 2, "linear", f, delta=dl) == 1.0 and weight(f + dl / 2, "linear", f, delta=dl) == 0.0
    assert weight(np.inf, "arctan") == 0.0 and weight(np.nan, "switch") == 1.0
    ds = np.linspace(0, 1, 201)
    for kind in ("switch", "arctan", "linear"):
        lam = np.array([weight(x, kind, f, K, dl) for x in ds])
        assert np.all((lam >= 0) & (lam <= 1)) and np.all(np.diff(lam) <= 1e-12)  # monotone non-increasing
    with pytest.raises(ValueError, match="lambda"):
        weight(0.1, "tanh")


def test_weighted_pinv_favours_heavy_weights():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(3, 8))
    w = np.array([0.1, 0.1, 0.1, 1, 1, 1, 1, 1.0])
    Jw = weighted_pinv(J, w, 0.0)
    np.testing.assert_allclose(J @ Jw, np.eye(3), atol=1e-10)
    xd = rng.normal(size=3)
    qw, q1 = Jw @ xd, np.linalg.pinv(J) @ xd
    assert np.linalg.norm(qw[:3]) / np.linalg.norm(qw) < np.linalg.norm(q1[:3]) / np.linalg.norm(q1)
    # it minimises the W^-1-weighted norm among exact solutions
    N = np.eye(8) - np.linalg.pinv(J) @ J
    for _ in range(20):
        alt = qw + N @ rng.normal(size=8)
        assert alt @ (alt / w) >= qw @ (qw / w) - 1e-9


@settings(max_examples=50, deadline=None)
@given(lam=st.floats(0, 1), seed=st.integers(0, 10_000))
def test_nsb_combination_properties(lam, seed):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(3, 8))
    Jo = rng.normal(size=8)
    err, xd = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.1
    w = np.ones(8)
    t = nsb_velocity(J, err, xd, 0.02, Jo, lam, w, 5.0, 10.0, 0.0)
    np.testing.assert_allclose(
        t.qdot, (1 - lam) * t.qdot_g + lam * (t.qdot_o + t.qdot_g - Jo * (Jo @ t.qdot_g) / (Jo @ Jo))
    )
    # with lambda = 1 the energy task is met exactly: sigma_dot = J_o qdot = -gamma_o sigma
    t1 = nsb_velocity(J, err, xd, 0.02, Jo, 1.0, w, 5.0, 10.0, 0.0)
    assert Jo @ t1.qdot == pytest.approx(-10.0 * 0.02, rel=1e-9, abs=1e-12)
    # no energy: the end-effector task alone, whatever lambda
    t0 = nsb_velocity(J, err, xd, 0.0, np.zeros(8), lam, w, 5.0, 10.0, 0.0)
    np.testing.assert_allclose(J @ t0.qdot, xd + 5.0 * err, atol=1e-9)


def test_controller_moves_away_and_validates(youbot):
    ctrl = NSBController(youbot, YOUBOT_SENSORS, NSBConfig(lambda_kind="switch"))
    st0 = ctrl.sensors.evaluate(YOUBOT_Q0)
    d = np.full(10, np.inf)
    d[1] = 0.1  # something 10 cm in front of the base (sensor 2 looks along +x)
    out = ctrl.step(YOUBOT_Q0, st0.ee_position, np.zeros(3), d)
    assert out.sigma == pytest.approx(0.5 * 0.2**2) and out.lam == 1.0
    # the energy decreases: the sensor backs off along its axis
    assert st0.axes[1] @ (st0.jacobians[1] @ out.qdot) < 0
    assert out.scale <= 1.0 and np.all(np.abs(out.qdot) <= np.asarray(ctrl.cfg.qdot_max) + 1e-12)
    with pytest.raises(ValueError, match="distances"):
        ctrl.step(YOUBOT_Q0, st0.ee_position, np.zeros(3), np.ones(9))
    with pytest.raises(ValueError, match="dt"):
        NSBConfig(dt=0.1, gamma_g=30.0)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["switch", "arctan", "linear"]))
def test_compiled_cycle_equals_numpy_reference(youbot, seed, kind):
    rng = np.random.default_rng(seed)
    ctrl = NSBController(youbot, YOUBOT_SENSORS, NSBConfig(lambda_kind=kind, rest=0.25))
    q = YOUBOT_Q0 + rng.uniform(-0.3, 0.3, 8)
    d = np.where(rng.random(10) < 0.5, rng.uniform(0.0, 0.4, 10), np.inf)
    if rng.random() < 0.2:
        d[rng.integers(10)] = np.nan
    xd, vd = rng.normal(size=3) * 0.3 + [0.5, 0, 0.4], rng.normal(size=3) * 0.2
    a, b = ctrl.step(q, xd, vd, d), ctrl.step_reference(q, xd, vd, d)
    np.testing.assert_allclose(a.qdot, b.qdot, rtol=1e-7, atol=1e-9)
    assert a.sigma == pytest.approx(b.sigma) and a.lam == b.lam and a.scale == pytest.approx(b.scale)
    np.testing.assert_allclose(a.J_o, b.J_o, atol=1e-12)


def test_bad_inputs_name_the_field(youbot):
    with pytest.raises(ValueError, match="rest"):
        NSBController(youbot, YOUBOT_SENSORS, NSBConfig(rest=(0.2, 0.3)))
    with pytest.raises(ValueError, match="rest"):
        NSBController(youbot, YOUBOT_SENSORS, NSBConfig(rest=-0.1))
    with pytest.raises(ValueError, match="jacobians"):
        energy_gradient(np.ones(3), 0.3, np.ones((3, 3)), np.ones((2, 3, 8)))
    with pytest.raises(ValueError, match="lambda_kind"):
        NSBConfig(lambda_kind="sigmoid")


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    special=st.lists(st.sampled_from([np.nan, np.inf, -0.1, 0.0, 1e-9, 5.0]), min_size=10, max_size=10),
)
def test_cycle_output_is_finite_and_within_limits(youbot, seed, special):
    """Whatever the readings (NaN, inf, negative, zero) and the configuration (stretched arm included),
    the command is finite and within the joint velocity limits."""
    rng = np.random.default_rng(seed)
    ctrl = NSBController(youbot, YOUBOT_SENSORS, NSBConfig(lambda_kind=["switch", "arctan", "linear"][seed % 3]))
    q = YOUBOT_Q0 + rng.uniform(-1.5, 1.5, 8)
    if seed % 4 == 0:
        q[4:7] = 0.0  # arm straight up: singular for horizontal end-effector motion
    out = ctrl.step(q, rng.normal(size=3) * 2, rng.normal(size=3), np.array(special, float))
    assert np.all(np.isfinite(out.qdot)) and np.isfinite(out.sigma)
    assert np.all(np.abs(out.qdot) <= np.asarray(ctrl.cfg.qdot_max) * (1 + 1e-12))
