"""An axis-aligned voxel box: the node lattice shared by the reachability grid and the obstacle octree.

A :class:`VoxelBox` is the finest level of an octree: cell ``(i, j, k)`` covers
``[origin + (i, j, k) res, origin + (i+1, j+1, k+1) res)`` (metres, world frame). Dense boolean or time
arrays over it are indexed ``[i, j, k]`` (x, y, z). Pruning into a real octree is in
:mod:`depthguard.octree.tree`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.validation import check_finite_array, check_positive

__all__ = ["VoxelBox", "MIN_RES", "MAX_RES"]

MIN_RES = 0.02
MAX_RES = 0.1


def check_res(res: object, name: str = "res") -> float:
    """Node size in metres, 0.02-0.1 m (the range the issue fixes), or ``ValueError``."""
    r = check_positive(res, name)
    if not (MIN_RES - 1e-12 <= r <= MAX_RES + 1e-12):
        raise ValueError(f"{name} must be between {MIN_RES} and {MAX_RES} m, got {res!r}")
    return r


@dataclass(frozen=True)
class VoxelBox:
    """A box of cubic cells.

    Attributes:
        origin: (3,) world position of the corner of cell (0, 0, 0), metres.
        res: cell edge length, metres.
        shape: (nx, ny, nz) number of cells along x, y, z.
    """

    origin: np.ndarray
    res: float
    shape: tuple[int, int, int]

    @classmethod
    def around(cls, lo: object, hi: object, res: float, pad: int = 0) -> VoxelBox:
        """The smallest box of ``res`` cells (on the lattice ``k res``) that covers ``[lo, hi]``, plus ``pad`` cells."""
        lo_a = check_finite_array(lo, (3,), "box lo")
        hi_a = check_finite_array(hi, (3,), "box hi")
        if np.any(hi_a < lo_a):
            raise ValueError(f"box hi {hi_a} must be >= lo {lo_a} on every axis")
        res = check_positive(res, "res")
        if isinstance(pad, bool) or not isinstance(pad, int | np.integer) or pad < 0:
            raise ValueError(f"box pad must be a whole number of cells >= 0, got {pad!r}")
        i0 = np.floor(lo_a / res).astype(int) - pad
        i1 = np.floor(hi_a / res).astype(int) + 1 + pad
        shape = tuple(int(x) for x in (i1 - i0))
        return cls(i0 * res, res, shape)  # type: ignore[arg-type]

    @property
    def size(self) -> int:
        """Number of cells."""
        return int(np.prod(self.shape))

    @property
    def hi(self) -> np.ndarray:
        """(3,) far corner, metres."""
        return self.origin + np.array(self.shape) * self.res

    def centres(self, idx: np.ndarray) -> np.ndarray:
        """(M, 3) cell centres (metres) of (M, 3) integer indices."""
        return self.origin + (np.asarray(idx) + 0.5) * self.res

    def index(self, points: np.ndarray) -> np.ndarray:
        """(M, 3) integer cell indices of (M, 3) points (may lie outside ``[0, shape)``)."""
        return np.floor((np.asarray(points, dtype=float) - self.origin) / self.res).astype(np.int64)

    def inside(self, idx: np.ndarray) -> np.ndarray:
        """(M,) bool: indices within the box."""
        idx = np.asarray(idx)
        return np.all((idx >= 0) & (idx < np.array(self.shape)), axis=-1)

    def coarsen(self, factor: int) -> VoxelBox:
        """The box of ``factor``-times larger cells covering this one (same origin)."""
        shape = tuple(math.ceil(s / factor) for s in self.shape)
        return VoxelBox(self.origin.copy(), self.res * factor, shape)  # type: ignore[arg-type]

    def corner_lo(self, idx: np.ndarray) -> np.ndarray:
        """(M, 3) lower corners of cells (metres)."""
        return self.origin + np.asarray(idx) * self.res
