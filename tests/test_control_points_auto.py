"""The ``auto`` control-point preset: spheres that cover every vertex of each link's collision geometry,
checked against the geometry read independently by pinocchio/coal (meshes, boxes, cylinders, spheres)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("trimesh")

from _meshtruth import geometry_points  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4, lwr4_urdf_path  # noqa: E402
from depthguard.robot.robots import load_robot, robot_urdf  # noqa: E402
from depthguard.robot.shapes import Shape  # noqa: E402
from depthguard.robot.spheres import cover_points, volume_ratio  # noqa: E402


def _uncovered(cps: ControlPointSet, q: np.ndarray, pts_by_link: dict[str, np.ndarray]) -> dict[str, float]:
    """Per link with spheres: the largest distance (m) by which one of its points lies outside all of them."""
    st = cps.evaluate(q)
    out = {}
    for link, pts in pts_by_link.items():
        idx = [i for i, nm in enumerate(st.names) if nm.startswith(link + "/")]
        if not idx:
            continue
        d = np.linalg.norm(pts[:, None, :] - st.centres[idx][None], axis=2) - st.radii[idx][None]
        out[link] = float(np.max(np.min(d, axis=1)))
    return out


@pytest.mark.parametrize("name", ["panda", "ur5", pytest.param("xarm7", marks=pytest.mark.slow)])
def test_auto_spheres_cover_every_mesh_vertex(name: str) -> None:
    model = load_robot(name)
    cps = ControlPointSet.build(model, "auto")
    rng = np.random.default_rng(5)
    q = rng.uniform(np.maximum(model.q_min, -2.5), np.minimum(model.q_max, 2.5))
    pts = geometry_points(str(robot_urdf(name)), q)
    worst = _uncovered(cps, q, pts)
    moving = [lk for lk in pts if model.joint_support_mask(model.model.frames[model.frame_id(lk)].parentJoint).any()]
    assert set(worst) == set(moving)  # every moving link has spheres, the fixed base none
    assert max(worst.values()) <= 1e-9, worst
    assert cps.names[0] == "ee" and cps.n_points <= 1 + 3 * len(moving)


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_auto_spheres_cover_the_mesh_surfaces_between_the_vertices(name: str) -> None:
    """Not only the vertices: a grid of 10 steps on every collision triangle (spheres fitted to points
    sampled on a surface used to leave up to 3.4 mm of the Panda's and 7.7 mm of the UR5's surface out)."""
    model = load_robot(name)
    cps = ControlPointSet.build(model, "auto")
    q = np.random.default_rng(7).uniform(np.maximum(model.q_min, -2.5), np.minimum(model.q_max, 2.5))
    worst = _uncovered(cps, q, geometry_points(str(robot_urdf(name)), q, faces=10))
    assert max(worst.values()) <= 1e-9, worst


def test_auto_spheres_cover_the_primitives_of_the_shipped_arm() -> None:
    lwr = load_lwr4()
    cps = ControlPointSet.build(lwr, "auto", auto_spheres=4)
    q = np.array([0.3, 0.6, 0.0, -1.3, 0.2, 0.9, 0.0])
    worst = _uncovered(cps, q, geometry_points(str(lwr4_urdf_path()), q))
    assert max(worst.values()) <= 1e-9, worst


def test_attached_payload_is_covered() -> None:
    model = load_robot("panda")
    box = Shape(link="panda_hand", kind="box", size=(0.06, 0.16, 0.30), xyz=(0.0, 0.0, 0.25))
    model.attach(box)
    cps = ControlPointSet.build(model, "auto")
    q = model.neutral()
    R, p = model.frame_pose(q, "panda_hand")
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * [0.03, 0.08, 0.15]
    world = (corners + [0.0, 0.0, 0.25]) @ R.T + p
    assert _uncovered(cps, q, {"panda_hand": world})["panda_hand"] <= 1e-9


def test_more_spheres_fit_tighter_and_counts_are_validated() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.05, -0.05, 0.0], [0.05, 0.05, 0.4], size=(3000, 3))  # a 0.4 m x 0.1 m link
    ratios = [volume_ratio(pts, cover_points(pts, k)[1]) for k in (1, 2, 3, 4)]
    assert ratios[0] > 8 and ratios[3] < 2.6 and all(np.diff(ratios) < 0), ratios
    for k in (1, 3, 5):
        c, r = cover_points(pts, k)
        assert np.all(np.min(np.linalg.norm(pts[:, None] - c[None], axis=2) - r[None], axis=1) <= 1e-12)
    with pytest.raises(ValueError, match="auto_spheres"):
        ControlPointSet.build(load_lwr4(), "auto", auto_spheres=0)
    with pytest.raises(ValueError, match="points"):
        cover_points(np.full((4, 3), np.nan), 2)
