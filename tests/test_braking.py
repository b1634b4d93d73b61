"""Braking model of the SSM monitor against Ruckig's own stop trajectories and the robot's kinematics."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.control.braking import chain_lengths, joint_stopping, point_stopping_distance

ruckig = pytest.importorskip("ruckig")
pytest.importorskip("pinocchio")


def _ruckig_stop(v, a, a_max, j_max):
    """Ruckig's velocity-mode stop (target 0), as the controller runs it; returns duration and trajectory."""
    n = len(v)
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.synchronization = ruckig.Synchronization.No
    inp.current_position = [0.0] * n
    inp.current_velocity = list(v)
    inp.current_acceleration = list(a)
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = [1e9] * n
    inp.max_acceleration = list(a_max)
    inp.max_jerk = list(j_max)
    res = otg.calculate(inp, traj)
    assert int(res.value if hasattr(res, "value") else res) >= 0
    return traj


def _path(traj, n_samples=400):
    ts = np.linspace(0.0, traj.duration, n_samples)
    return ts, np.array([traj.at_time(t)[0] for t in ts])


@settings(max_examples=200, deadline=None)
@given(
    v=st.floats(-3.0, 3.0),
    a=st.floats(-10.0, 10.0),
    a_max=st.floats(1.0, 20.0),
    j_max=st.floats(50.0, 2000.0),
)
def test_joint_stop_bounds_ruckig(v, a, a_max, j_max):
    """Travel and time never below Ruckig's stop (and equal to it), braking, overshooting or speeding up."""
    a = float(np.clip(a, -a_max, a_max))
    traj = _ruckig_stop([v], [a], [a_max], [j_max])
    ts, p = _path(traj)
    travelled = float(np.sum(np.abs(np.diff(p[:, 0]))))  # path length, sign changes included
    stop = joint_stopping(np.array([v]), np.array([a]), a_max, j_max)
    assert stop.travel[0] >= travelled - 1e-9
    assert stop.time[0] >= traj.duration - 1e-9
    # and exact: Ruckig's time, and its path length up to the sampling of the reference
    assert stop.time[0] == pytest.approx(traj.duration, rel=1e-6, abs=1e-9)
    assert stop.travel[0] <= travelled + 1e-5 + 1e-3 * travelled
    if a * v >= 0:  # monotone: the final position is the path length
        assert stop.travel[0] == pytest.approx(abs(p[-1, 0]), rel=1e-6, abs=1e-9)


def test_joint_stop_closed_forms():
    """Hand-computed: trapezoid (v=2, A=10, J=500: T = 0.2 + 0.02, d = v T / 2) and triangle (v=0.05)."""
    s = joint_stopping(np.array([2.0, -0.05]), np.zeros(2), 10.0, 500.0)
    assert s.time[0] == pytest.approx(0.22)
    assert s.travel[0] == pytest.approx(2.0 * 0.22 / 2)
    assert s.time[1] == pytest.approx(2 * np.sqrt(0.05 / 500))
    assert s.travel[1] == pytest.approx(0.05 * np.sqrt(0.05 / 500))


def _bound_and_swept_path(model, cps, seed: int, q_lo: np.ndarray, q_hi: np.ndarray):
    """A random state (q within 0.8 of [q_lo, q_hi], random velocity and acceleration): the monitor's bound of
    each control point's path during Ruckig's stop, and that path's length (forward kinematics along it)."""
    rng = np.random.default_rng(seed)
    n = model.n_dof
    q = rng.uniform(q_lo * 0.8, q_hi * 0.8)
    v = rng.uniform(-1.5, 1.5, n)
    a = rng.uniform(-8, 8, n)
    a_max, j_max = np.full(n, 10.0), np.full(n, 500.0)
    _, dq = _path(_ruckig_stop(v, a, a_max, j_max))
    paths = np.array([cps.evaluate(q + d).centres for d in dq])  # (T, N, 3)
    swept = np.sum(np.linalg.norm(np.diff(paths, axis=0), axis=2), axis=0)  # (N,)
    st_ = joint_stopping(v, a, a_max, j_max)
    L = chain_lengths(model, cps.joints, cps.offsets)
    return point_stopping_distance(cps.evaluate(q).jacobians, st_.travel, L), swept


@pytest.mark.parametrize("seed", range(6))
def test_point_stopping_distance_bounds_the_swept_path(seed):
    """Random states of the shipped arm: the bound is never below the control points' path length along
    Ruckig's stop (forward kinematics at 400 samples), and not absurdly larger."""
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    model = load_lwr4()
    bound, swept = _bound_and_swept_path(model, ControlPointSet.build(model, "ral-9"), seed, model.q_min, model.q_max)
    assert np.all(bound >= swept - 1e-9), (bound, swept)
    assert np.all(bound <= 3.0 * swept + 0.02)


@pytest.mark.parametrize("seed", range(4))
def test_point_stopping_distance_bounds_the_swept_path_with_a_base_on_rails(seed):
    """The youBot (base x and y prismatic, then revolute joints): the points near the base move by the
    base's whole travel, which the bound missed when it took their chain length (< 1 m) for the prismatic
    joints' lever (16 cm under the swept path before). Same check as above, with the monitor's own form of
    the bound (no ``prismatic`` flags: :func:`chain_lengths` carries them)."""
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.youbot import load_youbot

    model = load_youbot()
    lo, hi = np.maximum(model.q_min, -3.0), np.minimum(model.q_max, 3.0)
    bound, swept = _bound_and_swept_path(model, ControlPointSet.build(model, "auto"), seed, lo, hi)
    assert np.all(bound >= swept - 1e-9), (bound, swept)
    assert np.all(bound <= 4.0 * swept + 0.02)  # (looser than the arm's: the base's yaw has long levers)


def test_chain_lengths_bound_lever_arms():
    """Every Jacobian column norm (distance from the joint axis) stays below the chain length, anywhere."""
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    model = load_lwr4()
    cps = ControlPointSet.build(model, "ral-9")
    L = chain_lengths(model, cps.joints, cps.offsets)
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.uniform(model.q_min, model.q_max)
        lever = np.linalg.norm(cps.evaluate(q).jacobians, axis=1)
        assert np.all(lever <= L + 1e-12)
        assert np.all((lever > 1e-12) <= (L > 0))
