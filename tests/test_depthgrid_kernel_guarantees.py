"""The depth grid's vote kernels (RA-L'16 §V-VI, conservative form) attacked directly, against references
written here: cell points sampled inside the frustum piece and projected with an independent pinhole formula
(world frame, no ray table), and a per-cell rule and a column search written from the documented rules.

The safety claim: camera k clears a cell only if it truly sees through all of it (every point of the cell
strictly in front of the reading of the pixel it projects to); a block is cleared only if each of its cells
is; the column search never reports an occupied segment farther than the nearest one the rules give.

Faults these tests found (each fails on the old code):

* blocks with robot windows (``block_cleared``, ``tile_block_cleared``, so also the per-tile chunks): a
  window behind the vote (a box in front of the arm, the case windows are for) passed a block whose far
  depth lay in the arm's body, clearing the space between the box and the arm that camera k cannot see,
  though the per-cell rule keeps those cells occupied (``test_a_cleared_block_holds_only_cleared_cells``,
  ``test_a_box_in_front_of_the_arm_clears_no_block_in_front_of_the_arm``).
* ``cell_footprint`` of a piece with an infinite, huge (> 3.7e15 m) or NaN depth: ``int()`` of the far depth
  overflowed to a negative ``q`` (every pixel then "sees past" it: cleared), NaN corners were dropped from
  the bounding box (``test_nonfinite_and_huge_depths_are_never_involved``).
* ``pixel_touches_cell`` with a NaN depth or a corner behind camera k said "not touched" (a NaN has no side
  of a line) (``test_pixel_touches_cell_keeps_pixels_when_in_doubt``).
* ``column_search``: the cell index of an infinite or huge depth (``int()`` overflow) was INT64_MIN, so a
  search with an unbounded limit never went up; a pixel wider than the frustum bound (``h >= 1``, fx below
  ~0.71 px) made the search window negative: nothing found where the beyond-grid space is at distance 0
  (``test_column_search_with_an_unbounded_limit_still_finds_the_space_beyond_the_grid``).
* the fused query with such wide pixels (1x1 images, fx 0.6): the per-tile chunks' window came out negative
  and skipped the tile: "nothing within rho" for points right behind a measured surface
  (``test_one_pixel_cameras_with_wide_pixels_still_report_the_measured_surface``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthgrid import records as K
from depthguard.depthgrid.column import column_search
from depthguard.depthgrid.footprint import DEND_SCALE, FOOT_MAX, Q_MAX, cell_footprint, rect_footprint
from depthguard.depthgrid.grid import DepthGrid
from depthguard.depthgrid.gridmap import GridMap
from depthguard.depthgrid.pyramid import build_pyramid, pyramid_layout, window_aware_votes
from depthguard.depthgrid.records import Grid, Votes
from depthguard.depthgrid.votes import block_cleared, cell_occupied, pixel_touches_cell, tile_block_cleared


def PROPERTY(n):  # noqa: N802
    return settings(max_examples=n, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------ independent geometry
def camera(rng, eye, target, w=None, h=None):
    w = int(w or rng.integers(1, 41))
    h = int(h or rng.integers(1, 31))
    f = max(w, h) * rng.uniform(0.7, 1.5)
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), rng.normal(size=3))
    return Camera(
        width=w, height=h, fx=f, fy=f * rng.uniform(0.8, 1.25), cx=w * rng.uniform(0.3, 0.7),
        cy=h * rng.uniform(0.3, 0.7), R=R, t=t, min_depth=0.2, max_depth=6.0,
    )  # fmt: skip


def camera_pair(rng, facing=False, w0=None, h0=None):
    """A principal camera looking at the origin and a secondary one: beside it, or (``facing``) across the
    scene looking back at the principal camera (the cells near the principal camera then lie behind it)."""
    eye0 = rng.normal(size=3)
    eye0 = eye0 / np.linalg.norm(eye0) * rng.uniform(1.5, 2.5)
    c0 = camera(rng, eye0, rng.uniform(-0.2, 0.2, 3), w0, h0)
    if facing:
        eye1 = -eye0 * rng.uniform(0.5, 1.2) + rng.normal(scale=0.3, size=3)
        c1 = camera(rng, eye1, eye0 + rng.normal(scale=0.3, size=3))
    else:
        eye1 = eye0 + rng.normal(scale=1.0, size=3)
        c1 = camera(rng, eye1, rng.uniform(-0.3, 0.3, 3))
    return c0, c1


def cell_points(c0, u, v, d1, d2, rng, n=200):
    """World points of the principal cell ``(u, v, [d1, d2])``: its 8 corners, points on its 12 edges and
    random points inside, from the pinhole model (pixel (u, v) covers ``[u, u+1] x [v, v+1]``)."""
    s = rng.random((n, 3))
    s[:8] = [[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)]
    e = rng.random((36, 3))  # on the edges: two coordinates at 0 or 1
    for j in range(36):
        fixed = [a for a in range(3) if a != j % 3]
        e[j, fixed] = [(j // 3) & 1, (j // 6) & 1]
    s = np.concatenate([s, e])
    d = d1 + (d2 - d1) * s[:, 2]
    xc = np.stack([(u + s[:, 0] - c0.cx) / c0.fx * d, (v + s[:, 1] - c0.cy) / c0.fy * d, d], axis=1)
    return (xc - c0.t) @ c0.R  # R^T (x - t), row-wise


def project(cam, Xw):
    """(pu, pv, z) of world points in camera ``cam``: ``p = f x / z + c``."""
    Xc = Xw @ cam.R.T + cam.t
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return cam.fx * Xc[:, 0] / z + cam.cx, cam.fy * Xc[:, 1] / z + cam.cy, z


def setup(rng, facing=False, n_cells=None, dd=None, w0=None, h0=None):
    c0, c1 = camera_pair(rng, facing, w0, h0)
    dd = dd or float(rng.choice([0.01, 0.03, 0.08]))
    n = n_cells or int(rng.integers(8, 60))
    grid = DepthGrid(c0, dd, float(rng.uniform(0.3, 1.5)), n)
    return c0, c1, grid, GridMap(grid, [c1]).kernel_args()


def votes_record(vote, lo=None, hi=None):
    """The kernels' :class:`Votes` for one secondary camera: (1, 3H, W) votes with windows, and the pyramid."""
    H, W = vote.shape
    lo = np.full((H, W), np.inf, np.float32) if lo is None else lo
    hi = np.full((H, W), -np.inf, np.float32) if hi is None else hi
    votes = np.ascontiguousarray(np.concatenate([vote, lo, hi])[None].astype(np.float32))
    meta, n = pyramid_layout(H, W)
    pyr = np.zeros((1, n), np.float32)
    windows = bool(np.isfinite(lo).any())
    build_pyramid(np.ascontiguousarray(window_aware_votes(votes, H) if windows else votes[:, :H]), meta, pyr)
    return Votes(votes, pyr, meta, windows)


def random_vote_image(rng, c1, level):
    """Readings around ``level`` (metres) with holes (0, as the frame stage writes NaN, inf, 0 and negatives)."""
    H, W = c1.height, c1.width
    vote = (level + rng.uniform(-0.3, 0.3) * rng.random((H, W)) + rng.uniform(-0.2, 0.5)).astype(np.float32)
    vote[rng.random((H, W)) < rng.choice([0.0, 0.02, 0.2])] = 0.0
    if rng.random() < 0.3:
        vote[:] = np.float32(rng.choice([np.inf, 1e30, 0.0]))
    return vote


# --------------------------------------------------------------------------------------- footprints
@PROPERTY(25)
@given(seed=st.integers(0, 2**32 - 1), facing=st.booleans())
def test_the_footprint_holds_every_point_of_the_cell(seed, facing):
    """Every sampled point of an involved cell projects into its pixel box, no deeper than ``d_end`` (up to
    one ulp); a cell with a point at or behind camera k's plane, or outside its image, is not involved."""
    rng = np.random.default_rng(seed)
    c0, c1, grid, mp = setup(rng, facing)
    behind = involved = 0
    for _ in range(60):
        u, v, g = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height)), int(rng.integers(0, grid.n_cells))
        d1 = grid.d_min + g * grid.dd
        d2 = d1 + grid.dd
        u0, v0, du, dv, q = cell_footprint(0, u, v, d1, d2, mp.corner_rays, mp.cams)
        pu, pv, z = project(c1, cell_points(c0, u, v, d1, d2, rng))
        if np.any(z <= 1e-6):
            behind += 1
            assert u0 == -1, (u, v, g, z.min())
            continue
        outside = (pu.min() < 0) | (pv.min() < 0) | (pu.max() >= c1.width) | (pv.max() >= c1.height)
        if u0 < 0:
            # refused: outside the image, too wide or too far (within rounding at the image border)
            near_edge = pu.min() < 1e-6 or pv.min() < 1e-6 or pu.max() > c1.width - 1e-6 or pv.max() > c1.height - 1e-6
            too_big = np.ptp(np.floor(pu)) > FOOT_MAX - 1 or np.ptp(np.floor(pv)) > FOOT_MAX - 1
            assert outside or near_edge or too_big or z.max() > Q_MAX * DEND_SCALE * (1 - 1e-9), (u, v, g)
            continue
        assert not outside, (u, v, g)
        involved += 1
        e = 1e-9  # (a corner exactly on a pixel edge: rounding of the two projections)
        assert np.all((pu >= u0 - e) & (pu < u0 + du + 1 + e) & (pv >= v0 - e) & (pv < v0 + dv + 1 + e)), (u, v, g)
        assert np.all(z <= q * DEND_SCALE * (1 + 1e-15)), (z.max(), q * DEND_SCALE)
    assert involved + behind <= 60


@pytest.mark.parametrize(
    "d1,d2",
    [(1.0, math.inf), (math.nan, 1.0), (1.0, math.nan), (1e300, 1e300), (1e16, 1.1e16), (-math.inf, 1.0), (20.0, 21.0)],
    ids=["far-inf", "near-nan", "far-nan", "huge", "overflowing-int", "near-minus-inf", "beyond-q-max"],
)
def test_nonfinite_and_huge_depths_are_never_involved(d1, d2):
    """A piece with no finite far depth below ``Q_MAX`` steps gets no vote (old: ``q`` = INT64_MIN for an
    infinite or huge far depth, so ``d_end`` < 0 and every pixel "saw past" it; NaN corners left out)."""
    M = np.eye(3)[None].copy()
    rt = K.RayTable(M, np.linspace(-0.5, 0.5, 11), np.linspace(-0.5, 0.5, 11))
    cams = np.array([[0.0, 0.0, 0.0, 10.0, 10.0, 5.0, 5.0, 10.0, 10.0]])
    assert cell_footprint(0, 4, 4, 1.0, 1.01, rt, cams)[0] == 4  # (a finite piece is involved)
    assert cell_footprint(0, 4, 4, d1, d2, rt, cams)[0] == -1
    assert rect_footprint(0, 3, 3, 6, 6, d1, d2, rt, cams)[0] == -1
    grid = Grid(0.5, 0.01, 10)
    mp = K.MapArrays(rt, rt, cams, False, np.zeros((1, 1, 1, 1), np.int64))
    vt = votes_record(np.full((10, 10), 2.0, np.float32))
    stack = np.empty(3 * K.PYR_STACK, np.int64)
    # a block out to 1e16 m is not cleared by a camera that sees a wall at 2 m (old: q overflowed, cleared)
    assert not block_cleared(4, 4, 0, 10**18, grid, mp, vt, stack)


@pytest.mark.parametrize("d1,d2", [(math.nan, 1.0), (1.0, math.inf), (-1.0, 1.0)], ids=["nan", "inf", "behind"])
def test_pixel_touches_cell_keeps_pixels_when_in_doubt(d1, d2):
    """A NaN or infinite depth, or a corner behind camera k: no separating line can be trusted, the pixel is
    kept (old: NaN comparisons made every line 'separate', the pixel was dropped)."""
    M = np.eye(3)[None].copy()
    rt = K.RayTable(M, np.linspace(-0.5, 0.5, 11), np.linspace(-0.5, 0.5, 11))
    cams = np.array([[0.0, 0.0, 0.0, 10.0, 10.0, 5.0, 5.0, 10.0, 10.0]])
    for pu, pv in [(4, 4), (0, 0), (9, 2)]:
        assert pixel_touches_cell(0, 4, 4, d1, d2, pu, pv, rt, cams)


# ------------------------------------------------------------------------------------ per-cell votes
def own_rule_clears(c0, c1, u, v, d1, d2, vote, rng, margin=1e-6):
    """The documented rule written out, lax side: in front, inside the image and every pixel that a sampled
    point of the cell falls in reads beyond the cell's far depth (all within ``margin``). The kernel clears
    no more than this (it reads every pixel the exact projection touches, against a far depth rounded up)."""
    pu, pv, z = project(c1, cell_points(c0, u, v, d1, d2, rng, n=400))
    if np.any(z <= 1e-6 - margin) or pu.min() < -margin or pv.min() < -margin:
        return False
    if pu.max() >= c1.width + margin or pv.max() >= c1.height + margin:
        return False
    iu = np.clip(np.floor(pu).astype(int), 0, c1.width - 1)
    iv = np.clip(np.floor(pv).astype(int), 0, c1.height - 1)
    return bool(np.all(vote[iv, iu] > z.max() - margin))


@PROPERTY(20)
@given(seed=st.integers(0, 2**32 - 1), facing=st.booleans(), stored=st.booleans())
def test_a_cleared_cell_lies_strictly_in_front_of_every_reading_it_projects_to(seed, facing, stored):
    """Without robot windows: a cell that ``cell_occupied`` clears has every sampled point strictly in front
    of the reading of the secondary pixel it projects to (so a missing pixel, vote 0, clears nothing); the
    stored map answers as the on-the-fly one; the kernel clears no more than the documented rule. (Behind a
    robot pixel, ``need_vote``, a cell that no camera watches is not occupied either: no witness.)"""
    rng = np.random.default_rng(seed)
    c0, c1, grid, mp = setup(rng, facing, n_cells=40)
    if stored:
        mp = GridMap(grid, [c1], "stored", cache_dir=False).kernel_args()
    g_ = Grid(grid.d_min, grid.dd, grid.n_cells)
    level = float(
        np.median(project(c1, cell_points(c0, c0.width // 2, c0.height // 2, grid.d_min, grid.d_max, rng))[2])
    )
    vote = random_vote_image(rng, c1, level)
    vt = votes_record(vote)
    cleared = 0
    for _ in range(120):
        u, v, g = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height)), int(rng.integers(0, grid.n_cells))
        d1 = grid.d_min + g * grid.dd
        d2 = d1 + grid.dd
        for need_vote in (False, True):
            if cell_occupied(u, v, g, g_, mp, vt.votes, need_vote):
                continue
            if need_vote and cell_footprint(0, u, v, d1, d2, mp.corner_rays, mp.cams)[0] < 0:
                continue  # case iv without a witness: unseen, not cleared (docs/conventions.md)
            cleared += 1
            pu, pv, z = project(c1, cell_points(c0, u, v, d1, d2, rng))
            assert np.all(z > 0)
            iu, iv = np.floor(pu).astype(int), np.floor(pv).astype(int)
            assert np.all((iu >= 0) & (iu < c1.width) & (iv >= 0) & (iv < c1.height))
            assert np.all(vote[iv, iu] > z), (u, v, g, need_vote)
            assert own_rule_clears(c0, c1, u, v, d1, d2, vote, rng)
    if vote.max() == 0.0:
        assert cleared == 0


@PROPERTY(15)
@given(seed=st.integers(0, 2**32 - 1))
def test_a_pixel_the_cell_projects_to_is_always_touched(seed):
    """Every pixel that a sampled point of an involved cell (corners and edges included) falls in is touched
    (``pixel_touches_cell`` never drops it), 1x1 and facing cameras included."""
    rng = np.random.default_rng(seed)
    c0, c1, grid, mp = setup(rng, facing=bool(rng.integers(0, 2)))
    for _ in range(40):
        u, v, g = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height)), int(rng.integers(0, grid.n_cells))
        d1 = grid.d_min + g * grid.dd
        fp = cell_footprint(0, u, v, d1, d1 + grid.dd, mp.corner_rays, mp.cams)
        if fp[0] < 0:
            continue
        pu, pv, _ = project(c1, cell_points(c0, u, v, d1, d1 + grid.dd, rng))
        for iu, iv in set(zip(np.floor(pu).astype(int).tolist(), np.floor(pv).astype(int).tolist(), strict=True)):
            assert pixel_touches_cell(0, u, v, d1, d1 + grid.dd, iu, iv, mp.corner_rays, mp.cams), (u, v, g, iu, iv)


# --------------------------------------------------------------------------- blocks imply their cells
def random_windows(rng, vote, level):
    """Robot windows: some behind the vote (a box in front of the arm: a gap), some starting at it."""
    H, W = vote.shape
    lo = np.full((H, W), np.inf, np.float32)
    hi = np.full((H, W), -np.inf, np.float32)
    for _ in range(int(rng.integers(1, 4))):
        v0, u0 = int(rng.integers(0, H)), int(rng.integers(0, W))
        sl = (slice(v0, v0 + int(rng.integers(1, H + 1))), slice(u0, u0 + int(rng.integers(1, W + 1))))
        a = level + rng.uniform(-0.3, 0.3) if rng.random() < 0.6 else vote[sl] - rng.uniform(0, 0.05)
        lo[sl] = a
        hi[sl] = lo[sl] + rng.uniform(0.05, 0.5)
    return lo, hi


def box_in_front_of_the_arm(rng):
    c0, c1, grid, mp = setup(rng, n_cells=60, dd=0.01)
    H, W = c1.height, c1.width
    z = project(c1, cell_points(c0, c0.width // 2, c0.height // 2, grid.d_min, grid.d_max, rng))[2]
    level = float(np.median(z))
    vote = np.full((H, W), level - 0.25, np.float32)  # a box in front of everything
    lo = np.full((H, W), level, np.float32)  # the arm's body behind it
    hi = np.full((H, W), level + 0.2, np.float32)
    return c0, c1, grid, mp, vote, lo, hi


def check_blocks(c0, c1, grid, mp, vt, rng, n=40):
    g_ = Grid(grid.d_min, grid.dd, grid.n_cells)
    stack = np.empty(3 * K.PYR_STACK, np.int64)
    blocks = 0
    for _ in range(n):
        u, v = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height))
        g0 = int(rng.integers(0, grid.n_cells))
        g1 = int(rng.integers(g0 + 1, min(grid.n_cells, g0 + 12) + 1))
        if block_cleared(u, v, g0, g1, g_, mp, vt, stack):
            blocks += 1
            for g in range(g0, g1):
                assert not cell_occupied(u, v, g, g_, mp, vt.votes, False), ("block", u, v, g0, g1, g)
        ua, va = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height))
        ub, vb = min(c0.width, ua + int(rng.integers(1, 17))), min(c0.height, va + int(rng.integers(1, 17)))
        if tile_block_cleared(ua, va, ub, vb, g0, g1, g_, mp, vt, stack):
            blocks += 1
            for vv in range(va, vb):
                for uu in range(ua, ub):
                    for g in range(g0, g1):
                        assert not cell_occupied(uu, vv, g, g_, mp, vt.votes, True), ("tile", uu, vv, g)
    return blocks


@PROPERTY(25)
@given(seed=st.integers(0, 2**32 - 1), windows=st.booleans())
@example(seed=11, windows=True)  # (old: a cleared block held occupied cells)
def test_a_cleared_block_holds_only_cleared_cells(seed, windows):
    """``block_cleared`` and ``tile_block_cleared`` (and so the chunks) clear only blocks whose every cell the
    per-cell rule clears, with and without robot windows (old: a window behind the vote passed a block)."""
    rng = np.random.default_rng(seed)
    if windows and rng.random() < 0.5:
        c0, c1, grid, mp, vote, lo, hi = box_in_front_of_the_arm(rng)
    else:
        c0, c1, grid, mp = setup(rng, facing=bool(rng.integers(0, 2)))
        z = project(c1, cell_points(c0, c0.width // 2, c0.height // 2, grid.d_min, grid.d_max, rng))[2]
        vote = random_vote_image(rng, c1, float(np.median(z)))
        lo, hi = random_windows(rng, vote, float(np.median(z))) if windows else (None, None)
    check_blocks(c0, c1, grid, mp, votes_record(vote, lo, hi), rng)


def test_a_box_in_front_of_the_arm_clears_no_block_in_front_of_the_arm():
    """The case robot windows are for: camera k sees a box 0.25 m in front of the arm's body. A cell whose far
    depth lies in the body passes; the space between box and arm is hidden from k and stays occupied, and no
    column block or tile block (large footprints, through the min pyramid) clears it either."""
    rng = np.random.default_rng(5)  # (old code: 13 of 65 cleared blocks held occupied cells)
    c0, c1, grid, mp, vote, lo, hi = box_in_front_of_the_arm(rng)
    vt = votes_record(vote, lo, hi)
    g_ = Grid(grid.d_min, grid.dd, grid.n_cells)
    stack = np.empty(3 * K.PYR_STACK, np.int64)
    passed = occupied = 0
    for v in range(c0.height):
        for u in range(c0.width):
            occ = [cell_occupied(u, v, g, g_, mp, vt.votes, False) for g in range(grid.n_cells)]
            passed += occ.count(False)
            occupied += sum(occ)
            for g0 in range(0, grid.n_cells - 8, 2):
                for size in (2, 8):
                    if block_cleared(u, v, g0, g0 + size, g_, mp, vt, stack):
                        assert not any(occ[g0 : g0 + size]), (u, v, g0, size)
    assert passed > 0 and occupied > 0  # (both kinds of cell: the scene tests something)
    assert check_blocks(c0, c1, grid, mp, vt, rng, n=60) >= 0


# ----------------------------------------------------------------------------------------- column search
def column_reference(c0, c1, grid, u, v, s0, kind, vote, P_c, limit, rng):
    """Smallest ray distance from P to a segment of pixel (u, v) that the documented rules surely occupy
    (cells: :func:`own_rule_clears`, lax, so only cells the kernel must keep occupied; before / beyond the
    grid: occupied unless a robot pixel; the cell of a measured surface: occupied)."""
    a = (u + 0.5 - c0.cx) / c0.fx
    b = (v + 0.5 - c0.cy) / c0.fy
    h = 0.5 * math.sqrt(c0.fx**-2 + c0.fy**-2)
    r = np.array([a, b, 1.0])

    def ray_dist(lo, hi):
        s = min(max((P_c @ r) / (r @ r), lo), hi)
        return float(np.linalg.norm(P_c - s * r))

    robot = kind == K.KIND_ROBOT
    segs = []
    if not robot:
        if s0 < grid.d_min:
            segs.append((s0, grid.d_min))
        segs.append((max(grid.d_max, s0), np.inf))
    for g in range(grid.n_cells):
        d1, d2 = grid.d_min + g * grid.dd, grid.d_min + (g + 1) * grid.dd
        if d2 <= s0 + 1e-9:
            continue
        if kind == K.KIND_SURFACE and d1 <= s0 - 1e-9:
            segs.append((s0, d2))  # the measured surface's cell
            continue
        if own_rule_clears(c0, c1, u, v, d1, d2, vote, rng):
            continue
        if robot:  # a witness is needed: involved (in front, inside the image) by a margin
            pu, pv, z = project(c1, cell_points(c0, u, v, d1, d2, rng, n=20))
            if not (z.min() > 1e-3 and pu.min() > 1e-3 and pv.min() > 1e-3):
                continue
            if not (pu.max() < c1.width - 1e-3 and pv.max() < c1.height - 1e-3):
                continue
            if z.max() > Q_MAX * DEND_SCALE or np.ptp(np.floor(pu)) >= FOOT_MAX or np.ptp(np.floor(pv)) >= FOOT_MAX:
                continue
        segs.append((max(d1, s0), d2))
    best = math.inf
    for lo, hi in segs:
        dr = ray_dist(lo, hi)
        if dr * (1.0 - h) - h * P_c[2] < limit * (1 - 1e-9):
            best = min(best, dr)
    return best, (a, b, h, r)


@PROPERTY(15)
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from([K.KIND_SURFACE, K.KIND_UNKNOWN, K.KIND_ROBOT]))
def test_column_search_is_never_farther_than_the_nearest_occupied_segment(seed, kind):
    """``column_search`` for random points, pixels (1x1 principal images too), start depths before, inside
    and beyond the grid, and pixel kinds: the reported segment is no farther (ray distance) than any segment
    the documented rules occupy within the search bound, and nothing found only when there is none."""
    rng = np.random.default_rng(seed)
    small = rng.random() < 0.2
    c0, c1, grid, mp = setup(rng, bool(rng.integers(0, 2)), n_cells=int(rng.integers(4, 30)), w0=1 if small else 24,
                             h0=1 if small else 18)  # fmt: skip
    g_ = Grid(grid.d_min, grid.dd, grid.n_cells)
    z = project(c1, cell_points(c0, c0.width // 2, c0.height // 2, grid.d_min, grid.d_max, rng))[2]
    vote = random_vote_image(rng, c1, float(np.median(z)))
    vt = votes_record(vote)
    for _ in range(6):
        u, v = int(rng.integers(0, c0.width)), int(rng.integers(0, c0.height))
        s0 = float(np.float32(rng.choice([rng.uniform(0.2, grid.d_min), rng.uniform(grid.d_min, grid.d_max),
                                          rng.uniform(grid.d_max, grid.d_max + 0.3)])))  # fmt: skip
        d = rng.uniform(grid.d_min - 0.2, grid.d_max + 0.2)
        P_c = np.array([(u + rng.uniform(-3, 4) - c0.cx) / c0.fx * d, (v + rng.uniform(-3, 4) - c0.cy) / c0.fy * d, d])
        limit = float(rng.uniform(0.02, 0.5))
        best, (a, b, h, r) = column_reference(c0, c1, grid, u, v, s0, kind, vote, P_c, limit, rng)
        rect = ((u // 16) * 16, (v // 16) * 16, min(c0.width, (u // 16) * 16 + 16), min(c0.height, (v // 16) * 16 + 16))
        found, lo, hi, _ = column_search(
            u, v, a, b, s0, kind == K.KIND_SURFACE, kind == K.KIND_ROBOT, tuple(P_c), h, limit, rect, g_, mp, vt,
            K.scratch(1, grid.n_cells),
        )  # fmt: skip
        if best < math.inf:
            assert found, (u, v, s0, best)
        if found:
            dr = float(np.linalg.norm(P_c - min(max((P_c @ r) / (r @ r), lo), hi) * r))
            assert dr <= best + 1e-9, (u, v, s0, lo, hi, dr, best)
            assert lo >= s0 - 1e-6  # (never before the pixel's start)


def test_column_search_with_an_unbounded_limit_still_finds_the_space_beyond_the_grid():
    """A search bound so large that ``s_hi`` overflows ``int()`` (or is infinite): the space beyond the grid is
    still reached (old: the cell index of an infinite depth was INT64_MIN, nothing was found)."""
    rng = np.random.default_rng(0)
    c0 = camera(rng, [2.0, 0.0, 0.0], [0.0, 0.0, 0.0], 8, 6)
    grid = DepthGrid(c0, 0.03, 0.5, 10)
    mp = GridMap(grid, [c0]).kernel_args()  # a secondary camera where the principal one is: every cell involved
    g_ = Grid(grid.d_min, grid.dd, grid.n_cells)
    vt = votes_record(np.full((c0.height, c0.width), np.inf, np.float32))  # it sees through every cell
    a = (3.5 - c0.cx) / c0.fx
    b = (2.5 - c0.cy) / c0.fy
    h = 0.5 * math.sqrt(c0.fx**-2 + c0.fy**-2)
    for limit in (1e300, math.inf):
        found, lo, hi, _ = column_search(
            3, 2, a, b, grid.d_min, False, False, (0.0, 0.0, 1.0), h, limit, (0, 0, 8, 6), g_, mp, vt,
            K.scratch(1, grid.n_cells),
        )  # fmt: skip
        assert found and hi == math.inf and lo == pytest.approx(grid.d_max), (limit, found, lo, hi)


# ----------------------------------------------------------------------------------------------- end to end
def sphere_depth(cam, centres, radii, room=3.2):
    """(H, W) depth z_C through the pixel centres of a union of spheres inside a spherical room (the inside of
    a sphere of radius ``room`` about the origin, the background), float64."""
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(float)
    d = np.stack([(u.ravel() + 0.5 - cam.cx) / cam.fx, (v.ravel() + 0.5 - cam.cy) / cam.fy, np.ones(u.size)], 1)
    dw = d @ cam.R
    o = cam.position
    best = np.full(len(d), np.inf)
    for c, r in zip(centres, radii, strict=True):
        oc = o - c
        A = np.einsum("ij,ij->i", dw, dw)
        B = dw @ oc
        disc = B * B - A * (oc @ oc - r * r)
        t = (-B - np.sqrt(np.maximum(disc, 0))) / A
        best = np.minimum(best, np.where((disc >= 0) & (t > 0), t, np.inf))
    A, B = np.einsum("ij,ij->i", dw, dw), dw @ o
    best = np.minimum(best, (-B + np.sqrt(B * B - A * (o @ o - room * room))) / A)  # (the camera is inside)
    return best.reshape(cam.shape) * 1.0  # (t is the depth: the rays have z_C = 1)


@PROPERTY(8)
@given(seed=st.integers(0, 2**32 - 1), map_mode=st.sampled_from(["onthefly", "stored"]))
def test_fused_query_with_broken_secondary_readings_against_the_true_shadow(seed, map_mode):
    """Two cameras, one of them facing the principal camera across the scene, the secondary image full of
    missing readings of every kind (0, NaN, +-inf, negative), both map modes: the fused distance is a lower
    bound of the distance to every point of the principal camera's shadow that the secondary camera does
    not see free through a *valid* pixel (within the declared tolerance)."""
    rng = np.random.default_rng(seed)
    c0 = camera(rng, [2.0, 0.0, 0.3], [0.0, 0.0, 0.0], 64, 48)
    c1 = camera(rng, [-2.0, rng.uniform(-0.6, 0.6), 0.4], [0.0, 0.0, 0.0], 56, 40)
    n = int(rng.integers(1, 4))
    centres, radii = rng.uniform(-0.4, 0.4, (n, 3)), rng.uniform(0.08, 0.25, n)
    d0, d1 = sphere_depth(c0, centres, radii), sphere_depth(c1, centres, radii)
    broken = d1.astype(np.float32)
    holes = rng.random(broken.shape) < rng.choice([0.05, 0.3])
    broken[holes] = rng.choice(np.array([0.0, np.nan, np.inf, -np.inf, -1.0], np.float32), holes.sum())
    fusion = DepthGridFusion([c0, c1], dd=0.02, map_mode=map_mode, cache_dir=False)
    fusion.update([d0.astype(np.float32), broken])
    # control points that the principal camera sees free (in view, well in front of their pixel's surface)
    P = rng.uniform(-0.7, 0.7, (400, 3))
    pu, pv, z = project(c0, P)
    ok = (z > c0.min_depth + 0.3) & (pu >= 16) & (pu < c0.width - 16) & (pv >= 12) & (pv < c0.height - 12)
    P, pu, pv, z = P[ok], pu[ok], pv[ok], z[ok]
    P = P[z < d0[pv.astype(int), pu.astype(int)] - 0.05][:10]
    res = fusion.query(P, 0.0, rho=0.3, mode="min")
    tol = fusion.tolerance(P, 0.3)
    valid1 = np.isfinite(broken) & (broken > 0)
    for i, Pw in enumerate(P):
        # the principal camera's shadow near P: points behind its surface along its pixel rays
        X = Pw + rng.normal(size=(4000, 3)) * rng.uniform(0.02, 0.5, (4000, 1))
        pu, pv, z = project(c0, X)
        inside = (z > c0.min_depth) & (pu >= 0) & (pu < c0.width) & (pv >= 0) & (pv < c0.height)
        X, pu, pv, z = X[inside], pu[inside], pv[inside], z[inside]
        X = X[z >= d0[pv.astype(int), pu.astype(int)] + 0.05]  # (well behind the pixel's measured surface)
        qu, qv, zk = project(c1, X)
        seen = (zk > 0) & (qu >= 0) & (qu < c1.width) & (qv >= 0) & (qv < c1.height)
        free = np.zeros(len(X), bool)
        iu, iv = qu[seen].astype(int), qv[seen].astype(int)
        free[seen] = valid1[iv, iu] & (broken[iv, iu] > zk[seen])  # seen free through a valid reading
        hidden = X[~free]
        if len(hidden):
            dist = np.linalg.norm(hidden - Pw, axis=1).min()
            assert min(res.distance[i], 0.3) <= dist + tol[i] + 1e-7, (i, res.distance[i], dist)


@pytest.mark.parametrize("fx", [0.3, 0.6, 0.69, 0.8, 2.0], ids=["fx0.3", "fx0.6", "fx0.69", "fx0.8", "fx2"])
def test_one_pixel_cameras_with_wide_pixels_still_report_the_measured_surface(fx):
    """1x1 images: the measured surface at 1 m is an obstacle, so a point behind it or beside it is no farther
    than that point. A principal pixel wider than the frustum bound handles (``h >= 1``, fx below ~0.71 px) is
    refused by name (before: with h in [1, ~1.5) the chunk and column search windows came out negative:
    nothing within rho, inf)."""
    R, t = look_at(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]))
    c0 = Camera(width=1, height=1, fx=fx, fy=fx, cx=0.5, cy=0.5, R=R, t=t, min_depth=0.2, max_depth=4.0)
    R1, t1 = look_at(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.5]), np.array([0.0, -1.0, 0.0]))
    c1 = Camera(width=1, height=1, fx=fx, fy=fx, cx=0.5, cy=0.5, R=R1, t=t1, min_depth=0.2, max_depth=4.0)
    if 0.5 * math.sqrt(2.0) / fx >= 1.0:
        with pytest.raises(ValueError, match=r"cameras\[0\]: the depth grid needs pixels narrower"):
            DepthGridFusion([c0, c1], dd=0.05)
        return
    for chunks in (True, False):
        fusion = DepthGridFusion([c0, c1], dd=0.05)
        fusion._chunks = chunks
        fusion.update([np.full((1, 1), 1.0, np.float32), np.full((1, 1), 3.0, np.float32)])
        P = np.array([[0.0, 0.0, 1.5], [0.3, 0.0, 2.0], [0.0, 0.1, 1.2], [0.0, 0.0, 0.8]])
        res = fusion.query(P, 0.0, rho=0.6, mode="min")
        surface = np.array([0.0, 0.0, 1.0])  # (the pixel-centre ray is the optical axis)
        assert np.all(res.distance <= np.linalg.norm(P - surface, axis=1) + 1e-12), (chunks, res.distance)
