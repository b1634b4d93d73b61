"""Self-filter on real robots' collision meshes (Panda, UR5, xArm7 of example-robot-data) against an
independent ground truth: pinocchio/coal read the URDF, MuJoCo reads the mesh files and ray casts them
(``mj_multiRay``), coal measures distances. 640x480 Kinect v1 images, random configurations, two views."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")
pytest.importorskip("mujoco")
pytest.importorskip("trimesh")

from _meshtruth import MeshRobotTruth, distance_to_robot  # noqa: E402
from depthguard.camera import Camera, look_at  # noqa: E402
from depthguard.robot.robots import load_robot, robot_urdf  # noqa: E402
from depthguard.robot.selffilter import self_filter  # noqa: E402
from depthguard.robot.shapes import Shape  # noqa: E402

MARGIN = 0.03
ENV = (
    '<geom type="plane" size="5 5 0.1" pos="0 0 0" group="0"/>',
    '<geom type="box" size="0.05 3 2" pos="-1.3 0 1" group="0"/>',
)
VIEWS = ((1.4, 0.5, 1.0), (0.3, -1.3, 1.4))
_MODELS: dict[str, object] = {}


def _model(name: str):
    if name not in _MODELS:
        _MODELS[name] = load_robot(name)
    return _MODELS[name]


def _camera(eye) -> Camera:
    R, t = look_at(np.asarray(eye, float), np.array([0.0, 0.0, 0.4]))
    return Camera.kinect_v1(R, t, min_depth=0.3)


def _random_q(model, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(np.maximum(model.q_min, -2.5), np.minimum(model.q_max, 2.5))


def _check_view(name: str, model, q: np.ndarray, truth: MeshRobotTruth, eye) -> dict:
    cam = _camera(eye)
    measured = truth.depth(cam)
    robot_only = truth.robot_depth(cam)
    robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
    res = self_filter(cam, measured, q, model, margin=MARGIN)
    left = int(np.sum(robot_vis & ~res.mask))
    bg = res.mask & np.isfinite(measured) & ~robot_vis
    d = distance_to_robot(str(robot_urdf(name)), q, cam.unproject_image(measured)[bg])
    return {
        "robot": int(robot_vis.sum()),
        "left": left,
        "bg_removed": int(bg.sum()),
        "bg_beyond_margin": int(np.sum(d > MARGIN + 1e-6)),
        "bg_max_distance": float(d.max(initial=0.0)),
    }


def _assert_targets(r: dict) -> None:
    assert r["robot"] > 2000, r
    assert r["left"] <= 0.01 * r["robot"], r  # issue 10: <= 1 % of the robot's pixels left
    # removed background lies within the margin of the robot (coal distance to the URDF's meshes)
    assert r["bg_beyond_margin"] == 0 and r["bg_max_distance"] <= MARGIN + 1e-6, r


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_robot_pixels_removed_and_background_kept(name: str) -> None:
    model = _model(name)
    q = _random_q(model, 7)
    truth = MeshRobotTruth(str(robot_urdf(name)), q, ENV)
    for eye in VIEWS:
        r = _check_view(name, model, q, truth, eye)
        print(name, eye, r)
        _assert_targets(r)


def test_dense_meshes_meet_the_targets(tmp_path) -> None:
    """The Panda with each mesh triangle cut into four (the benchmark's ~10k-triangle case,
    ``bench.selffilter_meshes.dense_urdf``): the same surface, the same targets against the truth of the
    original meshes. Its meshes are convex, so each is drawn as its hull's rounded offset; the cut
    triangles' new vertices lie on the hull's facets to rounding, and some count as hull vertices, so the
    filter draws more triangles than for the original meshes (about 10k in all)."""
    from depthguard.bench.selffilter_meshes import dense_urdf
    from depthguard.robot.model import RobotModel
    from depthguard.robot.robots import ROBOTS

    dense = RobotModel.from_urdf(dense_urdf(robot_urdf("panda"), tmp_path), ee_frame=ROBOTS["panda"][1])

    def mesh_triangles(model) -> int:  # the meshes' triangles (the fingers' boxes are not meshes)
        g = model.geometry
        kinds = [x.shape.kind for x in g.geoms if x.is_mesh]
        return int(sum(b - a for (a, b), k in zip(g.fr, kinds, strict=True) if k == "mesh"))

    n0, n1 = mesh_triangles(_model("panda")), mesh_triangles(dense)
    assert n1 > 1.5 * n0 and dense.geometry.n_triangles > 10_000, (n0, n1, dense.geometry.n_triangles)
    q = _random_q(dense, 7)
    truth = MeshRobotTruth(str(robot_urdf("panda")), q, ENV)
    _assert_targets(_check_view("panda", dense, q, truth, VIEWS[0]))


@pytest.mark.slow
def test_decimated_dense_meshes_remove_nothing_beyond_the_margin(tmp_path) -> None:
    """``max_triangles`` (the load-time decimation of the benchmark's ``panda_x4_decimated``): the decimated
    meshes are inflated by ``margin - excess`` (at least ``slack``), so against the *original* meshes'
    truth nothing farther than the margin goes and the robot still does."""
    from depthguard.bench.selffilter_meshes import DECIMATE_TO, dense_urdf
    from depthguard.robot.model import RobotModel
    from depthguard.robot.robots import ROBOTS

    urdf = dense_urdf(robot_urdf("panda"), tmp_path)
    model = RobotModel.from_urdf(urdf, ee_frame=ROBOTS["panda"][1], max_triangles=DECIMATE_TO)
    g = model.geometry
    assert np.all(g.excess[g.slack > 0] > 0) and g.slack.max() < MARGIN / 2, (g.slack, g.excess)
    q = _random_q(model, 7)
    truth = MeshRobotTruth(str(robot_urdf("panda")), q, ENV)
    for eye in VIEWS:
        _assert_targets(_check_view("panda", model, q, truth, eye))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["panda", "ur5", "xarm7"])
@pytest.mark.parametrize("seed", [11, 12])
def test_random_configurations_slow(name: str, seed: int) -> None:
    model = _model(name)
    q = _random_q(model, seed)
    truth = MeshRobotTruth(str(robot_urdf(name)), q, ENV)
    for eye in VIEWS:
        _assert_targets(_check_view(name, model, q, truth, eye))


def test_holes_beside_a_mesh_robot_are_not_robot() -> None:
    """Issue 8 on a mesh robot: missing pixels inside the inflated silhouette are robot, beside it not."""
    model = _model("panda")
    q = _random_q(model, 7)
    truth = MeshRobotTruth(str(robot_urdf("panda")), q, ENV)
    cam = _camera(VIEWS[0])
    measured = truth.depth(cam)
    silhouette = np.isfinite(truth.robot_depth(cam))
    inflated = np.isfinite(self_filter(cam, np.zeros(cam.shape), q, model, margin=MARGIN).robot_depth)
    assert np.all(inflated[silhouette])
    m = measured.copy()
    m[silhouette] = np.nan
    outside = ~inflated
    holes_out = outside & (np.random.default_rng(0).uniform(size=m.shape) < 0.3)
    m[holes_out] = 0.0
    res = self_filter(cam, m, q, model, margin=MARGIN)
    assert np.all(res.mask[silhouette])
    assert not np.any(res.mask[holes_out])


def test_attached_tool_is_removed() -> None:
    """A box payload on the Panda's hand: filtered once attached, obstacle pixels before."""
    model = load_robot("panda")
    q = _random_q(model, 3)
    tool = Shape(link="panda_hand", kind="box", size=(0.06, 0.16, 0.10), xyz=(0.0, 0.0, 0.16), name="payload")
    pin_truth = MeshRobotTruth(str(robot_urdf("panda")), q, ENV)
    M = pin_truth.frames["panda_hand"]
    R = np.asarray(M.rotation)
    p = R @ np.array(tool.xyz) + np.asarray(M.translation)
    truth = MeshRobotTruth(str(robot_urdf("panda")), q, ENV, attach=(('type="box" size="0.03 0.08 0.05"', R, p),))
    cam = _camera(VIEWS[0])
    measured, robot_only = truth.depth(cam), truth.robot_depth(cam)
    robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
    before = self_filter(cam, measured, q, model, margin=MARGIN)
    model.attach(tool)
    after = self_filter(cam, measured, q, model, margin=MARGIN)
    assert np.sum(robot_vis & ~before.mask) > 200  # the payload reads as an obstacle without the attachment
    assert np.sum(robot_vis & ~after.mask) <= 0.01 * robot_vis.sum()
    with pytest.raises(ValueError, match="frame 'nope'"):
        model.attach(Shape(link="nope", kind="sphere", size=(0.1,)))
    with pytest.raises(ValueError, match="kind"):
        Shape(link="panda_hand", kind="cone", size=(0.1,))


def test_default_model_is_per_thread() -> None:
    """The shared default model (a RobotModel is not thread-safe) is one per thread: parallel calls agree."""
    from concurrent.futures import ThreadPoolExecutor

    from depthguard.robot.model import load_lwr4

    lwr = load_lwr4()
    cam = _camera(VIEWS[0])
    rng = np.random.default_rng(0)
    qs = [rng.uniform(lwr.q_min, lwr.q_max) * 0.7 for _ in range(8)]
    depth = np.full(cam.shape, 2.5)
    ref = [self_filter(cam, depth, q, lwr).mask for q in qs]
    with ThreadPoolExecutor(4) as ex:
        got = list(ex.map(lambda q: self_filter(cam, depth, q).mask, qs * 3))
    assert all(np.array_equal(g, ref[i % len(qs)]) for i, g in enumerate(got))


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    dist=st.floats(0.05, 3.0),
    junk=st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-9, 1e9]),
)
def test_property_never_raises_and_masks_only_inside_the_silhouette(seed: int, dist: float, junk: float) -> None:
    """Any configuration, camera distance (down to 5 cm: triangles cross the near plane) and junk depth:
    no exception; robot pixels only inside the inflated silhouette, measured ones at or behind its near side."""
    model = _model("panda")
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.q_min, model.q_max)
    target = model.frame_pose(q, "panda_link4")[1]
    eye = target + dist * rng.normal(size=3) / np.sqrt(3)
    R, t = look_at(eye, target + 1e-3 * rng.normal(size=3))
    cam = Camera(width=80, height=60, fx=70.0, fy=70.0, cx=40.0, cy=30.0, R=R, t=t, min_depth=0.01, max_depth=10.0)
    depth = rng.uniform(0.0, 3.0, cam.shape)
    depth[rng.uniform(size=cam.shape) < 0.3] = junk
    res = self_filter(cam, depth, q, model, margin=MARGIN)
    inside = np.isfinite(res.robot_depth)
    assert not np.any(res.mask & ~inside)
    measured = np.isfinite(depth) & (depth > 0)
    assert np.all(res.robot_depth[res.mask & measured] <= depth[res.mask & measured] + 1e-9)
    assert np.all(res.robot_depth[inside] >= 0.0)


def test_bad_inputs_raise_clear_errors() -> None:
    model = _model("panda")
    cam = _camera(VIEWS[0])
    with pytest.raises(ValueError, match="q"):
        self_filter(cam, np.zeros(cam.shape), np.zeros(7), model)  # the Panda's q has 9 entries
    with pytest.raises(ValueError, match="q"):
        self_filter(cam, np.zeros(cam.shape), np.full(9, np.nan), model)
    with pytest.raises(ValueError, match="margin"):
        self_filter(cam, np.zeros(cam.shape), np.zeros(9), model, margin=np.inf)
    with pytest.raises(ValueError, match="cannot resolve"):
        from depthguard.robot.shapes import resolve_mesh_path

        resolve_mesh_path("package://no_such_pkg/meshes/x.stl", robot_urdf("panda"))
