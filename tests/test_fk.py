"""The compiled forward kinematics (depthguard.robot.fk) against pinocchio, the independent reference.

Joint poses must equal ``data.oMi`` and the joint Jacobian ``data.J`` after ``computeJointJacobians``
(WORLD convention) on every shipped robot and on random trees of unaligned revolute and prismatic joints;
models with other joints are refused (the callers then use pinocchio), and the control points, sensor
kinematics and contact Jacobians built on it agree with the pinocchio path and with finite differences.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from depthguard.robot.control_points import ControlPointSet
from depthguard.robot.fk import ChainKinematics
from depthguard.robot.robots import load_robot


def _pin_reference(model: pin.Model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    return np.array([M.homogeneous for M in data.oMi]), np.array(data.J)


@pytest.mark.parametrize("name", ["lwr4", "panda", "ur5", "xarm7"])
def test_shipped_robots_match_pinocchio(name: str) -> None:
    robot = load_robot(name)
    chain = ChainKinematics.from_model(robot.model)
    assert chain is not None
    rng = np.random.default_rng(3)
    for _ in range(25):
        q = rng.uniform(robot.q_min, robot.q_max)
        H, Jw = chain.compute(q)
        H_ref, J_ref = _pin_reference(robot.model, q)
        np.testing.assert_allclose(H, H_ref, atol=1e-12)
        np.testing.assert_allclose(Jw, J_ref, atol=1e-12)


def _random_tree(rng: np.random.Generator, n: int) -> pin.Model:
    """A tree of ``n`` one-coordinate joints, unaligned axes, random placements and parents."""
    model = pin.Model()
    for j in range(1, n + 1):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        joint = (
            pin.JointModelRevoluteUnaligned(*axis) if rng.random() < 0.6 else pin.JointModelPrismaticUnaligned(*axis)
        )
        R = pin.exp3(rng.normal(size=3))
        placement = pin.SE3(R, rng.uniform(-0.5, 0.5, 3))
        parent = int(rng.integers(0, j))
        jid = model.addJoint(parent, joint, placement, f"j{j}")
        model.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
    return model


@pytest.mark.parametrize("seed", range(6))
def test_random_trees_match_pinocchio(seed: int) -> None:
    rng = np.random.default_rng(seed)
    model = _random_tree(rng, int(rng.integers(1, 10)))
    chain = ChainKinematics.from_model(model)
    assert chain is not None
    for _ in range(10):
        q = rng.uniform(-4.0, 4.0, model.nq)
        H, Jw = chain.compute(q)
        H_ref, J_ref = _pin_reference(model, q)
        np.testing.assert_allclose(H, H_ref, atol=1e-12)
        np.testing.assert_allclose(Jw, J_ref, atol=1e-12)


@pytest.mark.parametrize(
    "joint",
    [pin.JointModelSpherical(), pin.JointModelFreeFlyer(), pin.JointModelHelicalUnaligned(np.array([0, 0, 1.0]), 0.1)],
)
def test_other_joints_are_refused(joint) -> None:
    model = pin.Model()
    model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "a")
    model.addJoint(1, joint, pin.SE3.Identity(), "b")
    assert ChainKinematics.from_model(model) is None


def test_control_points_compiled_path_equals_the_pinocchio_path() -> None:
    robot = load_robot("panda")
    points = ControlPointSet.build(robot, "auto")
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(robot.q_min, robot.q_max)
        fast = points.evaluate(q)
        robot.update(q)
        slow = points.evaluate(q, updated=True)
        np.testing.assert_allclose(fast.centres, slow.centres, atol=1e-12)
        np.testing.assert_allclose(fast.jacobians, slow.jacobians, atol=1e-12)


def test_fallback_without_compiled_chain_gives_the_same_numbers() -> None:
    robot = load_robot("ur5")
    q = np.linspace(-1.0, 1.0, robot.n_dof)
    H, Jw = robot.joint_kinematics(q)
    robot.__dict__["_chain_kinematics"] = None  # as for a model with an unsupported joint
    H2, J2 = robot.joint_kinematics(q)
    np.testing.assert_allclose(H, H2, atol=1e-12)
    np.testing.assert_allclose(Jw, J2, atol=1e-12)


def test_control_point_jacobians_match_finite_differences() -> None:
    robot = load_robot("xarm7")
    points = ControlPointSet.build(robot, "auto")
    q = np.random.default_rng(5).uniform(robot.q_min, robot.q_max)
    J = points.evaluate(q).jacobians
    h = 1e-6
    for i in range(robot.n_dof):
        dq = np.zeros(robot.n_dof)
        dq[i] = h
        fd = (points.evaluate(q + dq).centres - points.evaluate(q - dq).centres) / (2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-7)
