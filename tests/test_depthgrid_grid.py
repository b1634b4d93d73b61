"""Depth grid (RA-L'16 eq. 4, §VIII workspace range) and the off-line map (§V)."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGrid, GridMap, workspace_depth_range
from depthguard.depthgrid import footprint as K
from depthguard.depthgrid.gridmap import map_key

WORKSPACE = (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5)


def small_camera(eye, target, w=96, h=72, f=80.0) -> Camera:
    R, t = look_at(eye, target)
    return Camera(
        width=w, height=h, fx=f, fy=f * 1.05, cx=w / 2 - 0.3, cy=h / 2 + 0.2, R=R, t=t, min_depth=0.3, max_depth=6.0
    )


def test_eq4_quantisation():
    cam = Camera.kinect_v1()
    g = DepthGrid(cam, 0.01, 0.5, 400)
    assert g.r(0.5) == 0 and g.r(0.5099) == 0 and g.r(0.5101) == 1 and g.r(0.495) == -1
    d1, d2 = g.cell_depths(7)
    assert d1 == pytest.approx(0.57) and d2 == pytest.approx(0.58)
    assert g.shape == (480, 640, 400) and g.size == 640 * 480 * 400
    assert g.d_max == pytest.approx(4.5)


def test_workspace_range_matches_dense_sampling():
    """The LP range equals the depth range of densely sampled box points that project inside the image."""
    R, t = look_at([2.6, -1.9, 1.9], [0.0, 0.0, 0.3])
    cam = Camera.kinect_v1(R, t)
    lo, hi = workspace_depth_range(cam, WORKSPACE)
    rng = np.random.default_rng(0)
    p = rng.uniform([-1.5, -1.5, -0.5], [1.5, 1.5, 1.5], size=(400_000, 3))
    # add the box faces, where the extremes lie
    for axis in range(3):
        for val in (WORKSPACE[2 * axis], WORKSPACE[2 * axis + 1]):
            q = rng.uniform([-1.5, -1.5, -0.5], [1.5, 1.5, 1.5], size=(100_000, 3))
            q[:, axis] = val
            p = np.concatenate([p, q])
    pr = cam.project(p)
    inside = (pr[:, 0] >= 0) & (pr[:, 0] <= 640) & (pr[:, 1] >= 0) & (pr[:, 1] <= 480) & (pr[:, 2] > 0)
    z = pr[inside, 2]
    assert lo <= z.min() + 1e-9 and hi >= z.max() - 1e-9
    assert z.min() - lo < 0.03 and hi - z.max() < 0.03
    grid = DepthGrid.from_workspace(cam, 0.01, WORKSPACE)
    assert grid.d_min == pytest.approx(lo) and grid.d_max >= hi
    assert grid.n_cells == int(np.ceil((hi - lo) / 0.01 - 1e-9))


def test_workspace_errors():
    cam = Camera.kinect_v1()
    with pytest.raises(ValueError, match="workspace"):
        DepthGrid.from_workspace(cam, 0.01, (0, 1, 0, 1, 0))
    with pytest.raises(ValueError, match="xmin < xmax"):
        DepthGrid.from_workspace(cam, 0.01, (1, 0, 0, 1, 0, 1))
    with pytest.raises(ValueError, match="not in the principal camera's field of view"):
        DepthGrid.from_workspace(cam, 0.01, (-1, 1, -1, 1, -5, -4))  # entirely behind the camera
    with pytest.raises(ValueError, match="dd"):
        DepthGrid.from_workspace(cam, 0.0, None)


def _cameras():
    return [
        small_camera([2.0, 0.0, 1.0], [0.0, 0.0, 0.6]),
        small_camera([0.0, 2.2, 1.4], [0.0, 0.0, 0.5]),
        small_camera([-1.6, -1.6, 2.0], [0.0, 0.0, 0.4]),
    ]


def test_footprint_contains_every_point_of_the_cell():
    """Random points inside random cells project into the footprint box, no deeper than d_end."""
    cams = _cameras()
    grid = DepthGrid.from_workspace(cams[0], 0.02, (-1, 1, -1, 1, 0, 1.2))
    gmap = GridMap(grid, cams[1:])
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(3000):
        u, v = int(rng.integers(0, cams[0].width)), int(rng.integers(0, cams[0].height))
        g = int(rng.integers(0, grid.n_cells))
        k = int(rng.integers(0, 2))
        fp = gmap.footprint(k, u, v, g)
        if fp is None:
            continue
        d1, d2 = grid.cell_depths(g)
        n = 20
        pts = cams[0].unproject(u + rng.random(n), v + rng.random(n), d1 + (d2 - d1) * rng.random(n))
        pr = cams[k + 1].project(pts)
        assert np.all(np.floor(pr[:, 0]) >= fp["u"][0]) and np.all(np.floor(pr[:, 0]) <= fp["u"][1])
        assert np.all(np.floor(pr[:, 1]) >= fp["v"][0]) and np.all(np.floor(pr[:, 1]) <= fp["v"][1])
        assert np.all(pr[:, 2] <= fp["d_end"] + 1e-12) and np.all(pr[:, 2] >= fp["d_start"] - 1e-12)
        corners = cams[0].unproject(
            np.array([u, u + 1, u, u + 1] * 2, dtype=float),
            np.array([v, v, v + 1, v + 1] * 2, dtype=float),
            np.repeat([d1, d2], 4),
        )
        zc = cams[k + 1].world_to_camera(corners)[:, 2]
        assert 0.0 <= fp["d_end"] - zc.max() <= K.DEND_SCALE + 1e-12
        checked += 1
    assert checked > 1000


def test_stored_map_equals_on_the_fly(tmp_path):
    cams = _cameras()
    grid = DepthGrid.from_workspace(cams[0], 0.02, (-1, 1, -1, 1, 0, 1.2))
    fly = GridMap(grid, cams[1:], "onthefly")
    stored = GridMap(grid, cams[1:], "stored", cache_dir=tmp_path)
    assert not stored.cache_hit and stored.nbytes > fly.nbytes
    H, W, n = grid.shape
    involved = 0
    for k in range(2):
        for v in range(0, H, 7):
            for u in range(0, W, 5):
                for g in range(0, n, 3):
                    d1 = grid.d_min + g * grid.dd
                    ref = K.cell_footprint(k, u, v, d1, d1 + grid.dd, fly.corner_rays, fly.cams)
                    got = tuple(int(x) for x in K.unpack(stored.packed[k, v, u, g]))
                    if ref[0] < 0:
                        assert got[0] == -1
                        continue
                    involved += 1
                    assert got == ref
    assert involved > 500
    # the cache: same calibration -> loaded; any change -> another key
    again = GridMap(grid, cams[1:], "stored", cache_dir=tmp_path)
    assert again.cache_hit
    assert np.array_equal(again.packed, stored.packed)
    moved = cams[2].with_pose(cams[2].R, cams[2].t + np.array([0.0, 0.0, 1e-6]))
    assert map_key(grid, [cams[1], moved]) != stored.key
    assert map_key(DepthGrid(grid.camera, grid.dd, grid.d_min + 1e-9, grid.n_cells), cams[1:]) != stored.key
    assert GridMap(grid, [cams[1], moved], "stored", cache_dir=tmp_path).cache_hit is False


def test_map_mode_error():
    cams = _cameras()
    grid = DepthGrid.from_workspace(cams[0], 0.05, None)
    with pytest.raises(ValueError, match="map_mode"):
        GridMap(grid, cams[1:], "lazy")
    with pytest.raises(ValueError, match="onthefly"):
        GridMap(grid, cams[1:], "stored", cache_dir=False, max_bytes=1000)
