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


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_column_search_equals_cell_by_cell(seed):
    rng = np.random.default_rng(seed)
    cams = [camera([2.0, 0.0, 1.0], [0.0, 0.0, 0.9]), camera([0.2, 2.2, 1.3], [0.0, 0.0, 0.8])]
    prims = [Sphere(rng.uniform([0.2, -0.3, 0.7], [0.8, 0.3, 1.2]), rng.uniform(0.05, 0.15)) for _ in range(2)]
    prims.append(Capsule(rng.uniform(-0.4, 0.0, 3) + [0, 0, 1.0], rng.uniform(-0.4, 0.0, 3) + [0, 0, 0.8], 0.05))
    robot = Scene((Box(np.array([0.5, rng.uniform(-0.2, 0.2), 0.9]), np.array([0.05, 0.1, 0.2])),))
    full = Scene((*prims, *robot.primitives, *WALLS))
    depths = [render_depth(c, full) for c in cams]
    masks = []
    for c, d in zip(cams, depths, strict=True):
        dr = render_depth(c, robot)
        masks.append(np.isfinite(dr) & (dr <= d + 1e-9))
    depths[1][rng.random(depths[1].shape) < 0.05] = np.nan
    fusion = DepthGridFusion(cams, dd=0.01, workspace=(-1, 1, -1, 1, 0, 1.6))
    fusion.update(depths, masks)
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
