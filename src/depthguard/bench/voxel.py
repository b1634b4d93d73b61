"""Baseline for the depth grid: a Cartesian voxel grid fused from several depth cameras (RA-L'16 Fig. 2a).

Each frame every voxel centre is projected into every camera (occlusion-aware inverse ray casting: the
pixel's measured depth tells whether the camera's ray reaches the voxel). A camera calls the voxel

* free when it measures beyond the voxel (``d_o > z + margin``),
* occupied when the measured surface is at the voxel (``|d_o - z| <= margin``),
* unknown when the voxel lies behind the measured surface or outside the camera's view,

with ``margin`` half the voxel diagonal. The fused voxel is free when any camera calls it free, so
an obstacle is what every camera has either seen or not seen (the same semantics as the depth grid:
occluded space counts as obstacle in the intersection of the cameras' gray areas). Missing pixels are
prepared as for the depth grid (:func:`depthguard.depthspace.prepare_frame`: filled, or unknown at the
near limit; robot pixels see past).

Queries scan the voxels inside the cube of side ``2 (ρ + r)`` around each control sphere, with the
same outputs as the depth-space methods (minimum distance, ICRA'12 eq. 9 direction, count).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.camera import Camera
from depthguard.depthgrid.grid import check_workspace
from depthguard.depthspace import MODES, PointDistances, prepare_frame

__all__ = ["VoxelFusion"]

FREE, OCCUPIED, UNKNOWN = 0, 1, 2


@nb.njit(cache=True, nogil=True, parallel=True)
def _fill(origin, res, shape, Rs, ts, intr, depths, out):
    nx, ny, nz = shape
    K = Rs.shape[0]
    margin = 0.5 * math.sqrt(3.0) * res
    for i in nb.prange(nx):
        x = origin[0] + (i + 0.5) * res
        for j in range(ny):
            y = origin[1] + (j + 0.5) * res
            for k in range(nz):
                z = origin[2] + (k + 0.5) * res
                state = UNKNOWN
                for c in range(K):
                    zc = Rs[c, 2, 0] * x + Rs[c, 2, 1] * y + Rs[c, 2, 2] * z + ts[c, 2]
                    if zc <= 1e-6:
                        continue
                    xc = Rs[c, 0, 0] * x + Rs[c, 0, 1] * y + Rs[c, 0, 2] * z + ts[c, 0]
                    yc = Rs[c, 1, 0] * x + Rs[c, 1, 1] * y + Rs[c, 1, 2] * z + ts[c, 1]
                    pu = intr[c, 0] * xc / zc + intr[c, 2]
                    pv = intr[c, 1] * yc / zc + intr[c, 3]
                    if not (pu >= 0.0 and pv >= 0.0 and pu < intr[c, 4] and pv < intr[c, 5]):
                        continue
                    d = depths[c, int(pv), int(pu)]
                    if d > zc + margin:
                        state = FREE
                        break
                    if d >= zc - margin:
                        state = OCCUPIED
                out[i, j, k] = state


@nb.njit(cache=True, nogil=True)
def _query_one(grid, origin, res, P, radius, rho, mode, alpha, out):
    nx, ny, nz = grid.shape
    reff = rho + radius
    half = 0.5 * math.sqrt(3.0) * res
    best = reff
    bx = by = bz = 0.0
    nxp = nyp = nzp = np.nan
    sx = sy = sz = 0.0
    count = 0
    i0 = max(0, int(math.floor((P[0] - reff - origin[0]) / res)))
    i1 = min(nx - 1, int(math.floor((P[0] + reff - origin[0]) / res)))
    j0 = max(0, int(math.floor((P[1] - reff - origin[1]) / res)))
    j1 = min(ny - 1, int(math.floor((P[1] + reff - origin[1]) / res)))
    k0 = max(0, int(math.floor((P[2] - reff - origin[2]) / res)))
    k1 = min(nz - 1, int(math.floor((P[2] + reff - origin[2]) / res)))
    for i in range(i0, i1 + 1):
        dx = P[0] - (origin[0] + (i + 0.5) * res)
        for j in range(j0, j1 + 1):
            dy = P[1] - (origin[1] + (j + 0.5) * res)
            dxy = dx * dx + dy * dy
            if dxy >= (reff + half) * (reff + half):
                continue
            for k in range(k0, k1 + 1):
                if grid[i, j, k] == FREE:
                    continue
                dz = P[2] - (origin[2] + (k + 0.5) * res)
                dc = math.sqrt(dxy + dz * dz)
                D = dc - half  # lower bound of the distance to the voxel
                if D < 0.0:
                    D = 0.0
                if D >= reff:
                    continue
                count += 1
                if dc > 1e-12:
                    ux, uy, uz = dx / dc, dy / dc, dz / dc
                else:
                    ux, uy, uz = 0.0, 0.0, 1.0
                if mode == 1:
                    w = 1.0 / (1.0 + math.exp(((D - radius) * 2.0 / rho - 1.0) * alpha))
                    sx += w * ux
                    sy += w * uy
                    sz += w * uz
                elif mode == 2:
                    sx += ux
                    sy += uy
                    sz += uz
                if D < best:
                    best = D
                    bx, by, bz = ux, uy, uz
                    nxp, nyp, nzp = P[0] - dc * ux, P[1] - dc * uy, P[2] - dc * uz
    if mode != 0:
        nrm = math.sqrt(sx * sx + sy * sy + sz * sz)
        if nrm > 1e-9:
            bx, by, bz = sx / nrm, sy / nrm, sz / nrm
    out[0] = best
    out[1] = bx
    out[2] = by
    out[3] = bz
    out[4] = nxp
    out[5] = nyp
    out[6] = nzp
    out[7] = count


@nb.njit(cache=True, nogil=True)
def _query_many(grid, origin, res, centres, radii, rho, mode, alpha):
    n = centres.shape[0]
    out = np.empty((n, 8))
    for i in range(n):  # one thread, as the depth grid's query (thread wake-up costs ms on a busy machine)
        _query_one(grid, origin, res, centres[i], radii[i], rho, mode, alpha, out[i])
    return out


class VoxelFusion:
    """Cartesian voxel grid over ``workspace`` at resolution ``res`` (metres), fused from ``cameras``.

    Args:
        cameras: the depth cameras.
        workspace: ``(xmin, xmax, ymin, ymax, zmin, zmax)`` world box, metres.
        res: voxel edge, metres (1 cm in the benchmark).
    """

    def __init__(self, cameras: list[Camera], workspace, res: float = 0.01) -> None:
        w = check_workspace(workspace)
        self.cameras = list(cameras)
        self.res = float(res)
        self.origin = np.array([w[0], w[2], w[4]])
        self.shape = tuple(int(math.ceil((w[2 * a + 1] - w[2 * a]) / res - 1e-9)) for a in range(3))
        self.grid = np.full(self.shape, UNKNOWN, dtype=np.uint8)
        self._Rs = np.stack([c.R for c in self.cameras])
        self._ts = np.stack([c.t for c in self.cameras])
        self._intr = np.array([[c.fx, c.fy, c.cx, c.cy, c.width, c.height] for c in self.cameras])
        hm = max(c.height for c in self.cameras)
        wm = max(c.width for c in self.cameras)
        self._depths = np.zeros((len(self.cameras), hm, wm), dtype=np.float32)

    @property
    def nbytes(self) -> int:
        return int(self.grid.nbytes)

    def update(self, depths, masks=None, invalid: str = "conservative") -> None:
        """Fill the voxel grid from one image per camera (same missing-depth policy as the depth grid)."""
        masks = [None] * len(self.cameras) if masks is None else masks
        for c, (cam, d, m) in enumerate(zip(self.cameras, depths, masks, strict=True)):
            fr = prepare_frame(cam, d, m, invalid=invalid)
            obs = np.asarray(fr.obstacle_depth, dtype=np.float32)
            missing = ~np.isfinite(np.asarray(d, dtype=np.float32)) | (np.asarray(d) <= 0)
            # an unknown pixel (near limit) never sees past anything; a filled hole counts as measured
            obs = np.where(missing & (obs == np.float32(cam.min_depth)), np.float32(0.0), obs)
            self._depths[c, : cam.height, : cam.width] = obs
        _fill(self.origin, self.res, self.shape, self._Rs, self._ts, self._intr, self._depths, self.grid)

    def query(self, centres, radii=0.0, rho: float = 0.4, mode: str = "all", alpha: float = 6.0) -> PointDistances:
        """Distances from N control spheres to the non-free voxels within ``rho`` (world frame)."""
        c = np.atleast_2d(np.asarray(centres, dtype=float))
        r = np.ascontiguousarray(np.broadcast_to(np.asarray(radii, dtype=float), (c.shape[0],)))
        raw = _query_many(
            self.grid, self.origin, self.res, np.ascontiguousarray(c), r, float(rho), MODES.index(mode), float(alpha)
        )
        found = raw[:, 0] < rho + r
        dist = np.where(found, np.maximum(raw[:, 0] - r, 0.0), np.inf)
        direction = np.where(found[:, None], raw[:, 1:4], np.nan)
        nearest = np.where(found[:, None], raw[:, 4:7], np.nan)
        return PointDistances(dist, direction, nearest, raw[:, 7].astype(np.int64))
