"""Continuous joints (docs/robots.md): loaded as one unbounded angle each, checked against pinocchio's own
continuous joint model (two coordinates, cos and sin) and driven by the controller far beyond a turn.

The reference is pinocchio's native model of the unmodified URDF (``buildModelFromUrdf``, whose continuous
joints are ``JointModelRUB*`` with ``q = (cos θ, sin θ)``): an independent parametrisation of the same
kinematics. The random chains of ``tests/test_urdf_guarantees.py`` also draw continuous joints (against a
reference written from the URDF specification).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pin = pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control import AvoidanceController, ControllerConfig, CycleInput, CycleStatus  # noqa: E402
from depthguard.control.warmup import warm_up  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import RobotModel  # noqa: E402
from depthguard.robot.robots import load_robot, robot_urdf  # noqa: E402

_KINOVA: list = []


def _kinova() -> RobotModel:
    if not _KINOVA:
        _KINOVA.append(load_robot("kinova"))
    return _KINOVA[0]


def _native_q(native: pin.Model, names: tuple[str, ...], q: np.ndarray) -> np.ndarray:
    """pinocchio's configuration (cos/sin for continuous joints) of our angles ``q`` (n,)."""
    out = np.zeros(native.nq)
    for name, angle in zip(names, q, strict=True):
        jid = native.getJointId(name)
        k, nq = native.idx_qs[jid], native.nqs[jid]
        out[k : k + nq] = [np.cos(angle), np.sin(angle)] if nq == 2 else [angle]
    return out


def test_kinova_loads_with_three_unbounded_joints() -> None:
    m = _kinova()
    native = pin.buildModelFromUrdf(str(robot_urdf("kinova")))
    unbounded = [n for n in m.joint_names if native.joints[native.getJointId(n)].nq == 2]
    assert len(unbounded) == 3 and m.n_dof == native.nv == 6 and native.nq == 9
    assert set(m.continuous_joints) == set(unbounded)
    for i, name in enumerate(m.joint_names):
        jid = native.getJointId(name)
        assert m.v_max[i] == native.velocityLimit[native.idx_vs[jid]], name
        if name in unbounded:
            assert m.q_min[i] == -np.inf and m.q_max[i] == np.inf, name
        else:
            k = native.idx_qs[jid]
            assert (m.q_min[i], m.q_max[i]) == (native.lowerPositionLimit[k], native.upperPositionLimit[k]), name


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    turns=st.lists(st.floats(-30.0, 30.0, allow_nan=False), min_size=6, max_size=6),
    seed=st.integers(0, 2**31 - 1),
)
def test_kinematics_match_pinocchios_continuous_joints_beyond_a_turn(turns: list[float], seed: int) -> None:
    m = _kinova()
    native = pin.buildModelFromUrdf(str(robot_urdf("kinova")))
    data = native.createData()
    rng = np.random.default_rng(seed)
    lo, hi = np.where(np.isfinite(m.q_min), m.q_min, -30.0), np.where(np.isfinite(m.q_max), m.q_max, 30.0)
    q = np.where(np.isfinite(m.q_min), rng.uniform(lo, hi), np.asarray(turns))
    qn = _native_q(native, m.joint_names, q)
    pin.forwardKinematics(native, data, qn)
    pin.updateFramePlacements(native, data)
    for frame in ("j2s6s200_end_effector", "j2s6s200_link_3", "j2s6s200_link_finger_tip_1"):
        R, p = m.frame_pose(q, frame)
        M = data.oMf[native.getFrameId(frame, pin.FrameType.BODY)]
        np.testing.assert_allclose(R, M.rotation, atol=1e-9, err_msg=frame)
        np.testing.assert_allclose(p, M.translation, atol=1e-9, err_msg=frame)
        # the Jacobian column of an angle is pinocchio's velocity column (nv is the same for both)
        J = pin.computeFrameJacobian(native, data, qn, native.getFrameId(frame), pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(m.frame_jacobian(q, frame), J, atol=1e-9, err_msg=frame)
    # the compiled chain agrees too
    H, _ = m.joint_kinematics(q)
    pin.forwardKinematics(native, data, qn)
    for i, name in enumerate(m.joint_names):
        np.testing.assert_allclose(H[i + 1], data.oMi[native.getJointId(name)].homogeneous, atol=1e-9)


def test_controller_drives_an_unbounded_joint_far_beyond_a_turn() -> None:
    m = _kinova()
    points = ControlPointSet.build(m, "auto")
    ctrl = AvoidanceController(points, ControllerConfig())
    q = np.where(np.isfinite(m.q_min), 0.5 * (np.nan_to_num(m.q_min) + np.nan_to_num(m.q_max)), 0.0)
    q[list(m.joint_names).index("j2s6s200_joint_1")] = 50.0  # eight turns: no limit to brake for
    qd, N = np.zeros(m.n_dof), points.n_points
    statuses = set()
    for k in range(400):
        t = k * 1e-3
        out = ctrl.step(
            CycleInput(t=t, q=q, qdot=qd, xdot_d=np.array([0.05, 0.0, 0.0]), distances=np.full(N, 0.3),
                       directions=np.tile([0.0, 0.0, 1.0], (N, 1)), t_joints=t, t_distances=t)
        )  # fmt: skip
        assert np.all(np.isfinite(out.qdot_cmd)) and np.all(np.isfinite(out.q_cmd))
        assert np.all(np.abs(out.qdot_cmd) <= m.v_max + 1e-9)
        assert np.all(out.qdot_min <= 1e-12) and np.all(out.qdot_max >= -1e-12)
        statuses.add(out.status)
        q, qd = out.q_cmd, out.qdot_cmd
    assert statuses == {CycleStatus.OK}
    assert np.linalg.norm(qd) > 1e-3  # it moves
    # the finite limits still hold: a bounded joint commanded towards its limit brakes before it
    j2 = list(m.joint_names).index("j2s6s200_joint_2")
    assert m.q_min[j2] <= q[j2] <= m.q_max[j2]


def test_warm_up_passes_every_status_with_unbounded_joints() -> None:
    m = _kinova()
    points = ControlPointSet.build(m, "auto")
    met = warm_up(points, ControllerConfig(), m, cycles=3)
    assert "OK" in met and all("INVALID" not in s or s == "STOP_INVALID_INPUT" for s in met), met


def test_named_continuous_joint_without_a_speed_is_refused(tmp_path) -> None:
    text = """<robot name="r"><link name="a"/><link name="b"/>
    <joint name="wheel" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 1 0"/></joint></robot>"""
    path = tmp_path / "r.urdf"
    path.write_text(text)
    with pytest.raises(ValueError, match="'wheel' is continuous without <limit>.*speed"):
        RobotModel.from_urdf(path)


def test_robot_without_a_name_is_refused_naming_the_root(tmp_path) -> None:
    path = tmp_path / "r.urdf"
    path.write_text('<robot><link name="a"/><link name="b"/><joint name="j" type="fixed"><parent link="a"/>'
                    '<child link="b"/></joint></robot>')  # fmt: skip
    with pytest.raises(ValueError, match=r"<robot name"):
        RobotModel.from_urdf(path)


@pytest.mark.slow
def test_every_example_robot_data_urdf_loads_or_is_refused_naming_the_element(capfd) -> None:
    """All 70 URDFs of example-robot-data: each loads, or is refused by our check naming the element, never by
    pinocchio's parser ("not a valid URDF", with its own lines on stderr)."""
    from depthguard.robot.robots import robot_data_dir

    paths = sorted((robot_data_dir() / "robots").rglob("*.urdf"))
    assert len(paths) >= 60
    loaded, refused = 0, {}
    for path in paths:
        try:
            RobotModel.from_urdf(path)
            loaded += 1
        except ValueError as exc:
            refused[path.name] = str(exc)
            assert str(exc).startswith(f"URDF {path}: "), exc
    assert loaded >= len(paths) - 8, refused
    assert "Error:" not in capfd.readouterr().err  # (pinocchio's URDF parser never got a bad file)
