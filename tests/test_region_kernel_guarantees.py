"""The shared geometric kernels of every depth-space distance query (:mod:`depthguard.kernels.region`),
attacked one by one against references written here, so that a distance is never over-reported.

* :func:`surveillance_box` contains every pixel whose frustum meets the cube of half side ρ' around P: the
  cube's corners and a grid of its points, projected by the pinhole formula written here (ICRA'12 eq. 3); the
  whole image when the cube reaches z <= 0. Off-axis points, points outside the image, near z = 0 and
  behind the camera, ρ' from 0 to metres, principal points outside the image, fx != fy, 1x1 images.
* :func:`tile_lower_bounds`: each tile's bound is at most the *exact* distance from P to the tile's frustum
  beyond its smallest depth (a convex polyhedron: nearest point by enumerating its faces, edges and vertices,
  the KKT conditions), itself checked against points sampled in the frustum; +inf only in RA-L'16 case i
  (``d_min > d_p + ρ'``) or for another part's rows.
* :func:`unseen_space`: the distance to the unseen region (outside the pyramid through the image border,
  nearer than the near limit) equals the distance to the nearest of its five half-spaces, built here from
  cross products of the image-corner rays, and is at most the distance to sampled unseen points; the
  direction is that half-space's inward normal.
* :func:`ray_distance_from`, :func:`first_index`, :func:`next_tile` against the analytic point-to-ray
  distance, the smallest multiple, and a driver that checks that no tile that can hold something nearer
  than the running best (``min``) or within reach (``all`` / ``hybrid``) is skipped.
* a point in doubt (a NaN or infinite coordinate, or beyond ``region.FAR``, where squared norms and indices
  overflow): the box is the whole image and P lies in the unseen space (distance 0), never "nothing"; through
  :func:`query_distances` and :class:`DepthGridFusion` too (a point 1e160 m away behind a wall, in its gray
  area, was "nothing within ρ").

The end-to-end check of :func:`depthguard.depthspace.query_distances` on random analytic scenes is
``tests/test_distance_guarantees.py``; here only scenes that it does not draw: spheres near and beyond the
image border of cameras whose principal point lies far off centre or outside the image.
"""

from __future__ import annotations

import itertools
import math
from functools import partial

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.kernels.hits import no_hits
from depthguard.kernels.records import intrinsics, query_params
from depthguard.kernels.region import (
    first_index,
    next_tile,
    ray_distance_from,
    surveillance_box,
    tile_lower_bounds,
    unseen_space,
)
from depthguard.validation import MAX_COORDINATE

SOME = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FEW = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
INF = math.inf


# ------------------------------------------------------------------------------------------ strategies
@st.composite
def cameras(draw, max_side=40):
    """A Camera with unusual intrinsics: 1x1 images, fx != fy, tiny and huge focal lengths, principal point
    anywhere from three images left of the image to three images right of it."""
    w = draw(st.integers(1, max_side))
    h = draw(st.integers(1, max_side))
    fx = max(w, 4) * 10 ** draw(st.floats(-1.5, 1.5))
    fy = fx * 10 ** draw(st.floats(-0.5, 0.5))
    cx = w * draw(st.sampled_from([0.5, 0.0, 1.0, -3.0, 4.0]) | st.floats(-3.0, 4.0))
    cy = h * draw(st.sampled_from([0.5, 0.0, 1.0, -3.0, 4.0]) | st.floats(-3.0, 4.0))
    near = draw(st.floats(0.01, 1.0))
    return Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, min_depth=near, max_depth=near + 8.0)


@st.composite
def points(draw, cam):
    """A camera-frame point seen near image point (pu, pv) (inside, on the border, on a pixel or tile corner, or
    outside the image) at depth z (behind the camera, near z = 0 and the near limit included), plus an
    offset of up to 5 % of its depth."""

    def coordinate(n):
        far = st.floats(-2.0, 3.0).map(lambda f: f * n)
        corner = st.tuples(st.integers(-2, n + 2), st.sampled_from([0.0]) | st.floats(-0.3, 0.3)).map(sum)
        return draw(st.sampled_from([0.0, 0.5 * n, float(n)]) | st.floats(-0.2 * n, 1.2 * n) | corner | far)

    pu, pv = coordinate(cam.width), coordinate(cam.height)
    near = cam.min_depth
    z = draw(st.sampled_from([0.0, 1e-7, -1e-7, near, 1.0]) | st.floats(-1.0, 5.0) | st.floats(0.8 * near, 2 * near))
    off = np.array([draw(st.sampled_from([0.0]) | st.floats(-0.05, 0.05)) for _ in range(3)]) * max(abs(z), 0.1)
    return np.array([(pu - cam.cx) / cam.fx * z, (pv - cam.cy) / cam.fy * z, z]) + off


@st.composite
def points_in_view(draw, cam):
    """A camera-frame point inside the view, near its side planes or its near plane."""
    pu = cam.width * draw(st.sampled_from([0.0, 1.0]) | st.floats(0.0, 1.0))
    pv = cam.height * draw(st.sampled_from([0.0, 1.0]) | st.floats(0.0, 1.0))
    z = cam.min_depth * draw(st.sampled_from([1.0]) | st.floats(1.0, 5.0))
    return np.array([(pu - cam.cx) / cam.fx * z, (pv - cam.cy) / cam.fy * z, z])


REFF = st.sampled_from([0.0, 1e-9, 0.4]) | st.floats(1e-6, 3.0)


# ------------------------------------------------------------------------------------------ references
def project(cam, X):
    """(M, 2) continuous image coordinates of camera-frame points X (M, 3) with z > 0 (ICRA'12 eq. 3)."""
    return np.stack([cam.fx * X[:, 0] / X[:, 2] + cam.cx, cam.fy * X[:, 1] / X[:, 2] + cam.cy], axis=1)


def cube_points(P, half, n=5):
    """(n³, 3) a grid over the cube of half side ``half`` around P, its 8 corners included."""
    g = np.linspace(-half, half, n)
    return P + np.array(list(itertools.product(g, g, g)))


def polyhedron_distance(P, N, c):
    """Exact distance from P to the convex polyhedron ``{x : N x >= c}`` (N (m, 3)): the nearest point is the
    projection of P onto the affine hull of the face, edge or vertex it lies on (KKT), so the nearest
    feasible projection over every set of 1-3 constraints (0 when P is inside)."""
    scale = 1.0 + np.abs(P).max()
    tol = 1e-11 * scale

    def feasible(x):
        return np.all(N @ x >= c - tol * np.linalg.norm(N, axis=1))

    if feasible(P):
        return 0.0
    best = INF
    for k in (1, 2, 3):
        for S in itertools.combinations(range(len(N)), k):
            A = N[list(S)]
            G = A @ A.T
            if abs(np.linalg.det(G)) < 1e-14 * np.prod(np.diag(G)):
                continue
            x = P - A.T @ np.linalg.solve(G, A @ P - c[list(S)])
            if feasible(x):
                best = min(best, float(np.linalg.norm(P - x)))
    return best


def frustum_constraints(cam, u0, u1, v0, v1, zmin):
    """``(N, c)``: the frustum of the image rectangle [u0, u1] x [v0, v1] at depths >= zmin as ``N x >= c``."""
    A0, A1 = (u0 - cam.cx) / cam.fx, (u1 - cam.cx) / cam.fx
    B0, B1 = (v0 - cam.cy) / cam.fy, (v1 - cam.cy) / cam.fy
    N = np.array([[1.0, 0.0, -A0], [-1.0, 0.0, A1], [0.0, 1.0, -B0], [0.0, -1.0, B1], [0.0, 0.0, 1.0]])
    return N, np.array([0.0, 0.0, 0.0, 0.0, zmin])


def frustum_samples(cam, u0, u1, v0, v1, zmin, P, rng, n=60):
    """Points of the frustum of [u0, u1) x [v0, v1) at depths >= zmin: jittered image points at the depth
    nearest to P along their ray (not before zmin), at zmin and behind it."""
    pu = rng.uniform(u0, u1, n)
    pv = rng.uniform(v0, v1, n)
    a, b = (pu - cam.cx) / cam.fx, (pv - cam.cy) / cam.fy
    s = np.maximum((P[0] * a + P[1] * b + P[2]) / (a * a + b * b + 1.0), zmin)
    s = np.concatenate([s, np.full(n, zmin), zmin + rng.uniform(0.0, 2.0, n)])
    a, b = np.tile(a, 3), np.tile(b, 3)
    return np.stack([a * s, b * s, s], axis=1)


# ---------------------------------------------------------------------------------- region of surveillance
def check_box_contains_cube(cam, P, reff):
    intr = intrinsics(cam)
    u0, u1, v0, v1 = surveillance_box(float(P[0]), float(P[1]), float(P[2]), float(reff), intr)
    if P[2] - reff <= 0.0:  # the cube reaches the camera plane or behind it: the whole image
        assert (u0, u1, v0, v1) == (0, cam.width - 1, 0, cam.height - 1), (P, reff)
        return
    q = project(cam, cube_points(P, reff))
    pix = np.floor(q)
    inside = (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
    # the projection of the cube (convex, in front) spans the corners' u and v ranges: every pixel between
    # the corners' pixels may meet it
    lo, hi = pix.min(axis=0), pix.max(axis=0)
    ref = (max(lo[0], 0), min(hi[0], cam.width - 1), max(lo[1], 0), min(hi[1], cam.height - 1))
    if inside.any():
        assert u0 <= ref[0] and ref[1] <= u1 and v0 <= ref[2] and ref[3] <= v1, (P, reff, (u0, u1, v0, v1), ref)
    assert 0 <= u0 and u1 <= cam.width - 1 and 0 <= v0 and v1 <= cam.height - 1


@SOME
@given(data=st.data(), reff=REFF)
def test_surveillance_box_contains_every_pixel_whose_frustum_meets_the_cube(data, reff):
    cam = data.draw(cameras())
    P = data.draw(points(cam))
    check_box_contains_cube(cam, P, reff)


@pytest.mark.parametrize(
    ("P", "reff"),
    [
        pytest.param((0.0, 0.0, 0.4 + 1e-7), 0.4, id="near-face-just-in-front"),
        pytest.param((0.0, 0.0, 0.4), 0.4, id="near-face-on-the-camera-plane"),
        pytest.param((0.0, 0.0, -1.0), 0.1, id="behind"),
        pytest.param((3.0, 0.0, 0.5), 0.1, id="beside-the-camera"),
        pytest.param((1e13, 0.0, 1.0 + 2e-6), 1.0, id="far-right-near-z0"),
        pytest.param((-1e13, 0.0, 1.0 + 2e-6), 1.0, id="far-left-near-z0"),
        pytest.param((-0.41, 0.0, 1.0), 0.4, id="left-of-the-view-reaching-in"),
        pytest.param((0.0, 0.0, 1e6), 1e-9, id="far-on-axis"),
    ],
)
def test_surveillance_box_at_the_edges_of_its_domain(P, reff):
    for cam in (
        Camera(width=32, height=24, fx=30.0, fy=45.0, cx=16.0, cy=12.0),
        Camera(width=1, height=1, fx=2.0, fy=2.0, cx=0.5, cy=0.5),
        Camera(width=20, height=10, fx=10.0, fy=10.0, cx=-30.0, cy=25.0),
    ):
        check_box_contains_cube(cam, np.array(P, float), reff)


IN_DOUBT = [
    pytest.param((math.nan, 0.0, 1.0), id="nan-x"),
    pytest.param((0.0, math.nan, 1.0), id="nan-y"),
    pytest.param((0.0, 0.0, math.nan), id="nan-z"),
    pytest.param((-math.inf, 0.0, 1.0), id="-inf-x"),
    pytest.param((0.0, math.inf, 1.0), id="inf-y"),
    pytest.param((0.0, 0.0, math.inf), id="inf-z"),
    pytest.param((1e12, 0.0, 1.0), id="far-x"),
    pytest.param((0.0, 0.0, 1e160), id="far-z"),
    pytest.param((-1e20, 0.0, 1e20), id="far-left"),
]


@pytest.mark.parametrize("P", IN_DOUBT)
def test_a_point_in_doubt_gets_the_whole_image(P):
    """Not finite, or so far that squared norms overflow: no box can be trusted (an empty one drops every
    obstacle)."""
    cam = Camera(width=32, height=24, fx=30.0, fy=30.0, cx=16.0, cy=12.0)
    assert surveillance_box(*P, 0.05, intrinsics(cam)) == (0, 31, 0, 23)
    assert surveillance_box(0.0, 0.0, 1.0, math.nan, intrinsics(cam)) == (0, 31, 0, 23)


# ----------------------------------------------------------------------------------------- tile bounds
@st.composite
def tile_cases(draw):
    cam = draw(cameras(max_side=24))
    P = draw(points(cam))
    reff = draw(REFF)
    tile = draw(st.integers(1, 8))
    th, tw = -(-cam.height // tile), -(-cam.width // tile)
    depth = st.sampled_from([INF, cam.min_depth, 1e-3]) | st.floats(0.01, 6.0)
    tmin = np.array([[draw(depth) for _ in range(tw)] for _ in range(th)], np.float32)
    u0 = draw(st.integers(0, cam.width - 1))
    v0 = draw(st.integers(0, cam.height - 1))
    box = (u0, draw(st.integers(u0, cam.width - 1)), v0, draw(st.integers(v0, cam.height - 1)))
    nparts = draw(st.sampled_from([1, 1, 2, 3]))
    return cam, P, reff, tile, tmin, box, draw(st.integers(0, nparts - 1)), nparts


@FEW
@given(case=tile_cases(), seed=st.integers(0, 2**16))
def test_tile_bounds_are_lower_bounds_of_the_tile_frustum_beyond_its_smallest_depth(case, seed):
    cam, P, reff, tile, tmin, box, part, nparts = case
    rng = np.random.default_rng(seed)
    lbs = np.full(tmin.size, np.nan)
    px, py, pz = (float(x) for x in P)
    t_u0, t_v0, ntu, ntiles = tile_lower_bounds(
        tmin, px, py, pz, float(reff), box, intrinsics(cam), tile, lbs, part, nparts
    )
    assert (t_u0, t_v0) == (box[0] // tile, box[2] // tile)
    assert ntu == box[1] // tile - t_u0 + 1 and ntiles == ntu * (box[3] // tile - t_v0 + 1)
    for k in range(ntiles):
        tv, tu = t_v0 + k // ntu, t_u0 + k % ntu
        dmin = float(tmin[tv, tu])
        if nparts > 1 and tv % nparts != part:
            assert lbs[k] == INF
            continue
        if dmin > pz + reff:  # RA-L'16 case i: every point at depth >= dmin is further than reff from P
            assert lbs[k] == INF
            continue
        assert not math.isnan(lbs[k]) and lbs[k] < INF, (k, lbs[k], dmin, P, reff)
        ua, ub = tu * tile, min(cam.width, tu * tile + tile)
        va, vb = tv * tile, min(cam.height, tv * tile + tile)
        exact = polyhedron_distance(P, *frustum_constraints(cam, ua, ub, va, vb, dmin))
        X = frustum_samples(cam, ua, ub, va, vb, dmin, P, rng)
        sampled = np.linalg.norm(X - P, axis=1).min()
        assert exact <= sampled * (1 + 1e-9) + 1e-12, (exact, sampled)  # (the reference itself)
        # (the reference's own rounding: 1e-12 of the scene's size)
        assert lbs[k] <= exact + 1e-12 * (1.0 + np.abs(P).max()), (k, lbs[k], exact, P, reff, dmin)


# ------------------------------------------------------------------------------------------ unseen space
def unseen_half_spaces(cam):
    """(5, 3) unit inward normals and (5,) offsets of the half-spaces whose union is the unseen region:
    ``n . x < c``. The side planes hold the camera centre and two image-corner rays (cross product), the
    normal turned towards the ray through the image centre; the near plane is ``z = min_depth``."""
    corners = [(0, 0), (cam.width, 0), (cam.width, cam.height), (0, cam.height)]
    ray = [np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0]) for u, v in corners]
    mid = np.array([(cam.width / 2 - cam.cx) / cam.fx, (cam.height / 2 - cam.cy) / cam.fy, 1.0])
    normals = []
    for i in range(4):
        n = np.cross(ray[i], ray[(i + 1) % 4])
        n /= np.linalg.norm(n)
        normals.append(n if n @ mid > 0 else -n)
    normals.append(np.array([0.0, 0.0, 1.0]))
    return np.array(normals), np.array([0.0, 0.0, 0.0, 0.0, cam.min_depth])


def is_unseen(cam, X):
    z = X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pu = cam.fx * X[:, 0] / z + cam.cx
        pv = cam.fy * X[:, 1] / z + cam.cy
    return ~((z >= cam.min_depth) & (pu >= 0) & (pu <= cam.width) & (pv >= 0) & (pv <= cam.height))


@SOME
@given(data=st.data(), reff=REFF, mode=st.sampled_from([0, 1, 2]), seed=st.integers(0, 2**16))
def test_unseen_space_distance_is_that_of_its_nearest_half_space(data, reff, mode, seed):
    cam = data.draw(cameras())
    P = data.draw(points(cam) | points_in_view(cam))
    radius = data.draw(st.sampled_from([0.0, 0.1]))
    rho = reff + 1e-3
    qp = query_params(rho, mode, 6.0, True, 16)
    h = unseen_space(no_hits(rho + radius), *(float(x) for x in P), radius, intrinsics(cam), qp)
    N, c = unseen_half_spaces(cam)
    s = np.maximum(N @ P - c, 0.0)  # distance to each half-space n . x < c
    truth = s.min()
    scale = 1e-12 * (1.0 + np.abs(P).max())
    assert h.count == 0.0  # the unseen space is not an obstacle pixel
    if truth >= rho + radius:
        assert h.best == rho + radius and h.sx == h.sy == h.sz == 0.0
        return
    assert abs(h.best - truth) <= scale, (h.best, truth)
    assert h.best >= 0.0
    b = np.array([h.bx, h.by, h.bz])
    j = [k for k in range(5) if abs(s[k] - truth) <= scale]
    assert any(np.allclose(b, N[k], atol=1e-9) for k in j), (b, N[j])
    if truth > 0:
        np.testing.assert_allclose([h.nx, h.ny, h.nz], P - truth * b, atol=1e-9 * (1 + np.abs(P).max()))
    # brute force: no unseen point nearer than the reported distance
    rng = np.random.default_rng(seed)
    X = P + rng.uniform(-1.0, 1.0, (400, 3)) * (truth + 0.05)
    X = X[is_unseen(cam, X)]
    if len(X):
        assert h.best <= np.linalg.norm(X - P, axis=1).min() + scale


@pytest.mark.parametrize("P", IN_DOUBT)
@pytest.mark.parametrize("mode", [0, 1, 2], ids=["min", "all", "hybrid"])
def test_a_point_in_doubt_lies_in_the_unseen_space(P, mode):
    cam = Camera(width=32, height=24, fx=30.0, fy=30.0, cx=16.0, cy=12.0)
    h = unseen_space(no_hits(0.4), *P, 0.0, intrinsics(cam), query_params(0.4, mode, 6.0, True, 16))
    assert h.best == 0.0 and math.isclose(math.hypot(h.bx, h.by, h.bz), 1.0)


@pytest.mark.parametrize("backend", ["depthspace", "fusion"])
@pytest.mark.parametrize("mode", ["min", "all", "hybrid"])
def test_a_point_too_far_for_the_arithmetic_is_not_reported_free(mode, backend):
    """A centre far away on the optical axis, behind a wall 2 m in front of the camera, lies in the wall's gray
    area (truth: 0); beyond 1e154 m its squared distances overflowed to inf, which made it "nothing within ρ"
    (from 1e18 m with the depth grid's cell index). The public queries refuse centres beyond
    ``MAX_COORDINATE`` (1e9 m) by name; up to there the answer is 0 (beyond ``FAR`` the kernels: in doubt)."""
    R, t = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])
    cam = Camera(width=32, height=24, fx=30.0, fy=30.0, cx=16.0, cy=12.0, R=R, t=t, min_depth=0.3)
    depth = np.full(cam.shape, 2.0, np.float32)
    if backend == "fusion":
        fusion = DepthGridFusion([cam], dd=0.02)
        fusion.update([depth])
    frame = prepare_frame(cam, depth)
    for z in (1e3, 1e6, 1e9, 1.1e9, 1e13, 1e20, 1e100, 1e160, 1e300):
        P = cam.camera_to_world(np.array([0.0, 0.0, z]))[None]
        query = fusion.query if backend == "fusion" else partial(query_distances, frame)
        if z > MAX_COORDINATE:
            with pytest.raises(ValueError, match="within 1e"):
                query(P, 0.0, rho=0.4, mode=mode)
        else:
            assert query(P, 0.0, rho=0.4, mode=mode).distance[0] == 0.0, z


# ------------------------------------------------------------------------------- rays, indices, tile order
@SOME
@given(
    P=st.tuples(*[st.floats(-10.0, 10.0)] * 3),
    a=st.floats(-5.0, 5.0),
    b=st.floats(-5.0, 5.0),
    s_min=st.floats(-1.0, 10.0),
)
def test_ray_distance_from_is_the_distance_to_the_half_ray(P, a, b, s_min):
    P = np.array(P)
    r = np.array([a, b, 1.0])
    dx, dy, dz, s = ray_distance_from(*P, a, b, s_min)
    t = max(s_min, float(P @ r / (r @ r)))  # the foot of the perpendicular, clamped to the half-ray
    tol = 1e-12 * (1.0 + np.abs(P).max() + abs(s_min)) * (1.0 + abs(a) + abs(b))
    assert abs(s - t) <= tol
    np.testing.assert_allclose([dx, dy, dz], P - t * r, atol=tol * 10)
    ss = np.linspace(s_min, s_min + 20.0, 401)
    assert math.sqrt(dx * dx + dy * dy + dz * dz) <= np.linalg.norm(P - ss[:, None] * r, axis=1).min() + tol * 10


@given(lo=st.integers(0, 10**6), step=st.integers(1, 64))
def test_first_index_is_the_smallest_multiple_at_or_above(lo, step):
    k = first_index(lo, step)
    assert k % step == 0 and lo <= k < lo + step


@SOME
@given(
    lbs=st.lists(st.sampled_from([INF, 0.0, -1.0]) | st.floats(0.0, 2.0), min_size=1, max_size=12),
    reff=st.floats(0.05, 1.5),
    mode=st.sampled_from([0, 1, 2]),
    stride=st.sampled_from([1, 2, 3]),
    seed=st.integers(0, 2**16),
)
def test_next_tile_never_skips_a_tile_that_can_hold_something_nearer(lbs, reff, mode, stride, seed):
    """A driver as the queries run it; a visited tile lowers ``best`` to a value not below its bound."""
    rng = np.random.default_rng(seed)
    orig = np.array(lbs)
    work = orig.copy()
    n = len(orig)
    best = reff
    visited = []
    for kk in range(n + 1):
        k, lattice_only = next_tile(work, n, kk, best, reff, mode, stride)
        if k < 0:
            break
        if k == n:
            continue
        assert k not in visited
        visited.append(k)
        # lattice_only: the tile cannot beat best (only its lattice pixels count, for the direction)
        assert lattice_only == (mode != 0 and stride > 1 and not orig[k] < best), (k, lattice_only, best)
        if rng.random() < 0.5 and orig[k] < best:
            best = float(rng.uniform(max(orig[k], 0.0), best))
    for k in set(range(n)) - set(visited):
        assert orig[k] >= (best if mode == 0 else reff), (k, orig[k], best, reff, visited)
    if mode != 0:  # every tile within reach, row-major after the nearest one (with a lattice)
        within = [k for k in range(n) if orig[k] < reff]
        assert sorted(visited) == within
        rest = visited[1:] if stride > 1 else visited
        assert rest == sorted(rest)


# --------------------------------------------------------------------------- end to end: the image border
@FEW
@given(seed=st.integers(0, 2**32 - 1), mode=st.sampled_from(["min", "all", "hybrid"]))
def test_spheres_at_the_image_border_of_off_centre_cameras_are_never_further_than_reported(seed, mode):
    """A sphere seen through a pixel at the image border of a camera whose principal point lies far off centre
    or outside the image (``test_distance_guarantees`` draws cx, cy in the middle 60 % of the image), control
    spheres around it, inside and outside the view: the reported distance is at most the distance to every
    point of the pixel frusta behind the depths the frame holds (exact ray casting here), and with the
    conservative policy to every unseen point of the sphere and to P itself when P is unseen."""
    rng = np.random.default_rng(seed)
    w, h = int(rng.integers(1, 30)), int(rng.integers(1, 30))
    fx = max(w, 4) * rng.uniform(0.4, 2.0)
    fy = fx * rng.uniform(0.6, 1.6)
    cx = w * rng.choice([-1.5, -0.2, 0.0, 1.0, 1.3, 2.5])
    cy = h * rng.choice([-1.5, -0.2, 0.0, 1.0, 1.3, 2.5])
    eye = rng.normal(size=3)
    R, t = look_at(eye, eye + rng.normal(size=3), rng.normal(size=3))
    cam = Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, R=R, t=t, min_depth=0.2)
    bu, bv = rng.choice([0.0, w - 1.0]) + rng.uniform(0, 1), rng.uniform(0, h)  # a border column
    depth = rng.uniform(0.5, 3.0)
    centre = np.array([(bu - cx) / fx * depth, (bv - cy) / fy * depth, depth])
    radius = rng.uniform(0.02, 0.3)
    v, u = np.mgrid[0:h, 0:w].astype(float)
    rays = np.stack([(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
    bq, aq = rays @ centre, (rays * rays).sum(axis=1)
    disc = bq * bq - aq * (centre @ centre - radius * radius)
    z = np.where(disc >= 0, (bq - np.sqrt(np.maximum(disc, 0.0))) / aq, np.inf)  # depth of the first hit
    invalid = str(rng.choice(["conservative", "ignore"]))
    frame = prepare_frame(cam, z.reshape(h, w).astype(np.float32), invalid=invalid)
    Pc = centre + rng.normal(scale=0.4, size=(24, 3))
    radii = rng.uniform(0.0, 0.1, len(Pc)) * (rng.random(len(Pc)) < 0.7)
    rho = float(rng.uniform(0.1, 1.0))
    res = query_distances(frame, cam.camera_to_world(Pc), radii, rho=rho, mode=mode)
    hit = np.flatnonzero(np.isfinite(z))
    zo = z[hit].astype(np.float32).astype(float)  # the depth the frame holds
    X = [np.zeros((0, 3))]
    for dd in (0.0, 0.02, 0.3, 1.0):  # jittered points of each pixel's frustum behind its depth
        pu = u.ravel()[hit] + rng.uniform(0.0, 1.0, len(hit))
        pv = v.ravel()[hit] + rng.uniform(0.0, 1.0, len(hit))
        s = zo + dd
        X.append(np.stack([(pu - cx) / fx * s, (pv - cy) / fy * s, s], axis=1))
    if invalid == "conservative":
        sph = rng.normal(size=(600, 3))
        sph = centre + radius * sph / np.linalg.norm(sph, axis=1, keepdims=True)
        X.append(sph[is_unseen(cam, sph)])
    X = np.concatenate(X)
    for i in range(len(Pc)):
        d = np.maximum(np.linalg.norm(X - Pc[i], axis=1) - radii[i], 0.0)
        truth = d.min() if len(d) else INF
        if invalid == "conservative" and is_unseen(cam, Pc[i][None])[0]:
            truth = 0.0
        tol = 1e-9 * (1.0 + np.linalg.norm(Pc[i]))
        assert min(res.distance[i], rho) <= truth + tol, (i, res.distance[i], truth, Pc[i], radii[i])
