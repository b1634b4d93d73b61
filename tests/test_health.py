"""Sensor health in the simulated cell: frozen, covered and moved cameras are named; a healthy one is not."""

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("pinocchio")

from scipy.spatial.transform import Rotation  # noqa: E402

from depthguard.robot.health import CameraHealth  # noqa: E402


@pytest.fixture(scope="module")
def cell():
    from depthguard.robot.model import load_lwr4
    from depthguard.sim.cell import CellSpec, build_cell
    from depthguard.sim.depthcam import KinectSim, kinect_camera

    cam = kinect_camera((1.75, -0.95, 1.5), (0.0, 0.0, 0.45), width=160, height=120)
    c = build_cell(CellSpec(cameras=[cam], boxes=[], people=[], q0=tuple(np.zeros(7))))
    return cam, c, KinectSim(c.model, cam, 0, seed=2), load_lwr4()


def _frames(cell, n, q=(0.3, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0)):
    cam, c, sim, _ = cell
    c.set_q(np.array(q))
    return [sim.capture(c.data) for _ in range(n)], np.array(q)


def test_healthy_camera_passes(cell):
    cam, _, _, model = cell
    h = CameraHealth(cam, "camera0", model)
    frames, q = _frames(cell, 6)
    assert all(h.check(f, q) is None for f in frames)


def test_frozen_stream(cell):
    cam, _, _, model = cell
    h = CameraHealth(cam, "camera0", model)
    frames, q = _frames(cell, 1)
    out = [h.check(frames[0].copy(), q) for _ in range(4)]
    assert out[:2] == [None, None] and out[2] == "frozen"
    fresh, _ = _frames(cell, 4)
    assert [h.check(f, q) for f in fresh] == ["frozen", "frozen", None, None]  # clears after 3 healthy frames


def test_covered_lens(cell):
    cam, _, _, model = cell
    h = CameraHealth(cam, "camera0", model)
    frames, q = _frames(cell, 2)
    covered = frames[0].copy()
    covered[:, :140] = np.nan
    assert h.check(covered, q) == "covered"
    near = frames[1].copy()
    near[:] = 0.2  # a hand on the lens: everything nearer than the 0.5 m near limit
    assert h.check(near, q) == "covered"


def test_moved_camera(cell):
    """Frames from a camera bumped by 8 degrees, checked against the calibrated pose: 'moved'."""
    from depthguard.sim.cell import CellSpec, build_cell
    from depthguard.sim.depthcam import KinectSim

    cam, _, _, model = cell
    R = Rotation.from_rotvec([0.0, np.deg2rad(8.0), 0.0]).as_matrix() @ cam.R
    bumped = cam.with_pose(R, -R @ cam.position)
    c2 = build_cell(CellSpec(cameras=[bumped], boxes=[], people=[], q0=tuple(np.zeros(7))))
    sim2 = KinectSim(c2.model, bumped, 0, seed=3)
    h = CameraHealth(cam, "camera0", model)
    q = np.array([0.3, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    c2.set_q(q)
    out = [h.check(sim2.capture(c2.data), q) for _ in range(3)]
    assert out == [None, None, "moved"]
