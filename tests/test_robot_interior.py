"""The robot's own body in the fusion (depthguard.robot.interior): chords, principal pixels, windows.

Ground truth: capsule membership of sampled ray points (brute force), the analytic scenes of
:mod:`depthguard.scene`, and the fusion's own lower-bound contract on a hidden obstacle.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.robot.interior import _capsule_chord, principal_robot_pixels, robot_windows
from depthguard.scene import Capsule, HalfSpace, Scene, Sphere, render_depth

WORKSPACE = (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5)
WALLS = (
    HalfSpace(np.array([-2.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
    HalfSpace(np.array([0.0, -2.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    HalfSpace(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 1.0])),
)
MARGIN = 0.03


def camera(eye, target, w=160, h=120, f=131.25) -> Camera:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float))
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2, cy=h / 2, R=R, t=t, min_depth=0.3, max_depth=6.0)


def _inside(p, a, b, r):
    ab = b - a
    s = np.clip((p - a) @ ab / max(ab @ ab, 1e-18), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1) <= r


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-0.3, 0.3),
    st.floats(-0.3, 0.3),
    st.lists(st.floats(-0.25, 0.25), min_size=6, max_size=6),
    st.floats(0.02, 0.15),
)
def test_capsule_chord_matches_sampled_membership(x, y, ends, r):
    a = np.array([ends[0], ends[1], 1.5 + ends[2]])
    b = np.array([ends[3], ends[4], 1.5 + ends[5]])
    s = np.linspace(0.5, 2.5, 20001)
    pts = s[:, None] * np.array([x, y, 1.0])
    inside = _inside(pts, a, b, r)
    s_in, s_out = _capsule_chord(x, y, a, b, r)
    if not inside.any():
        # the ray may graze the capsule between samples: then the chord is tiny
        assert not (s_in <= s_out) or s_out - s_in < 1e-3
        return
    step = s[1] - s[0]
    assert s_in == pytest.approx(s[inside][0], abs=step * 1.01)
    assert s_out == pytest.approx(s[inside][-1], abs=step * 1.01)


def _robot_scene():
    """Principal camera on +x, second camera on +y; a capsule 'link' at the origin, z = 1."""
    cams = [camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0]), camera([0.0, 2.0, 1.2], [0.0, 0.0, 0.9])]
    a, b, r = np.array([[0.0, -0.15, 1.0]]), np.array([[0.0, 0.15, 1.0]]), np.array([0.08])
    link = Capsule(a[0], b[0], float(r[0]))
    return cams, link, a, b, r


def test_principal_robot_pixels_start_where_the_ray_leaves_the_robot():
    cams, link, a, b, r = _robot_scene()
    cam = cams[0]
    depth = render_depth(cam, Scene((link, *WALLS))).astype(np.float32)
    robot = render_depth(cam, Scene((link,)))
    mask = np.isfinite(robot)
    d2, m2 = principal_robot_pixels(cam, depth, mask, a, b, r, margin=MARGIN)
    assert np.array_equal(d2[~mask], depth[~mask], equal_nan=True)
    # along the optical axis the ray leaves the inflated link at x = -(r + margin), depth 2 + r + margin
    v, u = cam.height // 2, cam.width // 2
    assert d2[v, u] == pytest.approx(2.0 + 0.08 + MARGIN, abs=2e-3)
    assert np.all(d2[mask] >= depth[mask])
    # a missing pixel inside the robot stays robot; a missing pixel next to it (margin only) is a hole
    inflated = np.isfinite(render_depth(cam, Scene((Capsule(a[0], b[0], 0.08 + MARGIN),))))
    band = inflated & ~mask
    assert band.any()
    holes = np.where(band | mask, np.nan, depth).astype(np.float32)
    holes[v, u] = np.nan
    _, m3 = principal_robot_pixels(cam, holes, band | mask, a, b, r, margin=MARGIN)
    assert m3[v, u]
    assert not m3[band].any()


def test_robot_windows_hold_the_inflated_chord():
    cams, link, a, b, r = _robot_scene()
    cam = cams[1]
    lo, hi = robot_windows(cam, a, b, r, margin=MARGIN)
    hit = np.isfinite(render_depth(cam, Scene((Capsule(a[0], b[0], 0.08 + MARGIN),))))
    assert np.array_equal(np.isfinite(lo), hit)
    ray = cam.pixel_ray_directions()[60, 80]
    s_in, s_out = _capsule_chord(ray[0], ray[1], cam.world_to_camera(a)[0], cam.world_to_camera(b)[0], 0.08 + MARGIN)
    assert lo[60, 80] == pytest.approx(s_in, abs=1e-5)
    assert hi[60, 80] == pytest.approx(s_out, abs=1e-5)
    with pytest.raises(ValueError, match="margin"):
        robot_windows(cam, a, b, r, margin=-1.0)


def _fusion_inputs(cams, link, a, b, r, others):
    full = Scene((link, *others, *WALLS))
    depths, masks = [], []
    for c in cams:
        d = render_depth(c, full).astype(np.float32)
        rob = render_depth(c, Scene((link,)))
        masks.append(np.isfinite(rob) & (rob <= d + 1e-6))
        depths.append(d)
    d0, m0 = principal_robot_pixels(cams[0], depths[0], masks[0], a, b, r, margin=MARGIN)
    windows = [None] + [robot_windows(c, a, b, r, margin=MARGIN) for c in cams[1:]]
    return depths, masks, [d0, *depths[1:]], [m0, *masks[1:]], windows


def test_the_robots_body_hidden_by_a_box_is_not_an_obstacle():
    """A box hides the link from the second camera: the cells behind the link's visible surface (its own
    body) are unseen by both cameras. Without the corrections they are an obstacle 0.1 m from a point
    in front of the link; with them the nearest unseen space lies behind the inflated link."""
    cams, link, a, b, r = _robot_scene()
    box = Sphere(np.array([0.0, 0.55, 1.05]), 0.15)  # between the second camera and the link
    depths, masks, d2, m2, windows = _fusion_inputs(cams, link, a, b, r, (box,))
    P = np.array([[0.25, 0.0, 1.0]])
    plain = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    plain.update(depths, masks)
    assert plain.query(P, 0.0, rho=0.4, mode="min").distance[0] < 0.2  # the link's own body
    fixed = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fixed.update(d2, m2, windows=windows)
    got = fixed.query(P, 0.0, rho=0.4, mode="min").distance[0]
    # still a lower bound of the distance to the box and to the space behind the inflated link
    bound = min(float(Scene((box,)).distance(P)[0]), 0.25 + 0.08 + MARGIN)
    assert got >= 0.25 + 0.08 - 0.02
    assert got <= bound + fixed.tolerance(P)[0] or not np.isfinite(got)


def test_a_hand_hidden_behind_the_link_is_still_found():
    """The corrections must not hide an obstacle behind the link that the second camera sees."""
    cams, link, a, b, r = _robot_scene()
    hand = Sphere(np.array([-0.3, 0.0, 1.0]), 0.08)  # behind the link from the principal camera
    depths, masks, d2, m2, windows = _fusion_inputs(cams, link, a, b, r, (hand,))
    P = np.array([[0.0, 0.0, 1.0]])
    truth = float(Scene((hand,)).distance(P)[0])
    fixed = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fixed.update(d2, m2, windows=windows)
    got = fixed.query(P, 0.0, rho=0.4, mode="min").distance[0]
    assert truth - fixed.tolerance(P)[0] <= got <= truth + fixed.tolerance(P)[0]


def test_windows_shape_is_checked():
    cams, link, a, b, r = _robot_scene()
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    d = [np.full(c.shape, 3.0, np.float32) for c in cams]
    with pytest.raises(ValueError, match="windows"):
        fusion.update(d, None, windows=[None])
    with pytest.raises(ValueError, match=r"windows\[1\]"):
        fusion.update(d, None, windows=[None, (np.zeros((3, 3)), np.zeros((3, 3)))])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    st.floats(-0.5, 2.5),
    st.floats(0.01, 0.4),
)
def test_capsule_boxes_hold_every_pixel_whose_ray_meets_the_capsule(pa, pb, z, r):
    """The image box of a capsule (also one that reaches behind the camera) holds every pixel whose centre
    ray meets it: brute force over every pixel of an 80x60 image."""
    from depthguard.robot.interior import _capsule_boxes

    cam = camera([0, 0, 0], [1, 0, 0], w=80, h=60, f=65.0)
    A = np.array([pa[0], pa[1], z + pa[2]])[None]
    B = np.array([pb[0], pb[1], z + pb[2]])[None]
    u0, u1, v0, v1 = _capsule_boxes(A, B, np.array([r]), cam.fx, cam.fy, cam.cx, cam.cy, 80, 60)[0]
    for v in range(60):
        for u in range(80):
            s_in, s_out = _capsule_chord((u + 0.5 - cam.cx) / cam.fx, (v + 0.5 - cam.cy) / cam.fy, A[0], B[0], r)
            if s_in <= s_out and s_out > 0.0:
                assert u0 <= u <= u1 and v0 <= v <= v1, (u, v, (u0, u1, v0, v1))


@pytest.mark.parametrize("name", ["lwr4", "panda", "ur5", "xarm7"])
def test_interior_capsules_lie_in_the_self_filter_geometry(name):
    """The corrections skip or clear space inside these capsules inflated by the margin: it must lie within
    the margin of the robot's collision geometry (coal). The chain capsules of a mesh robot
    (``link_capsules``, r = 0.05 m) do not: up to 4 cm more (measured); a mesh link gets the capsule
    inscribed in its own closed mesh instead."""
    pytest.importorskip("coal")
    from depthguard.bench.meshtruth import MeshRobotTruth, distance_to_robot
    from depthguard.robot.interior import interior_capsules
    from depthguard.robot.robots import load_robot

    def farthest(a, b, r, q, n=3000):  # from points uniform in the inflated capsules (rejection sampling)
        pts = []
        for k in range(len(r)):
            lo, hi = np.minimum(a[k], b[k]) - r[k] - MARGIN, np.maximum(a[k], b[k]) + r[k] + MARGIN
            p = rng.uniform(lo, hi, (n, 3))
            pts.append(p[_inside(p, a[k], b[k], r[k] + MARGIN)])
        pts = np.vstack(pts)
        d = distance_to_robot(str(model.urdf_path), q, pts)  # to the surface, unsigned
        far = d > MARGIN
        if far.any():  # deep inside a link is fine: MuJoCo's ray parity on the URDF's own meshes
            d[far] = np.where(MeshRobotTruth(str(model.urdf_path), q).inside(pts[far]), 0.0, d[far])
        return d.max()

    model = load_robot(name)
    rng = np.random.default_rng(7)
    for _ in range(2):
        q = rng.uniform(np.maximum(model.q_min, -2.5), np.minimum(model.q_max, 2.5))
        a, b, r = interior_capsules(model, q)
        if name == "lwr4":
            assert len(r) == 7 + 13  # its capsules, and balls inscribed in its base cylinder (a disc)
        else:  # why not the chain capsules
            assert farthest(*model.link_capsules(q), q, n=400) > MARGIN + 0.01
        if len(r):
            d = farthest(a, b, r, q)
            assert d <= MARGIN + 1e-6, f"{d:.4f} m from the collision geometry"


def _windows_two_sweeps(cam, a, b, reff, gap):
    """The windows' definition, pixel by pixel: two sweeps over the capsules in order, every chord tried in
    both (the kernel skips, in the second sweep, the pixels where nothing was met apart from the window)."""
    A, B = cam.world_to_camera(a), cam.world_to_camera(b)
    lo = np.full(cam.shape, np.nan, np.float32)
    hi = np.full(cam.shape, np.nan, np.float32)
    for v in range(cam.height):
        for u in range(cam.width):
            x, y = (u + 0.5 - cam.cx) / cam.fx, (v + 0.5 - cam.cy) / cam.fy
            w_lo, w_hi = np.inf, -np.inf
            for sweep in range(2):
                for k in range(len(reff)):
                    s, e = _capsule_chord(x, y, A[k], B[k], reff[k])
                    if not (s <= e) or e <= 0.0:
                        continue
                    s = max(s, 0.0)
                    if w_lo <= w_hi and s <= w_hi + gap and e >= w_lo - gap:
                        w_lo, w_hi = min(w_lo, s), max(w_hi, e)
                    elif sweep == 0 and (not (w_lo <= w_hi) or s < w_lo):
                        w_lo, w_hi = s, e
            if w_lo <= w_hi:
                lo[v, u], hi[v, u] = w_lo, w_hi
    return lo, hi


@settings(max_examples=15, deadline=None)
@given(st.lists(st.lists(st.floats(-0.35, 0.35), min_size=7, max_size=7), min_size=2, max_size=5))
def test_robot_windows_equal_the_two_sweep_definition(caps):
    """Capsules crossing one another in any order (chords met out of order, disjoint stretches along one
    ray): the kernel's windows are exactly those of the plain two-sweep definition."""
    cam = camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0], w=48, h=36, f=40.0)
    c = np.asarray(caps, float)
    a = c[:, 0:3] + [0.0, 0.0, 1.0]
    b = a + c[:, 3:6]
    r = 0.02 + np.abs(c[:, 6]) / 4
    lo, hi = robot_windows(cam, a, b, r, margin=MARGIN, gap=0.01)
    ref_lo, ref_hi = _windows_two_sweeps(cam, a, b, r + MARGIN, 0.01)
    assert np.array_equal(lo, ref_lo, equal_nan=True)
    assert np.array_equal(hi, ref_hi, equal_nan=True)


def test_robot_windows_join_chords_met_out_of_order():
    """Along the principal camera's axis: capsule 0 far, capsule 1 near (apart from it), capsule 2 between
    them. The first sweep sees the near and middle chords join; only the second joins the far one."""
    cam = camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0], w=48, h=36, f=40.0)
    xs = np.array([-0.2, 0.2, 0.0])
    a = np.stack([xs, np.full(3, -0.1), np.ones(3)], axis=1)
    b = a + [0.0, 0.2, 0.0]
    r = np.full(3, 0.1)
    lo, hi = robot_windows(cam, a, b, r, margin=MARGIN, gap=0.01)
    ref_lo, ref_hi = _windows_two_sweeps(cam, a, b, r + MARGIN, 0.01)
    assert np.array_equal(lo, ref_lo, equal_nan=True) and np.array_equal(hi, ref_hi, equal_nan=True)
    # the centre pixel's window spans all three: from the near capsule's front to the far one's back
    assert lo[18, 24] == pytest.approx(2.0 - 0.2 - 0.13, abs=0.01)
    assert hi[18, 24] == pytest.approx(2.0 + 0.2 + 0.13, abs=0.01)


def test_capsule_inscribed_in_a_mesh_lies_inside_it():
    """A box mesh 0.1 x 0.2 x 0.4 m: the capsule runs along its long axis, every point of it lies inside the
    box (analytic test), and it is not much thinner than the largest one (radius 0.05 m); an L-shaped
    (non-convex) mesh gets one inside it too; an open mesh gets none."""
    trimesh = pytest.importorskip("trimesh")
    from depthguard.robot.geometry import _inscribed_mesh_capsule

    box = trimesh.creation.box((0.1, 0.2, 0.4))
    a, b, r = _inscribed_mesh_capsule(np.asarray(box.vertices), np.asarray(box.faces))
    assert 0.040 <= r < 0.05 and abs((b - a)[2]) > 0.2
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.2, 0.2, (20000, 3))
    p = p[_inside(p, a, b, r)]
    assert len(p) > 300 and np.all(np.abs(p) <= [0.05, 0.1, 0.2])
    open_mesh = box.faces[:-2]
    assert _inscribed_mesh_capsule(np.asarray(box.vertices), np.asarray(open_mesh)) is None


def test_capsule_inscribed_in_a_non_convex_mesh_lies_inside_it():
    """An L-shaped mesh (two 6 cm bars, trimesh's boolean union): a capsule is found and lies inside it."""
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("manifold3d", reason="trimesh's boolean union needs manifold3d")
    from depthguard.robot.geometry import _inscribed_mesh_capsule

    rng = np.random.default_rng(4)
    ell = trimesh.boolean.union([trimesh.creation.box((0.3, 0.06, 0.06)), trimesh.creation.box((0.06, 0.3, 0.06))])
    a, b, r = _inscribed_mesh_capsule(np.asarray(ell.vertices), np.asarray(ell.faces))
    assert r >= 0.01
    p = rng.uniform(-0.2, 0.2, (50000, 3))
    p = p[_inside(p, a, b, r)]
    in_bar = (np.abs(p[:, 1]) <= 0.03) | (np.abs(p[:, 0]) <= 0.03)
    assert len(p) > 30 and np.all(in_bar & (np.abs(p[:, 2]) <= 0.03) & (np.abs(p[:, :2]) <= 0.15).all(axis=1))


@settings(max_examples=25, deadline=None)
@given(
    size=st.tuples(*[st.floats(0.02, 0.4)] * 3),
    angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
    shift=st.tuples(*[st.floats(-0.3, 0.3)] * 3),
    cylinder=st.booleans(),
)
def test_property_inscribed_mesh_capsule_never_leaves_the_solid(size, angles, shift, cylinder):
    """Random boxes and cylinders (meshes, posed anywhere): every point sampled in the inscribed capsule lies
    inside the solid, by the analytic test in the solid's own frame; a capsule is found once the solid's
    thinnest dimension leaves room for a 5 mm radius."""
    trimesh = pytest.importorskip("trimesh")
    from scipy.spatial.transform import Rotation

    from depthguard.robot.geometry import _inscribed_mesh_capsule

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles).as_matrix()
    T[:3, 3] = shift
    if cylinder:
        solid = trimesh.creation.cylinder(radius=size[0] / 2, height=size[2], sections=48, transform=T)
    else:
        solid = trimesh.creation.box(size, transform=T)
    got = _inscribed_mesh_capsule(np.asarray(solid.vertices), np.asarray(solid.faces))
    if got is None:
        assert min(size[0], size[2] if cylinder else min(size)) < 0.04
        return
    a, b, r = got
    rng = np.random.default_rng(0)
    lo, hi = np.minimum(a, b) - r, np.maximum(a, b) + r
    p = rng.uniform(lo, hi, (4000, 3))
    p = p[_inside(p, a, b, r)]
    local = (p - T[:3, 3]) @ T[:3, :3]  # into the solid's frame
    if cylinder:
        ok = (np.hypot(local[:, 0], local[:, 1]) <= size[0] / 2) & (np.abs(local[:, 2]) <= size[2] / 2)
    else:
        ok = np.all(np.abs(local) <= 0.5 * np.asarray(size), axis=1)
    assert ok.all()
