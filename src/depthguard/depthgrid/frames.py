"""Frame stage of the depth-grid fusion: one pass over each camera's image per frame (camera rate).

* principal camera: the start depth and kind of every pixel (:mod:`depthguard.depthgrid.records`),
  holes filled exactly as :func:`depthguard.depthspace.prepare_frame` does (``docs/conventions.md``);
* secondary cameras: the vote of every pixel, the depth it sees past: its measured depth less the vote
  margin; 0 for a missing pixel (never filled: it clears nothing); +inf for a robot pixel (it never
  confirms an obstacle) unless ``robot_occludes``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from depthguard.depthgrid import records as K
from depthguard.kernels.holefill import column_window_min, use_column_minima, window_min_at

__all__ = ["prepare_principal", "prepare_secondary", "write_windows"]


@nb.njit(cache=True, nogil=True)
def missing_pixels(depth):
    """(H, W) bool: the pixels without a reading (0, negative, NaN or inf)."""
    H, W = depth.shape
    missing = np.empty((H, W), dtype=np.bool_)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            missing[v, u] = not (d > 0.0 and d < np.inf)
    return missing


@nb.njit(cache=True, nogil=True)
def prepare_principal(depth, robot, has_mask, fill_radius, near_limit, conservative, start, kind, scratch, hole_at):
    """One pass over the principal image: start depth and kind of every pixel (module docstring); then the
    holes' window minima (:mod:`depthguard.kernels.holefill`). ``scratch``: (3, H, W) float32, ``hole_at``:
    (H W,) int32, reused from frame to frame (fresh pages would cost more than the pass itself)."""
    H, W = depth.shape
    missing = missing_pixels(depth)
    holes = 0  # (their flat indices: hole_at[:holes])
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            if has_mask and robot[v, u]:
                if not missing[v, u]:
                    start[v, u] = d  # case iv: the robot at d_r
                    kind[v, u] = K.KIND_ROBOT
                elif conservative:
                    start[v, u] = near_limit  # a robot pixel without a reading: unknown from the near limit
                    kind[v, u] = K.KIND_ROBOT
                else:
                    start[v, u] = np.inf
                    kind[v, u] = K.KIND_NONE
            elif not missing[v, u]:
                start[v, u] = d
                kind[v, u] = K.KIND_SURFACE
            elif not conservative:
                start[v, u] = np.inf
                kind[v, u] = K.KIND_NONE
            else:
                # a filled hole is not a measured surface: nothing before the nearest neighbouring depth
                # (the filling assumption), unknown from there on, so the other cameras may clear its cells
                # (a surface cell is occupied without a vote); without a neighbour, from the near limit
                start[v, u] = near_limit
                kind[v, u] = K.KIND_UNKNOWN
                hole_at[holes] = v * W + u
                holes += 1
    if holes == 0:
        return
    val = scratch[0]  # the hole filling's source: the measured non-robot depths, inf elsewhere
    for v in range(H):
        for u in range(W):
            val[v, u] = start[v, u] if kind[v, u] == K.KIND_SURFACE else np.float32(np.inf)
    r = fill_radius
    dense = use_column_minima(holes, H, W, r)
    if dense:
        column_window_min(val, r, val, scratch[1], scratch[2])  # (val now holds the column minima)
    for i in range(holes):
        v, u = divmod(hole_at[i], W)
        best = window_min_at(val, val, dense, v, u, r)
        if best < np.inf:
            start[v, u] = best


@nb.njit(cache=True, nogil=True)
def prepare_secondary(depth, robot, has_mask, conservative, robot_occludes, margin, out):
    """One pass over a secondary image: the depth each pixel sees up to (its vote, see the module docstring).

    A missing pixel is never filled here: it votes 0 (it clears nothing), so that a small dark object with
    no reading in front of a far background cannot clear the cell it occupies. Hole filling is for the
    principal camera only (where a filled pixel is an obstacle, never free space).
    """
    H, W = depth.shape
    missing = missing_pixels(depth)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            if has_mask and robot[v, u]:
                if robot_occludes:
                    out[v, u] = 0.0 if missing[v, u] else d - margin
                else:
                    out[v, u] = np.inf  # the robot never confirms an obstacle (docs/conventions.md)
            elif not missing[v, u]:
                out[v, u] = d - margin
            elif not conservative:
                out[v, u] = np.inf  # "ignore": a missing pixel is free space, as the caller asked
            else:
                out[v, u] = 0.0  # missing: never clears a cell, filled or not


def limit_robot_votes(cameras, depths, masks, votes, margin: float) -> None:
    """Several secondary cameras: a robot pixel of one no longer sees past what another one measures.

    A secondary robot pixel votes +inf (the robot never confirms an obstacle), so with two or more
    secondary cameras, camera k seeing the arm in front of a box would clear the box that camera j
    measures. For every measured, non-robot pixel of camera j, its point is projected into every other
    secondary camera k; where it lands on a robot pixel of k (vote +inf), that pixel's vote becomes at most
    the point's depth in k less ``margin``: k still sees past the stretch in front of the point, not the
    point itself, so the cell that holds it stays occupied unless a camera measures past it.

    Args:
        cameras: the secondary cameras; depths, masks: their (H, W) images (metres, NaN/0 = no reading)
            and robot masks (or None); votes: their (H, W) float32 vote images, updated in place.
    """
    if len(cameras) < 2:
        return
    for j, (cj, dj, mj) in enumerate(zip(cameras, depths, masks, strict=True)):
        d = np.asarray(dj, dtype=np.float64)
        ok = np.isfinite(d) & (d > 0)
        if mj is not None:
            ok &= ~np.asarray(mj, dtype=bool)
        vv, uu = np.nonzero(ok)
        if vv.size == 0:
            continue
        pw = cj.unproject(uu + 0.5, vv + 0.5, d[vv, uu])
        for k, ck in enumerate(cameras):
            if k == j:
                continue
            proj = ck.project(pw)
            front = proj[:, 2] > 1e-6
            pu = np.floor(proj[front, 0]).astype(np.int64)
            pv = np.floor(proj[front, 1]).astype(np.int64)
            zf = proj[front, 2]
            inside = (pu >= 0) & (pv >= 0) & (pu < ck.width) & (pv < ck.height)
            pu, pv, zf = pu[inside], pv[inside], zf[inside]
            vk = votes[k]
            robot = np.isposinf(vk[pv, pu])
            if np.any(robot):
                np.minimum.at(vk, (pv[robot], pu[robot]), (zf[robot] - margin).astype(np.float32))


@nb.njit(cache=True, nogil=True)
def _window_block(lo, hi, out_lo, out_hi):
    """``out_lo`` / ``out_hi`` (H, W) = the window ``[lo, hi]`` where both are finite and ``lo <= hi``,
    else ``+inf`` / ``-inf`` (no window)."""
    H, W = lo.shape
    for v in range(H):
        for u in range(W):
            a, b = lo[v, u], hi[v, u]
            if a <= b and np.isfinite(a) and np.isfinite(b):
                out_lo[v, u], out_hi[v, u] = a, b
            else:
                out_lo[v, u], out_hi[v, u] = np.inf, -np.inf


def write_windows(votes: np.ndarray, hm: int, cameras, windows) -> bool:
    """Write the secondary cameras' robot windows into the ``lo`` / ``hi`` row blocks of ``votes``
    (K, 3 hm, W) (:func:`depthguard.depthgrid.votes.pixel_sees_past`; no window: lo = +inf, hi = -inf).

    ``windows``: ``None`` or one entry per camera (the principal camera's, ``windows[0]``, is ignored):
    ``None`` or ``(lo, hi)`` (H, W) depth images of camera k (``lo > hi`` or NaN = none). Returns whether
    any window was set."""
    any_set = False
    for k in range(1, len(cameras)):
        cam = cameras[k]
        block_lo, block_hi = votes[k - 1, hm : 2 * hm], votes[k - 1, 2 * hm :]
        if windows is None or windows[k] is None or cam.shape != block_lo.shape:
            block_lo[...] = np.inf  # no window (and the rows and columns beyond a smaller camera's image)
            block_hi[...] = -np.inf
        if windows is None or windows[k] is None:
            continue
        any_set = True
        lo = np.asarray(cam.check_image(windows[k][0], f"windows[{k}][0]"), dtype=np.float32)
        hi = np.asarray(cam.check_image(windows[k][1], f"windows[{k}][1]"), dtype=np.float32)
        _window_block(lo, hi, block_lo[: cam.height, : cam.width], block_hi[: cam.height, : cam.width])
    return any_set
