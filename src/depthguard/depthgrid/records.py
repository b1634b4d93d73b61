"""Typed records of the depth-grid kernels and the constants they share (see :mod:`depthguard.depthgrid.query`).

Conventions shared by every depth-grid kernel (the method: :mod:`depthguard.depthgrid.fusion`):

* the principal camera's pixel-corner rays are ``c = ((u' - cx)/fx, (v' - cy)/fy, 1)``, ``u' = 0..W``;
  for secondary camera k, the corner ray ``M_k c`` of corner (u', v') (the pixel-centre rays likewise), with
  ``M_k = R_k R_0^T``, computed where it is needed from a :class:`RayTable` (``footprint.ray``), and
  ``cams[k] = (b_k, fx, fy, cx, cy, W, H)`` with
  ``b_k = t_k - M_k t_0``, so the cell corner at depth ``d`` is ``X_k = d M_k c + b_k``;
* principal pixel kinds: 0 nothing, 1 measured surface at ``start``, 2 unknown from ``start`` on
  (missing pixel at the near limit), 3 robot at ``start`` (RA-L'16 case iv).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "RayTable",
    "Grid",
    "MapArrays",
    "Votes",
    "Principal",
    "Scratch",
    "ColumnCache",
    "column_cache",
    "KIND_NONE",
    "KIND_SURFACE",
    "KIND_UNKNOWN",
    "KIND_ROBOT",
    "BLOCK",
    "TILE_BLOCK",
    "PYR_STACK",
    "scratch",
]

KIND_NONE, KIND_SURFACE, KIND_UNKNOWN, KIND_ROBOT = 0, 1, 2, 3
BLOCK = 8  # first block size (cells) tried along a column; then 2, then single cells
TILE_BLOCK = 8  # depth cells per tile-wide block
PYR_STACK = 256  # entries (3 int64 each) of the explicit stack of the min-pyramid descent


class Grid(NamedTuple):
    """The depth grid (RA-L'16 eq. 4): near face ``d_min`` of the first cell, cell depth ``dd`` (metres),
    number of depth cells per pixel."""

    d_min: float
    dd: float
    n_cells: int


class RayTable(NamedTuple):
    """The principal camera's rays as seen from the secondary cameras' orientation: ray (u', v') of camera k
    is ``M[k] @ (us[u'], vs[v'], 1)``; ``M`` (K, 3, 3) float64, ``us`` (W or W+1,) and ``vs`` (H or H+1,) the
    normalised coordinates ``(u' - cx) / fx``, ``(v' - cy) / fy`` of the pixel corners (or centres). A few
    kilobytes instead of a (K, H+1, W+1, 3) table (14.8 MB at 640x480), which the queries would read."""

    M: np.ndarray
    us: np.ndarray
    vs: np.ndarray


class MapArrays(NamedTuple):
    """The off-line map (RA-L'16 §V): ``corner_rays`` and ``centre_rays`` (:class:`RayTable`, pixel corners
    and centres), ``cams`` (K, 9), and, when ``stored``, every cell's packed footprint ``pmap`` (K, H, W, n_cells)."""

    corner_rays: RayTable
    centre_rays: RayTable
    cams: np.ndarray
    stored: bool
    pmap: np.ndarray


class Votes(NamedTuple):
    """Per frame: ``votes`` (K, 3 H, W) float32: rows ``[0, H)`` the depth each secondary pixel sees past
    (0: nothing, +inf: everything), rows ``[H, 2H)`` and ``[2H, 3H)`` the low and high ends of its robot
    window (+inf / -inf: none; :func:`depthguard.depthgrid.votes.pixel_sees_past`); the block-minimum
    pyramid ``pyr`` (K, n) of the votes with layout ``meta`` (L, 3); ``windows``: any window set."""

    votes: np.ndarray
    pyr: np.ndarray
    meta: np.ndarray
    windows: bool = False


class Principal(NamedTuple):
    """Per frame, the principal image: ``start`` (H, W) float32 start depth and ``kind`` (H, W) uint8 of
    each pixel, and per 16x16 tile the smallest start ``tmin`` and the largest non-robot start ``tmax``."""

    start: np.ndarray
    kind: np.ndarray
    tmin: np.ndarray
    tmax: np.ndarray


class ColumnCache(NamedTuple):
    """Per frame, the cell states that the column searches have already decided, shared by every point
    and every query of the frame (a cell's state depends on the frame only).

    ``words`` (H, W, 1 + 2 nw) uint64, one contiguous record per principal pixel: word 0 the frame
    generation its bits belong to (bits of an older generation count as unset, so a new frame costs no
    clearing), words ``1 .. nw`` the cells decided cleared (bit ``g``), words ``1 + nw .. 2 nw`` those
    decided occupied; ``nw = ceil(n_cells / 64)``. ``gen``: this frame's generation (>= 1); ``on``: use
    the cache (off for the threaded query: its threads would share the bits).

    ``tiles`` (n_tiles, n_cells // TILE_BLOCK + 1) uint8: per principal tile (row-major, ``TILE`` pixels
    square), the tile-wide block states decided so far (0 unknown, 1 cleared, 2 not cleared; a tile
    block's state depends on the tile and the frame only, not on the query point), valid where
    ``tile_gen`` (n_tiles,) int64 equals ``gen``.
    """

    words: np.ndarray
    nw: int
    gen: int
    on: bool
    tiles: np.ndarray
    tile_gen: np.ndarray


def column_cache(height: int, width: int, n_cells: int, on: bool = True, tile: int = 16) -> ColumnCache:
    """An empty :class:`ColumnCache` for an (height, width) principal image, ``n_cells`` depth cells and
    ``tile``-pixel tiles (``on=False``: a disabled one; give it ``height = width = 1``)."""
    nw = max(1, -(-n_cells // 64))
    n_tiles = -(-height // tile) * -(-width // tile)
    return ColumnCache(
        np.zeros((height, width, 1 + 2 * nw), np.uint64),
        nw,
        1,
        on,
        np.zeros((n_tiles, n_cells // TILE_BLOCK + 1), np.uint8),
        np.zeros(n_tiles, np.int64),
    )


class Scratch(NamedTuple):
    """Per query point: tile bounds ``lbs``, tile-block states ``tstate`` (0 unknown, 1 cleared, 2 not
    cleared), the pyramid descent's ``stack``, and the frame's shared :class:`ColumnCache` ``cache``."""

    lbs: np.ndarray
    tstate: np.ndarray
    stack: np.ndarray
    cache: ColumnCache


def scratch(n_tiles: int, n_cells: int) -> Scratch:
    """A :class:`Scratch` for one point, without a column cache (tests and tools; the query allocates
    its own)."""
    return Scratch(
        np.empty(n_tiles),
        np.zeros(n_cells // TILE_BLOCK + 1, dtype=np.uint8),
        np.empty(3 * PYR_STACK, np.int64),
        column_cache(1, 1, n_cells, on=False),
    )
