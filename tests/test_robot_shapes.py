"""URDF collision geometry: package:// and relative mesh paths, primitives, attachments, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pinocchio")
trimesh = pytest.importorskip("trimesh")

from depthguard.robot.model import RobotModel  # noqa: E402
from depthguard.robot.shapes import Shape, inflation_directions  # noqa: E402

URDF = """<robot name="two">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="arm">
    <collision><origin xyz="0 0 0.2"/><geometry><mesh filename="{mesh}" scale="0.5 0.5 0.5"/></geometry></collision>
    <collision><origin xyz="0 0 0.5"/><geometry><cylinder radius="0.04" length="0.2"/></geometry></collision>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="2" effort="10"/></joint>
</robot>"""


def _package(tmp_path: Path) -> Path:
    pkg = tmp_path / "my_robot_description"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "package.xml").write_text("<package><name>my_robot_description</name></package>")
    trimesh.creation.box(extents=(0.1, 0.1, 0.4)).export(pkg / "meshes" / "arm.stl")
    return pkg


@pytest.mark.parametrize("ref", ["package://my_robot_description/meshes/arm.stl", "../meshes/arm.stl"])
def test_mesh_paths_resolve_from_the_urdf_folders(tmp_path: Path, ref: str) -> None:
    pkg = _package(tmp_path)
    urdf = pkg / "urdf" / "two.urdf"
    urdf.write_text(URDF.format(mesh=ref))
    m = RobotModel.from_urdf(urdf)
    kinds = sorted(g.shape.kind for g in m.geometry.geoms)
    assert kinds == ["box", "cylinder", "mesh"]
    mesh = next(g for g in m.geometry.geoms if g.shape.kind == "mesh")
    np.testing.assert_allclose(np.ptp(mesh.vertices, axis=0), [0.05, 0.05, 0.2], atol=1e-9)  # scale 0.5
    np.testing.assert_allclose(mesh.vertices.mean(axis=0), [0, 0, 0.2], atol=1e-9)
    assert m.geometry.n_triangles == 12 + 12 + 4 * 24


def test_missing_mesh_is_a_clear_error(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    urdf = pkg / "urdf" / "two.urdf"
    urdf.write_text(URDF.format(mesh="package://other_pkg/meshes/arm.stl"))
    with pytest.raises(ValueError, match="other_pkg"):
        RobotModel.from_urdf(urdf)
    (pkg / "meshes" / "bad.stl").write_text("not a mesh")
    urdf.write_text(URDF.format(mesh="../meshes/bad.stl"))
    with pytest.raises(ValueError, match="bad.stl"):
        RobotModel.from_urdf(urdf)


def test_inflation_moves_every_face_out_by_the_margin() -> None:
    for mesh in (trimesh.creation.box(extents=(0.1, 0.2, 0.3)), trimesh.creation.icosphere(2, 0.1)):
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        o = inflation_directions(v, f)
        n = np.asarray(mesh.face_normals)
        for k in range(3):  # each moved vertex is >= 1 margin above each adjacent face's plane
            assert np.all(np.einsum("ij,ij->i", o[f[:, k]], n) >= 1 - 1e-9)
        assert np.max(np.linalg.norm(o, axis=1)) <= np.sqrt(3) + 1e-6  # a box corner needs sqrt(3)


def test_shape_validation_names_the_field() -> None:
    with pytest.raises(ValueError, match="box needs size"):
        Shape(link="a", kind="box", size=(0.1, 0.2))
    with pytest.raises(ValueError, match="xyz"):
        Shape(link="a", kind="sphere", size=(0.1,), xyz=(0, 0, np.nan))
    with pytest.raises(ValueError, match="mesh file"):
        Shape(link="a", kind="mesh")
