"""Force estimation F̂ = (J_cᵀ)^# r (SAPHARI §6.1): exactness on observable forces, the unobservable null
space, the stacked two-contact form, damping near singularities, and the point Jacobian."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from depthguard.robot.contact_force import estimate_contact_forces, observable_error, point_jacobian
from depthguard.robot.model import load_lwr4

Q = np.array([0.2, -1.0, 0.3, 1.4, -0.2, -0.8, 0.1])


@pytest.fixture(scope="module")
def robot():
    return load_lwr4()


def _contact(robot, q, link, s=0.5, offset=(0.06, 0.0, 0.0)):
    """A point on ``link``: along its capsule axis at s, offset in the joint frame."""
    k = next(i for i, c in enumerate(robot.capsules) if c.link == link)
    R, p = robot.joint_poses(q)
    j = robot._cap_joint[k]
    local = robot._cap_a[k] + s * (robot._cap_b[k] - robot._cap_a[k]) + np.asarray(offset)
    return R[j] @ local + p[j]


def test_point_jacobian_matches_finite_differences(robot):
    link = "lwr_link_5"
    p = _contact(robot, Q, link)
    R, o = robot.frame_pose(Q, link)
    local = R.T @ (p - o)
    J = point_jacobian(robot, Q, link, p)
    h = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        Rp, op = robot.frame_pose(Q + dq, link)
        Rm, om = robot.frame_pose(Q - dq, link)
        fd = ((Rp @ local + op) - (Rm @ local + om)) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-7)


def test_point_jacobian_compiled_path_equals_the_other_paths_and_checks_q(robot):
    """The one-call compiled path (float64 q) equals the checked path (a list q), the pinocchio buffer path
    (``update=False``), and raises the same errors."""
    p = _contact(robot, Q, "lwr_link_6")
    J = point_jacobian(robot, Q, "lwr_link_6", p)
    np.testing.assert_array_equal(J, point_jacobian(robot, list(Q), "lwr_link_6", list(p)))
    robot.update(Q)
    np.testing.assert_allclose(J, point_jacobian(robot, Q, "lwr_link_6", p, update=False), atol=1e-14)
    for bad, msg in ((np.r_[Q[:6], np.nan], "q must be finite"), (Q[:6], "q must have shape")):
        with pytest.raises(ValueError, match=msg):
            point_jacobian(robot, bad, "lwr_link_6", p)
    with pytest.raises(ValueError, match="point_world"):
        point_jacobian(robot, np.r_[Q[:6], np.nan], "lwr_link_6", p[:2])


@pytest.mark.parametrize("link", ["lwr_link_4", "lwr_link_5", "lwr_link_6"])
def test_single_contact_force_is_recovered_exactly(robot, link):
    p = _contact(robot, Q, link)
    J = point_jacobian(robot, Q, link, p)
    F = np.array([12.0, -7.0, 20.0])
    est = estimate_contact_forces(J, J.T @ F)
    assert est.unobservable.shape[1] == 0 and est.damping == 0.0
    np.testing.assert_allclose(est.forces[0], F, atol=1e-8)


def test_link_1_has_unobservable_force_components_and_the_error_uses_the_projection(robot):
    """A point on link 1 moves only with joint 1: two of three force directions are unobservable."""
    p = _contact(robot, Q, "lwr_link_1", offset=(0.07, 0.0, 0.0))
    J = point_jacobian(robot, Q, "lwr_link_1", p)
    F = np.array([3.0, 10.0, -4.0])
    est = estimate_contact_forces(J, J.T @ F)
    assert est.unobservable.shape == (3, 2)
    np.testing.assert_allclose(J.T @ est.unobservable, 0.0, atol=1e-9)  # null space of J_cᵀ: no torque
    err, frac = observable_error(est, F)
    assert np.linalg.norm(err) < 1e-6 * np.linalg.norm(F)  # the observable part is exact
    assert frac < 1.0
    # the unobservable part is invisible: adding it changes nothing
    F2 = F + 5.0 * est.unobservable[:, 0]
    np.testing.assert_allclose(estimate_contact_forces(J, J.T @ F2).stacked, est.stacked, atol=1e-9)


def test_two_contacts_stacked_form(robot):
    p1, p2 = _contact(robot, Q, "lwr_link_3"), _contact(robot, Q, "lwr_link_6")
    J1, J2 = point_jacobian(robot, Q, "lwr_link_3", p1), point_jacobian(robot, Q, "lwr_link_6", p2)
    F = np.array([0.0, 15.0, -10.0, 5.0, 20.0, 0.0])
    r = J1.T @ F[:3] + J2.T @ F[3:]
    est = estimate_contact_forces([J1, J2], r)
    assert est.forces.shape == (2, 3)
    err, frac = observable_error(est, F)
    assert np.linalg.norm(err) < 1e-6 * np.linalg.norm(F)
    A = np.hstack([J1.T, J2.T])
    np.testing.assert_allclose(A @ est.unobservable, 0.0, atol=1e-8)
    assert 0.0 < frac <= 1.0


def test_damping_bounds_the_estimate_near_a_singular_jacobian():
    J = np.zeros((3, 7))
    J[0, 0], J[1, 1], J[2, 2] = 0.5, 0.4, 1e-5  # nearly singular in z
    r = np.zeros(7)
    r[2] = 0.01  # a little torque noise on the weak direction
    und = np.linalg.pinv(J.T) @ r
    est = estimate_contact_forces(J, r, eps=0.02, lambda_max=0.05)
    assert np.abs(und).max() > 500  # the plain pseudo-inverse explodes
    assert np.abs(est.stacked).max() < 10 and est.damping > 0


@given(
    arrays(float, (3, 7), elements=st.floats(-1, 1)),
    arrays(float, (7,), elements=st.floats(-100, 100)),
)
def test_estimate_is_finite_and_bounded_for_any_jacobian(J, r):
    """Property: finite output, never larger than ‖r‖ / λ_min-ish (damped) for any J, r."""
    est = estimate_contact_forces(J, r, eps=0.02, lambda_max=0.05)
    assert np.all(np.isfinite(est.stacked))
    smax = est.singular_values[0]
    bound = np.linalg.norm(r) / max(min(0.02, smax if smax > 0 else 0.02), 1e-12) * 10
    assert np.linalg.norm(est.stacked) <= bound + 1e-9


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="jacobians"):
        estimate_contact_forces([np.zeros((3, 7)), np.zeros((3, 6))], np.zeros(7))
    with pytest.raises(ValueError, match="r must"):
        estimate_contact_forces(np.zeros((3, 7)), np.zeros(6))
    with pytest.raises(ValueError, match="finite"):
        estimate_contact_forces(np.full((3, 7), np.nan), np.zeros(7))
    with pytest.raises(ValueError, match="finite"):
        estimate_contact_forces([np.eye(3, 7), np.eye(3, 7)], np.array([np.inf] + [0.0] * 6))


@pytest.mark.parametrize(
    ("link", "force"),
    [
        ("lwr_link_3", (0.0, 20.0, -30.0)),
        ("lwr_link_4", (10.0, 15.0, 0.0)),
        ("lwr_link_5", (0.0, -25.0, 10.0)),
        ("lwr_link_6", (5.0, 20.0, 5.0)),
    ],
)
def test_force_estimate_in_simulation_steady_error_and_settling_time(link, force):
    """A known force at a point of a link (MuJoCo ``mj_applyFT``), the residual at 200 Hz, F̂ at the
    known point: steady error (norm and per component) on the observable part, and settling time."""
    pytest.importorskip("mujoco")
    from depthguard.robot.residual import MomentumObserver, RigidBodyDynamics
    from depthguard.sim.contact_cell import ContactCell
    from depthguard.sim.depthcam import kinect_camera

    q0 = np.array([0.0, -1.1, 0.0, 1.5, 0.0, -0.9, 0.0])
    cell = ContactCell([], kinect_camera((-2.8, 0, 1.6), (0.3, 0, 0.4), width=64, height=48), q0)
    obs = MomentumObserver(
        RigidBodyDynamics(cell.robot, np.full(7, cell.armature), cell.damping), 100.0, 0.005, "average"
    )
    obs.update(cell.q(), cell.qd(), np.zeros(7))
    robot = cell.robot
    local = np.array([0.0, -0.065, 0.05])  # on the surface side, in the link frame
    F = np.array(force)
    errs, t = [], []
    for i in range(40):
        Rl, ol = robot.frame_pose(cell.q(), link)
        cell.set_applied_force(link, Rl @ local + ol, F)
        tau = cell.step(np.zeros(7), 5)
        r = obs.update(cell.q(), cell.qd(), tau)
        Rl, ol = robot.frame_pose(cell.q(), link)
        est = estimate_contact_forces(point_jacobian(robot, cell.q(), link, Rl @ local + ol), r)
        err, frac = observable_error(est, F)
        errs.append(err)
        t.append((i + 1) * 0.005)
    errs = np.abs(np.array(errs))
    norm = np.linalg.norm(errs, axis=1) / np.linalg.norm(F)
    assert norm[-1] < 0.02 and np.all(errs[-1] < 0.02 * np.linalg.norm(F))  # steady state, per component
    settle = t[int(np.argmax(norm < 0.05))]
    assert settle <= 0.04  # ≈ 3 time constants (9.8 ms each)
    assert frac > 0.5
