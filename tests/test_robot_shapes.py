"""URDF collision geometry: package:// and relative mesh paths, primitives, attachments, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pinocchio")
trimesh = pytest.importorskip("trimesh")

from depthguard.robot.inflation import inflation_directions, rounded_box  # noqa: E402
from depthguard.robot.model import RobotModel  # noqa: E402
from depthguard.robot.shapes import Shape  # noqa: E402

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
    boxes = [g for g in m.geometry.geoms if g.shape.kind == "box"]
    assert mesh.filter_mesh is not None  # the box-shaped mesh is convex: drawn as its rounded offset
    rounded = len(boxes[0].filter_mesh[2]) + len(mesh.filter_mesh[2])
    assert m.geometry.n_triangles == rounded + 4 * 24  # box and mesh (rounded), prism


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


def test_inflation_stays_within_the_margin_and_moves_every_face_out() -> None:
    """Offsets at most one margin long (nothing inflated lies farther than the margin from its face); every
    face moves out by at least half the margin (a box corner: 1 / sqrt(3)), a smooth surface's by nearly
    all of it."""
    for mesh, least in (
        (trimesh.creation.box(extents=(0.1, 0.2, 0.3)), 1 / np.sqrt(3)),
        (trimesh.creation.icosphere(2, 0.1), 0.98),
    ):
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        o = inflation_directions(v, f)
        n = np.asarray(mesh.face_normals)
        assert np.max(np.linalg.norm(o, axis=1)) <= 1 + 1e-9
        for k in range(3):
            assert np.all(np.einsum("ij,ij->i", o[f[:, k]], n) >= least - 1e-6)


def test_rounded_box_lies_within_the_margin_and_holds_the_box_grown_by_86_percent_of_it() -> None:
    size, margin = np.array([0.1, 0.2, 0.3]), 0.03
    v, o, f = rounded_box(size)
    inflated = trimesh.Trimesh(v + margin * o, f, process=False)
    assert inflated.is_watertight and inflated.is_winding_consistent and inflated.volume > 0
    # every vertex on the true Minkowski sum's surface: exactly the margin from the box
    dist = np.linalg.norm(np.maximum(np.abs(inflated.vertices) - size / 2, 0.0), axis=1)
    np.testing.assert_allclose(dist, margin, atol=1e-12)
    # points 0.86 margin from the box, all around it (faces, edges and corners), are inside
    y = np.random.default_rng(0).uniform(-1, 1, size=(4000, 3)) * (size / 2 + 2 * margin)
    c = np.clip(y, -size / 2, size / 2)
    out = np.linalg.norm(y - c, axis=1) > 1e-9
    x = c[out] + 0.86 * margin * (y - c)[out] / np.linalg.norm(y - c, axis=1)[out, None]
    assert len(x) > 2000 and np.all(inflated.contains(x))


def test_shape_validation_names_the_field() -> None:
    with pytest.raises(ValueError, match="box needs size"):
        Shape(link="a", kind="box", size=(0.1, 0.2))
    with pytest.raises(ValueError, match="xyz"):
        Shape(link="a", kind="sphere", size=(0.1,), xyz=(0, 0, np.nan))
    with pytest.raises(ValueError, match="mesh file"):
        Shape(link="a", kind="mesh")
