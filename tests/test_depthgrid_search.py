"""The column search (RA-L'16 §VI case iii/iv) with its block skipping equals a cell-by-cell search."""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthgrid import _kernels as K
from depthguard.depthspace import TILE
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

WALLS = (
    HalfSpace(np.array([-2.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
    HalfSpace(np.array([0.0, -2.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    HalfSpace(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 1.0])),
)


def camera(eye, target, w=96, h=72, f=80.0) -> Camera:
    R, t = look_at(eye, target)
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2 - 0.5, cy=h / 2 - 0.5, R=R, t=t, min_depth=0.3, max_depth=6.0)


def brute_force(fusion, u, v, P_c, limit):
    """Nearest occupied depth interval of pixel (u, v), testing every cell with the per-cell rule."""
    g_ = fusion.grid
    cam = fusion.cameras[0]
    kind = int(fusion._kind[v, u])
    s0 = float(fusion._start[v, u])
    surface, robot = kind == K.KIND_SURFACE, kind == K.KIND_ROBOT
    a = (u + 0.5 - cam.cx) / cam.fx
    b = (v + 0.5 - cam.cy) / cam.fy
    h = 0.5 * math.sqrt(cam.fx**-2 + cam.fy**-2)
    s_line = (P_c @ np.array([a, b, 1.0])) / (a * a + b * b + 1.0)
    g_start = -1 if s0 < g_.d_min else min(int(math.floor((s0 - g_.d_min) / g_.dd)), g_.n_cells)
    best = None
    for g in range(g_start, g_.n_cells + 1):
        lo, hi = K._seg_lo_hi(g, g_start, s0, g_.d_min, g_.dd, g_.n_cells)
        dr = K._ray_seg_dist(P_c[0], P_c[1], P_c[2], a, b, s_line, lo, hi)
        if not dr * (1.0 - h) - h * P_c[2] < limit:
            continue
        if g < 0 or g >= g_.n_cells:
            occupied = not robot
        elif surface and g == g_start:
            occupied = True
        else:
            occupied = K.cell_occupied(u, v, g, g_.d_min, g_.dd, *fusion.map.kernel_args(), fusion._votes, robot)
        if occupied and (best is None or dr < best[0]):
            best = (dr, lo, hi)
    return best, (a, b, s0, surface, robot, h)


def scene_setup(seed, blocker=False, robot_occludes=False):
    """Two cameras, a few obstacles, a robot box (masked in both images), dropouts in the secondary image.

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
    depths[1][rng.random(depths[1].shape) < 0.05] = np.nan
    fusion = DepthGridFusion(cams, dd=0.01, workspace=(-1, 1, -1, 1, 0, 1.6), robot_occludes=robot_occludes)
    fusion.update(depths, masks)
    return rng, cams, fusion


@pytest.mark.parametrize(
    "seed,blocker,eager",
    [
        (0, False, False),
        (1, False, False),
        (2, False, True),
        (3, False, True),
        (4, True, False),
        (5, True, True),
        (6, True, True),
        (7, True, True),
    ],
)
def test_column_search_equals_cell_by_cell(seed, blocker, eager):
    """Block skipping (column blocks, tile blocks and, with ``eager``, the runs of tile blocks decided at
    once by ``tile_chunk_cleared`` for a random depth chunk) finds the same cell as a cell-by-cell search."""
    rng, cams, fusion = scene_setup(seed, blocker)
    cam = cams[0]
    g_ = fusion.grid
    checked = found_n = 0
    for _ in range(20):
        P = rng.uniform([0.0, -0.4, 0.6], [0.6, 0.4, 1.3])
        P_c = cam.world_to_camera(P)
        limit = float(rng.uniform(0.2, 0.6))
        # one tile at a time, its block states shared by its columns as in the query
        px, py, _ = cam.project(P)
        tu = int(np.clip(px // TILE + rng.integers(-1, 2), 0, cam.width // TILE - 1))
        tv = int(np.clip(py // TILE + rng.integers(-1, 2), 0, cam.height // TILE - 1))
        tstate = np.zeros(g_.n_cells // K.TILE_BLOCK + 1, dtype=np.uint8)
        stack = np.empty(3 * K.PYR_STACK, dtype=np.int64)
        if eager:
            tb0 = int(rng.integers(0, g_.n_cells // K.TILE_BLOCK))
            tb1 = int(rng.integers(tb0, g_.n_cells // K.TILE_BLOCK + 1))
            K.tile_chunk_cleared(
                tu * TILE,
                tv * TILE,
                min(cam.width, tu * TILE + TILE),
                min(cam.height, tv * TILE + TILE),
                tb0,
                tb1,
                g_.d_min,
                g_.dd,
                g_.n_cells,
                fusion.map.corner_rays,
                fusion.map.cams,
                fusion._votes,
                fusion._pyr,
                fusion._pyr_meta,
                stack,
                tstate,
                bool(rng.integers(0, 2)),
            )
        for v in range(tv * TILE, tv * TILE + TILE, 2):
            for u in range(tu * TILE, tu * TILE + TILE, 2):
                if fusion._kind[v, u] == K.KIND_NONE:
                    continue
                ref, (a, b, s0, surface, robot_px, h) = brute_force(fusion, u, v, P_c, limit)
                found, lo, hi, _ = K.column_search(
                    u,
                    v,
                    a,
                    b,
                    s0,
                    surface,
                    robot_px,
                    P_c[0],
                    P_c[1],
                    P_c[2],
                    h,
                    limit,
                    g_.d_min,
                    g_.dd,
                    g_.n_cells,
                    *fusion.map.kernel_args(),
                    fusion._votes,
                    tu * TILE,
                    tv * TILE,
                    min(cam.width, tu * TILE + TILE),
                    min(cam.height, tv * TILE + TILE),
                    tstate,
                    fusion._pyr,
                    fusion._pyr_meta,
                    stack,
                )
                checked += 1
                assert found == (ref is not None)
                if found:
                    found_n += 1
                    s_line = (P_c @ np.array([a, b, 1.0])) / (a * a + b * b + 1.0)
                    dr = K._ray_seg_dist(P_c[0], P_c[1], P_c[2], a, b, s_line, lo, hi)
                    assert dr == pytest.approx(ref[0], abs=1e-12)
    assert checked > 50 and found_n > 10, (checked, found_n)


def test_min_pyramid_equals_pixel_loop():
    """``rect_sees_past`` (min pyramid) answers exactly as the pixel loop over the rectangle."""
    rng = np.random.default_rng(11)
    votes = rng.uniform(0.5, 3.0, size=(2, 37, 53)).astype(np.float32)
    votes[0, 10:14, 20:30] = 0.0
    votes[1][rng.random((37, 53)) < 0.01] = np.inf
    meta, n = K.pyramid_layout(37, 53)
    pyr = np.zeros((2, n), dtype=np.float32)
    K.build_pyramid(votes, meta, pyr)
    stack = np.empty(3 * K.PYR_STACK, dtype=np.int64)
    for _ in range(3000):
        k = int(rng.integers(0, 2))
        u0, u1 = sorted(rng.integers(0, 53, 2))
        v0, v1 = sorted(rng.integers(0, 37, 2))
        thr = float(rng.choice([rng.uniform(0.4, 1.0), rng.uniform(0.0, 3.1)]))
        ref = bool(np.all(votes[k, v0 : v1 + 1, u0 : u1 + 1] > thr))
        assert K.rect_sees_past(k, u0, v0, u1, v1, thr, votes, pyr, meta, stack) == ref


def _same(a, b):
    return np.array_equal(a, b, equal_nan=True)


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
