"""Pruning the node grid into a real octree: 8 equal children become one parent (OctoMap's ``prune``)."""

from __future__ import annotations

import numpy as np

from depthguard.octree.grid import VoxelBox

__all__ = ["prune"]


def prune(occupied: np.ndarray, box: VoxelBox, levels: int = 16) -> list[tuple[float, np.ndarray]]:
    """Leaves of the pruned octree of a dense (nx, ny, nz) bool grid.

    Returns:
        ``[(size, lower corners (K, 3))]`` per level, finest first: the nodes whose 8 children are all
        occupied are merged (recursively), so a solid region of 8^k nodes becomes one leaf. The lattice is
        the box's, with cells aligned to multiples of ``2^l res`` from its origin.
    """
    occ = np.asarray(occupied, dtype=bool)
    if isinstance(levels, bool) or int(levels) != levels or levels < 1:
        raise ValueError(f"levels must be an integer >= 1, got {levels!r}")
    if occ.shape != box.shape:
        raise ValueError(f"occupied grid has shape {occ.shape}, expected the box's {box.shape}")
    out = []
    cur = occ
    for lv in range(levels):
        shp = tuple((s + 1) // 2 for s in cur.shape)
        pad = np.zeros(tuple(2 * s for s in shp), dtype=bool)
        pad[: cur.shape[0], : cur.shape[1], : cur.shape[2]] = cur
        full = pad.reshape(shp[0], 2, shp[1], 2, shp[2], 2).all(axis=(1, 3, 5))
        if lv == levels - 1:  # the coarsest level allowed: its nodes stay leaves (were dropped before)
            full[...] = False
        # leaves at this level: occupied cells whose parent is not full
        parent_full = np.repeat(np.repeat(np.repeat(full, 2, 0), 2, 1), 2, 2)[
            : cur.shape[0], : cur.shape[1], : cur.shape[2]
        ]
        leaves = np.argwhere(cur & ~parent_full)
        size = box.res * (1 << lv)
        out.append((size, box.origin + leaves * size))
        if not full.any() or max(cur.shape) == 1:
            if full.any():
                out.append((size * 2, box.origin + np.argwhere(full) * size * 2))
            break
        cur = full
    return out
