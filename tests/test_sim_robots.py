"""The simulated cell with another robot than the shipped arm: the Franka Panda built from its own collision
meshes (MuJoCo reads the STL files), driven in the controller's q order, filtered by the mesh self-filter."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("pinocchio")
pytest.importorskip("trimesh")

from depthguard.sim.cell import CellSpec, build_cell  # noqa: E402
from depthguard.sim.depthcam import KinectSim, placement  # noqa: E402
from depthguard.sim.pipeline import Kinematics, self_filter  # noqa: E402

Q0 = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.02, 0.02)


@pytest.fixture(scope="module")
def panda():
    cell = build_cell(CellSpec(cameras=placement("ral", 320, 240), q0=Q0, room=(-1.1, 2.0, -1.1, 2.0), robot="panda"))
    return cell, Kinematics("auto", robot="panda", auto_spheres=2)


def test_panda_cell_matches_the_controllers_model(panda) -> None:
    import mujoco

    cell, kin = panda
    assert cell.nq == 9 and kin.n == 9
    assert "mesh" in {mujoco.mjtGeom(t).name.lower().split("_")[-1] for t in cell.model.geom_type[cell.robot_geoms]}
    rng = np.random.default_rng(3)
    for _ in range(4):
        q = np.clip(np.array(Q0) + rng.uniform(-0.4, 0.4, 9), kin.q_min, kin.q_max)
        cell.set_q(q)
        np.testing.assert_allclose(cell.q(), q, atol=1e-12)
        np.testing.assert_allclose(cell.ee_position(), kin.evaluate(q).centres[0], atol=1e-6)


def test_panda_self_filter_leaves_no_robot_pixels_in_simulated_kinects(panda) -> None:
    import mujoco

    cell, kin = panda
    cell.set_q(np.array(Q0))
    for i, cam in enumerate(cell.cameras):
        sim = KinectSim(cell.model, cam, i, seed=i)
        depth = sim.capture(cell.data)  # noise, quantisation, shadow bands
        n = cam.width * cam.height
        geomid, dist = np.empty(n, np.int32), np.empty(n)
        mujoco.mj_multiRay(cell.model, cell.data, cam.position, sim._rays, None, True, -1, geomid, dist, None, n, 1e3)
        robot = np.isin(geomid, cell.robot_geoms).reshape(cam.shape) & np.isfinite(depth)
        assert robot.sum() > 300
        mask = self_filter(cam, depth, cell.q(), kin)
        assert np.sum(robot & ~mask) <= 0.01 * robot.sum()
        assert np.sum(mask & ~robot & np.isfinite(depth)) < 0.5 * robot.sum()


def test_meshes_that_mujoco_cannot_read_go_inline() -> None:
    """Meshes in other formats (or decimated) reach MuJoCo as the vertices the model loaded (UR5, decimated)."""
    import mujoco

    from depthguard.robot.robots import load_robot
    from depthguard.sim.robotdesc import RobotDesc, geoms_from_model, parse_urdf

    model = load_robot("ur5", max_triangles=200)
    geoms = geoms_from_model(model)
    inline = [g for g in geoms if g.kind == "mesh" and g.mesh is None]
    assert inline and all(len(g.faces) <= 200 for g in inline)
    d = parse_urdf(model.urdf_path.read_text(), str(model.urdf_path), "tool0", geoms)
    desc = RobotDesc(d.name, d.root, d.joints, d.geoms, d.ee_link, d.source, tuple(model.joint_names))
    cell = build_cell(CellSpec(q0=(0.0, -1.2, 1.2, 0.0, 0.5, 0.0), robot="ur5"), desc)
    meshes = cell.model.geom_type[cell.robot_geoms] == mujoco.mjtGeom.mjGEOM_MESH
    assert meshes.sum() == len([g for g in geoms if g.kind == "mesh"])
    assert cell.nq == 6  # the URDF's root link "world" became a body of its own
    q = np.array([0.3, -1.0, 1.1, -0.4, 0.6, 0.2])
    cell.set_q(q)
    _, p = model.frame_pose(q, "tool0")
    np.testing.assert_allclose(cell.ee_position(), p, atol=1e-6)
