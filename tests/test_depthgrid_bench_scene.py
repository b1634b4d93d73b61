"""The benchmark scene at full resolution (640x480, 2 cameras 4 m apart, noise and dropouts)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import prepare_frame, query_distances

WORKSPACE = (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5)


def test_grid_size_from_the_workspace():
    """RA-L'16 §VIII: the workspace box gives d_min and about 343 cells at Δd = 1 cm (here 345)."""
    fusion = DepthGridFusion(bench_cameras(), dd=0.01, workspace=WORKSPACE)
    assert fusion.grid.shape[:2] == (480, 640)
    assert 300 <= fusion.grid.n_cells <= 400
    assert 0.2 < fusion.grid.d_min < 1.0


@pytest.mark.slow  # two 640x480 scenes
@pytest.mark.parametrize("reach", [0.0, 0.2])
def test_bench_scene_bounds(reach):
    cams = bench_cameras()
    scene = person_scene(reach=reach)
    depths = [noisy_depth(c, scene, seed=1 + i) for i, c in enumerate(cams)]
    _, centres, radii = arm_chain_points()
    truth = np.maximum(scene.distance(centres) - radii, 0.0)
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths)
    single = query_distances(prepare_frame(cams[0], depths[0]), centres, radii, rho=0.4, mode="all").distance
    tol = fusion.tolerance(centres, 0.4)
    # Kinect-like noise at the secondary camera (sigma 1.4 mm z^2, about 1 cm at 2.9 m) adds to the sampling
    noise = 3 * 0.0014 * 3.0**2
    for mode in ("all", "min", "hybrid"):
        fused = fusion.query(centres, radii, rho=0.4, mode=mode).distance
        found = np.isfinite(fused)
        assert np.all(fused[found] <= truth[found] + tol[found] + noise)
        assert np.all(truth[~found] + tol[~found] + noise >= 0.4)
        assert np.all(fused >= single - tol)
