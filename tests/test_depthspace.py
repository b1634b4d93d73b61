"""Single-camera depth-space distances against analytic geometry and the exact point-to-frustum distance."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthspace import lower_bound_slack, prepare_frame, query_distances
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth
from reference_geometry import depthspace_exact


def _camera(width=320, height=240, f=262.5, eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0), up=(0.0, -1.0, 0.0)):
    R, t = look_at(eye, target, up)
    return Camera(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2, R=R, t=t, max_depth=6.0)


WALL = HalfSpace(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]))  # z >= 4 is solid


def _footprint(cam, depth):
    return depth / min(cam.fx, cam.fy)


def test_visible_sphere_gives_true_distance_within_one_footprint():
    cam = _camera()
    sphere = Sphere(np.array([0.1, -0.05, 2.0]), 0.2)
    frame = prepare_frame(cam, render_depth(cam, Scene((sphere, WALL))))
    # points on the camera side of the sphere: the nearest surface point is visible
    dirs = np.array([[0, 0, -1], [0.3, 0, -1], [-0.3, 0.2, -1], [0, -0.4, -1]], dtype=float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for gap in (0.05, 0.15, 0.3):
        pts = sphere.center + dirs * (sphere.radius + gap)
        res = query_distances(frame, pts, 0.0, rho=0.4, mode="min")
        truth = Scene((sphere, WALL)).distance(pts)
        tol = _footprint(cam, 2.0) + lower_bound_slack(cam, 2.0, gap)
        assert np.all(res.distance <= truth + 1e-9), (res.distance, truth)
        assert np.all(res.distance >= truth - tol), (res.distance, truth, tol)
        # the nearest point lies on the sphere, the direction points from it to the control point
        assert np.allclose(np.linalg.norm(res.nearest - sphere.center, axis=1), sphere.radius, atol=3 * tol)
        assert np.all(np.einsum("ij,ij->i", res.direction, dirs) > 0.95)


def test_sphere_radius_is_subtracted():
    cam = _camera()
    frame = prepare_frame(cam, render_depth(cam, Scene((Sphere(np.array([0.0, 0.0, 2.0]), 0.2), WALL))))
    P = np.array([[0.0, 0.0, 1.5]])
    d0 = query_distances(frame, P, 0.0, mode="min").distance[0]
    d1 = query_distances(frame, P, 0.1, mode="min").distance[0]
    assert d0 - d1 == pytest.approx(0.1, abs=1e-9)
    assert d0 == pytest.approx(0.3, abs=0.005)


def test_occluded_point_is_at_most_true_distance_and_in_gray_area():
    cam = _camera()
    box = Box(np.array([0.0, 0.0, 1.5]), np.array([0.2, 0.2, 0.05]))
    scene = Scene((box, WALL))
    frame = prepare_frame(cam, render_depth(cam, scene))
    hidden = np.array([[0.0, 0.0, 2.0], [0.05, 0.05, 2.3], [0.1, -0.1, 1.8]])  # right behind the box
    res = query_distances(frame, hidden, 0.0, rho=0.4)
    assert np.all(res.distance <= scene.distance(hidden))
    assert np.all(res.distance < 0.01)  # inside the box's shadow: the gray area is an obstacle


@pytest.mark.parametrize("corner", [(-1, -1), (1, -1), (-1, 1), (1, 1)])
def test_nothing_missed_off_axis(corner):
    """Obstacles beside off-axis points (near the image corners) are found: the region covers the whole cube."""
    cam = _camera()
    half_x = cam.width / 2 / cam.fx * 2.0
    half_y = cam.height / 2 / cam.fy * 2.0
    P = np.array([corner[0] * 0.75 * half_x, corner[1] * 0.75 * half_y, 2.0])
    for offset in ([0.3, 0, 0], [-0.3, 0, 0], [0, 0.3, 0], [0, -0.3, 0], [0.2, 0.2, -0.1]):
        ball = Sphere(P + np.array(offset), 0.05)
        q = cam.project(ball.center)
        if not (0 <= q[0] < cam.width and 0 <= q[1] < cam.height):
            continue  # outside the field of view: nobody can see it (covered by the unseen-space test)
        scene = Scene((ball, WALL))
        frame = prepare_frame(cam, render_depth(cam, scene), invalid="ignore")
        res = query_distances(frame, P[None], 0.0, rho=0.4, mode="min")
        truth = scene.distance(P[None])[0]
        assert np.isfinite(res.distance[0]), f"obstacle at {offset} missed"
        assert res.distance[0] <= truth + 1e-9  # (the ball's shadow may come closer than the ball itself)


def test_modes_agree_on_distance_and_search_matches_exhaustive_reference():
    cam = _camera()
    scene = Scene(
        (
            Capsule(np.array([-0.3, -0.2, 2.0]), np.array([0.3, 0.1, 2.2]), 0.08),
            Sphere(np.array([0.25, 0.3, 1.6]), 0.1),
            Box(np.array([-0.4, 0.3, 2.5]), np.array([0.1, 0.2, 0.1])),
            WALL,
        )
    )
    depth = render_depth(cam, scene)
    frame = prepare_frame(cam, depth, invalid="ignore")
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.6, -0.5, 1.2], [0.6, 0.5, 2.8], size=(40, 3))
    radii = rng.uniform(0.0, 0.08, size=40)
    res = {m: query_distances(frame, pts, radii, rho=0.3, mode=m) for m in ("min", "all", "hybrid")}
    np.testing.assert_array_equal(res["min"].distance, res["all"].distance)
    np.testing.assert_array_equal(res["all"].distance, res["hybrid"].distance)
    np.testing.assert_array_equal(res["all"].obstacle_pixels, res["hybrid"].obstacle_pixels)
    assert np.all(res["min"].obstacle_pixels <= res["all"].obstacle_pixels)
    # against the exact distance to the pixel frusta behind the measured depths (an independent reference
    # written from the definition, tests/reference_geometry.py): a lower bound within the declared slack
    for i in range(len(pts)):
        Pc = cam.world_to_camera(pts[i])
        reff = 0.3 + radii[i]
        exact, per_pixel = depthspace_exact(cam, frame.obstacle_depth, Pc, reff + 0.05)
        slack = lower_bound_slack(cam, max(Pc[2], 0.0), min(exact, reff))
        d = res["min"].distance[i]
        if exact < reff:
            assert np.isfinite(d) and d <= max(exact - radii[i], 0.0) + 1e-9
        if np.isfinite(d) and d > 0:
            assert d + radii[i] >= exact - slack
        n = res["all"].obstacle_pixels[i]
        assert (per_pixel < reff).sum() <= n <= (per_pixel < reff + slack).sum()
    found = np.isfinite(res["all"].distance)
    assert np.allclose(np.linalg.norm(res["all"].direction[found], axis=1), 1.0)
    assert np.all(np.isnan(res["all"].direction[~found]))


def test_robot_mask_pixels_are_skipped():
    cam = _camera()
    robot = Sphere(np.array([0.0, 0.0, 2.0]), 0.15)
    depth = render_depth(cam, Scene((robot, WALL)))
    only_wall = render_depth(cam, Scene((WALL,)))
    mask = np.abs(depth - only_wall) > 1e-9
    P = np.array([[0.0, 0.0, 1.7]])
    assert query_distances(prepare_frame(cam, depth), P, 0.0).distance[0] < 0.2
    frame = prepare_frame(cam, depth, mask=mask)
    assert not np.isfinite(query_distances(frame, P, 0.0).distance[0])
    assert np.isfinite(frame.robot_depth[mask]).all() and np.isnan(frame.robot_depth[~mask]).all()


def test_missing_depth_policies():
    cam = _camera()
    scene = Scene((Box(np.array([0.0, 0.0, 2.0]), np.array([0.5, 0.5, 0.02])), WALL))
    depth = render_depth(cam, scene)
    P = np.array([[0.0, 0.0, 1.75]])  # 0.23 m in front of the plate
    truth = scene.distance(P)[0]
    small = depth.copy()
    small[118:122, 158:162] = np.nan  # a 4x4 hole right in front of P: filled with its neighbours' depth
    frame = prepare_frame(cam, small)
    assert frame.filled_pixels == 16 and frame.unknown_pixels == 0
    assert query_distances(frame, P, 0.0, mode="min").distance[0] == pytest.approx(truth, abs=0.01)
    big = depth.copy()
    big[100:140, 140:180] = np.nan  # too large to fill: the middle is unknown, an obstacle at the near limit
    frame = prepare_frame(cam, big)
    assert frame.unknown_pixels > 0
    assert query_distances(frame, P, 0.0, mode="min").distance[0] < 0.01  # P sits on an unknown ray
    ignored = prepare_frame(cam, big, invalid="ignore")
    assert query_distances(ignored, P, 0.0, mode="min").distance[0] > truth - 0.01  # the hole is free space


def test_unseen_space_outside_the_field_of_view_is_an_obstacle():
    cam = _camera()
    frame = prepare_frame(cam, render_depth(cam, Scene((WALL,))))
    edge_x = cam.width / 2 / cam.fx * 2.0  # the FOV's right border at depth 2
    P = np.array([[edge_x - 0.1, 0.0, 2.0]])
    d = query_distances(frame, P, 0.0, rho=0.4).distance[0]
    a1 = (cam.width - cam.cx) / cam.fx
    plane = (a1 * 2.0 - P[0, 0]) / math.sqrt(1 + a1 * a1)
    assert d == pytest.approx(plane, abs=1e-6)
    ignored = prepare_frame(cam, render_depth(cam, Scene((WALL,))), invalid="ignore")
    assert not np.isfinite(query_distances(ignored, P, 0.0, rho=0.4).distance[0])


def _random_scene(draw):
    prims = [WALL]
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["sphere", "box", "capsule"]))
        c = np.array([draw(st.floats(-0.8, 0.8)), draw(st.floats(-0.6, 0.6)), draw(st.floats(1.2, 3.2))])
        size = draw(st.floats(0.03, 0.3))
        if kind == "sphere":
            prims.append(Sphere(c, size))
        elif kind == "box":
            prims.append(Box(c, np.array([size, draw(st.floats(0.02, 0.3)), draw(st.floats(0.02, 0.3))])))
        else:
            e = np.array([draw(st.floats(-0.3, 0.3)) for _ in range(3)])
            prims.append(Capsule(c - e, c + e, size / 2))
    return Scene(tuple(prims))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_property_never_larger_than_truth_plus_tolerance(data):
    """Over random scenes, camera poses and points: reported <= true distance + declared tolerance."""
    yaw = data.draw(st.floats(-0.3, 0.3))
    eye = np.array([data.draw(st.floats(-0.3, 0.3)), data.draw(st.floats(-0.3, 0.3)), 0.0])
    cam = _camera(width=160, height=120, f=131.25, eye=eye, target=eye + [math.sin(yaw), 0.0, math.cos(yaw)])
    scene = _random_scene(data.draw)
    depth = render_depth(cam, scene)
    policy = data.draw(st.sampled_from(["conservative", "ignore"]))
    frame = prepare_frame(cam, depth, invalid=policy)
    pts = np.array(
        [
            [data.draw(st.floats(-0.8, 0.8)), data.draw(st.floats(-0.6, 0.6)), data.draw(st.floats(1.0, 3.5))]
            for _ in range(5)
        ]
    )
    radius = data.draw(st.floats(0.0, 0.1))
    mode = data.draw(st.sampled_from(["min", "all", "hybrid"]))
    res = query_distances(frame, pts, radius, rho=0.4, mode=mode)
    truth = scene.distance(pts) - radius
    # declared tolerance: one pixel footprint at the far end of the region (sampling through pixel centres)
    tol = np.array([_footprint(cam, p[2] + 0.5) for p in cam.world_to_camera(pts)])
    finite = np.isfinite(res.distance)
    # Both claims hold under the conservative policy only: with "ignore", space outside the field of view is
    # free by request, and obstacles there are missed, so a point near the edge of the view may be reported at
    # the distance of the visible part of an obstacle (fresh seeds: a point at y = -0.5 m, z = 1 m, out of
    # the view, 0.308 m reported against 0.296 m to the part of a sphere outside it)
    if policy == "conservative":
        assert np.all(res.distance[finite] <= np.maximum(truth[finite], 0.0) + tol[finite])
        # "nothing within rho" must be true: no obstacle closer than rho - tolerance
        assert np.all(truth[~finite] >= 0.4 - tol[~finite])


def test_literal_ral16_form_over_reports_off_axis_but_frustum_does_not():
    """Why the default is the frustum bound: beside a wall seen obliquely, eqs. 5-7 exceed the truth."""
    cam = _camera()
    # a slab whose side face is a plane through the camera centre, 25 degrees off axis
    ang = math.radians(25.0)
    n = np.array([math.cos(ang), 0.0, -math.sin(ang)])  # normal of the plane x cos - z sin = 0
    P = np.array([[math.tan(ang) * 2.0 - 0.25, 0.0, 2.0]])  # 0.25 m beside the plane (horizontally)
    truth = abs(P[0] @ n)
    depth = np.full(cam.shape, np.nan)
    cols = np.arange(cam.width) + 0.5
    right = (cols - cam.cx) / cam.fx > math.tan(ang)
    depth[:, right] = 1.0  # everything to the right of the plane is an obstacle surface at 1 m, shadow behind
    wall = np.where(np.isnan(depth), 4.0, depth)
    frame = prepare_frame(cam, wall, invalid="ignore")
    d = {m: query_distances(frame, P, 0.0, rho=0.4, mode="min", model=m).distance[0] for m in ("frustum", "ral16")}
    assert d["frustum"] <= truth + 1e-9
    assert d["ral16"] > truth + 0.01  # ~ 1/cos(25 deg): about 2.5 cm too far at 0.25 m


def test_to_world_rotates_and_masks_rows_as_the_frame_change_says():
    """The kernel rows (camera frame) become world-frame distances, directions and nearest points:
    ``V_W = R^T V_C``, ``x_W = R^T (x_C - t)``, the distance ``max(d - r, 0)`` where ``d < rho + r``, and
    inf / NaN / NaN for a row with nothing within reach (whatever garbage the row holds)."""
    from depthguard.depthspace import to_world

    rng = np.random.default_rng(5)
    R, t = look_at(np.array([1.5, -2.0, 1.2]), np.array([0.1, 0.3, 0.6]))
    cam = Camera(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0, R=R, t=t)
    n = 40
    raw = rng.normal(size=(n, 12))
    raw[:, 0] = rng.uniform(0.0, 0.8, n)
    raw[:, 7] = rng.integers(0, 500, n)
    raw[::7, 4:7] = np.nan  # nothing found: the kernel leaves NaN here
    raw[::7, 0] = np.inf
    radii = rng.uniform(0.0, 0.1, n)
    res = to_world(cam, raw, radii, 0.4)
    found = raw[:, 0] < 0.4 + radii
    assert 0 < found.sum() < n
    np.testing.assert_array_equal(res.distance[found], np.maximum(raw[found, 0] - radii[found], 0.0))
    assert np.all(np.isinf(res.distance[~found]))
    assert np.all(np.isnan(res.direction[~found])) and np.all(np.isnan(res.nearest[~found]))
    np.testing.assert_allclose(res.direction[found], raw[found, 1:4] @ R, rtol=0, atol=1e-14)
    np.testing.assert_allclose(res.nearest[found], (raw[found, 4:7] - t) @ R, rtol=0, atol=1e-14)
    back = cam.world_to_camera(res.nearest[found])  # an independent round trip through the camera
    np.testing.assert_allclose(back, raw[found, 4:7], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.obstacle_pixels, raw[:, 7].astype(np.int64))
