"""Robot model: URDF loading, forward kinematics, Jacobians (finite differences), limits, capsules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from depthguard.robot.model import RobotModel, load_lwr4, lwr4_urdf_path  # noqa: E402
from depthguard.scene import Capsule  # noqa: E402


def _panda_urdf(name: str = "panda.urdf") -> Path:
    """The Franka Panda URDF shipped by example-robot-data, located through the installed distribution's
    file list (``importlib.metadata``), so it works for any install prefix or layout."""
    from importlib import metadata

    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data (extra 'robot') not installed")
    suffix = f"panda_description/urdf/{name}"
    for f in dist.files or []:
        if str(f).replace("\\", "/").endswith(suffix):
            path = Path(dist.locate_file(f))
            assert path.is_file(), path
            return path
    raise AssertionError(f"example-robot-data {dist.version} lists no {suffix}")


@pytest.fixture(scope="module")
def lwr() -> RobotModel:
    return load_lwr4()


def test_lwr4_shipped_and_limits(lwr: RobotModel) -> None:
    assert lwr4_urdf_path().is_file()
    assert lwr.n_dof == 7
    deg = np.pi / 180
    np.testing.assert_allclose(lwr.q_max, np.array([170, 120, 170, 120, 170, 120, 170]) * deg, atol=1e-5)
    np.testing.assert_allclose(lwr.q_min, -lwr.q_max)
    assert np.all(lwr.v_max > 1.5) and np.all(lwr.v_max < 4.0)


def test_lwr4_forward_kinematics_by_hand(lwr: RobotModel) -> None:
    # straight up: 0.3105 + 0.40 + 0.39 + 0.078 + 0.10 tool
    _, p = lwr.frame_pose(np.zeros(7))
    np.testing.assert_allclose(p, [0, 0, 1.2785], atol=1e-9)
    # A2 = +90 deg about -y tilts the whole arm above the shoulder towards -x
    q = np.zeros(7)
    q[1] = np.pi / 2
    _, p = lwr.frame_pose(q)
    np.testing.assert_allclose(p, [-(1.2785 - 0.3105), 0, 0.3105], atol=1e-9)
    # elbow bent by A4 = +90 deg about +y: forearm points to +x from the elbow at z = 0.7105
    q = np.zeros(7)
    q[3] = np.pi / 2
    _, p = lwr.frame_pose(q)
    np.testing.assert_allclose(p, [0.39 + 0.078 + 0.1, 0, 0.7105], atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_frame_jacobian_matches_finite_differences(lwr: RobotModel, seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = rng.uniform(lwr.q_min, lwr.q_max) * 0.8
    J = lwr.frame_jacobian(q)
    R0, p0 = lwr.frame_pose(q)
    h = 1e-6
    for i in range(lwr.n_dof):
        dq = np.zeros(7)
        dq[i] = h
        R1, p1 = lwr.frame_pose(q + dq)
        np.testing.assert_allclose((p1 - p0) / h, J[:3, i], atol=1e-5)
        W = (R1 @ R0.T - R0 @ R1.T) / (2 * h)  # skew(omega)
        np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], J[3:, i], atol=1e-5)


def test_capsules_follow_the_links_and_contain_the_joint_origins(lwr: RobotModel) -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(lwr.q_min, lwr.q_max)
    a, b, r = lwr.link_capsules(q)
    assert a.shape == b.shape == (len(lwr.capsules), 3) and r.shape == (len(lwr.capsules),)
    _, origins = lwr.joint_poses(q)
    caps = [Capsule(a[k], b[k], r[k]) for k in range(len(r))]
    for o in origins[1:]:  # every joint centre lies inside the robot's capsules
        assert min(float(c.distance(o[None])[0]) for c in caps) == 0.0
    _, ee = lwr.frame_pose(q)
    assert min(float(c.distance(ee[None])[0]) for c in caps) == 0.0
    # capsule lengths do not change with q (rigid links)
    a0, b0, _ = lwr.link_capsules(np.zeros(7))
    np.testing.assert_allclose(np.linalg.norm(b - a, axis=1), np.linalg.norm(b0 - a0, axis=1), atol=1e-12)


def test_panda_loads_offline_with_limits_and_jacobian() -> None:
    panda = RobotModel.from_urdf(_panda_urdf(), ee_frame="panda_hand")
    assert panda.n_dof == 9  # 7 arm joints + 2 fingers
    np.testing.assert_allclose(panda.q_max[0], 2.8973)
    np.testing.assert_allclose(panda.v_max[0], 2.175)
    q = np.zeros(9)
    q[3] = -1.5
    J = panda.frame_jacobian(q)
    _, p0 = panda.frame_pose(q)
    for i in range(7):
        dq = np.zeros(9)
        dq[i] = 1e-6
        np.testing.assert_allclose((panda.frame_pose(q + dq)[1] - p0) / 1e-6, J[:3, i], atol=1e-5)
    a, _, _ = panda.link_capsules(q)  # mesh-only links fall back to chain capsules
    assert len(a) >= 8


def test_panda_primitive_collision_urdf_gives_capsules() -> None:
    panda = RobotModel.from_urdf(_panda_urdf("panda_collision.urdf"))
    assert len(panda.capsules) >= 8
    assert all(c.radius > 0.0 for c in panda.capsules)


def test_bad_inputs_raise_clear_errors(lwr: RobotModel, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="q"):
        lwr.frame_pose(np.zeros(6))
    with pytest.raises(ValueError, match="finite"):
        lwr.frame_pose(np.full(7, np.nan))
    with pytest.raises(ValueError, match="frame 'nope'"):
        lwr.frame_pose(np.zeros(7), "nope")
    with pytest.raises(ValueError, match="urdf_path"):
        RobotModel.from_urdf(tmp_path / "missing.urdf")


def test_shipped_urdf_parses_in_mujoco() -> None:
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_path(str(lwr4_urdf_path()))
    assert m.njnt == 7
    assert m.ngeom >= 8


def test_point_jacobian_matches_finite_differences(lwr: RobotModel) -> None:
    q = np.array([0.2, -0.7, 0.4, 1.1, -0.3, 0.6, 0.9])
    point = np.array([0.03, -0.05, 0.02])
    p0, J = lwr.point_jacobian(q, "lwr_link_5", point)
    h = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        p1, _ = lwr.point_jacobian(q + dq, "lwr_link_5", point)
        np.testing.assert_allclose((p1 - p0) / h, J[:, i], atol=1e-5)
    assert np.all(J[:, 5:] == 0.0)  # joints after link 5 do not move it
