"""Self-filter against exact ground truth (analytic scenes): robot pixels left in, obstacle pixels removed."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")

from depthguard.camera import Camera, look_at  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402
from depthguard.robot.selffilter import (  # noqa: E402
    render_capsules_depth,
    self_filter,
    self_filter_capsules,
    self_filter_tasks,
)
from depthguard.scene import Capsule, HalfSpace, Scene, Sphere, render_depth  # noqa: E402

Q = np.array([0.3, 0.6, 0.0, -1.3, 0.2, 0.9, 0.0])
MARGIN = 0.03
# the LWR's base is a URDF cylinder (the scenes here draw it as its bounding capsule); the filter draws it as
# a 24-gon prism around the circle; inflated, its corners stand out by (r + margin) (1 / cos(pi / 24) - 1)
TOL = (0.075 + MARGIN) * (1.0 / np.cos(np.pi / 24) - 1.0) + 1e-9


@pytest.fixture(scope="module")
def lwr():
    return load_lwr4()


def _camera(eye=(1.6, 0.4, 1.2), target=(0.0, 0.0, 0.6)) -> Camera:
    R, t = look_at(np.array(eye), np.array(target))
    return Camera.kinect_v1(R, t, min_depth=0.3)


def _robot_scene(lwr, q) -> tuple[Capsule, ...]:
    a, b, r = lwr.link_capsules(q)
    return tuple(Capsule(a[k], b[k], r[k]) for k in range(len(r)))


def _wall_and_floor() -> tuple:
    return (
        HalfSpace(np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
        HalfSpace(np.zeros(3), np.array([0, 0, 1.0])),
    )


def _hand_next_to_forearm(lwr, q, clearance: float, cam: Camera) -> Sphere:
    """A 5 cm ball ``clearance`` from the forearm surface, on the camera side and a bit to its left."""
    a, b, r = lwr.link_capsules(q)
    k = [c.link for c in lwr.capsules].index("lwr_link_4")
    mid = 0.5 * (a[k] + b[k])
    axis = (b[k] - a[k]) / np.linalg.norm(b[k] - a[k])
    to_cam = cam.position - mid
    side = to_cam - (to_cam @ axis) * axis
    side /= np.linalg.norm(side)
    lateral = np.cross(axis, side)
    u = (side + lateral) / np.linalg.norm(side + lateral)
    return Sphere(mid + u * (r[k] + clearance + 0.05), 0.05)


def _counts(measured, robot_only, hand_only, mask):
    """(robot pixels left in, hand pixels removed, background pixels removed, robot pixels visible)."""
    robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
    hand_vis = np.isfinite(hand_only) & (np.abs(measured - hand_only) < 1e-9) & ~robot_vis
    other = np.isfinite(measured) & ~robot_vis & ~hand_vis
    return int(np.sum(robot_vis & ~mask)), int(np.sum(hand_vis & mask)), other & mask, int(robot_vis.sum())


@pytest.mark.parametrize("seed", range(3))
def test_render_matches_exact_ray_casting(lwr, seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = rng.uniform(lwr.q_min, lwr.q_max) * 0.7
    cam = _camera(eye=(1.5 * np.cos(seed), 1.5 * np.sin(seed), 1.0 + 0.3 * seed))
    a, b, r = lwr.link_capsules(q)
    ours = render_capsules_depth(cam, a, b, r)
    truth = render_depth(cam, Scene(_robot_scene(lwr, q)), max_range=np.inf)
    assert np.array_equal(np.isfinite(ours), np.isfinite(truth))
    assert np.nanmax(np.abs(ours - truth)) < 1e-9


@pytest.mark.parametrize("clearance", [0.05, 0.10])
def test_hand_next_to_forearm_and_wall(lwr, clearance: float) -> None:
    cam = _camera()
    robot = _robot_scene(lwr, Q)
    hand = _hand_next_to_forearm(lwr, Q, clearance, cam)
    measured = render_depth(cam, Scene(robot + (hand,) + _wall_and_floor()))
    robot_only = render_depth(cam, Scene(robot))
    hand_only = render_depth(cam, Scene((hand,)))
    res = self_filter(cam, measured, Q, lwr, margin=MARGIN)
    left, hand_removed, bg_removed, n_robot = _counts(measured, robot_only, hand_only, res.mask)
    assert n_robot > 2000 and np.isfinite(hand_only).sum() > 500
    assert left == 0
    assert hand_removed == 0
    # background (wall, floor) removed only within the margin of the robot: where the base meets the floor
    pts = cam.unproject_image(measured)
    assert np.all(Scene(robot).distance(pts[bg_removed]) <= MARGIN + TOL)


def test_hand_within_the_margin_is_removed_only_where_it_is_that_close(lwr) -> None:
    cam = _camera()
    robot = _robot_scene(lwr, Q)
    hand = _hand_next_to_forearm(lwr, Q, 0.01, cam)
    measured = render_depth(cam, Scene(robot + (hand,) + _wall_and_floor()))
    res = self_filter(cam, measured, Q, lwr, margin=MARGIN)
    pts = cam.unproject_image(measured)
    removed = res.mask & np.isfinite(measured)
    assert np.all(Scene(robot).distance(pts[removed]) <= MARGIN + TOL)  # the documented limit, no more


def test_latency_within_the_margin_leaves_no_robot_pixels(lwr) -> None:
    cam = _camera()
    q_true = Q + np.array([0.01, -0.01, 0.01, 0.01, 0.0, 0.01, 0.0])  # < 3 cm motion at 1.2 m reach
    a0, _, _ = lwr.link_capsules(Q)
    a1, _, _ = lwr.link_capsules(q_true)
    assert np.max(np.linalg.norm(a1 - a0, axis=1)) < MARGIN
    robot = _robot_scene(lwr, q_true)
    measured = render_depth(cam, Scene(robot + _wall_and_floor()))
    robot_only = render_depth(cam, Scene(robot))
    res = self_filter(cam, measured, Q, lwr, margin=MARGIN)  # the filter sees the old joint state
    left, _, _, n_robot = _counts(measured, robot_only, np.full(cam.shape, np.nan), res.mask)
    assert n_robot > 2000 and left == 0


def _ring(mask: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Pixels at Chebyshev distance lo..hi (pixels) from ``mask``."""
    grown = [mask]
    for _ in range(hi):
        g = grown[-1].copy()
        g[1:] |= grown[-1][:-1]
        g[:-1] |= grown[-1][1:]
        g[:, 1:] |= g[:, :-1].copy()
        g[:, :-1] |= g[:, 1:].copy()
        grown.append(g)
    return grown[hi] & ~grown[lo - 1]


def test_missing_depth_inside_the_inflated_silhouette_is_robot_and_beside_it_is_not(lwr) -> None:
    """Issue 8: a hole beside the robot is unknown space, not robot (the old pad made it robot, i.e. free)."""
    cam = _camera()
    robot = _robot_scene(lwr, Q)
    measured = render_depth(cam, Scene(robot + _wall_and_floor()))
    sil = np.isfinite(render_depth(cam, Scene(robot)))
    a, b, r = lwr.link_capsules(Q)
    inflated = np.isfinite(render_capsules_depth(cam, a, b, r + MARGIN))  # exact silhouette + margin
    # the links' capsules are the filter's own geometry; the base's is a stand-in for its cylinder (larger
    # than it), so its rim is left out of the band: rays there pass more than the margin from the cylinder
    k = slice(1, None) if lwr.capsules[0].link == "lwr_link_0" else slice(None)
    links = np.isfinite(render_capsules_depth(cam, a[k], b[k], r[k] + MARGIN))
    rng = np.random.default_rng(0)
    holes = sil & (rng.uniform(size=sil.shape) < 0.2)
    band = _ring(sil, 1, 2) & links  # a real camera's missing edges, within the margin's silhouette
    beside = _ring(inflated, 2, 4)  # just outside the inflated silhouette (beyond the prism's sub-pixel corners)
    m = measured.copy()
    m[holes] = np.nan
    m[band] = 0.0  # the 0 = no reading convention
    m[beside] = np.nan
    res = self_filter(cam, m, Q, lwr, margin=MARGIN)
    assert holes.sum() > 500 and band.sum() > 300 and beside.sum() > 1000
    assert np.all(res.mask[holes]) and np.all(res.mask[band])
    assert np.all(np.isfinite(res.robot_depth[holes | band]))
    assert not np.any(res.mask[beside])


def test_pad_px_is_deprecated_and_has_no_effect(lwr) -> None:
    cam = _camera()
    m = render_depth(cam, Scene(_robot_scene(lwr, Q) + _wall_and_floor()))
    m[::7, ::5] = np.nan
    ref = self_filter(cam, m, Q, lwr, margin=MARGIN)
    with pytest.warns(DeprecationWarning, match="pad_px"):
        res = self_filter(cam, m, Q, lwr, margin=MARGIN, pad_px=3)
    assert np.array_equal(res.mask, ref.mask)


def test_background_seen_past_a_robot_that_moved_is_kept(lwr) -> None:
    cam = _camera()
    q_now = Q + np.array([0.0, -0.4, 0.0, 0.5, 0.0, 0.0, 0.0])  # arm moved far away from Q
    measured = render_depth(cam, Scene(_robot_scene(lwr, q_now) + _wall_and_floor()))
    res = self_filter(cam, measured, Q, lwr, margin=MARGIN)
    wall_only = render_depth(cam, Scene(_wall_and_floor()))
    stale_sil = np.isfinite(render_depth(cam, Scene(_robot_scene(lwr, Q))))
    sees_wall = stale_sil & (np.abs(measured - wall_only) < 1e-9)
    # (floor points within the margin of the base, which did not move, are robot by definition)
    far = Scene(_robot_scene(lwr, Q)).distance(cam.unproject_image(measured)[sees_wall]) > MARGIN
    assert far.sum() > 50 and not np.any(res.mask[sees_wall][far])


def test_robot_depth_is_never_behind_the_robot(lwr) -> None:
    cam = _camera()
    a, b, r = lwr.link_capsules(Q)
    exact = render_capsules_depth(cam, a, b, r)
    res = self_filter_capsules(cam, np.full(cam.shape, np.nan), a, b, r, margin=MARGIN)
    hit = np.isfinite(exact)
    assert np.all(res.robot_depth[hit] <= exact[hit] + 1e-12)
    assert np.all(res.mask[hit])


def test_bad_inputs_raise_clear_errors(lwr) -> None:
    cam = _camera()
    with pytest.raises(ValueError, match="depth image has shape"):
        self_filter(cam, np.zeros((10, 10)), Q, lwr)
    with pytest.raises(ValueError, match="margin"):
        self_filter(cam, np.zeros(cam.shape), Q, lwr, margin=-1.0)
    with pytest.raises(ValueError, match="pad_px"):
        self_filter(cam, np.zeros(cam.shape), Q, lwr, pad_px=1.5)
    with pytest.raises(ValueError, match="q"):
        self_filter(cam, np.zeros(cam.shape), Q[:3], lwr)


def test_default_model_is_the_shipped_lwr(lwr) -> None:
    cam = _camera()
    measured = render_depth(cam, Scene(_robot_scene(lwr, Q) + _wall_and_floor()))
    mask, robot_depth = self_filter(cam, measured, Q)  # (camera, depth, q) as the simulator calls it
    ref = self_filter(cam, measured, Q, lwr)
    assert np.array_equal(mask, ref.mask) and np.array_equal(robot_depth, ref.robot_depth, equal_nan=True)


@pytest.mark.slow
@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_property_no_robot_left_and_nothing_removed_beyond_the_margin(seed: int) -> None:
    lwr = load_lwr4()
    rng = np.random.default_rng(seed)
    q = rng.uniform(lwr.q_min, lwr.q_max) * 0.8
    ang = rng.uniform(-0.45 * np.pi, 0.45 * np.pi)  # in front of the wall at x = -1
    eye = np.array([1.8 * np.cos(ang), 1.8 * np.sin(ang), rng.uniform(0.8, 1.8)])
    R, t = look_at(eye, np.array([0.0, 0.0, 0.6]))
    cam = Camera(width=160, height=120, fx=130.0, fy=130.0, cx=79.5, cy=59.5, R=R, t=t, min_depth=0.3)
    robot = _robot_scene(lwr, q)
    blobs = tuple(Sphere(rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.4]), rng.uniform(0.03, 0.15)) for _ in range(4))
    measured = render_depth(cam, Scene(robot + blobs + _wall_and_floor()))
    robot_only = render_depth(cam, Scene(robot))
    res = self_filter(cam, measured, q, lwr, margin=MARGIN)
    robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
    assert not np.any(robot_vis & ~res.mask)  # no robot pixel left in
    removed = res.mask & np.isfinite(measured) & (measured > 0)
    pts = cam.unproject_image(measured)[removed]
    assert np.all(Scene(robot).distance(pts) <= MARGIN + TOL)  # nothing removed beyond the margin


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), margin=st.floats(0.0, 0.08), holes=st.floats(0.0, 0.3))
def test_the_mask_alone_is_the_same_mask(seed: int, margin: float, holes: float) -> None:
    """``with_depth=False`` tests measured pixels as points against the capsules instead of intersecting
    their rays: the mask must be the same, pixel for pixel, with noisy depths that straddle the inflated
    surfaces, holes inside and beside the silhouette, and the camera close to the robot."""
    lwr = load_lwr4()
    rng = np.random.default_rng(seed)
    q = rng.uniform(lwr.q_min, lwr.q_max) * 0.8
    ang = rng.uniform(-np.pi, np.pi)
    dist = rng.uniform(0.6, 2.0)
    eye = np.array([dist * np.cos(ang), dist * np.sin(ang), rng.uniform(0.3, 1.8)])
    R, t = look_at(eye, np.array([0.0, 0.0, rng.uniform(0.2, 0.9)]))
    cam = Camera(width=160, height=120, fx=130.0, fy=130.0, cx=79.5, cy=59.5, R=R, t=t, min_depth=0.1)
    robot = _robot_scene(lwr, q)
    assume(np.isfinite(render_depth(cam, Scene(robot))).any())  # (seed 9460626: the arm out of the view)
    measured = render_depth(cam, Scene(robot + _wall_and_floor()))
    measured = measured * (1.0 + rng.normal(0.0, 0.03, measured.shape))  # points on both sides of the margin
    measured[rng.random(measured.shape) < holes] = np.nan
    full = self_filter(cam, measured, q, lwr, margin=margin)
    fast = self_filter(cam, measured, q, lwr, margin=margin, with_depth=False)
    assert fast.robot_depth is None
    assert full.mask.any()
    assert np.array_equal(full.mask, fast.mask)


def test_tasks_on_threads_give_each_camera_s_own_filter(lwr) -> None:
    from concurrent.futures import ThreadPoolExecutor

    cams = [_camera(), _camera(eye=(-0.4, 1.7, 1.0)), _camera(eye=(1.2, -1.2, 0.5))]
    depths = [render_depth(c, Scene(_robot_scene(lwr, Q) + _wall_and_floor())) for c in cams]
    with ThreadPoolExecutor(2) as pool:
        got = [f.result() for f in [pool.submit(task) for task in self_filter_tasks(cams, depths, Q, lwr)]]
    for c, d, g in zip(cams, depths, got, strict=True):
        ref = self_filter(c, d, Q, lwr)
        assert np.array_equal(g.mask, ref.mask) and np.array_equal(g.robot_depth, ref.robot_depth, equal_nan=True)
    with pytest.raises(ValueError, match="2 cameras but 1 depth images"):
        self_filter_tasks(cams[:2], depths[:1], Q, lwr)
