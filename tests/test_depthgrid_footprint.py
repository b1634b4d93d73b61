"""The exact-projection pixel test of the fusion's vote (``depthgrid.votes.pixel_touches_cell``), against
points sampled inside the cell and projected with the secondary camera's own model."""

from __future__ import annotations

import numpy as np

from depthguard.camera import look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthgrid.votes import pixel_touches_cell

WORKSPACE = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)


def _cams():
    from depthguard.camera import Camera

    def cam(eye, w=160, h=120):
        R, t = look_at(np.asarray(eye, float), np.array([0.0, 0.0, 0.45]))
        f = 575.0 * w / 640
        return Camera(fx=f, fy=f, cx=w / 2, cy=h / 2, width=w, height=h, R=R, t=t, min_depth=0.5, max_depth=4.5)

    return [cam((1.75, -0.95, 1.5)), cam((-0.75, 1.85, 1.5))]


def test_a_pixel_declared_untouched_holds_no_point_of_the_cell():
    """Never drops a pixel that sees part of the cell (soundness), and keeps every pixel whose square holds
    a sampled point; it does drop some bounding-box corners (it is not a no-op)."""
    cams = _cams()
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    g = fusion.grid
    mp = fusion.map.kernel_args()
    rng = np.random.default_rng(7)
    c0, c1 = cams
    dropped = kept = 0
    for _ in range(300):
        u, v = int(rng.integers(20, 140)), int(rng.integers(20, 100))
        gi = int(rng.integers(100, 300))
        fp = fusion.map.footprint(0, u, v, gi)
        if fp is None:
            continue
        d1, d2 = g.cell_depths(gi)
        s = rng.random((4000, 3))
        pts = c0.unproject(u + s[:, 0], v + s[:, 1], d1 + (d2 - d1) * s[:, 2])
        pc = c1.world_to_camera(pts)
        pu = np.floor(c1.fx * pc[:, 0] / pc[:, 2] + c1.cx).astype(int)
        pv = np.floor(c1.fy * pc[:, 1] / pc[:, 2] + c1.cy).astype(int)
        hit = set(zip(pu.tolist(), pv.tolist(), strict=True))
        for pv_ in range(fp["v"][0], fp["v"][1] + 1):
            for pu_ in range(fp["u"][0], fp["u"][1] + 1):
                touches = pixel_touches_cell(0, u, v, d1, d2, pu_, pv_, mp.corner_rays, mp.cams)
                if (pu_, pv_) in hit:
                    assert touches, (u, v, gi, pu_, pv_)
                dropped += not touches
                kept += touches
    assert dropped > 0.05 * (dropped + kept)
