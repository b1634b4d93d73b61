"""The principal camera's frame in the depth grid (depthgrid.frames, depthgrid.chunks) against the policy
written out pixel by pixel in numpy (docs/conventions.md, "Missing depth"; depthgrid.fusion, "Filled
holes")."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.depthgrid import records as K
from depthguard.depthgrid.chunks import tile_bounds
from depthguard.depthgrid.frames import prepare_principal


def _window_min(a: np.ndarray, r: int, v: int, u: int) -> float:
    return float(a[max(0, v - r) : v + r + 1, max(0, u - r) : u + r + 1].min())


@settings(max_examples=80, deadline=None)
@given(
    st.integers(1, 30), st.integers(1, 30), st.integers(0, 6), st.floats(0.0, 0.97), st.floats(0.0, 0.5),
    st.booleans(), st.booleans(), st.integers(0, 2**31),
)  # fmt: skip
def test_principal_frame_follows_the_policy_pixel_by_pixel(h, w, r, p_missing, p_robot, has_mask, cons, seed):
    """Start depth and kind of every principal pixel (depthgrid.fusion, "Filled holes"): a reading is a
    surface; a robot pixel starts at its reading (or, conservative, at the near limit); a conservative hole
    is unknown from the smallest measured non-robot depth of its window, or from the near limit. Sparse and
    dense holes take different paths in the kernel (the hole fraction ranges over both)."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.3, 6.0, (h, w)).astype(np.float32)
    missing = rng.random((h, w)) < p_missing
    depth[missing] = rng.choice(np.array([np.nan, 0.0, -1.0, np.inf], np.float32), missing.sum())
    robot = (rng.random((h, w)) < p_robot) & has_mask
    near = np.float32(0.25)
    start = np.full((h, w), -7.0, np.float32)
    kind = np.full((h, w), 99, np.uint8)
    mask = robot if has_mask else np.zeros((1, 1), bool)
    scratch = np.full((3, h, w), -3.0, np.float32)  # (reused from frame to frame: stale contents)
    prepare_principal(depth, mask, has_mask, r, near, cons, start, kind, scratch, np.full(h * w, -1, np.int32))
    measured = np.where(missing | robot, np.inf, depth)
    for v in range(h):
        for u in range(w):
            if robot[v, u]:
                want = (depth[v, u], K.KIND_ROBOT) if not missing[v, u] else None
                if want is None:
                    want = (near, K.KIND_ROBOT) if cons else (np.inf, K.KIND_NONE)
            elif not missing[v, u]:
                want = (depth[v, u], K.KIND_SURFACE)
            elif not cons:
                want = (np.inf, K.KIND_NONE)
            else:
                m = _window_min(measured, r, v, u)
                want = (m if np.isfinite(m) else near, K.KIND_UNKNOWN)
            assert (start[v, u], kind[v, u]) == (np.float32(want[0]), want[1]), (v, u)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 50), st.integers(1, 50), st.integers(1, 17), st.floats(0.0, 1.0), st.integers(0, 2**31))
def test_tile_bounds_are_each_tiles_smallest_start_and_largest_non_robot_start(h, w, tile, p_inf, seed):
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.1, 9.0, (h, w)).astype(np.float32)
    start[rng.random((h, w)) < p_inf] = np.inf
    kind = rng.choice(np.array([K.KIND_NONE, K.KIND_SURFACE, K.KIND_UNKNOWN, K.KIND_ROBOT], np.uint8), (h, w))
    tmin, tmax = tile_bounds(start, kind, tile)
    non_robot = np.where((kind == K.KIND_SURFACE) | (kind == K.KIND_UNKNOWN), start, -np.inf)
    for tv in range(-(-h // tile)):
        for tu in range(-(-w // tile)):
            win = np.s_[tv * tile : (tv + 1) * tile, tu * tile : (tu + 1) * tile]
            assert tmin[tv, tu] == start[win].min()
            assert tmax[tv, tu] == non_robot[win].max()
    assert tmin.shape == tmax.shape == (-(-h // tile), -(-w // tile))
