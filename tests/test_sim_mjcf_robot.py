"""The URDF -> MJCF writer keeps pinocchio's frames: MuJoCo body poses equal the model's frame poses."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from depthguard.robot.youbot import load_youbot, youbot_urdf_path  # noqa: E402
from depthguard.sim.mjcf_robot import build_model, rpy_quat, urdf_to_mjcf_body  # noqa: E402


def test_rpy_quat_matches_rotation_matrix():
    import mujoco

    from depthguard.robot.shapes import rpy_to_matrix as _rpy_to_matrix

    rng = np.random.default_rng(0)
    for _ in range(20):
        rpy = rng.uniform(-3, 3, 3)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, np.array(rpy_quat(tuple(rpy))))
        np.testing.assert_allclose(R.reshape(3, 3), _rpy_to_matrix(rpy), atol=1e-12)


def test_mujoco_bodies_follow_pinocchio_frames():
    import mujoco

    robot = load_youbot()
    m, d = build_model(urdf_to_mjcf_body(youbot_urdf_path()))
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-1, 1, 8)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        for f in ("platform", "link5", "link7", "link8"):
            R, p = robot.frame_pose(q, f)
            b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f)
            np.testing.assert_allclose(d.xpos[b], p, atol=1e-9)
            np.testing.assert_allclose(d.xmat[b].reshape(3, 3), R, atol=1e-9)
