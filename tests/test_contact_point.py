"""Contact point from depth (SAPHARI §6.2, Algorithm 1): the tessellated surface, the nearest vertex
(vectorised = literal loop), the hand from a simulated Kinect frame, against MuJoCo's true contact."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from depthguard.robot.contact_point import (
    RobotSurface,
    contact_from_hand,
    foreground_mask,
    image_box,
    locate_hands,
    nearest_vertex,
    nearest_vertex_loop,
)
from depthguard.robot.model import load_lwr4

Q0 = np.array([0.0, -1.1, 0.0, 1.5, 0.0, -0.9, 0.0])


@pytest.fixture(scope="module")
def robot():
    return load_lwr4()


@pytest.fixture(scope="module")
def surface(robot):
    return RobotSurface(robot, spacing=0.01)


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-300), 0, 1)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def test_vertices_lie_on_the_capsule_surfaces_and_cover_them(robot, surface):
    V, S = surface.pose(Q0)
    a, b, r = robot.link_capsules(Q0)
    names = [c.link for c in robot.capsules]
    for k, link in enumerate(surface.link_names):
        vk = V[surface.link == k]
        caps = [i for i, n in enumerate(names) if n == link]
        d = np.min([np.abs(_segment_distance(vk, a[i], b[i]) - r[i]) for i in caps], axis=0)
        assert d.max() < 1e-9  # on the surface
    # covering: random surface points have a vertex within the spacing
    rng = np.random.default_rng(0)
    for i in range(len(a)):
        ax = b[i] - a[i]
        if np.linalg.norm(ax) < 1e-9:
            continue
        n = np.cross(ax, [1.0, 0.0, 0.0])
        n /= np.linalg.norm(n)
        m = np.cross(ax / np.linalg.norm(ax), n)
        for _ in range(20):
            phi, s = rng.uniform(0, 2 * np.pi), rng.uniform(0, 1)
            p = a[i] + s * ax + r[i] * (np.cos(phi) * n + np.sin(phi) * m)
            assert nearest_vertex(V, p)[1] < surface.spacing


def test_vertices_move_with_forward_kinematics(robot, surface):
    q1 = Q0 + 0.3
    V1, _ = surface.pose(q1)
    R, p = robot.joint_poses(q1)
    i = surface.n_vertices // 2
    j = surface.joint[i]
    np.testing.assert_allclose(V1[i], R[j] @ surface.local[i] + p[j], atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(arrays(float, (3,), elements=st.floats(-1.5, 1.5)))
def test_vectorised_nearest_vertex_equals_algorithm_1_loop(surface, p_h):
    V, _ = surface.pose(Q0)
    per_link = [V[surface.link == k] for k in range(len(surface.link_names))]
    i, d = nearest_vertex(V, p_h)
    p_c, link, d_loop = nearest_vertex_loop(per_link, p_h)
    assert d == pytest.approx(d_loop, abs=1e-12)
    assert surface.link_names[surface.link[i]] == surface.link_names[link] or d == pytest.approx(d_loop)


def _foreground_numpy(depth, bg, robot_mask, margin, erode, box):
    """foreground_mask's definition, in numpy (what the compiled pass must reproduce)."""
    H, W = depth.shape
    u0, u1, v0, v1 = box or (0, W, 0, H)
    win = (slice(v0, v1), slice(u0, u1))
    d, b = depth[win].astype(np.float32), bg[win].astype(np.float32)
    m = margin[win] if np.ndim(margin) == 2 else margin
    with np.errstate(invalid="ignore"):
        fg = np.isfinite(d) & (d > 0) & (d < np.where(np.isfinite(b) & (b > 0), b, np.inf) - m) & ~robot_mask[win]
    if erode:  # 4-neighbour erosion by scipy, an independent implementation (the image border erodes nothing)
        from scipy.ndimage import binary_erosion, generate_binary_structure

        fg = binary_erosion(fg, generate_binary_structure(2, 1), border_value=1)
    out = np.zeros((H, W), bool)
    out[win] = fg
    return out


def test_compiled_foreground_mask_equals_its_numpy_definition():
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.5, 3.0, (60, 80)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    depth[rng.random(depth.shape) < 0.05] = 0.0
    bg = (depth + rng.uniform(-0.1, 0.3, depth.shape)).astype(np.float32)
    bg[rng.random(depth.shape) < 0.1] = np.nan
    robot_mask = rng.random(depth.shape) < 0.1
    margin = rng.uniform(0.0, 0.2, depth.shape)
    for m in (margin, margin.astype(np.float32), 0.05, np.float64(0.05), 0):
        for box in (None, (5, 70, 3, 50), (0, 1, 0, 60)):
            for erode in (True, False):
                np.testing.assert_array_equal(
                    foreground_mask(depth, bg, robot_mask, m, erode=erode, box=box),
                    _foreground_numpy(depth, bg, robot_mask, m, erode, box),
                )


def test_bad_spacing_raises(robot):
    with pytest.raises(ValueError, match="spacing"):
        RobotSurface(robot, spacing=0.0)


mujoco = pytest.importorskip("mujoco")


@pytest.mark.parametrize(
    ("link", "direction"),
    [("lwr_link_6", (0.0, 1.0, 0.0)), ("lwr_link_3", (0.0, 0.0, -1.0)), ("lwr_link_4", (0.0, 1.0, 0.0))],
)
def test_contact_point_from_a_kinect_frame_matches_the_simulator(robot, surface, link, direction):
    """A hand pressed on a link, seen by the simulated Kinect 2.8 m behind the robot: the contact point
    (Algorithm 1 on the tracked hand) is within 3 cm of MuJoCo's contact point, on the right link."""
    from depthguard.robot.selffilter import self_filter
    from depthguard.sim.contact_cell import ContactCell, HandScript
    from depthguard.sim.contact_experiment import CAMERA_EYE, CAMERA_TARGET, _background
    from depthguard.sim.depthcam import KinectSim, kinect_camera

    cam = kinect_camera(CAMERA_EYE, CAMERA_TARGET)
    hand = HandScript("hand0", link, 0.5, direction, 15.0, t_touch=0.2, duration=1.0, approach=0.05, v_approach=0.25)
    cell = ContactCell([hand], cam, Q0)
    sim = KinectSim(cell.model, cam, seed=3)
    bg = _background(cell, sim)
    for _ in range(40):
        cell.step(np.zeros(7), 10)
    f, p_true, l_true = cell.contacts()[0]
    assert np.linalg.norm(f) > 5.0 and l_true == link
    q = cell.q()
    depth = sim.capture(cell.data)
    fg = foreground_mask(depth, bg, self_filter(cam, depth, q, robot).mask, 0.05)
    V, S = surface.pose(q)
    hands = locate_hands(cam, depth, fg, S, surface.axis_radii, 1)
    assert len(hands) == 1
    cp = contact_from_hand(surface, q, V, hands[0].position)
    assert np.linalg.norm(cp.position - p_true) < 0.03
    assert cp.link == link


def test_no_hand_no_contact(robot, surface):
    from depthguard.sim.depthcam import kinect_camera

    cam = kinect_camera((-2.8, 0, 1.6), (0.3, 0, 0.45))
    depth = np.full(cam.shape, 4.0, np.float32)
    fg = foreground_mask(depth, depth, np.zeros(cam.shape, bool), 0.05)
    V, S = surface.pose(Q0)
    assert locate_hands(cam, depth, fg, S, surface.axis_radii, 2) == []


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_image_box_holds_the_whole_image_of_every_sphere(seed):
    """Points on the spheres' surfaces, far off the optical axis included (where ``px -+ f r / (z - r)`` was
    too small: 1.43 against 1.56 in x/z at 45 deg, 1 m, r = 0.3 m), project inside the box."""
    from depthguard.camera import Camera

    rng = np.random.default_rng(seed)
    # a wide lens (about +-58 deg by +-50 deg), where the off-axis error is large
    cam = Camera(width=640, height=480, fx=200.0, fy=200.0, cx=319.5, cy=239.5, R=np.eye(3), t=np.zeros(3))
    n = int(rng.integers(1, 4))
    z = rng.uniform(0.6, 3.0, n)
    ang = rng.uniform(-0.9, 0.9, (n, 2))
    centres = np.column_stack([np.tan(ang[:, 0]) * z, np.tan(ang[:, 1]) * z, z])
    reach = rng.uniform(0.0, 0.9, n) * (z - 0.01)
    box = image_box(cam, centres, reach)
    d = rng.normal(size=(n, 4000, 3))
    pts = centres[:, None] + d / np.linalg.norm(d, axis=-1, keepdims=True) * reach[:, None, None]
    pts = pts.reshape(-1, 3)
    u = cam.fx * pts[:, 0] / pts[:, 2] + cam.cx
    v = cam.fy * pts[:, 1] / pts[:, 2] + cam.cy
    seen = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    if not seen.any():
        return
    assert box is not None
    u0, u1, v0, v1 = box
    assert np.all((np.floor(u[seen]) >= u0) & (np.floor(u[seen]) < u1))
    assert np.all((np.floor(v[seen]) >= v0) & (np.floor(v[seen]) < v1))


def test_image_box_of_the_reported_off_axis_sphere():
    from depthguard.camera import Camera

    cam = Camera(width=4000, height=4000, fx=1000.0, fy=1000.0, cx=2000.0, cy=2000.0, R=np.eye(3), t=np.zeros(3))
    c = np.array([[np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)]])  # 45 deg off axis, 1 m away
    u0, u1, _, _ = image_box(cam, c, 0.3)
    # the tangent through the optical centre: angle 45 deg + asin(0.3), x/z = tan of it
    assert u1 >= 1000.0 * np.tan(np.pi / 4 + np.arcsin(0.3)) + 2000.0
