"""The column search (RA-L'16 §VI cases iii/iv) and the fused query against first-principles references.

The references (``tests/reference_geometry.py``) are written from the definitions: a secondary camera
clears a cell when every pixel of the bounding box of the cell's 8 projected corners reads beyond the
cell's far depth; distances are exact point-to-frustum-piece distances. They share no code with the
kernels. Footprints exactly on a pixel boundary or far depths within the 0.4 mm quantum are ambiguous,
so each reference is computed twice (``lax``: fewer cells occupied, ``strict``: more) and the kernel must
lie between the two.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthgrid import records as K
from depthguard.depthgrid.chunks import tile_chunk_cleared
from depthguard.depthgrid.column import column_search
from depthguard.depthgrid.pyramid import build_pyramid, pyramid_layout, rect_sees_past, window_aware_votes
from depthguard.depthgrid.records import Grid, Votes
from depthguard.depthspace import TILE, lower_bound_slack
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth
from reference_geometry import _clears, grid_exact, unseen_distance

WALLS = (
    HalfSpace(np.array([-2.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
    HalfSpace(np.array([0.0, -2.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    HalfSpace(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 1.0])),
)


def camera(eye, target, w=96, h=72, f=80.0) -> Camera:
    R, t = look_at(eye, target)
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2 - 0.5, cy=h / 2 - 0.5, R=R, t=t, min_depth=0.3, max_depth=6.0)


def column_reference(inputs, fusion, u, v, P_c, limit, strict):
    """Nearest occupied segment (its ray distance) of principal pixel (u, v), from the definitions."""
    cams, depths, masks = inputs
    g_ = fusion.grid
    cam = cams[0]
    robot = bool(masks[0][v, u])
    s0 = float(depths[0][v, u])
    a = (u + 0.5 - cam.cx) / cam.fx
    b = (v + 0.5 - cam.cy) / cam.fy
    h = 0.5 * math.sqrt(cam.fx**-2 + cam.fy**-2)
    r = np.array([a, b, 1.0])

    def ray_dist(lo, hi):  # distance from P to the centre-ray points at depths [lo, hi]
        s = min(max((P_c @ r) / (r @ r), lo), hi)
        return float(np.linalg.norm(P_c - s * r))

    d_max = g_.d_min + g_.n_cells * g_.dd
    segs = []
    if not robot:
        if s0 < g_.d_min:
            segs.append((s0, g_.d_min, True))
        segs.append((max(d_max, s0), np.inf, True))
    g = np.arange(max(0, int(math.floor((s0 - g_.d_min) / g_.dd))), g_.n_cells)
    d1 = g_.d_min + g * g_.dd
    g = g[d1 + g_.dd > s0]
    d1 = g_.d_min + g * g_.dd
    uu, vv = np.full(len(g), u), np.full(len(g), v)
    votes = np.where(masks[1], np.inf, np.where(np.isfinite(depths[1]), depths[1], 0.0))
    eps = 1e-9 if strict else -1e-9
    cleared, _ = _clears(cam, cams[1], votes, uu, vv, d1, d1 + g_.dd, eps, quantise=strict)
    _, involved = _clears(cam, cams[1], votes, uu, vv, d1, d1 + g_.dd, -eps, quantise=False)
    occupied = ~cleared & (involved | (not robot))
    if not robot and len(g) and d1[0] <= s0:
        occupied[0] = True  # the cell of the measured surface
    for lo, hi, occ in zip(np.maximum(d1, s0), d1 + g_.dd, occupied, strict=True):
        segs.append((lo, hi, occ))
    best = None
    for lo, hi, occ in segs:
        dr = ray_dist(lo, hi)
        if occ and dr * (1.0 - h) - h * P_c[2] < limit and (best is None or dr < best):
            best = dr
    return best, (a, b, s0, not robot, robot, h)


def scene_setup(seed, blocker=False, robot_occludes=False):
    """Two cameras, a few obstacles, a robot box (masked in both images), drop-outs in the secondary image.

    With ``blocker`` a person-sized box stands between the principal camera and the workspace, so that
    most of the principal pixels near the robot are RA-L'16 case iii (``d_o < d_p``), as in ``ral-shadow``.
    """
    rng = np.random.default_rng(seed)
    cams = [camera([2.0, 0.0, 1.0], [0.0, 0.0, 0.9]), camera([0.2, 2.2, 1.3], [0.0, 0.0, 0.8])]
    prims = [Sphere(rng.uniform([0.2, -0.3, 0.7], [0.8, 0.3, 1.2]), rng.uniform(0.05, 0.15)) for _ in range(2)]
    prims.append(Capsule(rng.uniform(-0.4, 0.0, 3) + [0, 0, 1.0], rng.uniform(-0.4, 0.0, 3) + [0, 0, 0.8], 0.05))
    if blocker:
        y = rng.uniform(-0.15, 0.15)
        prims.append(Box(np.array([1.25, y, 0.9]), np.array([0.08, rng.uniform(0.15, 0.3), 0.5])))
    robot = Scene((Box(np.array([0.5, rng.uniform(-0.2, 0.2), 0.9]), np.array([0.05, 0.1, 0.2])),))
    full = Scene((*prims, *robot.primitives, *WALLS))
    depths = [render_depth(c, full) for c in cams]
    masks = []
    for c, d in zip(cams, depths, strict=True):
        dr = render_depth(c, robot)
        masks.append(np.isfinite(dr) & (dr <= d + 1e-9))
    # drop-outs in the secondary image where a Kinect has them (a band at the image border, a blob): they
    # clear nothing, so scattered random drop-outs would stop every tile-wide chunk from clearing
    depths[1][:, :6] = np.nan
    r0, c0 = int(rng.integers(10, 50)), int(rng.integers(10, 80))
    depths[1][r0 : r0 + 6, c0 : c0 + 6] = np.nan
    fusion = DepthGridFusion(cams, dd=0.01, workspace=(-1, 1, -1, 1, 0, 1.6), robot_occludes=robot_occludes)
    fusion.update(depths, masks)
    fusion.inputs = (cams, depths, masks)  # for the references
    return rng, cams, fusion


@pytest.mark.parametrize(
    "seed,blocker,eager",
    [(0, False, False), (1, False, True), (4, True, False), (5, True, True), (6, True, True)],
)
def test_column_search_matches_the_definition(seed, blocker, eager):
    """Block skipping (column blocks, tile blocks and, with ``eager``, the runs of tile blocks decided at
    once by ``tile_chunk_cleared`` for a random depth chunk) finds the nearest occupied segment of the
    definition (within the lax/strict ambiguity)."""
    rng, cams, fusion = scene_setup(seed, blocker)
    cam = cams[0]
    g_ = fusion.grid
    grid = Grid(g_.d_min, g_.dd, g_.n_cells)
    mp = fusion.map.kernel_args()
    vt = Votes(fusion._votes, fusion._pyr, fusion._pyr_meta)
    checked = found_n = 0
    for _ in range(12):
        P = rng.uniform([0.0, -0.4, 0.6], [0.6, 0.4, 1.3])
        P_c = cam.world_to_camera(P)
        limit = float(rng.uniform(0.2, 0.6))
        px, py, _ = cam.project(P)
        tu = int(np.clip(px // TILE + rng.integers(-1, 2), 0, cam.width // TILE - 1))
        tv = int(np.clip(py // TILE + rng.integers(-1, 2), 0, cam.height // TILE - 1))
        rect = (tu * TILE, tv * TILE, min(cam.width, tu * TILE + TILE), min(cam.height, tv * TILE + TILE))
        sc = K.scratch(1, g_.n_cells)
        if eager:
            tb0 = int(rng.integers(0, g_.n_cells // K.TILE_BLOCK))
            tb1 = int(rng.integers(tb0, g_.n_cells // K.TILE_BLOCK + 1))
            tile_chunk_cleared(rect, tb0, tb1, grid, mp, vt, sc, bool(rng.integers(0, 2)))
        for v in range(tv * TILE, tv * TILE + TILE, 3):
            for u in range(tu * TILE, tu * TILE + TILE, 3):
                lax, (a, b, s0, surface, robot_px, h) = column_reference(fusion.inputs, fusion, u, v, P_c, limit, False)
                strict, _ = column_reference(fusion.inputs, fusion, u, v, P_c, limit, True)
                found, lo, hi, _ = column_search(
                    u, v, a, b, s0, surface, robot_px, tuple(P_c), h, limit, rect, grid, mp, vt, sc
                )
                checked += 1
                if lax is not None:
                    assert found
                if strict is None:
                    assert not found
                if found:
                    found_n += 1
                    r = np.array([a, b, 1.0])
                    dr = float(np.linalg.norm(P_c - min(max((P_c @ r) / (r @ r), lo), hi) * r))
                    assert strict - 1e-9 <= dr <= (np.inf if lax is None else lax + 1e-9)
    assert checked > 50 and found_n >= 5, (checked, found_n)


@pytest.mark.slow  # the exact reference: about 10-25 s of CPU per scene
@pytest.mark.parametrize("seed,blocker", [(30, False), (31, True), (32, True)])
def test_query_is_a_lower_bound_of_the_exact_distance(seed, blocker):
    """The fused distance lies between the exact distance to the occupied space (by definition, with the
    unseen space) less the declared frustum slack and the exact distance itself."""
    rng, cams, fusion = scene_setup(seed, blocker)
    cam0, (cams_, depths, masks) = cams[0], fusion.inputs
    g_ = fusion.grid
    kind = np.where(masks[0], "robot", np.where(np.isfinite(depths[0]), "surface", "none"))
    start = np.where(np.isfinite(depths[0]), depths[0], np.inf)
    votes = np.where(masks[1], np.inf, np.where(np.isfinite(depths[1]), depths[1], 0.0))
    P = rng.uniform([-0.4, -0.5, 0.4], [0.9, 0.5, 1.4], size=(8, 3))
    radii = rng.uniform(0.0, 0.08, len(P))
    res = {m: fusion.query(P, radii, rho=0.4, mode=m) for m in ("all", "min")}
    np.testing.assert_array_equal(res["all"].distance, res["min"].distance)
    found = 0
    for i in range(len(P)):
        Pc = cam0.world_to_camera(P[i])
        reff = 0.4 + radii[i]
        ex = {}
        for strict in (False, True):
            d = grid_exact(cams_, [votes], start, kind, g_.d_min, g_.dd, g_.n_cells, Pc, reff + 0.05, strict)
            ex[strict] = min(d, unseen_distance(cam0, Pc))
        k = res["all"].distance[i]
        if ex[False] < reff:
            assert np.isfinite(k) and k <= max(ex[False] - radii[i], 0.0) + 1e-9
        if np.isfinite(k) and k > 0:
            found += 1
            assert k + radii[i] >= ex[True] - lower_bound_slack(cam0, max(Pc[2], 0.0), reff)
    assert found >= 1


def test_min_pyramid_equals_pixel_loop():
    """``rect_sees_past`` (min pyramid) answers exactly as the pixel loop over the rectangle."""
    rng = np.random.default_rng(11)
    votes = rng.uniform(0.5, 3.0, size=(2, 37, 53)).astype(np.float32)
    votes[0, 10:14, 20:30] = 0.0
    votes[1][rng.random((37, 53)) < 0.01] = np.inf
    meta, n = pyramid_layout(37, 53)
    pyr = np.zeros((2, n), dtype=np.float32)
    build_pyramid(votes, meta, pyr)
    stack = np.empty(3 * K.PYR_STACK, dtype=np.int64)
    for _ in range(3000):
        k = int(rng.integers(0, 2))
        u0, u1 = sorted(rng.integers(0, 53, 2))
        v0, v1 = sorted(rng.integers(0, 37, 2))
        thr = float(rng.choice([rng.uniform(0.4, 1.0), rng.uniform(0.0, 3.1)]))
        ref = bool(np.all(votes[k, v0 : v1 + 1, u0 : u1 + 1] > thr))
        assert rect_sees_past(k, u0, v0, u1, v1, thr, Votes(votes, pyr, meta), stack) == ref


def test_min_pyramid_with_robot_windows_equals_pixel_rule():
    """With robot windows, ``rect_sees_past`` on the window-aware pyramid answers exactly as the per-pixel
    rule ``vote > d or lo <= d <= hi`` over the rectangle: windows that start before the vote (the pixel
    sees past everything up to ``hi``), windows behind the vote (a gap), windows touching the threshold."""
    rng = np.random.default_rng(12)
    K_, H, W = 2, 37, 53
    vote = rng.uniform(0.5, 3.0, size=(K_, H, W)).astype(np.float32)
    vote[0, 10:14, 20:30] = 0.0
    lo = np.full((K_, H, W), np.inf, np.float32)
    hi = np.full((K_, H, W), -np.inf, np.float32)
    blobs = []
    for k in range(K_):  # a few window blobs, some starting in front of the vote, some behind it
        for _ in range(6):
            v0, u0 = int(rng.integers(0, H - 8)), int(rng.integers(0, W - 8))
            dv, du = int(rng.integers(2, 9)), int(rng.integers(2, 9))
            blobs.append((k, u0, v0, du, dv))
            a = rng.uniform(0.2, 2.5)
            lo[k, v0 : v0 + dv, u0 : u0 + du] = a
            hi[k, v0 : v0 + dv, u0 : u0 + du] = a + rng.uniform(0.05, 0.8)
    votes = np.concatenate([vote, lo, hi], axis=1)
    meta, n = pyramid_layout(H, W)
    pyr = np.zeros((K_, n), dtype=np.float32)
    build_pyramid(window_aware_votes(votes, H), meta, pyr)
    vt = Votes(votes, pyr, meta, True)
    stack = np.empty(3 * K.PYR_STACK, dtype=np.int64)
    gaps = contiguous = 0
    for _ in range(4000):
        if rng.random() < 0.5:  # a rectangle inside a window blob
            k, bu, bv, du, dv = blobs[int(rng.integers(0, len(blobs)))]
            u0, u1 = sorted(bu + rng.integers(0, du, 2))
            v0, v1 = sorted(bv + rng.integers(0, dv, 2))
        else:
            k = int(rng.integers(0, K_))
            u0, u1 = sorted(rng.integers(0, W, 2))
            v0, v1 = sorted(rng.integers(0, H, 2))
        r = (k, slice(v0, v1 + 1), slice(u0, u1 + 1))
        thr = float(rng.choice([rng.uniform(0.2, 1.2), rng.uniform(0.0, 3.3), float(rng.choice(hi[r].ravel()))]))
        thr32 = np.float32(thr)
        in_window = (lo[r] <= thr32) & (thr32 <= hi[r])
        ref = bool(np.all((vote[r] > thr32) | in_window))
        gaps += int(ref and np.any(in_window & (lo[r] > vote[r])))
        contiguous += int(ref and np.any(in_window & (lo[r] <= vote[r])))
        assert rect_sees_past(k, u0, v0, u1, v1, thr, vt, stack) == ref, (k, u0, v0, u1, v1, thr)
    assert gaps > 20 and contiguous > 20  # both kinds of window did turn answers


def _same(a, b):
    return np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("seed,robot_occludes", [(30, False), (31, True)])
def test_column_cache_changes_no_answer(seed, robot_occludes):
    """The frame's column cache (cell states decided by earlier searches) changes no answer: queries in
    any order of modes, radii and points equal the queries without the cache, and a new frame set forgets
    the old states (the second frame set has the blocker moved)."""
    for frame in range(2):
        rng, cams, fusion = scene_setup(seed + 10 * frame, blocker=True, robot_occludes=robot_occludes)
        P = np.vstack([rng.uniform([-0.4, -0.5, 0.4], [0.9, 0.5, 1.4], size=(10, 3)), [[0.5, 0.0, 0.9]]])
        radii = rng.uniform(0.0, 0.08, len(P))
        votes_cached = votes_fresh = 0
        for rho, mode in [(0.4, "hybrid"), (0.2, "min"), (0.4, "min"), (0.2, "all"), (0.4, "hybrid")]:
            fusion.column_cache = False
            ref = fusion.query(P, radii, rho=rho, mode=mode)
            votes_fresh += int(fusion.last_votes.sum())
            fusion.column_cache = True
            got = fusion.query(P, radii, rho=rho, mode=mode)
            votes_cached += int(fusion.last_votes.sum())
            for f in ("distance", "direction", "nearest", "obstacle_pixels"):
                assert _same(getattr(got, f), getattr(ref, f)), (frame, mode, rho, f)
        assert votes_cached < 0.5 * votes_fresh  # the cache did save votes
    # one fusion object over two frame sets: the second set's answers are its own
    rng, cams, fusion = scene_setup(seed, blocker=True, robot_occludes=robot_occludes)
    P = rng.uniform([-0.4, -0.5, 0.4], [0.9, 0.5, 1.4], size=(12, 3))
    fusion.query(P, 0.05, rho=0.4, mode="hybrid")
    _, _, other = scene_setup(seed + 10, blocker=True, robot_occludes=robot_occludes)
    fusion.update(*other.inputs[1:])
    got = fusion.query(P, 0.05, rho=0.4, mode="hybrid")
    fusion.column_cache = False
    ref = fusion.query(P, 0.05, rho=0.4, mode="hybrid")
    assert _same(got.distance, ref.distance) and _same(got.direction, ref.direction)


@pytest.mark.parametrize("seed,robot_occludes", [(20, False), (21, False), (22, True), (23, False), (24, True)])
def test_chunked_query_equals_block_search(seed, robot_occludes):
    """Per-tile chunk tests and whole-tile skipping change no answer: the query with them equals the
    query with the block-by-block column search, in every mode, with a blocker in front of the principal
    camera, robot masks in both cameras and dropouts (the column search itself equals the cell-by-cell
    search, test above)."""
    rng, cams, fusion = scene_setup(seed, blocker=True, robot_occludes=robot_occludes)
    P = np.vstack([rng.uniform([-0.4, -0.5, 0.4], [0.9, 0.5, 1.4], size=(14, 3)), [[0.5, 0.0, 0.9]]])
    radii = rng.uniform(0.0, 0.08, len(P))
    saved = 0
    for rho in (0.2, 0.4):
        for mode in ("min", "all", "hybrid"):
            fusion._chunks = False
            ref = fusion.query(P, radii, rho=rho, mode=mode)
            ref_cells = fusion.last_cells.copy()
            fusion._chunks = True
            got = fusion.query(P, radii, rho=rho, mode=mode)
            assert _same(got.distance, ref.distance), (mode, rho)
            assert _same(got.direction, ref.direction), (mode, rho)
            assert _same(got.nearest, ref.nearest), (mode, rho)
            assert _same(got.obstacle_pixels, ref.obstacle_pixels), (mode, rho)
            assert np.all(fusion.last_cells <= ref_cells)
            saved += int((ref_cells - fusion.last_cells).sum())
    assert saved > 0  # the chunk tests did skip column searches


def _free_run_by_bits(words, g, going_up, lowest, n_cells):
    """Bit-by-bit reference of :func:`depthguard.depthgrid.column._free_run`."""

    def free(k):
        return bool((int(words[0, 0, 1 + (k >> 6)]) >> (k & 63)) & 1)

    step, stop = (1, n_cells) if going_up else (-1, lowest - 1)
    g += step
    while g != stop and free(g):
        g += step
    return g


@pytest.mark.parametrize("n_cells", [1, 63, 64, 65, 200])
def test_free_run_equals_the_bit_by_bit_scan(n_cells):
    """The word-at-a-time scan of cached free cells (trailing/leading zero counts) ends where a scan of
    one bit at a time ends, up and down, from every start, on sparse, dense and full bit sets (the bits
    beyond ``n_cells`` set too, as a stale record may leave them)."""
    from depthguard.depthgrid.column import _free_run

    rng = np.random.default_rng(n_cells)
    nw = (n_cells + 63) // 64
    for density in (0.0, 0.3, 0.9, 0.99, 1.0):
        words = np.zeros((1, 1, 1 + 2 * nw), np.uint64)
        bits = rng.random(64 * nw) < density
        for k in np.flatnonzero(bits):
            words[0, 0, 1 + (k >> 6)] |= np.uint64(1) << np.uint64(k & 63)
        for lowest in (0, n_cells // 3):
            for g in range(lowest - 1, n_cells + 1):
                for up in (True, False):
                    if (up and g >= n_cells) or (not up and g < lowest):
                        continue
                    want = _free_run_by_bits(words, g, up, lowest, n_cells)
                    assert _free_run(words, 0, 0, g, up, lowest, n_cells) == want, (density, lowest, g, up)
