"""Guarantees of the camera model, the analytic test scenes, hole filling and the depth-image conversion,
attacked with random and extreme inputs. Every reference is independent of the code under test: the pinhole
formula written out here, numpy, brute-force window minima, sphere tracing of signed-distance functions
written here, and coal (FCL) for point distances.

Faults these tests pinned (each fails on the code before them):

* ``look_at`` returned an all-NaN ``R`` for a NaN ``up`` (no error), a zero row for an ``up`` of 1e300, garbage
  for (3, 3) ``eye``/``target``, a non-orthonormal ``R`` (a row 1.0000056 long) for ``eye`` and ``target``
  1e-160 m apart, and refused a perpendicular ``up`` of length 1e-12 as "parallel";
* ``Camera.project`` gave ``p_x = nan`` (and numpy warnings) for a point on the optical axis at ``z_C > 0``
  below 1/DBL_MAX (``0 * (1 / z)``); ``Camera.strided(10**400)`` raised ``OverflowError``;
* the scene primitives took NaN centres, negative radii, zero or NaN normals and non-rotation box matrices:
  one zero-normal half-space made ``render_depth`` NaN everywhere (hiding every other solid: ``np.minimum``
  passes NaN on); a half-space with a 1e-200 normal had NaN distances; ``render_depth(max_range=nan)`` blanked
  the image instead of raising, and ``max_range=inf`` left inf (not NaN) where nothing was hit;
* hole filling with a radius near 2**62 read uninitialised memory (a hole took -3e33 m or any value) and near
  2**63 killed the process (SIGFPE): ``2 r + 1`` wrapped around in int64;
* ``metres_or_nan`` took a divisor of 0, -1, NaN, inf, 1e300 or 1e-50 and returned an image of NaN (a camera that
  silently saw nothing), and raised ``AttributeError`` for a list.
"""

from __future__ import annotations

import coal  # the dev extra installs it
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthspace import fill_missing_depth
from depthguard.kernels.depthimage import metres_or_nan
from depthguard.kernels.holefill import column_minima_if_dense, column_window_min, window_min_at
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

FAST = settings(max_examples=40, deadline=None)
BIG_R = (2**62, 2**63 - 1)  # radii whose 2 r + 1 wraps in int64


def _rotation(seed: int) -> np.ndarray:
    """A random proper rotation (QR of a Gaussian matrix, det fixed to +1)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _camera(seed: int, w: int = 12, h: int = 9) -> Camera:
    rng = np.random.default_rng(seed)
    return Camera(
        width=w, height=h, fx=rng.uniform(4, 40), fy=rng.uniform(4, 40), cx=rng.uniform(-2, w + 2),
        cy=rng.uniform(-2, h + 2), R=_rotation(seed + 1), t=rng.uniform(-2, 2, 3), max_depth=8.0,
    )  # fmt: skip


# --------------------------------------------------------------------------------------------------- camera
@FAST
@given(st.integers(0, 2**31), st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(1e-6, 1e3))
def test_project_and_unproject_follow_the_pinhole_formula(seed, xc, yc, zc):
    cam = _camera(seed)
    pc = np.array([xc, yc, zc])
    pw = cam.R.T @ (pc - cam.t)  # independent inverse of P_C = R P_W + t
    want = [cam.fx * xc / zc + cam.cx, cam.fy * yc / zc + cam.cy, zc]
    got = cam.project(pw)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * (1 + np.abs(want).max()) * 1e3)
    back = cam.unproject(got[0], got[1], got[2])
    np.testing.assert_allclose(back, pw, rtol=1e-8, atol=1e-8 * (1 + np.abs(pw).max()))


@FAST
@given(st.floats(0.0, 1e-300, exclude_min=True), st.floats(-1.0, 1.0))
@example(5e-324, 0.0)  # below 1/DBL_MAX: x * (1 / z) was 0 * inf = nan
def test_project_in_front_of_the_camera_is_never_nan(z, x):
    cam = Camera(width=4, height=3, fx=2.0, fy=2.0, cx=2.0, cy=1.5)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        p = cam.project(np.array([x, 0.0, z]))
    assert not np.isnan(p[:2]).any()
    if x == 0.0:
        assert p[0] == cam.cx and p[1] == cam.cy  # fx * 0 / z + cx


def test_project_behind_the_camera_is_nan():
    cam = Camera(width=4, height=3, fx=2.0, fy=2.0, cx=2.0, cy=1.5)
    p = cam.project(np.array([[0.1, 0.2, 0.0], [0.1, 0.2, -1.0], [np.nan, 0.0, 1.0], [0.0, 0.0, np.nan]]))
    assert np.isnan(p[:, :2]).all()


@FAST
@given(st.integers(0, 2**31), st.integers(1, 30), st.integers(1, 23), st.integers(1, 40))
def test_rays_through_pixel_centres_and_strided_cameras(seed, w, h, step):
    cam = _camera(seed, w, h)
    v, u = np.mgrid[0:h, 0:w]
    want = np.stack([(u + 0.5 - cam.cx) / cam.fx, (v + 0.5 - cam.cy) / cam.fy, np.ones((h, w))], axis=-1)
    np.testing.assert_allclose(cam.pixel_ray_directions(), want, rtol=1e-12, atol=1e-12)
    p = cam.project(cam.unproject(u + 0.5, v + 0.5, 2.0))  # each centre lands in its own pixel
    assert np.array_equal(np.floor(p[..., 0] + 1e-9), u) and np.array_equal(np.floor(p[..., 1] + 1e-9), v)
    small = cam.strided(step)
    kept = want[::step, ::step]
    assert small.shape == kept.shape[:2]
    np.testing.assert_allclose(small.pixel_ray_directions(), kept, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(small.R, cam.R)
    np.testing.assert_array_equal(small.t, cam.t)


@pytest.mark.parametrize("step", [0, -1, True, 1.0, "2", 2**31, 10**400], ids=lambda s: repr(s)[:12])
def test_strided_refuses_bad_steps_by_name(step):
    with pytest.raises(ValueError, match="step"):
        Camera.kinect_v1().strided(step)


BAD_FIELDS = [
    *[(k, x) for k in ("fx", "fy") for x in (np.nan, np.inf, -np.inf, 0.0, -1.0, "abc", None)],
    *[(k, x) for k in ("cx", "cy") for x in (np.nan, np.inf, "abc", None)],
    *[(k, x) for k in ("width", "height") for x in (0, -3, 2.5, np.nan, True, 2**31)],
    ("R", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
    ("R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]]),
    ("R", np.eye(2)),
    ("R", np.full((3, 3), np.nan)),
    ("R", [[1, 1e-3, 0], [0, 1, 0], [0, 0, 1]]),
    ("t", [1, 2]),
    ("t", [0, 0, np.inf]),
    ("min_depth", 0.0),
    ("min_depth", np.nan),
    ("max_depth", 0.1),
    ("max_depth", np.inf),
    ("depth_scale", -0.001),
]


@pytest.mark.parametrize("name,value", BAD_FIELDS, ids=[f"{k}-{i}" for i, (k, _) in enumerate(BAD_FIELDS)])
def test_camera_refuses_bad_fields_by_name(name, value):
    kw = dict(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0)
    kw[name] = value
    with pytest.raises(ValueError, match=name):
        Camera(**kw)


vec = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array)
scale = st.sampled_from([1e-160, 1e-12, 1e-3, 1.0, 1e3, 1e200, 1e300])


@settings(max_examples=80, deadline=None)
@given(vec, vec, vec, scale, scale, st.floats(-10, 10))
@example(np.zeros(3), np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 1e-160, 1.0, 0.0)  # |R[1]| was 1.0000056
@example(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 1.0, 1e300, 0.0)  # R had a zero row
@example(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 1.0, 1e-12, 0.0)  # "parallel"
def test_look_at_gives_a_rotation_that_looks_at_the_target(eye, direction, up, dscale, uscale, offset):
    target = eye + offset + direction * dscale
    eye = eye + offset
    up = up * uscale
    d = target - eye
    assert np.all(np.isfinite(d))
    dn = np.abs(d).max()
    u = up / np.abs(up).max() if up.any() else up
    if dn == 0 or not u.any():
        return
    dh, uh = d / dn, u / np.linalg.norm(u)
    dh /= np.linalg.norm(dh)
    sin = np.linalg.norm(np.cross(dh, uh))
    if sin < 1e-10:
        with pytest.raises(ValueError, match="up"):
            look_at(eye, target, up)
    if sin < 1e-6:  # (near the 1e-9 threshold either answer is right)
        return
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        R, t = look_at(eye, target, up)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R[2], dh, atol=1e-12)  # optical axis at the target
    assert abs(R[0] @ uh) < 1e-12 and R[1] @ uh < 0  # up is up in the image (y down)
    np.testing.assert_allclose(t, -R @ eye, rtol=1e-12, atol=1e-300)


LOOK_AT_BAD = [
    ("up", dict(up=[np.nan, 0.0, 1.0])),  # returned an all-NaN R
    ("up", dict(up=[np.inf, 0.0, 1.0])),
    ("up", dict(up=[0.0, 0.0, 0.0])),
    ("up", dict(up=[1.0, 0.0, 0.0])),  # parallel
    ("up", dict(up=[-2.0, 0.0, 0.0])),  # antiparallel
    ("up", dict(up=[0.0, 1.0])),
    ("up", dict(up="abc")),
    ("eye", dict(eye=[0.0, 0.0])),
    ("eye", dict(eye=np.zeros((3, 3)), target=np.ones((3, 3)))),  # returned a (3, 3, 3) "R"
    ("eye", dict(eye=[np.nan, 0.0, 0.0])),
    ("target", dict(target=[1.0, np.inf, 0.0])),
    ("target", dict(target=None)),
    ("coincide", dict(target=[0.0, 0.0, 0.0])),
    ("eye", dict(eye=[-1e308, 0.0, 0.0], target=[1e308, 0.0, 0.0])),  # the difference overflows
]


@pytest.mark.parametrize("what,kw", LOOK_AT_BAD, ids=[f"{w}-{i}" for i, (w, _) in enumerate(LOOK_AT_BAD)])
def test_look_at_refuses_degenerate_input_by_name(what, kw):
    args = dict(eye=[0.0, 0.0, 0.0], target=[1.0, 0.0, 0.0], up=[0.0, 0.0, 1.0]) | kw
    with np.errstate(over="raise", invalid="raise", divide="raise"), pytest.raises(ValueError, match=what):
        look_at(**args)


# ---------------------------------------------------------------------------------------------------- scene
def _unit(v) -> np.ndarray:
    v = np.asarray(v, float) / np.abs(v).max()
    return v / np.linalg.norm(v)


def _sdf(prim) -> callable:
    """Signed distance (metres, negative inside) of a primitive, written here from the textbook formulas."""
    if isinstance(prim, Sphere):
        return lambda p: np.linalg.norm(p - prim.center, axis=-1) - prim.radius
    if isinstance(prim, Capsule):

        def capsule(p):
            ab = prim.b - prim.a
            L2 = ab @ ab
            s = np.clip((p - prim.a) @ ab / L2, 0.0, 1.0) if L2 > 0 else np.zeros(p.shape[:-1])
            return np.linalg.norm(p - (prim.a + s[..., None] * ab), axis=-1) - prim.radius

        return capsule
    if isinstance(prim, Box):

        def box(p):
            q = np.abs((p - prim.center) @ prim.R) - prim.half_extents
            return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

        return box
    n = _unit(prim.normal)
    return lambda p: (p - prim.point) @ n


def _reference_depth(cam: Camera, prim, max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) z-depth of the first hit through each pixel centre by sphere tracing (exact from below for a
    1-Lipschitz SDF), and (H, W) bool: ambiguous rays (a near miss or a grazing approach not resolved), skipped."""
    d = cam.vector_to_world(cam.pixel_ray_directions().reshape(-1, 3))
    norm = np.linalg.norm(d, axis=1)
    d = d / norm[:, None]
    o = cam.position
    if isinstance(prim, HalfSpace):  # (sphere tracing converges slowly along a plane: the line-plane formula)
        n = _unit(prim.normal)
        h, dn = (o - prim.point) @ n, d @ n
        with np.errstate(divide="ignore"):
            s = np.where(h <= 0, 0.0, np.where(dn < 0, h / -np.where(dn < 0, dn, 1.0), np.inf))
        amb = np.abs(dn) < 1e-9
    else:
        sdf = _sdf(prim)
        smax = min(2.0 * max_range, 30.0) * norm.max()
        s = np.zeros(len(d))
        done = np.zeros(len(d), bool)
        closest = np.full(len(d), np.inf)
        for _ in range(3000):
            f = sdf(o + s[:, None] * d)
            done |= f <= 1e-11
            closest = np.minimum(closest, f)
            live = ~done & (s <= smax)
            if not live.any():
                break
            s = np.where(live, s + np.maximum(f, 0.0), s)
        s = np.where(done, s, np.inf)
        amb = ~done & (closest < 1e-6)
    z = s / norm
    return np.where(np.isfinite(z) & (z <= max_range), z, np.nan).reshape(cam.shape), amb.reshape(cam.shape)


def _primitive(kind: int, seed: int):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-0.6, 0.6, 3)
    r = float(rng.choice([0.0, rng.uniform(0.0, 0.8)]))
    if kind == 0:
        return Sphere(c, r)
    if kind == 1:  # (sometimes of zero length)
        return Capsule(c, c + rng.choice([0.0, 1.0]) * rng.uniform(-1, 1, 3), r)
    if kind == 2:  # (sometimes flat)
        return Box(c, rng.uniform(0, 0.7, 3) * (rng.random(3) > 0.15), _rotation(seed))
    return HalfSpace(c, rng.normal(size=3) * 10.0 ** rng.uniform(-200, 200))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 3), st.integers(0, 2**31), st.floats(0.2, 3.0), st.sampled_from([8.0, np.inf]))
def test_render_depth_matches_sphere_tracing(kind, seed, dist, max_range):
    """Nearest hit, z-depth, 0 inside, NaN beyond ``max_range`` or behind the camera, any pose and size."""
    rng = np.random.default_rng(seed + 7)
    eye = rng.normal(size=3)
    eye *= dist / np.linalg.norm(eye)  # (inside some solids, outside others)
    R, t = look_at(eye, rng.uniform(-0.5, 0.5, 3), rng.normal(size=3))
    cam = Camera(width=10, height=8, fx=rng.uniform(4, 20), fy=rng.uniform(4, 20), cx=5.0, cy=4.0, R=R, t=t)
    prim = _primitive(kind, seed)
    want, amb = _reference_depth(cam, prim, max_range)
    got = render_depth(cam, Scene((prim,)), max_range=max_range)
    with np.errstate(invalid="ignore"):
        ok = (np.isnan(got) & np.isnan(want)) | (np.abs(got - want) <= 1e-7 * (1 + np.nan_to_num(want)))
    assert (ok | amb).all(), (got[~ok], want[~ok])


def test_render_depth_of_shapes_behind_and_around_the_camera():
    cam = Camera(width=6, height=4, fx=4.0, fy=4.0, cx=3.0, cy=2.0)
    behind = Scene(
        (Sphere([0.0, 0.0, -2.0], 1.0), Box([0, 0, -3.0], [5.0, 5.0, 0.5]), HalfSpace([0, 0, -1], [0, 0, 1]))
    )
    assert np.isnan(render_depth(cam, behind)).all()
    for inside in (Sphere([0.0, 0.0, 0.1], 0.5), Capsule([0, 0, -1], [0, 0, 1], 0.2), Box([0, 0, 0], [1, 1, 1])):
        assert (render_depth(cam, Scene((inside,))) == 0).all()
    near, far = Sphere([0.0, 0.0, 2.0], 0.5), Sphere([0.0, 0.0, 5.0], 3.0)  # the nearest hit, in either order
    dd = 1 + 2 * 0.125**2  # |d|^2 of pixel (3, 2)'s ray (0.125, 0.125, 1); |d s - c|^2 = r^2 with d.c = 2
    want = (2 - np.sqrt(4 - dd * (4 - 0.25))) / dd
    for order in ((near, far), (far, near)):
        assert render_depth(cam, Scene(order))[2, 3] == pytest.approx(want, rel=1e-12)


BAD_PRIMITIVES = [
    ("radius", lambda: Sphere([0, 0, 1], -0.5)),  # rendered as +0.5, distance grew by 0.5
    ("radius", lambda: Sphere([0, 0, 1], np.nan)),
    ("radius", lambda: Capsule([0, 0, 1], [0, 1, 1], np.inf)),
    ("center", lambda: Sphere([np.nan, 0, 1], 0.5)),
    ("center", lambda: Sphere([0, 1], 0.5)),
    ("b", lambda: Capsule([0, 0, 1], [0, np.inf, 1], 0.1)),
    ("half_extents", lambda: Box([0, 0, 1], [0.1, -0.1, 0.1])),
    ("R", lambda: Box([0, 0, 1], [0.1, 0.1, 0.1], np.diag([1.0, 1.0, 2.0]))),
    ("R", lambda: Box([0, 0, 1], [0.1, 0.1, 0.1], np.diag([1.0, 1.0, -1.0]))),
    ("normal", lambda: HalfSpace([0, 0, 0], [0, 0, 0])),  # blanked the whole image
    ("normal", lambda: HalfSpace([0, 0, 0], [0, np.nan, 1])),
    ("point", lambda: HalfSpace([0, 0, np.inf], [0, 0, 1])),
]


@pytest.mark.parametrize("name,make", BAD_PRIMITIVES, ids=[f"{n}-{i}" for i, (n, _) in enumerate(BAD_PRIMITIVES)])
def test_primitives_refuse_bad_fields_by_name(name, make):
    with pytest.raises(ValueError, match=f"'{name}'"):
        make()


@pytest.mark.parametrize("max_range", [np.nan, -1.0, 0.0, "8", True], ids=["nan", "negative", "zero", "str", "bool"])
def test_render_depth_refuses_a_bad_max_range(max_range):
    cam = Camera(width=4, height=3, fx=4.0, fy=4.0, cx=2.0, cy=1.5)
    with pytest.raises(ValueError, match="max_range"):
        render_depth(cam, Scene((Sphere([0.0, 0.0, 2.0], 0.5),)), max_range=max_range)


@pytest.mark.parametrize("scale", [1e-200, 1e-20, 1.0, 1e200], ids=["1e-200", "1e-20", "1", "1e200"])
def test_half_space_normal_of_any_length(scale):
    """The normal's length does not matter (a 1e-200 normal's norm underflowed: NaN distances and depths)."""
    cam = Camera(width=6, height=4, fx=4.0, fy=4.0, cx=3.0, cy=2.0)
    wall = HalfSpace([0.0, 0.0, 2.0], np.array([0.0, 0.0, -1.0]) * scale)
    np.testing.assert_allclose(wall.distance(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 3.0]])), [1.5, 0.0])
    np.testing.assert_allclose(render_depth(cam, Scene((wall,))), 2.0)


def _coal_point_distance(shape, R, t, p) -> float:
    res = coal.DistanceResult()
    d = coal.distance(coal.Sphere(0.0), coal.Transform3s(np.eye(3), p), shape, coal.Transform3s(R, t),
                      coal.DistanceRequest(), res)  # fmt: skip
    return max(d, 0.0)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([0.0, 1e-9, 0.05, 0.4]), st.sampled_from([0.0, 1e-9, 0.3]))
def test_point_distances_match_coal_with_degenerate_sizes(seed, r, half):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.5, 1.5, (6, 3))
    c = rng.uniform(-0.3, 0.3, 3)
    R = _rotation(seed)
    ax = R[:, 2]
    cases = [
        (Sphere(c, r), coal.Sphere(r), np.eye(3), c),
        (Capsule(c - half * ax, c + half * ax, r), coal.Capsule(r, 2 * half), R, c),
        (Box(c, [half, r, 0.2], R), coal.Box(2 * half, 2 * r, 0.4), R, c),
        (HalfSpace(c, ax * (r + 1e-3)), coal.Halfspace(ax, float(ax @ c)), np.eye(3), np.zeros(3)),
    ]
    for prim, shape, Rs, ts in cases:
        want = [_coal_point_distance(shape, Rs, ts, q) for q in p]
        np.testing.assert_allclose(prim.distance(p), want, atol=1e-6, err_msg=type(prim).__name__)
        np.testing.assert_allclose(Scene((prim,)).distance(p), want, atol=1e-6)


# ------------------------------------------------------------------------------------------------ hole fill
def _window_min(val: np.ndarray, v: int, u: int, r: int) -> np.float32:
    """Brute force: the minimum of the (2 r + 1)² window of (v, u), clipped at the border (inf if empty)."""
    win = val[max(0, v - r) : v + r + 1, max(0, u - r) : u + r + 1]
    return win.min() if win.size else np.float32(np.inf)


def _image(seed: int, h: int, w: int) -> np.ndarray:
    """(h, w) float32 with NaN holes, ±inf, 0, negatives, tiny and huge values."""
    rng = np.random.default_rng(seed)
    img = rng.uniform(0.1, 9.0, (h, w)).astype(np.float32)
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-40, 3e38], np.float32)
    pick = rng.random((h, w)) < rng.uniform(0, 0.9)
    img[pick] = rng.choice(special, pick.sum())
    return img


radius = st.one_of(st.integers(0, 6), st.sampled_from([40, 2**31, *BIG_R]))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 14), st.integers(1, 14), radius, st.booleans())
@example(0, 6, 7, 2**62, False)  # 2 r + 1 wrapped: uninitialised memory
@example(0, 6, 7, 2**63 - 1, False)  # INT64_MIN // -1: SIGFPE
def test_window_minimum_kernels_are_the_brute_force_window_minimum(seed, h, w, r, transposed):
    """Both paths of ``window_min_at`` and ``column_window_min`` equal the brute-force minimum of the clipped
    window, for any radius (also larger than the image or near int64's limit) and non-contiguous input."""
    img = _image(seed, w, h).T if transposed else _image(seed, h, w)  # (a transposed view: not C-contiguous)
    val = np.where(np.isnan(img), np.float32(np.inf), img)  # the kernels' input: no NaN
    col = np.full((h, w), -7.0, np.float32)
    scratch = [np.full((h, w), -1e30, np.float32) for _ in range(2)]  # (stale scratch must never show through)
    column_window_min(val, r, col, *scratch)
    want_col = np.array([[val[max(0, v - r) : v + r + 1, u].min() for u in range(w)] for v in range(h)])
    assert np.array_equal(col, want_col)
    dense, colmin = column_minima_if_dense(val, h * w, r)
    for v in range(h):
        for u in range(w):
            want = _window_min(val, v, u, r)
            assert window_min_at(val, colmin, dense, v, u, r) == want
            assert window_min_at(val, col, True, v, u, r) == want
            assert window_min_at(val, col, False, v, u, r) == want


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 12), st.integers(1, 12), radius, st.booleans())
@example(0, 6, 7, 2**62, False)
def test_filled_holes_are_never_farther_than_the_window_minimum(seed, h, w, r, with_robot):
    """The conservative policy (docs/conventions.md, "Missing depth"): a missing non-robot pixel (0, NaN, inf or
    negative) takes exactly the minimum valid non-robot depth of its window, or the near limit with none there;
    valid pixels keep their depth; robot pixels are inf."""
    cam = Camera(width=w, height=h, fx=10.0, fy=10.0, cx=w / 2, cy=h / 2, min_depth=0.3)
    depth = _image(seed, h, w)
    robot = np.random.default_rng(seed + 1).random((h, w)) < (0.3 if with_robot else 0.0)
    if seed % 2:  # (non-contiguous views)
        depth, robot = depth[:, ::-1], robot[:, ::-1]
    f = fill_missing_depth(cam, depth, robot, "conservative", r)
    missing = ~(np.isfinite(depth) & (depth > 0))
    valid = np.where(missing | robot, np.float32(np.inf), depth)
    for v in range(h):
        for u in range(w):
            got = f.obstacle_depth[v, u]
            if robot[v, u]:
                assert got == np.inf
            elif not missing[v, u]:
                assert got == depth[v, u]
            else:
                m = _window_min(valid, v, u, r)
                assert got == (m if m < np.inf else np.float32(cam.min_depth))


# ------------------------------------------------------------------------------------------- depth images
samples_dtype = st.sampled_from(["<u2", ">u2", "<f4", ">f4"])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), samples_dtype, st.sampled_from([1.0, 1000.0, 5000.0, 0.25, 1e-30, 1e30]), st.booleans())
def test_metres_or_nan_is_numpy_division_with_nan_for_no_reading(seed, dtype, divisor, strided):
    rng = np.random.default_rng(seed)
    if dtype.endswith("u2"):
        raw = rng.integers(0, 65536, (7, 9)).astype(np.uint16)
        raw[rng.random(raw.shape) < 0.3] = 0
    else:
        raw = _image(seed, 7, 9)
    samples = raw.astype(dtype)[::2, ::-1] if strided else raw.astype(dtype)
    with np.errstate(all="ignore"):
        x = samples.astype(np.float32) / np.float32(divisor)
    want = np.where((x > 0) & np.isfinite(x), x, np.float32(np.nan))
    got = metres_or_nan(samples, divisor)
    assert got.dtype == np.float32 and got.shape == samples.shape
    assert np.array_equal(got, want, equal_nan=True)


BAD_DIVISORS = [0, 0.0, -1000.0, np.nan, np.inf, -np.inf, 1e300, 1e-50, 1e-39, 10**400, True, "1000", None, [1000]]


@pytest.mark.parametrize("divisor", BAD_DIVISORS, ids=[f"d{i}" for i in range(len(BAD_DIVISORS))])
def test_metres_or_nan_refuses_a_bad_divisor(divisor):
    """Each of these turned every sample into NaN (a camera that silently saw nothing) or raised a bare error."""
    with pytest.raises(ValueError, match="divisor"):
        metres_or_nan(np.full((2, 3), 1000, np.uint16), divisor)


@pytest.mark.parametrize(
    "samples", [[[1000, 0]], np.zeros((2, 2)), np.zeros((2, 2), np.int32)], ids=["list", "f8", "i4"]
)
def test_metres_or_nan_refuses_other_samples(samples):
    with pytest.raises(ValueError, match="depth samples"):
        metres_or_nan(samples, 1000.0)
