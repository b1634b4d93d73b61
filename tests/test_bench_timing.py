"""The machine-speed reference of the benchmarks (``depthguard.bench.timing``)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.bench.timing import _nearest_pixel_kernel, _reference_frame, reference_speed, with_reference


def test_reference_kernel_computes_the_nearest_back_projected_pixel():
    depth, points = _reference_frame()
    depth, points = depth[::16, ::16].copy(), points[:2]
    fx = fy = 525.0 / 16
    cx, cy = (depth.shape[1] - 1) / 2, (depth.shape[0] - 1) / 2
    out = np.empty(len(points))
    _nearest_pixel_kernel(depth, fx, fy, cx, cy, points, out)
    v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
    X = np.stack([(u + 0.5 - cx) / fx * depth, (v + 0.5 - cy) / fy * depth, depth], axis=-1).reshape(-1, 3)
    ref = np.linalg.norm(X[None] - points[:, None], axis=-1).min(axis=1)
    np.testing.assert_allclose(out, ref, rtol=1e-6)


def test_reference_speed_and_ratio():
    ref = reference_speed(repeat=2)
    assert ref["us_median"] > 0 and ref["hz_median"] == pytest.approx(1e6 / ref["us_median"])
    assert "brute force" in ref["kernel"]
    entry = with_reference({"name": "x", "hz_median": 2 * ref["hz_median"]}, ref)
    assert entry["vs_reference"] == pytest.approx(2.0) and entry["name"] == "x"
