"""The cell file's robot section reaches the chain: attachments are filtered and covered by control spheres,
explicit spheres are added, and what is not supported (a camera carried by the robot) is refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from depthguard.io.cellfile import CellError, read_cell  # noqa: E402
from depthguard.runner.chain import cell_control_points, load_cell_robot  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "cells"
Q = np.array([0.3, 0.5, -0.2, -1.1, 0.4, 0.9, 0.1])


def _cylinder_surface(R: np.ndarray, p: np.ndarray, radius: float, length: float, n: int = 40) -> np.ndarray:
    """(M, 3) world points on a cylinder along the z axis of the pose (R, p), its ends included."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    z = np.linspace(-length / 2, length / 2, n)
    ring = np.stack([np.cos(a), np.sin(a)], 1)
    side = np.concatenate([np.column_stack([radius * ring, np.full(n, zz)]) for zz in z])
    rr = np.linspace(0, radius, 6)
    caps = np.concatenate([np.column_stack([r * ring, np.full(n, s * length / 2)]) for r in rr for s in (-1, 1)])
    return np.concatenate([side, caps]) @ R.T + p


def test_example_gripper_is_filtered_and_covered_by_control_spheres():
    cell = read_cell(EXAMPLES / "realsense-d435.toml")
    model = load_cell_robot(cell)
    assert [s.name for s in model.attachments] == ["gripper"]
    assert any(g.shape.name == "gripper" for g in model.geometry.geoms)  # the self-filter rasterises it
    points = cell_control_points(cell, model)
    grip = [i for i, n in enumerate(points.names) if n.startswith("gripper/")]
    assert grip, points.names
    st = points.evaluate(Q)
    # the cylinder of the file (radius 0.045, length 0.12, 6 cm beyond the flange), from the flange's pose
    Rf, pf = model.frame_pose(Q, "lwr_flange")
    surf = _cylinder_surface(Rf, pf + Rf @ np.array([0.0, 0.0, 0.06]), 0.045, 0.12)
    gap = np.linalg.norm(surf[:, None, :] - st.centres[grip][None], axis=2) - st.radii[grip][None]
    assert gap.min(axis=1).max() <= 1e-9, "a point of the gripper lies outside every control sphere"


def test_explicit_sphere_is_added_at_its_link_position(tmp_path):
    text = (EXAMPLES / "realsense-d435.toml").read_text()
    text = text.replace(
        "[[robot.attachments]]",
        '[[robot.spheres]]\nlink = "lwr_link_4"\nposition = [0.0, 0.05, 0.1]\nradius = 0.07\n\n[[robot.attachments]]',
        1,
    )
    p = tmp_path / "cell.toml"
    p.write_text(text)
    cell = read_cell(p)
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    k = points.names.index("lwr_link_4/sphere0")
    st = points.evaluate(Q)
    R4, p4 = model.frame_pose(Q, "lwr_link_4")
    np.testing.assert_allclose(st.centres[k], p4 + R4 @ np.array([0.0, 0.05, 0.1]), atol=1e-12)
    assert st.radii[k] == 0.07


def test_attachment_on_an_unknown_link_names_it(tmp_path):
    text = (EXAMPLES / "realsense-d435.toml").read_text().replace('link = "lwr_flange"', 'link = "lwr_flang"')
    p = tmp_path / "cell.toml"
    p.write_text(text)
    with pytest.raises(CellError, match=r"robot\.attachments\[0\].*lwr_flang"):
        load_cell_robot(read_cell(p))


def test_camera_carried_by_the_robot_runs_in_run_only(tmp_path):
    """A camera on a link is read; ``run``'s chain and the nodes check the link; calibrate refuses it on the
    simulated cell (whose cameras stand in the world)."""
    from depthguard.runner.calibrate import calibrate_cell
    from depthguard.runner.carried import carried_camera, check_camera_parents
    from depthguard.runner.chain import Chain

    text = (EXAMPLES / "realsense-d435.toml").read_text()
    text = text.replace("rate = 30.0\nmatrix", 'rate = 30.0\nparent = "lwr_link_7"\nmatrix', 1)
    assert 'parent = "lwr_link_7"' in text
    p = tmp_path / "cell.toml"
    p.write_text(text)
    cell = read_cell(p)
    assert cell.cameras[0].parent == "lwr_link_7"
    model = load_cell_robot(cell)
    cam = cell.cameras[0].build(width=640, height=480, fx=600.0, fy=600.0, cx=320.0, cy=240.0)
    chain = Chain(cell, [cam], model)
    assert chain.parents == ["lwr_link_7"]
    with pytest.raises(CellError, match=r"cameras\[0\]\.parent = 'lwr_link_77' is not a link"):
        Chain(cell, [cam], model, parents=["lwr_link_77"])
    assert check_camera_parents(cell, model) == [(0, "lwr_link_7")]
    # the camera moves with its link: a point fixed to the link keeps its camera coordinates
    q0, q1 = np.zeros(7), np.linspace(0.3, -0.4, 7)
    c0, c1 = (carried_camera(cam, model, q, "lwr_link_7") for q in (q0, q1))
    (R0, p0), (R1, p1) = (model.frame_pose(q, "lwr_link_7") for q in (q0, q1))
    x_link = np.array([0.05, -0.02, 0.3])
    np.testing.assert_allclose(c0.world_to_camera((R0 @ x_link + p0)[None]), cam.world_to_camera(x_link[None]))
    np.testing.assert_allclose(c1.world_to_camera((R1 @ x_link + p1)[None]), cam.world_to_camera(x_link[None]))
    assert np.linalg.norm(c0.position - c1.position) > 0.05
    with pytest.raises(CellError, match=r"parent = 'lwr_link_7'.*calibrate"):
        calibrate_cell(p, "sim:ral-hexagon", quick=True)


def _solid_samples(kind: str, size, rng, n: int = 4000) -> np.ndarray:
    """(n, 3) points inside the solid in its own frame (the boundary included), by its definition."""
    u = rng.uniform(-1, 1, (n, 3))
    if kind == "box":
        return u * 0.5 * np.array(size)
    r = size[0]
    ang, rad = rng.uniform(0, 2 * np.pi, n), r * np.sqrt(rng.uniform(0, 1, n))
    rad[: n // 4] = r  # a quarter on the mantle
    disk = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
    if kind == "cylinder":
        return np.column_stack([disk, u[:, 2] * 0.5 * size[1]])
    d = rng.normal(size=(n, 3))
    d *= r * rng.uniform(0, 1, n)[:, None] ** (1 / 3) / np.linalg.norm(d, axis=1, keepdims=True)
    if kind == "sphere":
        return d
    return d + np.outer(u[:, 2] * 0.5 * size[1], [0.0, 0.0, 1.0])  # capsule: balls along the segment


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("kind", ["box", "cylinder", "capsule", "sphere", "mesh"])
def test_shape_cover_contains_the_whole_solid(kind, seed, tmp_path):
    from depthguard.robot.shapes import Shape, rpy_to_matrix
    from depthguard.robot.spheres import shape_cover

    rng = np.random.default_rng(seed)
    xyz, rpy = tuple(rng.uniform(-0.2, 0.2, 3)), tuple(rng.uniform(-np.pi, np.pi, 3))
    if kind == "mesh":  # a box as a mesh file, covered through its faces
        trimesh = pytest.importorskip("trimesh")
        size = tuple(rng.uniform(0.02, 0.3, 3))
        path = tmp_path / "part.stl"
        trimesh.creation.box(extents=size).export(path)
        shape, pts = Shape("l", "mesh", mesh=str(path), xyz=xyz, rpy=rpy), _solid_samples("box", size, rng)
    else:
        n = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1}[kind]
        size = tuple(rng.uniform(0.01, 0.3, n))
        shape, pts = Shape("l", kind, size=size, xyz=xyz, rpy=rpy), _solid_samples(kind, size, rng)
    world = pts @ rpy_to_matrix(rpy).T + np.array(xyz)
    c, r = shape_cover(shape)
    assert 1 <= len(r) <= 4
    outside = (np.linalg.norm(world[:, None] - c[None], axis=2) - r[None]).min(axis=1)
    assert outside.max() <= 1e-9, f"{kind}: a point {outside.max():.2e} m outside every sphere"


def _edited(tmp_path, old: str, new: str) -> Path:
    text = (EXAMPLES / "realsense-d435.toml").read_text()
    assert old in text
    p = tmp_path / "cell.toml"
    p.write_text(text.replace(old, new, 1))
    return p


def test_ssm_in_the_cell_file_turns_the_monitor_on(tmp_path):
    from depthguard.camera import Camera
    from depthguard.control.cycle import AvoidanceController
    from depthguard.io.cellfile import CellError
    from depthguard.runner.chain import _controller_config, cell_distance_stage

    cell = read_cell(_edited(tmp_path, "[controller]\n", "[controller]\nssm = true\n"))
    cfg = _controller_config(cell)
    # the monitor's distances reach max(rho, ssm_range = 0.6 m); the repulsion keeps rho (docs/ssm.md)
    assert cfg.avoidance == "both" and cfg.ssm.sensing_range == max(cell.distance["rho"], 0.6)
    cams = [Camera(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0, R=np.eye(3), t=np.zeros(3))]
    stage = cell_distance_stage(cell, cams)
    assert stage.rho == cell.distance["rho"] and stage.ssm_range == cfg.ssm.sensing_range
    near = read_cell(_edited(tmp_path, "[controller]\n", "[controller]\nssm = true\nssm_range = 0.1\n"))
    assert _controller_config(near).ssm.sensing_range == near.distance["rho"]  # never below rho
    assert cell_distance_stage(near, cams).ssm_range is None
    with pytest.raises(CellError, match="controller.ssm_range"):
        read_cell(_edited(tmp_path, "[controller]\n", "[controller]\nssm = true\nssm_range = -1\n"))
    model = load_cell_robot(cell)
    assert AvoidanceController(cell_control_points(cell, model), cfg).monitor is not None
    plain = _controller_config(read_cell(EXAMPLES / "realsense-d435.toml"))
    assert plain.avoidance == "repulsion" and plain.ssm is None


def test_octree_backend_is_refused_by_the_chain_not_replaced(tmp_path):
    from depthguard.runner.chain import Chain

    cell = read_cell(_edited(tmp_path, "[distance]\n", '[distance]\nbackend = "octree"\n'))
    model = load_cell_robot(cell)
    cams = [c.build(width=640, height=480, fx=600.0, fy=600.0, cx=320.0, cy=240.0) for c in cell.cameras]
    with pytest.raises(CellError, match=r"distance\.backend = 'octree'"):
        Chain(cell, cams, model)


def test_distance_settings_of_the_cell_file_reach_the_stage(tmp_path):
    from depthguard.runner.chain import cell_distance_stage

    one = read_cell(_edited(tmp_path, "[distance]\n", '[distance]\ninvalid = "ignore"\nfill_radius = 2\n'))
    cams = [c.build(width=640, height=480, fx=600.0, fy=600.0, cx=320.0, cy=240.0) for c in one.cameras]
    stage = cell_distance_stage(one, cams)
    assert (stage.invalid, stage.fill_radius) == ("ignore", 2)
    hexagon = (EXAMPLES / "sim-hexagon.toml").read_text()
    p = tmp_path / "two.toml"
    p.write_text(hexagon.replace("fill_radius = 4\n", "fill_radius = 3\n", 1))
    two = read_cell(p)
    assert cell_distance_stage(two, [c.build() for c in two.cameras]).fusion.fill_radius == 3
    p.write_text(hexagon.replace('invalid = "conservative"', 'invalid = "ignore"', 1))
    with pytest.raises(CellError, match="conservative"):
        cell_distance_stage(read_cell(p), [c.build() for c in read_cell(p).cameras])


def test_distance_node_places_the_cameras_the_robot_carries():
    """The distance node's cameras of one frame set: world cameras at the image size, a carried one where its
    link was at its frame's joint state, and none at all without that joint state (no distances)."""
    from depthguard.nodes.distance import frame_set_cameras
    from depthguard.runner.carried import carried_camera

    cell = read_cell(EXAMPLES / "sim-hexagon.toml")
    model = load_cell_robot(cell)
    cams0 = [c.build() for c in cell.cameras]
    depths = [np.zeros((120, 160)), np.zeros((240, 320))]
    q = np.linspace(-0.5, 0.5, 7)
    cams = frame_set_cameras(cams0, depths, model, [(1, "lwr_link_4")], {1: q})
    assert (cams[0].width, cams[1].width) == (160, 320)
    np.testing.assert_allclose(cams[0].R, cams0[0].R)
    placed = carried_camera(cams0[1], model, q, "lwr_link_4")
    np.testing.assert_allclose(cams[1].R, placed.R)
    np.testing.assert_allclose(cams[1].t, placed.t)
    assert not np.allclose(cams[1].t, cams0[1].t)
    assert frame_set_cameras(cams0, depths, model, [(1, "lwr_link_4")], {1: None}) is None


def test_live_view_draws_a_carried_camera_where_its_link_is(tmp_path):
    """A camera carried by a link (pose given in the link's frame) is drawn at the pose of the latest joint
    state; without a usable joint state its cloud is not drawn at all (None), rather than misplaced."""
    pytest.importorskip("viser")
    from depthguard.runner.carried import carried_camera
    from depthguard.runner.chain import cell_control_points, load_cell_robot
    from depthguard.viz.live import LiveView

    text = (EXAMPLES / "sim-hexagon.toml").read_text()
    text = text.replace("eye = [2.0, -1.09, 1.5]", 'parent = "lwr_link_4"\neye = [2.0, -1.09, 1.5]', 1)
    p = tmp_path / "cell.toml"
    p.write_text(text)
    cell = read_cell(p)
    model = load_cell_robot(cell)
    local = [c.build() for c in cell.cameras]
    view = LiveView(
        cell, model, cell_control_points(cell, model), local, port=int(np.random.default_rng().integers(18900, 19700))
    )
    try:
        q = np.linspace(-0.4, 0.4, 7)
        cams = view._world_cameras(q)
        placed = carried_camera(local[0], model, q, "lwr_link_4")
        np.testing.assert_allclose(cams[0].R, placed.R)
        np.testing.assert_allclose(cams[0].t, placed.t)
        np.testing.assert_allclose(cams[1].t, local[1].t)  # a world camera stays
        assert view._world_cameras(None) is None
        assert view._world_cameras(np.full(7, np.nan)) is None
    finally:
        view.close()


def test_the_cell_files_timeouts_reach_the_controller(tmp_path):
    """`[controller]` rate, joint_timeout and distance_timeout of the cell file are the controller's: with
    distances from one frame at t = 0 it stops on stale distances at the first tick after distance_timeout,
    and a joint state older than joint_timeout stops it while a younger one does not."""
    from depthguard.runner.chain import Chain, load_cell_robot

    old, new = "joint_timeout = 0.05\ndistance_timeout = 0.1", "joint_timeout = 0.03\ndistance_timeout = 0.2"
    p = _edited(tmp_path, old, new)
    cell = read_cell(p)
    model = load_cell_robot(cell)
    cams = [c.build(width=160, height=120, fx=150.0, fy=150.0, cx=80.0, cy=60.0) for c in cell.cameras]
    q, z = np.array([0.3, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0]), np.zeros(7)

    def chain_with_distances_at_0():
        chain = Chain(cell, cams, model)
        chain.on_frames([np.full((120, 160), 3.0, np.float32)], q, 0.0)
        chain.query(0.0, q)
        return chain

    chain = chain_with_distances_at_0()
    assert (chain.config.dt, chain.config.joint_timeout, chain.config.distance_timeout) == (0.01, 0.03, 0.2)
    status = [chain.control(0.01 * k, q, z, 0.01 * k, np.zeros(3)).status.name for k in range(30)]
    assert "STOP_STALE_DISTANCES" not in status[:21] and set(status[21:]) == {"STOP_STALE_DISTANCES"}
    chain = chain_with_distances_at_0()
    assert chain.control(0.05, q, z, 0.05 - 0.02, np.zeros(3)).status.name != "STOP_STALE_JOINTS"
    assert chain.control(0.06, q, z, 0.06 - 0.04, np.zeros(3)).status.name == "STOP_STALE_JOINTS"
