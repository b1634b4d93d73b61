"""Avoidance controller: body constraints (eqs. 12-14), end-effector repulsion (eqs. 10-11), the 1 kHz
cycle and its safe stop."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control.body import body_velocity_bounds, risk  # noqa: E402
from depthguard.control.cycle import (  # noqa: E402
    AvoidanceController,
    ControllerConfig,
    CycleInput,
    CycleStatus,
)
from depthguard.control.endeffector import dls_damping, dls_inverse, repulsive_velocity  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402

Q0 = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
RHO, ALPHA = 0.4, 6.0


@pytest.fixture(scope="module")
def points() -> ControlPointSet:
    return ControlPointSet.build(load_lwr4(), "ral-9")


def _approach_speed_bound(J: np.ndarray, n: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Largest speed towards the obstacle (along -n) that any joint velocity in [lo, hi] can give."""
    g = -(n @ J)  # approach speed per unit joint velocity
    return float(np.sum(np.maximum(g * lo, g * hi)))


def test_risk_profile_matches_the_papers_reading() -> None:
    assert risk(0.0, RHO, ALPHA) == pytest.approx(1 / (1 + np.exp(-ALPHA)))
    assert risk(RHO / 2, RHO, ALPHA) == pytest.approx(0.5)
    assert risk(RHO, RHO, ALPHA) == pytest.approx(1 / (1 + np.exp(ALPHA)))
    assert risk(np.inf, RHO, ALPHA) == 0.0


def test_body_bounds_slow_motion_towards_the_obstacle_and_stop_it_at_contact(points) -> None:
    st = points.evaluate(Q0)
    k = st.names.index("lwr_link_4/0")  # forearm point
    J = st.jacobians[k]
    v_max = points.model.v_max
    rng = np.random.default_rng(0)
    for _ in range(5):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        speeds, away = [], []
        for D in [np.inf, 0.5, 0.4, 0.3, 0.2, 0.1, 0.05, 0.01, 0.0]:
            dist = np.full(st.centres.shape[0], np.inf)
            dirs = np.zeros((len(dist), 3))
            dist[k], dirs[k] = D, n
            lo, hi = body_velocity_bounds(st.jacobians, dist, dirs, v_max, RHO, ALPHA)
            assert np.all(lo <= 0) and np.all(hi >= 0) and np.all(lo >= -v_max) and np.all(hi <= v_max)
            speeds.append(_approach_speed_bound(J, n, lo, hi))
            away.append(_approach_speed_bound(J, -n, lo, hi))
        speeds = np.array(speeds)
        assert np.all(np.diff(speeds) <= 1e-12)  # slower as the obstacle comes closer
        assert speeds[0] == pytest.approx(speeds[1])  # nothing within rho: no restriction
        assert speeds[-2] < 0.05 * speeds[0]
        assert speeds[-1] == 0.0  # contact: no motion towards the obstacle at all
        assert away[-1] == pytest.approx(away[0])  # moving away is never restricted


def test_body_bounds_take_the_most_restrictive_point(points) -> None:
    st = points.evaluate(Q0)
    N = st.centres.shape[0]
    v_max = points.model.v_max
    dirs = np.tile([1.0, 0.0, 0.0], (N, 1))
    d1 = np.full(N, np.inf)
    d1[3] = 0.1
    d2 = np.full(N, np.inf)
    d2[5] = 0.05
    both = np.minimum(d1, d2)
    lo1, hi1 = body_velocity_bounds(st.jacobians, d1, dirs, v_max, RHO, ALPHA)
    lo2, hi2 = body_velocity_bounds(st.jacobians, d2, dirs, v_max, RHO, ALPHA)
    lo, hi = body_velocity_bounds(st.jacobians, both, dirs, v_max, RHO, ALPHA)
    np.testing.assert_allclose(lo, np.maximum(lo1, lo2))
    np.testing.assert_allclose(hi, np.minimum(hi1, hi2))


def _distances(centres: np.ndarray, radii: np.ndarray, obstacle: np.ndarray, r_obs: float):
    diff = centres - obstacle
    norm = np.linalg.norm(diff, axis=1)
    return norm - radii - r_obs, diff / norm[:, None]


def _run(points, xdot_d, obstacle=None, r_obs=0.05, steps=3000, cfg=None, ee_free=True):
    ctrl = AvoidanceController(points, cfg or ControllerConfig())
    q, qd, t = Q0.copy(), np.zeros(7), 0.0
    log = []
    for _ in range(steps):
        st = points.evaluate(q)
        N = len(st.radii)
        if obstacle is None:
            dist, dirs = np.full(N, np.inf), np.zeros((N, 3))
        else:
            dist, dirs = _distances(st.centres, st.radii, obstacle, r_obs)
            if ee_free:
                dist[0] = np.inf
        out = ctrl.step(CycleInput(t, q, qd, t, xdot_d, dist, dirs, t))
        log.append((t, q.copy(), st.centres.copy(), dist.copy(), out))
        q, qd, t = out.q_cmd, out.qdot_cmd, t + 0.001
    return log


def test_free_motion_tracks_the_end_effector_velocity(points) -> None:
    xd = np.array([0.1, 0.05, -0.05])
    log = _run(points, xd, steps=1500)
    _, q, c, _, out = log[-1]
    assert out.status == CycleStatus.OK and out.scale == 1.0
    J = points.evaluate(q).jacobians[0]
    np.testing.assert_allclose(J @ out.qdot_cmd, xd, atol=2e-3)
    ee = np.array([e[2][0] for e in log])
    np.testing.assert_allclose((ee[-1] - ee[-501]) / 0.5, xd, atol=3e-3)


def _obstacle_on_path(points, xd, clearance):
    """A 5 cm ball on the free path of the body point that moves most, ``clearance`` beyond its sphere."""
    free = _run(points, xd, steps=1500)
    body = [i for i, nm in enumerate(points.names) if nm != "ee"]
    c0, c1 = free[0][2], free[-1][2]
    k = body[int(np.argmax(np.linalg.norm(c1[body] - c0[body], axis=1)))]
    move = c1[k] - c0[k]
    return c0[k] + move / np.linalg.norm(move) * (points.radii[k] + 0.05 + clearance), body


@pytest.mark.slow
def test_closed_loop_motion_towards_an_obstacle_slows_as_it_comes_closer(points) -> None:
    xd = np.array([0.0, 0.0, -0.15])  # pushes the arm down: the wrist sweeps towards the obstacle
    obstacle, body = _obstacle_on_path(points, xd, 0.15)
    log = _run(points, xd, obstacle=obstacle, steps=3000)
    dmin = np.array([np.min(e[3][body]) for e in log])
    assert dmin.min() > 0.0  # never touches within 3 s
    assert dmin.min() < 0.04  # it did get close: the constraint was active
    speed = -np.diff(dmin) / 0.001  # approach speed
    peak = speed.max()
    for d in (0.1, 0.06, 0.03):  # slower and slower as the obstacle comes closer
        assert speed[dmin[1:] < d].max() < peak
    assert speed[dmin[1:] < 0.03].max() < 0.1 * peak
    assert any(e[4].status == CycleStatus.SCALED for e in log)
    scales = np.array([e[4].scale for e in log])
    assert scales[-1] < 0.1


def test_closed_loop_body_point_stops_at_contact(points) -> None:
    xd = np.array([0.0, 0.0, -0.15])
    obstacle, body = _obstacle_on_path(points, xd, 0.003)  # starts 3 mm from contact
    log = _run(points, xd, obstacle=obstacle, steps=2000)
    dmin = np.array([np.min(e[3][body]) for e in log])
    assert dmin[0] < 0.004  # (a neighbouring sphere may already touch it: then D < 0 from the start)
    assert dmin.min() > min(dmin[0], 0.0) - 1e-4  # stops at contact, does not push through
    assert np.all(np.abs(log[-1][4].qdot_cmd) < 0.05)


def test_end_effector_is_pushed_away_from_an_obstacle(points) -> None:
    st = points.evaluate(Q0)
    obstacle = st.centres[0] + np.array([0.0, 0.0, 0.25])  # above the end effector
    log = _run(points, np.zeros(3), obstacle=obstacle, steps=400, ee_free=False)
    ee = np.array([e[2][0] for e in log])
    assert ee[-1, 2] < ee[0, 2] - 0.01  # moved down, away from it
    v_rep = repulsive_velocity(0.0, np.array([0.0, 0.0, -1.0]), 2.0, RHO, ALPHA)
    assert v_rep[2] < -1.9 and repulsive_velocity(np.inf, np.ones(3), 2.0, RHO, ALPHA).tolist() == [0, 0, 0]


def test_damped_least_squares_only_near_singularities(points) -> None:
    J = points.evaluate(Q0).jacobians[0]
    assert dls_damping(J) == 0.0
    np.testing.assert_allclose(dls_inverse(J, 0.0), np.linalg.pinv(J))
    Js = points.evaluate(np.zeros(7)).jacobians[0]  # arm straight up: singular in z
    lam = dls_damping(Js)
    assert lam > 0.0
    assert np.all(np.isfinite(dls_inverse(Js, lam)))


def _stop_run(points, make_input, steps=600):
    ctrl = AvoidanceController(points)
    q, qd, t = Q0.copy(), np.zeros(7), 0.0
    N = points.n_points
    free = (np.full(N, np.inf), np.zeros((N, 3)))
    for _ in range(500):  # get moving
        out = ctrl.step(CycleInput(t, q, qd, t, np.array([0.2, 0.0, 0.0]), *free, t))
        q, qd, t = out.q_cmd, out.qdot_cmd, t + 0.001
    assert np.linalg.norm(out.qdot_cmd) > 0.1
    outs = []
    for _ in range(steps):
        out = ctrl.step(make_input(t, q, qd, free))
        outs.append(out)
        q, qd, t = out.q_cmd, out.qdot_cmd, t + 0.001
    return ctrl, outs


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("stale_distances", CycleStatus.STOP_STALE_DISTANCES),
        ("missing_distances", CycleStatus.STOP_STALE_DISTANCES),
        ("nan_distances", CycleStatus.STOP_INVALID_INPUT),
        ("stale_joints", CycleStatus.STOP_STALE_JOINTS),
        ("nan_joints", CycleStatus.STOP_INVALID_INPUT),
    ],
)
def test_safe_stop_when_data_goes_stale(points, case: str, expected: CycleStatus) -> None:
    xd = np.array([0.2, 0.0, 0.0])
    t_frozen = {}

    def make(t, q, qd, free):
        t_frozen.setdefault("t", t)
        t0 = t_frozen["t"] - 0.2  # 200 ms old
        dist, dirs = free
        if case == "stale_distances":
            return CycleInput(t, q, qd, t, xd, dist, dirs, t0)
        if case == "missing_distances":
            return CycleInput(t, q, qd, t, xd, None, None, t)
        if case == "nan_distances":
            return CycleInput(t, q, qd, t, xd, np.full_like(dist, np.nan), dirs, t)
        if case == "stale_joints":
            return CycleInput(t, q, qd, t0, xd, dist, dirs, t)
        return CycleInput(t, np.full(7, np.nan), qd, t, xd, dist, dirs, t)

    ctrl, outs = _stop_run(points, make)
    assert all(o.status == expected for o in outs)
    v = np.array([o.qdot_cmd for o in outs])
    a = np.array([o.qddot_cmd for o in outs])
    assert np.all(np.abs(v[-1]) < 1e-9)  # stopped
    assert np.all(np.abs(a) <= 10.0 + 1e-9)
    assert np.all(np.abs(np.diff(a, axis=0)) / 0.001 <= 500.0 * (1 + 1e-6))  # jerk-limited
    speed = np.linalg.norm(v, axis=1)
    assert speed[0] > 0.05  # no velocity jump at the trigger: it brakes


def test_fresh_data_resumes_after_a_stop_once_valid_for_resume_time(points) -> None:
    ctrl = AvoidanceController(points)  # resume_time 0.1 s
    N = points.n_points
    dist, dirs = np.full(N, np.inf), np.zeros((N, 3))
    out = ctrl.step(CycleInput(1.0, Q0, np.zeros(7), 1.0, np.zeros(3), dist, dirs, 0.0))
    assert out.status == CycleStatus.STOP_STALE_DISTANCES
    statuses = []
    for k in range(1, 102):
        t = 1.0 + k * 0.001
        statuses.append(ctrl.step(CycleInput(t, Q0, np.zeros(7), t, np.zeros(3), dist, dirs, t)).status)
    assert statuses[:100] == [CycleStatus.STOP_RESUME_WAIT] * 100
    assert statuses[100] == CycleStatus.OK


@pytest.mark.slow
def test_joint_position_limits_hold_when_the_task_pulls_beyond_reach(points) -> None:
    model = points.model
    for xd in (np.array([-0.4, 0.0, 0.0]), np.array([0.0, 0.4, -0.3])):
        log = _run(points, xd, steps=5000)
        qs = np.array([e[1] for e in log])
        assert np.all(qs >= model.q_min) and np.all(qs <= model.q_max)
        v = np.array([e[4].qdot_cmd for e in log])
        assert np.all(np.abs(v) <= model.v_max + 1e-9)


def test_body_bounds_reject_a_non_finite_direction_with_a_finite_distance(points) -> None:
    st = points.evaluate(Q0)
    N = st.centres.shape[0]
    dist, dirs = np.full(N, np.inf), np.zeros((N, 3))
    dist[3], dirs[3] = 0.1, np.nan  # used to impose no bound at all, silently
    with pytest.raises(ValueError, match="directions must be finite"):
        body_velocity_bounds(st.jacobians, dist, dirs, points.model.v_max, RHO, ALPHA)
    dist[3] = np.inf  # nothing within rho: the direction does not matter
    lo, hi = body_velocity_bounds(st.jacobians, dist, dirs, points.model.v_max, RHO, ALPHA)
    np.testing.assert_array_equal(hi, points.model.v_max)
