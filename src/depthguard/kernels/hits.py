"""Aggregation of obstacle hits into one answer per control sphere (ICRA'12 §III, eq. 9; RA-L'16 eq. 11).

A query visits obstacle pieces (pixels, depth-grid segments, the unseen space) and calls :func:`add_hit`
for each one within reach; the running state is a :class:`Hits` record (immutable, so that the compiled
code keeps it in registers). Modes: 0 ``min`` (distance and direction of the nearest piece), 1 ``all``
(the nearest distance with the direction of the sum of all pieces' directions weighted by the magnitude
profile of eq. 7/9), 2 ``hybrid`` (the nearest distance with the mean direction, RA-L'16 eq. 11).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from depthguard.kernels import FASTMATH

__all__ = [
    "Hits",
    "no_hits",
    "add_hit",
    "nearer_hit",
    "write_hits",
    "store_hits",
    "merge_hits",
    "OUT_WIDTH",
    "HITS_WIDTH",
]

OUT_WIDTH = 10  # out row: distance, direction (3), nearest (3), count, column searches, votes
HITS_WIDTH = 13  # a part's row (store_hits): the Hits fields (11), column searches, votes


class Hits(NamedTuple):
    """Running answer (camera frame, metres): ``best`` distance from the sphere centre (starts at ρ + r),
    unit direction ``b`` of the nearest piece, nearest point ``n``, number of pieces within reach
    ``count`` and the direction sum ``s``."""

    best: float
    bx: float
    by: float
    bz: float
    nx: float
    ny: float
    nz: float
    count: float
    sx: float
    sy: float
    sz: float


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def no_hits(reff):
    """The state before the first hit: nothing within ``reff`` = ρ + sphere radius."""
    return Hits(reff, 0.0, 0.0, 0.0, np.nan, np.nan, np.nan, 0.0, 0.0, 0.0, 0.0)


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def add_hit(h, D, ix, iy, iz, nx, ny, nz, counted, radius, rho, mode, alpha):
    """``h`` plus one piece at distance ``D`` (from the sphere centre, < ρ + r) in unit direction ``i``
    (from the piece towards the point), nearest point ``n``; ``counted``: the piece is an obstacle pixel
    (the unseen space is not counted). Eq. 9 weight ``1 / (1 + exp(((D - r) 2/ρ - 1) α))`` in mode 1."""
    w = 1.0
    if mode == 1:
        w = 1.0 / (1.0 + math.exp(((D - radius) * 2.0 / rho - 1.0) * alpha))
    sx = h.sx + w * ix
    sy = h.sy + w * iy
    sz = h.sz + w * iz
    count = h.count + 1.0 if counted else h.count
    if D < h.best:
        return Hits(D, ix, iy, iz, nx, ny, nz, count, sx, sy, sz)
    return Hits(h.best, h.bx, h.by, h.bz, h.nx, h.ny, h.nz, count, sx, sy, sz)


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def nearer_hit(h, D, ix, iy, iz, nx, ny, nz):
    """``h`` plus a piece that competes for the nearest distance only (not in the direction sum nor in
    the count): the pixels off the direction lattice (:func:`depthguard.kernels.records.direction_stride`)."""
    if D < h.best:
        return Hits(D, ix, iy, iz, nx, ny, nz, h.count, h.sx, h.sy, h.sz)
    return h


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def write_hits(h, mode, out):
    """Write out[0:8] = distance, direction (3), nearest (3), count; the direction of modes 1 and 2 is
    the normalised sum (the nearest piece's when the sum vanishes)."""
    bx, by, bz = h.bx, h.by, h.bz
    if mode != 0:
        nrm = math.sqrt(h.sx * h.sx + h.sy * h.sy + h.sz * h.sz)
        if nrm > 1e-9:
            bx, by, bz = h.sx / nrm, h.sy / nrm, h.sz / nrm
    out[0] = h.best
    out[1] = bx
    out[2] = by
    out[3] = bz
    out[4] = h.nx
    out[5] = h.ny
    out[6] = h.nz
    out[7] = h.count


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def store_hits(h, cells, tests, row):
    """``row[0:13]`` = the fields of ``h`` in order, then ``cells`` and ``tests`` (a part of a query,
    :func:`merge_hits`)."""
    row[0] = h.best
    row[1] = h.bx
    row[2] = h.by
    row[3] = h.bz
    row[4] = h.nx
    row[5] = h.ny
    row[6] = h.nz
    row[7] = h.count
    row[8] = h.sx
    row[9] = h.sy
    row[10] = h.sz
    row[11] = cells
    row[12] = tests


@nb.njit(cache=True, nogil=True, fastmath=FASTMATH)
def merge_hits(parts, mode, stride):
    """The rows that the whole query writes (N, ``OUT_WIDTH``), from the hits of K disjoint parts of each
    sphere's pieces: ``parts`` (K, N, ``HITS_WIDTH``) (:func:`store_hits`, each part started from
    :func:`no_hits`). The nearest piece is that of the part with the smallest ``best`` (the first part on a
    tie: the one that holds the unseen space, which the whole query visits first); the counts, the direction
    sums, the column searches and the votes add up. ``stride``: the direction lattice (the count is scaled by
    ``stride²`` in modes 1 and 2, as the whole query does)."""
    nparts, n = parts.shape[0], parts.shape[1]
    out = np.empty((n, OUT_WIDTH))
    for i in range(n):
        j = 0
        for p in range(1, nparts):
            if parts[p, i, 0] < parts[j, i, 0]:
                j = p
        count = sx = sy = sz = cells = tests = 0.0
        for p in range(nparts):
            count += parts[p, i, 7]
            sx += parts[p, i, 8]
            sy += parts[p, i, 9]
            sz += parts[p, i, 10]
            cells += parts[p, i, 11]
            tests += parts[p, i, 12]
        r = parts[j, i]
        h = Hits(r[0], r[1], r[2], r[3], r[4], r[5], r[6], count, sx, sy, sz)
        write_hits(h, mode, out[i])
        if mode != 0:
            out[i, 7] *= stride * stride
        out[i, 8] = cells
        out[i, 9] = tests
    return out
