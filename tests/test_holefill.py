"""The hole filling's window minimum (kernels.holefill) against numpy; its users' frames are checked against
the policy pixel by pixel in test_missing_depth.py, test_depthgrid_frames.py and test_octree_fusion.py."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.kernels.holefill import column_window_min


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 40), st.integers(1, 12), st.integers(0, 7), st.floats(0.0, 1.0), st.integers(0, 2**31))
def test_column_window_min_is_the_clipped_vertical_window_minimum(h, w, r, p_inf, seed):
    rng = np.random.default_rng(seed)
    val = rng.uniform(0.1, 9.0, (h, w)).astype(np.float32)
    val[rng.random((h, w)) < p_inf] = np.inf
    want = np.array([[val[max(0, v - r) : v + r + 1, u].min() for u in range(w)] for v in range(h)], np.float32)
    out = np.full((h, w), -1.0, np.float32)
    column_window_min(val, r, out, np.empty_like(val), np.empty_like(val))
    assert np.array_equal(out, want)
    column_window_min(val, r, val, np.empty_like(val), np.empty_like(val))  # in place, as the frame stage does
    assert np.array_equal(val, want)
