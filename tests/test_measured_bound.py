"""The measured bound (depthguard.sim.measured_bound) on analytic scenes with a known answer.

One camera at the origin looking along +z (R = I) at a wall 3 m away; the bound is the distance from a
sphere to the space that no camera sees free, so it is known in closed form: the wall's half-space
``z >= 3``, a missing block's frustum, a second camera's view. The lattice makes the bound smaller by at
most half its diagonal (sqrt(3)/2 h) and by at most one more spacing where the frontier is oblique.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.sim.measured_bound import measured_bound, measured_views

H = 0.01
HALF = 0.5 * np.sqrt(3) * H


def _cam(R=None, t=None) -> Camera:
    return Camera(
        width=160,
        height=120,
        fx=120.0,
        fy=120.0,
        cx=80.0,
        cy=60.0,
        R=np.eye(3) if R is None else R,
        t=np.zeros(3) if t is None else t,
        min_depth=0.3,
    )


def _wall(cam: Camera, z: float = 3.0) -> np.ndarray:
    return np.full(cam.shape, z, np.float32)


def _bound(cams, depths, masks, centre, radius, rho=0.5, caps=None, margin=0.0):
    v = measured_views(cams, depths, masks)
    return float(measured_bound(v, np.array([centre], float), np.array([radius]), rho, caps, margin, H)[0])


def test_a_wall_bounds_the_space_behind_it():
    cam = _cam()
    no_robot = [np.zeros(cam.shape, bool)]
    for zc, want in ((2.7, 0.2), (2.5, 0.4), (2.0, 0.5)):  # 0.5 = rho: nothing unseen within reach
        b = _bound([cam], [_wall(cam)], no_robot, (0.0, 0.0, zc), 0.1)
        assert want - HALF - 1e-9 <= b <= want + 1e-9, (zc, b)


def test_a_missing_block_beyond_the_fill_radius_is_unseen_along_its_whole_ray():
    cam = _cam()
    d = _wall(cam)
    d[50:70, 90:110] = np.nan  # 20 x 20 pixels: wider than the 9 x 9 fill window, so its centre stays a hole
    m = np.zeros(cam.shape, bool)
    # the hole's inner part (not reached by the fill) spans pixels u 94-105, i.e. x/z in [14/120, 26/120)
    centre = np.array([0.0, 0.0, 1.5])
    b = _bound([cam], [d], [m], centre, 0.05)
    x_edge = 14.0 / 120.0 * 1.5  # the frustum's near side at the sphere's depth
    want = x_edge - 0.05  # perpendicular distance to that plane is a little less: the frustum is oblique
    assert b <= want + 1e-9
    assert b >= want * np.cos(np.arctan(14.0 / 120.0)) - HALF - H
    # a 4 x 4 hole is filled from its neighbours (the missing-depth policy): the wall again
    d2 = _wall(cam)
    d2[58:62, 98:102] = np.nan
    assert _bound([cam], [d2], [m], centre, 0.05) == pytest.approx(0.5)


def test_a_second_camera_clears_the_principals_hidden_space_but_not_its_own_holes():
    cam0 = _cam()
    d0 = _wall(cam0)
    d0[40:80, 60:100] = 2.0  # a panel at 2 m hides what lies behind it from the principal camera
    # the second camera 1 m to the side (at x = -1), looking at the same wall along parallel axes; the rule,
    # not the physics, is under test: its image shows the wall only
    cam1 = _cam(t=np.array([1.0, 0.0, 0.0]))
    d1 = _wall(cam1)
    m = [np.zeros(cam0.shape, bool), np.zeros(cam1.shape, bool)]
    centre = (0.0, 0.0, 2.3)  # behind the panel
    alone = _bound([cam0], [d0], m[:1], centre, 0.05)
    assert alone == pytest.approx(0.0)
    both = _bound([cam0, cam1], [d0, d1], m, centre, 0.05)
    # the hidden space is cleared; what remains is the panel that the principal measures, 0.3 - 0.05 away
    assert 0.25 - HALF - 1e-9 <= both <= 0.25 + 1e-9
    d1_hole = d1.copy()
    d1_hole[:, 120:] = np.nan  # the second camera's missing columns cover the sphere's ray (u = 80 + 120 * 1/2.3)
    assert _bound([cam0, cam1], [d0, d1_hole], m, centre, 0.05) == pytest.approx(0.0)
    # ... unless those pixels are the robot's: a secondary camera's robot pixel sees past, but it does not
    # erase the panel that the principal camera measures
    m_rob = [m[0], np.zeros(cam1.shape, bool)]
    m_rob[1][:, 120:] = True
    assert 0.25 - HALF - 1e-9 <= _bound([cam0, cam1], [d0, d1_hole], m_rob, centre, 0.05) <= 0.25 + 1e-9


def test_with_one_camera_the_space_that_the_robot_hides_is_free():
    """The depth space skips robot pixels (ICRA'12 §IV-B): behind the robot's pixels nothing is unseen."""
    cam = _cam()
    d = _wall(cam)
    d[40:80, 60:100] = 2.0
    m = np.zeros(cam.shape, bool)
    centre = (0.0, 0.0, 2.3)
    assert _bound([cam], [d], [m], centre, 0.05) == pytest.approx(0.0)  # a panel: its shadow is unseen
    m[40:80, 60:100] = True  # the same pixels are the robot's
    assert _bound([cam], [d], [m], centre, 0.05) == pytest.approx(0.5)


def test_space_inside_the_inflated_capsules_is_the_robot():
    cam = _cam()
    d = _wall(cam)
    d[:, :] = np.nan  # nothing measured: everything unseen, except inside the capsule
    m = [np.zeros(cam.shape, bool)]
    caps = (np.array([[0.0, 0.0, 1.5]]), np.array([[0.0, 0.0, 1.5]]), np.array([0.2]))
    b = _bound([cam], [d], m, (0.0, 0.0, 1.5), 0.05, caps=caps, margin=0.05)
    assert 0.2 - HALF - 1e-9 <= b <= 0.2 + 1e-9  # from the sphere's surface (0.05) to the inflated 0.25


def test_a_principal_robot_pixel_without_reading_sees_free_in_front_of_the_robot():
    """The fill rule for a depth edge on the robot (``principal_robot_pixels``, which the fusion applies): a
    robot pixel of the principal camera without a reading, with valid pixels around and none of them a
    non-robot one nearer, sees free what lies in front of the robot along its ray, and nothing behind it.
    The second camera measures nothing, so only that rule can free the space on those rays."""
    cam, side = _cam(), _cam(np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), np.array([0.0, 0.0, 3.0]))
    d = _wall(cam)
    m = np.zeros(cam.shape, bool)
    d[50:70, 70:90], m[50:70, 70:90] = 1.8, True  # the robot's pixels, a ball at 2 m
    d[58:62, 78:82] = np.nan  # a few of them without a reading, on the ray through the ball's centre
    caps = (np.array([[0.0, 0.0, 2.0]]), np.array([[0.0, 0.0, 2.0]]), np.array([0.17]))
    nothing = np.full(side.shape, np.nan, np.float32)
    views = ([cam, side], [d, nothing], [m, np.zeros(side.shape, bool)])
    front = _bound(*views, (0.0, 0.0, 1.0), 0.05, rho=0.3, caps=caps, margin=0.03)
    assert front == pytest.approx(0.3)  # in front of the robot: all free (it was 0 before the rule)
    behind = _bound(*views, (0.0, 0.0, 2.5), 0.05, rho=0.3, caps=caps, margin=0.03)
    assert behind <= HALF + 1e-9  # behind the robot, on those rays: unseen
    d[56, 76] = 0.95  # a valid non-robot pixel in the window, nearer than the points in front of the ball
    near = _bound(*views, (0.0, 0.0, 1.35), 0.05, rho=0.3, caps=caps, margin=0.03)
    assert near <= 0.05  # those rays are no longer seen free beyond 0.95 m


def test_bad_input_is_refused():
    cam = _cam()
    with pytest.raises(ValueError, match="one depth image"):
        measured_views([cam], [], [])
    v = measured_views([cam], [_wall(cam)], [np.zeros(cam.shape, bool)])
    with pytest.raises(ValueError, match="radii"):
        measured_bound(v, np.zeros((2, 3)), np.zeros(3), 0.5)
    with pytest.raises(ValueError, match="positive"):
        measured_bound(v, np.zeros((1, 3)), np.zeros(1), float("nan"))


def test_segment_distance_against_dense_sampling():
    """The bound's segment-segment distance (used by the principal robot-edge rule) against the minimum
    over 400 x 400 sampled point pairs, random segments including degenerate and parallel ones."""
    from depthguard.sim.bound_robot import _segment_distance2

    rng = np.random.default_rng(3)
    s = np.linspace(0.0, 1.0, 400)
    for k in range(40):
        p0, p1, q0, q1 = rng.normal(size=(4, 3))
        if k % 10 == 1:
            p1 = p0.copy()  # a point
        if k % 10 == 2:
            q1 = q0 + 0.7 * (p1 - p0)  # parallel
        P = p0 + s[:, None] * (p1 - p0)
        Q = q0 + s[:, None] * (q1 - q0)
        brute = np.min(np.sum((P[:, None] - Q[None]) ** 2, axis=2))
        got = _segment_distance2(p0, p1, q0, q1)
        assert got <= brute + 1e-12 and np.sqrt(brute) - np.sqrt(got) < 0.02, (k, got, brute)


def test_triangle_distance_against_dense_sampling():
    """The bound's point-triangle distance (for mesh robots) against the minimum over 20,000 points sampled
    on the triangle: never above it, and within the sampling's resolution of it; random triangles,
    including degenerate (zero-area) ones."""
    from depthguard.sim.bound_robot import _triangle_distance2

    rng = np.random.default_rng(4)
    for k in range(300):
        tri = rng.normal(size=(3, 3))
        if k % 10 == 1:
            tri[2] = tri[0] + rng.random() * (tri[1] - tri[0])  # zero area
        if k % 10 == 2:
            tri[1] = tri[0]  # two vertices the same
        p = 2.0 * rng.normal(size=3)
        u = rng.random((20000, 2))
        flip = u.sum(axis=1) > 1.0
        u[flip] = 1.0 - u[flip]
        pts = tri[0] + u[:, :1] * (tri[1] - tri[0]) + u[:, 1:] * (tri[2] - tri[0])
        brute = np.sqrt(np.min(np.sum((pts - p) ** 2, axis=1)))
        got = np.sqrt(_triangle_distance2(p, tri))
        assert got <= brute + 1e-9 and brute - got <= 0.06, (k, got, brute)


def _box_mesh(lo, hi):
    """The 12 triangles of an axis-aligned box, outward-facing, (12, 3, 3)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return np.array([[c[a], c[b], c[d]] for a, b, cc, d in quads for a, b, d in ((a, b, cc), (a, cc, d))])


def test_space_the_self_filter_counts_as_a_mesh_robot_is_not_unseen_space():
    """A mesh robot: points within the self-filter's inflation of its mesh, or inside it when it is closed,
    are the robot, not unseen space; with a closed box in a camera that measures nothing, the bound is the
    distance to the inflated box's surface (the box tested by ray parity inside, by distance outside). With
    the mesh open (parity off), its inside beyond the inflation is unseen again. Never below the bound
    without meshes."""
    from depthguard.sim.measured_bound import RobotMeshes

    cam = _cam()
    nothing = np.full(cam.shape, np.nan, np.float32)
    views = measured_views([cam], [nothing], [np.zeros(cam.shape, bool)])
    tri = _box_mesh([-0.3, -0.3, 1.2], [0.3, 0.3, 1.8])  # a 0.6 m cube about (0, 0, 1.5)
    infl = 0.05
    ball = np.column_stack([tri.mean(axis=1), np.linalg.norm(tri - tri.mean(axis=1)[:, None], axis=2).max(1)])
    box = np.array([[[-0.35, -0.35, 1.15], [0.35, 0.35, 1.85]]])

    def mesh(closed):
        return RobotMeshes(tri, np.array([[0, 12]]), np.array([infl]), np.array([closed]), box, ball)

    def bound(centre, meshes):
        c = np.array([centre], float)
        return float(measured_bound(views, c, np.array([0.05]), 0.5, None, 0.0, H, meshes=meshes)[0])

    # from the box's centre: everything out to the inflated faces (0.35 m) is the robot
    inside = bound((0.0, 0.0, 1.5), mesh(True))
    assert 0.35 - 0.05 - HALF - 1e-9 <= inside <= 0.35 - 0.05 + 1e-9
    assert bound((0.0, 0.0, 1.5), mesh(False)) == pytest.approx(0.0)  # open: the deep inside is unseen
    assert bound((0.0, 0.0, 1.5), None) == pytest.approx(0.0)
    # beside the box, 0.2 m off its face: the unseen space starts right there, meshes or not
    assert bound((0.5, 0.0, 1.5), mesh(True)) == pytest.approx(0.0)
    # a sphere in the inflation layer: the layer is the robot, beyond it unseen
    layer = bound((0.0, 0.0, 1.82), mesh(False))
    assert layer <= 0.03 + 1e-9 and layer >= bound((0.0, 0.0, 1.82), None)
