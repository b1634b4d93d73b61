"""Single-camera depth-space distances (ICRA'12 §III, RA-L'16 §IV-VI).

Two stages, at two rates (DESIGN.md §1):

* :func:`prepare_frame`, once per camera frame (30 Hz): applies the robot mask, the missing-depth policy
  (hole filling) and builds a tile-minimum image used for pruning;
* :func:`query_distances`, as often as the controller wants (kHz): for many control spheres at once,
  the minimum distance to the obstacles *including the gray area* behind them, its direction, the
  nearest obstacle point and the number of obstacle pixels within ρ.

Point-to-pixel distance. ``model="frustum"`` (default) returns a *lower bound* of the Euclidean distance
from the control point ``P`` to the pixel frustum behind the measured depth ``d_o`` (the observed surface
plus its gray area, RA-L'16 eqs. 5-7). With ``r = ((u+.5-cx)/fx, (v+.5-cy)/fy, 1)`` the pixel-centre ray,
``s* = max(d_o, P·r / r·r)`` and ``d_ray = |P - s* r|``, every frustum point at depth ``z`` lies within
``h z`` of the ray point at depth ``z`` (``h = ½ sqrt(fx⁻² + fy⁻²)``) and the nearest frustum point has
``z ≤ d_p + D``, so ``D ≥ d_ray (1 - h) - h d_p``. The literal RA-L eqs. 5-7 evaluate the pixel at the
control point's depth, which over-estimates the distance by up to ``1/cos θ`` off the optical axis
(≈ 15 % at the edge of a Kinect image); this form never over-estimates and is as cheap.
``model="icra"`` is ICRA'12 eq. 4 at the pixel centre, with the gray area handled by ``d_o := d_p`` when
``d_o < d_p``; ``model="ral16"`` is the literal RA-L'16 eqs. 5-7. Both are kept for comparison only.

Region of surveillance (eq. 5). The exact pixel bounding box of the cube of side ``2ρ'`` around ``P``
(ρ' = ρ + sphere radius) is obtained by projecting its 8 corners, plus one pixel of margin; the whole
image when the cube reaches behind the camera. (A box centred on ``p_x`` misses obstacles at the sides of
off-axis points.) Pixels deeper than ``d_p + ρ'`` are skipped (RA-L case i).

Unseen space (DESIGN.md §5.2). With ``invalid="conservative"`` the space outside the field of view and
nearer than ``min_depth`` counts as an obstacle, exactly like a missing pixel does.

First call: the numba kernels are compiled and cached on disk (``cache=True``): about 5-10 s the first
time on a new machine, well under a second afterwards.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from depthguard.camera import Camera
from depthguard.validation import check_points

__all__ = [
    "TILE",
    "DepthFrame",
    "PointDistances",
    "prepare_frame",
    "query_distances",
    "MODES",
    "INVALID_POLICIES",
    "DISTANCE_MODELS",
    "lower_bound_slack",
    "tile_min",
]

TILE = 16
# fast-math without the no-NaN / no-inf assumptions: +inf marks "nothing" in the depth images and tile minima
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}
MODES = ("min", "all", "hybrid")
INVALID_POLICIES = ("conservative", "ignore")
DISTANCE_MODELS = ("frustum", "icra", "ral16")


class DepthFrame(NamedTuple):
    """One camera frame, prepared for distance queries (all arrays read-only).

    Attributes:
        camera: the camera.
        obstacle_depth: (H, W) float32 depth in metres of what counts as obstacle at each pixel; +inf
            where nothing does (robot pixels, or missing pixels under ``invalid="ignore"``).
        robot_mask: (H, W) bool, True on robot pixels.
        robot_depth: (H, W) float32, the measured robot depth on robot pixels, NaN elsewhere.
        tile_min: (ceil(H/TILE), ceil(W/TILE)) float32 minimum of ``obstacle_depth`` over each tile.
        invalid: the missing-depth policy used.
        filled_pixels: missing pixels filled from valid neighbours.
        unknown_pixels: missing pixels set to the near limit (unknown space).
    """

    camera: Camera
    obstacle_depth: np.ndarray
    robot_mask: np.ndarray
    robot_depth: np.ndarray
    tile_min: np.ndarray
    invalid: str
    filled_pixels: int
    unknown_pixels: int


class PointDistances(NamedTuple):
    """Distances for N control spheres (world frame, metres).

    Attributes:
        distance: (N,) distance from the sphere's surface to the nearest obstacle (>= 0); ``inf`` when
            nothing lies within ρ.
        direction: (N, 3) unit repulsive direction, from the obstacle towards the point; for ``mode="min"``
            the nearest obstacle's, for ``"all"`` the v-weighted sum of all (ICRA'12 eq. 9), for
            ``"hybrid"`` the mean (RA-L'16 eq. 11). NaN when nothing lies within ρ.
        nearest: (N, 3) nearest obstacle point; NaN when nothing lies within ρ.
        obstacle_pixels: (N,) number of obstacle pixels within ρ (in ``"min"`` mode only those met before
            the search region shrank, so a lower bound).
    """

    distance: np.ndarray
    direction: np.ndarray
    nearest: np.ndarray
    obstacle_pixels: np.ndarray

    def __len__(self) -> int:  # the number of points, not of fields
        return len(self.distance)

    def to_json(self, names: list[str]) -> list[dict]:
        """The ``points`` list of the ``depthguard distance --json`` contract."""
        out = []
        for i, name in enumerate(names):
            found = bool(np.isfinite(self.distance[i]))
            out.append(
                {
                    "name": name,
                    "distance": float(self.distance[i]) if found else None,
                    "direction": [float(x) for x in self.direction[i]] if found else None,
                    "nearest": [float(x) for x in self.nearest[i]] if found else None,
                    "obstacle_pixels": int(self.obstacle_pixels[i]),
                }
            )
        return out


def lower_bound_slack(camera: Camera, depth: float, distance: float = 0.0) -> float:
    """How far below the true distance the frustum bound may lie, from the bound alone (metres).

    ``2 h (d_p + D)``, i.e. about 1.4 pixel footprints at depth ``d_p + D``. Sampling (one ray per pixel)
    adds up to one pixel footprint at the obstacle's depth for curved or oblique surfaces.
    """
    h = 0.5 * math.sqrt(camera.fx**-2 + camera.fy**-2)
    return 2.0 * h * (depth + distance)


# --------------------------------------------------------------------------------------------- frame stage
@nb.njit(cache=True)
def _fill_holes(depth, missing, robot, fill_radius, near_limit, conservative, out):
    """Missing-depth policy (DESIGN.md §4). Returns (filled, unknown) counts."""
    H, W = depth.shape
    filled = 0
    unknown = 0
    for v in range(H):
        for u in range(W):
            if robot[v, u]:
                out[v, u] = np.inf
                continue
            if not missing[v, u]:
                out[v, u] = depth[v, u]
                continue
            if not conservative:
                out[v, u] = np.inf
                continue
            best = np.inf
            for vv in range(max(0, v - fill_radius), min(H, v + fill_radius + 1)):
                for uu in range(max(0, u - fill_radius), min(W, u + fill_radius + 1)):
                    if not missing[vv, uu] and not robot[vv, uu] and depth[vv, uu] < best:
                        best = depth[vv, uu]
            if best < np.inf:
                out[v, u] = best
                filled += 1
            else:
                out[v, u] = near_limit
                unknown += 1
    return filled, unknown


@nb.njit(cache=True)
def tile_min(img, tile):
    """(ceil(H/tile), ceil(W/tile)) float32 minimum of ``img`` (H, W) over each ``tile x tile`` block."""
    H, W = img.shape
    th = (H + tile - 1) // tile
    tw = (W + tile - 1) // tile
    out = np.full((th, tw), np.inf, dtype=np.float32)
    for tv in range(th):
        for v in range(tv * tile, min(H, tv * tile + tile)):
            for tu in range(tw):
                m = out[tv, tu]
                for u in range(tu * tile, min(W, tu * tile + tile)):
                    if img[v, u] < m:
                        m = img[v, u]
                out[tv, tu] = m
    return out


def prepare_frame(
    camera: Camera,
    depth: np.ndarray,
    mask: np.ndarray | None = None,
    invalid: str = "conservative",
    fill_radius: int = 4,
) -> DepthFrame:
    """Prepare one depth image for distance queries (per frame, camera rate).

    Args:
        camera: the camera that took the image.
        depth: (H, W) depth ``z_C`` in metres; 0, NaN and inf mean no reading.
        mask: optional (H, W) bool robot mask (True = robot pixel, skipped as in ICRA'12 §IV-B).
        invalid: ``"conservative"`` (default): a missing pixel within ``fill_radius`` pixels (square window)
            of valid non-robot pixels takes the minimum of their depths (the nearer surface); any other
            missing pixel is unknown, i.e. an obstacle at ``camera.min_depth`` whose whole ray is gray area.
            ``"ignore"``: missing pixels are free space (ICRA'12 behaviour; only on explicit request).
        fill_radius: hole-filling radius in pixels (>= 0).
    Returns:
        A :class:`DepthFrame`.
    """
    if invalid not in INVALID_POLICIES:
        raise ValueError(f"invalid must be one of {INVALID_POLICIES}, got {invalid!r}")
    if isinstance(fill_radius, bool) or not isinstance(fill_radius, int | np.integer) or fill_radius < 0:
        raise ValueError(f"fill_radius must be an integer >= 0, got {fill_radius!r}")
    d = np.asarray(camera.check_image(depth, "depth"), dtype=np.float32)
    missing = ~np.isfinite(d) | (d <= 0)
    if mask is None:
        robot = np.zeros(camera.shape, dtype=bool)
    else:
        robot = np.asarray(camera.check_image(mask, "mask")).astype(bool)
    obs = np.empty(camera.shape, dtype=np.float32)
    filled, unknown = _fill_holes(
        d, missing, robot, int(fill_radius), np.float32(camera.min_depth), invalid == "conservative", obs
    )
    robot_depth = np.where(robot & ~missing, d, np.float32(np.nan)).astype(np.float32)
    tmin = tile_min(obs, TILE)
    for a in (obs, robot, robot_depth, tmin):
        a.setflags(write=False)
    return DepthFrame(camera, obs, robot, robot_depth, tmin, invalid, int(filled), int(unknown))


# ---------------------------------------------------------------------------------------------- query stage
@nb.njit(cache=True, inline="always", fastmath=FASTMATH, error_model="numpy")
def _ray_point_distance(px, py, pz, a, b, d_start):
    """Nearest point at depth >= d_start on the ray s (a, b, 1): returns (dx, dy, dz, s)."""
    s = (px * a + py * b + pz) / (a * a + b * b + 1.0)
    if s < d_start:
        s = d_start
    return px - s * a, py - s * b, pz - s, s


@nb.njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _query_one(obs, tmin, tile, fx, fy, cx, cy, Pc, radius, rho, mode, model, alpha, near_limit, unseen, out):
    """Distance query for one point; writes out[0:8] = best, dir(3), nearest(3), count (camera frame)."""
    H, W = obs.shape
    px, py, pz = Pc[0], Pc[1], Pc[2]
    reff = rho + radius
    best = reff
    bx = by = bz = 0.0
    nx = ny = nz = np.nan
    count = 0
    sx = sy = sz = 0.0
    h = 0.5 * math.sqrt(1.0 / (fx * fx) + 1.0 / (fy * fy))

    # unseen space: outside the field of view and nearer than the near limit (DESIGN.md §5.2)
    if unseen:
        for k in range(5):
            if k == 0:
                a0 = (0.0 - cx) / fx
                nrm = math.sqrt(1.0 + a0 * a0)
                ux, uy, uz = 1.0 / nrm, 0.0, -a0 / nrm
            elif k == 1:
                a1 = (W - cx) / fx
                nrm = math.sqrt(1.0 + a1 * a1)
                ux, uy, uz = -1.0 / nrm, 0.0, a1 / nrm
            elif k == 2:
                b0 = (0.0 - cy) / fy
                nrm = math.sqrt(1.0 + b0 * b0)
                ux, uy, uz = 0.0, 1.0 / nrm, -b0 / nrm
            elif k == 3:
                b1 = (H - cy) / fy
                nrm = math.sqrt(1.0 + b1 * b1)
                ux, uy, uz = 0.0, -1.0 / nrm, b1 / nrm
            else:
                ux, uy, uz = 0.0, 0.0, 1.0
            s = px * ux + py * uy + pz * uz
            if k == 4:
                s -= near_limit
            if s < 0.0:
                s = 0.0
            if s < reff:
                w = 1.0
                if mode == 1:
                    w = 1.0 / (1.0 + math.exp(((s - radius) * 2.0 / rho - 1.0) * alpha))
                sx += w * ux
                sy += w * uy
                sz += w * uz
                if s < best:
                    best = s
                    bx, by, bz = ux, uy, uz
                    nx, ny, nz = px - s * ux, py - s * uy, pz - s * uz

    # region of surveillance: pixel bounding box of the cube of side 2 reff (eq. 5, DESIGN.md §4)
    u0, u1, v0, v1 = 0, W - 1, 0, H - 1
    if pz - reff > 1e-6:
        umin = vmin = np.inf
        umax = vmax = -np.inf
        for cxs in (-reff, reff):
            for cys in (-reff, reff):
                for czs in (-reff, reff):
                    z = pz + czs
                    qx = fx * (px + cxs) / z + cx
                    qy = fy * (py + cys) / z + cy
                    umin = min(umin, qx)
                    umax = max(umax, qx)
                    vmin = min(vmin, qy)
                    vmax = max(vmax, qy)
        u0 = max(0, int(math.floor(max(umin, -1.0))) - 1)
        u1 = min(W - 1, int(math.floor(min(umax, W + 1.0))) + 1)
        v0 = max(0, int(math.floor(max(vmin, -1.0))) - 1)
        v1 = min(H - 1, int(math.floor(min(vmax, H + 1.0))) + 1)
    if u0 > u1 or v0 > v1:
        out[0] = best
        out[1], out[2], out[3] = bx, by, bz
        out[4], out[5], out[6] = nx, ny, nz
        out[7] = count
        return

    t_u0, t_u1 = u0 // tile, u1 // tile
    t_v0, t_v1 = v0 // tile, v1 // tile
    ntu = t_u1 - t_u0 + 1
    ntiles = ntu * (t_v1 - t_v0 + 1)
    lbs = np.empty(ntiles)
    zmax = pz + reff
    for k in range(ntiles):
        tv = t_v0 + k // ntu
        tu = t_u0 + k % ntu
        dmin = tmin[tv, tu]
        if dmin > zmax:
            lbs[k] = np.inf
            continue
        # lower bound over the whole tile frustum: its centre ray and half-diagonal
        ua = tu * tile
        ub = min(W, ua + tile)
        va = tv * tile
        vb = min(H, va + tile)
        a = ((ua + ub) * 0.5 - cx) / fx
        b = ((va + vb) * 0.5 - cy) / fy
        hT = 0.5 * math.sqrt(((ub - ua) / fx) ** 2 + ((vb - va) / fy) ** 2)
        dx, dy, dz, s = _ray_point_distance(px, py, pz, a, b, dmin)
        dr = math.sqrt(dx * dx + dy * dy + dz * dz)
        lbs[k] = dr * (1.0 - hT) - hT * pz
    order = np.argsort(lbs) if mode == 0 else np.arange(ntiles)

    for kk in range(ntiles):
        k = order[kk]
        if lbs[k] >= best:
            if mode == 0:
                break  # nearest-first: every remaining tile is farther (ICRA'12 §III, shrinking region)
            if lbs[k] >= reff:
                continue
        tv = t_v0 + k // ntu
        tu = t_u0 + k % ntu
        for v in range(max(v0, tv * tile), min(v1 + 1, tv * tile + tile)):
            b = (v + 0.5 - cy) / fy
            for u in range(max(u0, tu * tile), min(u1 + 1, tu * tile + tile)):
                do = obs[v, u]
                if do > zmax:
                    continue
                a = (u + 0.5 - cx) / fx
                if model == 0:
                    dx, dy, dz, s = _ray_point_distance(px, py, pz, a, b, do)
                    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                    D = dr * (1.0 - h) - h * pz
                    if D < 0.0:
                        D = 0.0
                elif model == 1:
                    s = do if do > pz else pz
                    dx, dy, dz = px - s * a, py - s * b, pz - s
                    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                    D = dr
                else:  # literal RA-L'16 eqs. 5-7: nearest pixel edge, evaluated at the point's depth
                    qx = fx * px / pz + cx
                    qy = fy * py / pz + cy
                    ox = min(max(qx, u), u + 1.0)
                    oy = min(max(qy, v), v + 1.0)
                    s = do if do > pz else pz
                    a = (ox - cx) / fx
                    b = (oy - cy) / fy
                    dx, dy, dz = px - s * a, py - s * b, pz - s
                    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                    D = dr
                if D >= reff:
                    continue
                count += 1
                if dr < 1e-12:  # the point sits on the ray: push away from the visible surface
                    dx, dy, dz = px - do * a, py - do * b, pz - do
                    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if dr < 1e-12:
                        dx, dy, dz, dr = 0.0, 0.0, 1.0, 1.0
                ix, iy, iz = dx / dr, dy / dr, dz / dr
                if mode == 1:
                    w = 1.0 / (1.0 + math.exp(((D - radius) * 2.0 / rho - 1.0) * alpha))
                    sx += w * ix
                    sy += w * iy
                    sz += w * iz
                elif mode == 2:
                    sx += ix
                    sy += iy
                    sz += iz
                if D < best:
                    best = D
                    bx, by, bz = ix, iy, iz
                    nx, ny, nz = s * a, s * b, s
    if mode != 0:
        nrm = math.sqrt(sx * sx + sy * sy + sz * sz)
        if nrm > 1e-9:
            bx, by, bz = sx / nrm, sy / nrm, sz / nrm
    out[0] = best
    out[1], out[2], out[3] = bx, by, bz
    out[4], out[5], out[6] = nx, ny, nz
    out[7] = count


def _query_many_py(obs, tmin, tile, fx, fy, cx, cy, R, t, centres, radii, rho, mode, model, alpha, near, unseen):
    n = centres.shape[0]
    out = np.empty((n, 8))
    for i in nb.prange(n):
        Pc = R @ centres[i] + t
        _query_one(obs, tmin, tile, fx, fy, cx, cy, Pc, radii[i], rho, mode, model, alpha, near, unseen, out[i])
    return out


# One thread by default: on a loaded machine (a robot PC runs the controller too) a parallel kernel waits for
# a free core and its latency jumps by a scheduler time slice (several ms); opt in with parallel=True.
_query_many = nb.njit(cache=True, error_model="numpy")(_query_many_py)
_query_many_parallel = nb.njit(cache=True, parallel=True, error_model="numpy")(_query_many_py)


def query_distances(
    frame: DepthFrame,
    centres: np.ndarray,
    radii: np.ndarray | float = 0.0,
    rho: float = 0.4,
    mode: str = "all",
    alpha: float = 6.0,
    model: str = "frustum",
    parallel: bool = False,
) -> PointDistances:
    """Distances from N control spheres to the obstacles seen by one camera (ICRA'12 §III-IV).

    Args:
        frame: a frame from :func:`prepare_frame`.
        centres: (N, 3) sphere centres in the world frame, metres.
        radii: (N,) sphere radii in metres (or one number for all).
        rho: radius of surveillance ρ in metres, measured from the sphere surface.
        mode: ``"min"`` (nearest obstacle only, nearest-first search with a shrinking region),
            ``"all"`` (direction of ICRA'12 eq. 9) or ``"hybrid"`` (direction of RA-L'16 eq. 11).
        alpha: shape factor α of the magnitude profile (eq. 7), used for the eq. 9 weights.
        model: ``"frustum"`` (lower bound, default), ``"icra"`` (eq. 4 at the pixel centre) or ``"ral16"``
            (literal RA-L'16 eqs. 5-7, which over-estimates off the optical axis); the last two for comparison.
        parallel: spread the points over numba's threads (faster on an idle multi-core machine, slower
            and jittery when the cores are busy).
    Returns:
        :class:`PointDistances` in the world frame.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if model not in DISTANCE_MODELS:
        raise ValueError(f"model must be one of {DISTANCE_MODELS}, got {model!r}")
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
    c = np.atleast_2d(np.asarray(centres, dtype=float))
    r = np.broadcast_to(np.asarray(radii, dtype=float), (c.shape[0],)) if c.ndim == 2 else radii
    c, r = check_points(c, r)
    cam = frame.camera
    kernel = _query_many_parallel if parallel else _query_many
    raw = kernel(
        frame.obstacle_depth,
        frame.tile_min,
        TILE,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        np.ascontiguousarray(cam.R),
        np.ascontiguousarray(cam.t),
        np.ascontiguousarray(c),
        np.ascontiguousarray(r),
        float(rho),
        MODES.index(mode),
        DISTANCE_MODELS.index(model),
        float(alpha),
        float(cam.min_depth),
        frame.invalid == "conservative",
    )
    return _to_world(cam, raw, r, rho)


def _to_world(cam: Camera, raw: np.ndarray, radii: np.ndarray, rho: float) -> PointDistances:
    """Kernel output (camera frame, centre distances) -> world-frame :class:`PointDistances`."""
    found = raw[:, 0] < rho + radii
    dist = np.where(found, np.maximum(raw[:, 0] - radii, 0.0), np.inf)
    direction = np.where(found[:, None], cam.vector_to_world(raw[:, 1:4]), np.nan)
    nearest = np.where(found[:, None], cam.camera_to_world(np.nan_to_num(raw[:, 4:7])), np.nan)
    return PointDistances(dist, direction, nearest, raw[:, 7].astype(np.int64))
