"""The monitor's stopping distance S_s against the controller's own stop.

From random states (random joint positions, measured velocities and a random task run for a random number
of cycles, so the stop starts with non-zero accelerations too), the distances are withheld and the
controller brakes with its jerk-limited stop (``STOP_STALE_DISTANCES``). The path of every control point
during that stop (the controller's own commands, forward kinematics each cycle) must never exceed the
monitor's S_s for the state the stop started from, and the stop must end within the monitor's T_s.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control.cycle import AvoidanceController, ControllerConfig, CycleInput, CycleStatus  # noqa: E402
from depthguard.control.ssm import SsmConfig  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402

# every term but S_s zeroed: S_p = S_s (+ 1e-9 T_s), T_r = 0
S_S_ONLY = SsmConfig(
    v_h_near=1e-9, v_h_far=1e-9, near_limit=0.0, v_h_floor=0.0, camera_period=0.0, processing_latency=0.0,
    communication_latency=0.0, control_period=0.0, intrusion=0.0, sensor_uncertainty=0.0, robot_uncertainty=0.0,
)  # fmt: skip


@pytest.fixture(scope="module")
def points() -> ControlPointSet:
    return ControlPointSet.build(load_lwr4(), "ral-9")


def _one_stop(points, rng, a_max, j_max):
    model = points.model
    cfg = ControllerConfig(a_max=a_max, j_max=j_max, avoidance="ssm", ssm=S_S_ONLY)
    ctrl = AvoidanceController(points, cfg)
    N = points.n_points
    lo, hi = np.asarray(model.q_min) + 0.4, np.asarray(model.q_max) - 0.4
    q = rng.uniform(lo, hi)
    qd = rng.uniform(-1.0, 1.0, 7) * np.asarray(model.v_max) * rng.uniform(0.1, 0.8)
    xdot = rng.normal(size=3) * rng.uniform(0.0, 0.4)
    free = (np.full(N, np.inf), np.zeros((N, 3)))
    t, k = 0.0, 0
    out = None
    for k in range(int(rng.integers(1, 60))):  # move: the generator heads for the task's velocity
        t = k * cfg.dt
        out = ctrl.step(CycleInput(t, q, qd, t, xdot, *free, t))
        q, qd = out.q_cmd, out.qdot_cmd
    v0, a0 = out.qdot_cmd.copy(), out.qddot_cmd.copy()
    # the monitor's S_s and T_s for that state (nothing seen, so the scale is 1 and qdot_nominal = 0)
    model.update(q)
    J = points.evaluate(q, updated=True).jacobians
    m = ctrl.monitor.update(J, v0, a0, np.zeros(7), *free)
    s_s = m.s_p
    path = np.zeros(N)
    prev = points.evaluate(q).centres
    t_stop = None
    for i in range(1, 2000):  # distances withheld: the controller's jerk-limited stop
        t = (k + i) * cfg.dt
        out = ctrl.step(CycleInput(t, q, qd, t, xdot, None, None, t))
        assert out.status == CycleStatus.STOP_STALE_DISTANCES
        q, qd = out.q_cmd, out.qdot_cmd
        cur = points.evaluate(q).centres
        path += np.linalg.norm(cur - prev, axis=1)
        prev = cur
        if np.max(np.abs(qd)) < 1e-9:
            t_stop = i * cfg.dt
            break
    return path, s_s, t_stop, m.stop_time, np.abs(v0).max()


@pytest.mark.parametrize("limits", [(10.0, 500.0), (4.0, 150.0)])
def test_monitor_stopping_distance_bounds_the_controllers_stop(points, limits):
    rng = np.random.default_rng(int(limits[0]))
    speeds, ratios = [], []
    for _ in range(12):
        path, s_s, t_stop, T_s, speed = _one_stop(points, rng, *limits)
        speeds.append(speed)
        assert t_stop is not None
        assert np.all(path <= s_s + 1e-6), (path, s_s)
        assert t_stop <= T_s + 2e-3, (t_stop, T_s)
        ratios.append(np.max(path / np.maximum(s_s, 1e-12)))
    assert max(speeds) > 0.5  # the states really moved
    assert max(ratios) > 0.7  # and the bound is not vacuous: close to the real path somewhere


def test_nothing_within_rho_is_taken_as_the_sensing_range(points):
    """+inf means "nothing within rho": with ``sensing_range`` = rho the monitor slows a fast arm whose S_p
    exceeds rho; trusting +inf (the default) lets it run at full speed."""
    from depthguard.control.braking import chain_lengths
    from depthguard.control.ssm import SsmMonitor

    model = points.model
    q = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    model.update(q)
    J = points.evaluate(q, updated=True).jacobians
    L = chain_lengths(model, points.joints, points.offsets)
    N = points.n_points
    qd = np.full(7, 1.0)
    args = (J, np.zeros(7), np.zeros(7), qd, np.full(N, np.inf), np.zeros((N, 3)))  # at rest, asked for qd
    trusting = SsmMonitor(L, 10.0, 500.0, SsmConfig()).update(*args)
    ranged = SsmMonitor(L, 10.0, 500.0, SsmConfig(sensing_range=0.4)).update(*args)
    assert trusting.scale == 1.0
    assert np.max(trusting.s_p) > 0.4  # the case that matters: S_p beyond the query's range
    assert 0.0 < ranged.scale < 1.0 and np.all(ranged.s_p <= 0.4 + 1e-9)
    with pytest.raises(ValueError, match="sensing_range"):
        SsmConfig(sensing_range=0.0)
