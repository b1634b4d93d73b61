"""Inputs full of NaN / ±inf / 0 / negative depths and +inf sentinels, run through every distance kernel.

Used by ``tests/test_kernel_nonfinite.py``: the same function runs compiled (numba) in the test process
and as plain Python (``NUMBA_DISABLE_JIT=1``) in a subprocess; the answers must agree, which they cannot
if the compiler were allowed to assume finite values (fast-math ``nnan`` / ``ninf``).
Run as a script: ``python tests/nonfinite_case.py OUT.npz``.
"""

from __future__ import annotations

import sys

import numpy as np

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import prepare_frame, query_distances

SPECIAL = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-30, 1e30], dtype=np.float32)


def _camera(eye, target, w=40, h=30, f=34.0) -> Camera:
    R, t = look_at(eye, target)
    return Camera(width=w, height=h, fx=f, fy=f * 1.02, cx=w / 2 - 0.3, cy=h / 2 + 0.2, R=R, t=t, min_depth=0.3)


def _depth(rng: np.random.Generator, cam: Camera) -> np.ndarray:
    d = rng.uniform(0.6, 3.5, cam.shape).astype(np.float32)
    special = rng.random(cam.shape) < 0.3
    d[special] = rng.choice(SPECIAL, size=int(special.sum()))
    d[:6, :8] = np.nan  # a hole too large to fill: unknown space
    d[-6:, -8:] = np.inf
    return d


def run(seed: int = 0) -> dict[str, np.ndarray]:
    """Every kernel over non-finite inputs; returns the arrays to compare (names -> arrays)."""
    rng = np.random.default_rng(seed)
    cams = [_camera([2.0, 0.0, 1.0], [0.0, 0.0, 0.9]), _camera([0.2, 2.2, 1.3], [0.0, 0.0, 0.8])]
    depths = [_depth(rng, c) for c in cams]
    masks = [rng.random(c.shape) < 0.15 for c in cams]
    P = np.vstack([rng.uniform([-0.6, -0.6, 0.3], [0.8, 0.6, 1.5], size=(6, 3)), [[1.7, 0.0, 1.0], [9.0, 0.0, 1.0]]])
    radii = rng.uniform(0.0, 0.1, len(P))
    out: dict[str, np.ndarray] = {}
    for inv in ("conservative", "ignore"):
        for fill in (0, 2):
            fr = prepare_frame(cams[0], depths[0], masks[0], invalid=inv, fill_radius=fill)
            out[f"ds_obs_{inv}_{fill}"] = fr.obstacle_depth
            out[f"ds_tmin_{inv}_{fill}"] = fr.tile_min
            for mode in ("min", "all", "hybrid"):
                for model in ("frustum", "icra", "ral16"):
                    res = query_distances(fr, P, radii, rho=0.4, mode=mode, model=model)
                    for name, arr in zip(res._fields, res, strict=True):
                        out[f"ds_{inv}_{fill}_{mode}_{model}_{name}"] = np.asarray(arr)
            res = query_distances(fr, P, radii, rho=0.4, mode="hybrid", direction_stride=2)  # the lattice
            for name, arr in zip(res._fields, res, strict=True):
                out[f"ds_{inv}_{fill}_hybrid_lattice_{name}"] = np.asarray(arr)
        fusion = DepthGridFusion(cams, dd=0.05, workspace=(-1, 1, -1, 1, 0, 1.6), fill_radius=2)
        fusion.update(depths, masks, invalid=inv)
        for mode in ("min", "all", "hybrid"):
            res = fusion.query(P, radii, rho=0.4, mode=mode)
            for name, arr in zip(res._fields, res, strict=True):
                out[f"grid_{inv}_{mode}_{name}"] = np.asarray(arr)
        res = fusion.query(P, radii, rho=0.4, mode="hybrid", direction_stride=2)  # the lattice
        for name, arr in zip(res._fields, res, strict=True):
            out[f"grid_{inv}_hybrid_lattice_{name}"] = np.asarray(arr)
    return out


if __name__ == "__main__":
    np.savez(sys.argv[1], **run(int(sys.argv[2]) if len(sys.argv) > 2 else 0))
