"""Region of surveillance, unseen space and tile lower bounds, shared by every distance query.

* :func:`unseen_space` (``docs/conventions.md``, missing-depth rule): with the conservative policy the
  space outside the camera's field of view (the four side planes of the viewing pyramid) and nearer than
  its near limit (the plane ``z = near_limit``) is an obstacle. The distance from P to each half-space is
  that of P to its bounding plane (0 inside), its direction the plane's inward normal.
* :func:`surveillance_box` (ICRA'12 eq. 5, RA-L'16 eq. 8): the exact pixel bounding box of the cube of side
  ``2 (ρ + r)`` around P, from its 8 projected corners, plus one pixel of margin; the whole image when the
  cube reaches behind the camera. (A box centred on P's pixel misses obstacles beside off-axis points.)
* :func:`tile_lower_bounds`: per image tile, a lower bound of the distance from P to everything the tile's
  pixels can hold beyond the tile's smallest start depth: the distance to the tile-centre ray from that
  depth on, less the tile frustum's half-diagonal slack ``hT (d_ray + d_p)``; +inf for a tile whose
  smallest depth lies beyond ``d_p + ρ + r`` (RA-L'16 case i).

Domain: ``ρ + r`` finite and >= 0, P (camera frame, metres) with ``|p_x| + |p_y| + |p_z| <`` :data:`FAR`.
Beyond (a NaN or infinite coordinate, or a point so far that the arithmetic overflows), a point is in
doubt: the box is the whole image and the point lies in the unseen space (distance 0, with the conservative
policy); its pixels and tiles give no distance (``tests/test_region_kernel_guarantees.py``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.kernels import FASTMATH
from depthguard.kernels.hits import add_hit

__all__ = [
    "unseen_space",
    "surveillance_box",
    "tile_lower_bounds",
    "ray_distance_from",
    "nearest_tile",
    "next_tile",
    "first_index",
    "FAR",
]

#: metres: a point with ``|p_x| + |p_y| + |p_z|`` at or beyond this is in doubt: far beyond any depth camera's
#: range, it comes from a wrong unit or transform; and squared norms overflow near 1e154 m, float-to-integer
#: pixel and cell indices near 1e18 pixels or cells
FAR = 1e12


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def ray_distance_from(px, py, pz, a, b, s_min):
    """Nearest point at depth ``>= s_min`` on the ray ``s (a, b, 1)``: returns ``(dx, dy, dz, s)``, P minus it."""
    s = (px * a + py * b + pz) / (a * a + b * b + 1.0)
    if s < s_min:
        s = s_min
    return px - s * a, py - s * b, pz - s, s


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def unseen_space(h, px, py, pz, radius, intr, qp):
    """``h`` plus the five unseen half-spaces within reach (see the module docstring); a point in doubt (not
    finite, or at or beyond :data:`FAR`) lies in each of them (distance 0)."""
    reff = qp.rho + radius
    lost = not abs(px) + abs(py) + abs(pz) < FAR
    for k in range(5):
        if k == 0:
            a0 = (0.0 - intr.cx) / intr.fx
            nrm = math.sqrt(1.0 + a0 * a0)
            ux, uy, uz = 1.0 / nrm, 0.0, -a0 / nrm
        elif k == 1:
            a1 = (intr.width - intr.cx) / intr.fx
            nrm = math.sqrt(1.0 + a1 * a1)
            ux, uy, uz = -1.0 / nrm, 0.0, a1 / nrm
        elif k == 2:
            b0 = (0.0 - intr.cy) / intr.fy
            nrm = math.sqrt(1.0 + b0 * b0)
            ux, uy, uz = 0.0, 1.0 / nrm, -b0 / nrm
        elif k == 3:
            b1 = (intr.height - intr.cy) / intr.fy
            nrm = math.sqrt(1.0 + b1 * b1)
            ux, uy, uz = 0.0, -1.0 / nrm, b1 / nrm
        else:
            ux, uy, uz = 0.0, 0.0, 1.0
        s = px * ux + py * uy + pz * uz
        if k == 4:
            s -= intr.near_limit
        if s < 0.0 or lost:
            s = 0.0
        if s < reff:
            h = add_hit(
                h, s, ux, uy, uz, px - s * ux, py - s * uy, pz - s * uz, False, radius, qp.rho, qp.mode, qp.alpha
            )
    return h


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def surveillance_box(px, py, pz, reff, intr):
    """Inclusive pixel box ``(u0, u1, v0, v1)`` of the region of surveillance (empty when u0 > u1 or v0 > v1);
    the whole image for a cube that reaches z <= 1e-6 and for a point in doubt (see the module docstring)."""
    W = intr.width
    H = intr.height
    u0, u1, v0, v1 = 0, W - 1, 0, H - 1
    if pz - reff > 1e-6 and abs(px) + abs(py) + abs(pz) < FAR:
        umin = vmin = np.inf
        umax = vmax = -np.inf
        for cxs in (-reff, reff):
            for cys in (-reff, reff):
                for czs in (-reff, reff):
                    z = pz + czs
                    qx = intr.fx * (px + cxs) / z + intr.cx
                    qy = intr.fy * (py + cys) / z + intr.cy
                    umin = min(umin, qx)
                    umax = max(umax, qx)
                    vmin = min(vmin, qy)
                    vmax = max(vmax, qy)
        u0 = max(0, int(math.floor(max(umin, -1.0))) - 1)
        u1 = min(W - 1, int(math.floor(min(umax, W + 1.0))) + 1)
        v0 = max(0, int(math.floor(max(vmin, -1.0))) - 1)
        v1 = min(H - 1, int(math.floor(min(vmax, H + 1.0))) + 1)
    return u0, u1, v0, v1


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def tile_lower_bounds(tmin, px, py, pz, reff, box, intr, tile, lbs, part=0, nparts=1):
    """Fill ``lbs[k]`` for the tiles ``k`` over ``box`` = ``(u0, u1, v0, v1)`` (row-major from ``(t_v0, t_u0)``);
    +inf (never visited) for the tiles of the rows ``tv % nparts != part`` (another part of a shared query).

    Returns ``(t_u0, t_v0, ntu, ntiles)``: tile ``k`` is ``(t_v0 + k // ntu, t_u0 + k % ntu)``.
    """
    W = intr.width
    H = intr.height
    u0, u1, v0, v1 = box
    t_u0, t_u1 = u0 // tile, u1 // tile
    t_v0, t_v1 = v0 // tile, v1 // tile
    ntu = t_u1 - t_u0 + 1
    ntiles = ntu * (t_v1 - t_v0 + 1)
    zmax = pz + reff
    for k in range(ntiles):
        tv = t_v0 + k // ntu
        tu = t_u0 + k % ntu
        dmin = tmin[tv, tu]
        if dmin > zmax or (nparts > 1 and tv % nparts != part):
            lbs[k] = np.inf
            continue
        ua = tu * tile
        ub = min(W, ua + tile)
        va = tv * tile
        vb = min(H, va + tile)
        a = ((ua + ub) * 0.5 - intr.cx) / intr.fx
        b = ((va + vb) * 0.5 - intr.cy) / intr.fy
        hT = 0.5 * math.sqrt(((ub - ua) / intr.fx) ** 2 + ((vb - va) / intr.fy) ** 2)
        dx, dy, dz, _ = ray_distance_from(px, py, pz, a, b, dmin)
        lbs[k] = math.sqrt(dx * dx + dy * dy + dz * dz) * (1.0 - hT) - hT * pz
    return t_u0, t_v0, ntu, ntiles


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def nearest_tile(lbs, ntiles):
    """Index of the smallest entry of ``lbs[:ntiles]`` (``min`` mode visits tiles nearest first)."""
    k = 0
    for j in range(1, ntiles):
        if lbs[j] < lbs[k]:
            k = j
    return k


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def next_tile(lbs, ntiles, kk, best, reff, mode, stride):
    """The tile to visit at step ``kk`` (``0 <= kk <= ntiles``) of a query: ``(index, lattice_only)``;
    index ``ntiles`` skips the step, -1 stops.

    ``min`` mode (``mode`` 0): nearest tile first (its bound set to +inf once taken), stopping when no
    tile can be nearer than ``best`` (ICRA'12's shrinking region). Modes ``all`` / ``hybrid``: row-major
    order, skipping the tiles out of reach ``reff``; with a direction lattice (``stride > 1``, whose
    off-lattice pixels compete for the nearest distance only) the nearest tile goes first, so that
    ``best`` shrinks early (one O(ntiles) scan, not one per tile), and ``lattice_only`` says that the
    tile's lower bound is not below ``best``: only its lattice pixels can count.
    """
    if mode == 0:
        k = nearest_tile(lbs, ntiles)
        if not lbs[k] < best:
            return -1, False
        lbs[k] = np.inf
        return k, False
    if stride > 1:
        if kk == 0:
            k = nearest_tile(lbs, ntiles)
            if not lbs[k] < reff:
                return -1, False  # (the nearest tile out of reach: every tile is)
            lbs[k] = np.inf
            return k, False
        kk -= 1  # then every tile in row-major order (the nearest one now at +inf)
    if kk >= ntiles:
        return -1, False
    if lbs[kk] >= reff:
        return ntiles, False
    return kk, stride > 1 and not lbs[kk] < best


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False)
def first_index(lo, step):
    """The smallest multiple of ``step`` at or above ``lo`` (``lo >= 0``)."""
    return (lo + step - 1) // step * step
