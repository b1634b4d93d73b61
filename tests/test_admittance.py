"""Admittance at the contact point (SAPHARI §6.3): the mass-damper-spring, task priority with the end
effector in the null space, the soft/stiff sets."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.control.admittance import (
    SOFT,
    STIFF,
    AdmittanceParams,
    ContactAdmittance,
    admittance_step,
    task_priority_velocity,
)
from depthguard.robot.contact_force import point_jacobian
from depthguard.robot.model import load_lwr4

Q0 = np.array([0.0, -1.1, 0.0, 1.5, 0.0, -0.9, 0.0])


def test_admittance_reaches_the_spring_equilibrium_and_returns():
    F = np.array([0.0, 30.0, 0.0])
    for p in (SOFT, STIFF):
        v, e = np.zeros(3), np.zeros(3)
        for _ in range(4000):  # 20 s at 200 Hz
            v = admittance_step(p, v, e, F, 0.005)
            e = e + v * 0.005
        np.testing.assert_allclose(e, F / p.stiffness, rtol=1e-3)
        for _ in range(4000):
            v = admittance_step(p, v, e, np.zeros(3), 0.005)
            e = e + v * 0.005
        assert np.linalg.norm(e) < 1e-3
    assert SOFT.stiffness < STIFF.stiffness and SOFT.damping < STIFF.damping


def test_admittance_without_spring_moves_at_force_over_damping():
    p = AdmittanceParams(mass=1.0, damping=50.0)
    v = np.zeros(3)
    for _ in range(2000):
        v = admittance_step(p, v, np.zeros(3), np.array([10.0, 0, 0]), 0.005)
    np.testing.assert_allclose(v, [0.2, 0, 0], atol=1e-9)


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="mass"):
        AdmittanceParams(mass=0.0, damping=1.0)


def test_task_priority_primary_exact_secondary_in_null_space():
    rng = np.random.default_rng(2)
    J1, J2 = rng.normal(size=(3, 7)), rng.normal(size=(3, 7))
    v1, v2 = rng.normal(size=3), rng.normal(size=3)
    qd = task_priority_velocity(J1, v1, J2, v2, lam=1e-6)
    np.testing.assert_allclose(J1 @ qd, v1, atol=1e-6)
    np.testing.assert_allclose(J2 @ qd, v2, atol=1e-5)  # 7 DOF: both 3-D tasks fit
    J2c = np.vstack([J1[:2], rng.normal(size=(1, 7))])  # conflicts with task 1 in two rows
    qd = task_priority_velocity(J1, v1, J2c, rng.normal(size=3), lam=1e-6)
    np.testing.assert_allclose(J1 @ qd, v1, atol=1e-6)  # the primary task still wins


def test_contact_admittance_moves_the_contact_point_along_the_force_and_holds_the_end_effector():
    robot = load_lwr4()
    adm = ContactAdmittance(robot, SOFT)
    q = Q0.copy()
    a, b, _ = robot.link_capsules(q)
    k = next(i for i, c in enumerate(robot.capsules) if c.link == "lwr_link_3")
    p0 = 0.5 * (a[k] + b[k]) + np.array([0.0, -0.07, 0.0])
    adm.set_contacts(q, ["lwr_link_3"], [p0])
    ee0 = robot.frame_pose(q)[1]
    F = np.array([0.0, 20.0, 0.0])
    dt = 0.005
    for _ in range(60):
        q = q + adm.step(q, F[None], ee0, dt) * dt
    disp = adm.errors()[0]
    assert disp[1] > 0.02 and abs(disp[0]) < 0.3 * disp[1] and abs(disp[2]) < 0.3 * disp[1]
    assert np.linalg.norm(robot.frame_pose(q)[1] - ee0) < 0.3 * np.linalg.norm(disp)
    # the commanded contact velocity is realised through J_c, as far as J_c reaches (rank 2 on link 3)
    J = point_jacobian(robot, q, "lwr_link_3", adm.errors()[0] + adm.contacts[0].x0)
    qd = adm.step(q, F[None], ee0, dt)
    reach = J @ np.linalg.pinv(J, rcond=1e-3) @ adm.contacts[0].v
    np.testing.assert_allclose(J @ qd, reach, atol=2e-3)


def test_joint_velocity_is_scaled_into_the_limits():
    robot = load_lwr4()
    adm = ContactAdmittance(robot, AdmittanceParams(mass=0.01, damping=0.0))
    q = Q0.copy()
    adm.set_contacts(q, ["lwr_link_6"], [robot.frame_pose(q, "lwr_link_6")[1]])
    qd = adm.step(q, np.array([[0.0, 1e4, 0.0]]), robot.frame_pose(q)[1], 0.005)
    assert np.all(np.abs(qd) <= robot.v_max + 1e-12)
