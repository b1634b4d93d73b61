"""Single-camera depth-space distances (ICRA'12 §III, RA-L'16 §IV-VI).

Two stages, at two rates (docs/conventions.md):

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

Unseen space (docs/conventions.md). With ``invalid="conservative"`` the space outside the field of view and
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
from depthguard.kernels.holefill import column_minima_if_dense, window_min_at
from depthguard.kernels.pixels import query_many, query_many_parallel
from depthguard.kernels.records import direction_stride as resolve_stride
from depthguard.kernels.records import intrinsics, query_params
from depthguard.validation import check_float_depth, check_query

__all__ = [
    "TILE",
    "DepthFrame",
    "FilledDepth",
    "PointDistances",
    "fill_missing_depth",
    "prepare_frame",
    "query_distances",
    "MODES",
    "INVALID_POLICIES",
    "DISTANCE_MODELS",
    "lower_bound_slack",
    "tile_min",
    "check_query",
    "check_float_depth",
]

TILE = 16
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
@nb.njit(cache=True, nogil=True)
def _fill_holes(depth, missing, robot, fill_radius, near_limit, conservative, out):
    """Missing-depth policy (docs/conventions.md). Returns (filled, unknown) counts.

    A missing non-robot pixel takes the minimum valid non-robot depth of its (2 r + 1)^2 window (or, with
    none there, the near limit: unknown). One pass writes the valid depths (inf elsewhere); then each hole's
    window minimum (:mod:`depthguard.kernels.holefill`: sparse holes read their windows, dense ones the
    column minima of their row)."""
    H, W = depth.shape
    r = fill_radius
    filled = 0
    unknown = 0
    val = np.empty((H, W), np.float32)  # valid non-robot depth, inf elsewhere
    hole_value = near_limit if conservative else np.float32(np.inf)
    holes = 0
    for v in range(H):
        for u in range(W):
            rb, ms = robot[v, u], missing[v, u]
            val[v, u] = np.inf if rb or ms else depth[v, u]
            out[v, u] = np.inf if rb else (hole_value if ms else depth[v, u])
            holes += ms and not rb
    if not conservative or holes == 0:
        return filled, unknown
    dense, colmin = column_minima_if_dense(val, holes, r)
    for v in range(H):
        for u in range(W):
            if robot[v, u] or not missing[v, u]:
                continue
            best = window_min_at(val, colmin, dense, v, u, r)
            if best < np.inf:
                out[v, u] = best
                filled += 1
            else:
                unknown += 1
    return filled, unknown


@nb.njit(cache=True, nogil=True)
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


class FilledDepth(NamedTuple):
    """One depth image after the robot mask and the missing-depth policy (:func:`fill_missing_depth`).

    Attributes:
        depth: (H, W) float32, the image as given.
        missing: (H, W) bool, no reading (0, NaN, inf or negative).
        robot: (H, W) bool, robot pixels.
        obstacle_depth: (H, W) float32, as :attr:`DepthFrame.obstacle_depth`.
        filled_pixels, unknown_pixels: as in :class:`DepthFrame`.
    """

    depth: np.ndarray
    missing: np.ndarray
    robot: np.ndarray
    obstacle_depth: np.ndarray
    filled_pixels: int
    unknown_pixels: int


def check_depth_policy(
    camera: Camera, depth: np.ndarray, mask: np.ndarray | None, invalid: str, fill_radius: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """The checks of :func:`fill_missing_depth`'s arguments: ``ValueError`` naming the bad one (a depth image
    that is not of a float dtype too: integers are most likely millimetres), else the (H, W) float32 depth
    and the mask as given (an (H, W) array, not copied) or None."""
    if invalid not in INVALID_POLICIES:
        raise ValueError(f"invalid must be one of {INVALID_POLICIES}, got {invalid!r}")
    if isinstance(fill_radius, bool) or not isinstance(fill_radius, int | np.integer) or fill_radius < 0:
        raise ValueError(f"fill_radius must be an integer >= 0, got {fill_radius!r}")
    d = np.asarray(check_float_depth(camera.check_image(depth, "depth")), dtype=np.float32)
    return d, None if mask is None else np.asarray(camera.check_image(mask, "mask"))


def fill_missing_depth(
    camera: Camera,
    depth: np.ndarray,
    mask: np.ndarray | None = None,
    invalid: str = "conservative",
    fill_radius: int = 4,
) -> FilledDepth:
    """The robot mask and the missing-depth policy of :func:`prepare_frame` (same arguments), without the
    depth space's tile minima: what other backends (the octree) start from. Returns a :class:`FilledDepth`."""
    d, robot = check_depth_policy(camera, depth, mask, invalid, fill_radius)
    missing = ~np.isfinite(d) | (d <= 0)
    robot = np.zeros(camera.shape, dtype=bool) if robot is None else robot.astype(bool)
    obs = np.empty(camera.shape, dtype=np.float32)
    filled, unknown = _fill_holes(
        d, missing, robot, int(fill_radius), np.float32(camera.min_depth), invalid == "conservative", obs
    )
    return FilledDepth(d, missing, robot, obs, int(filled), int(unknown))


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
    f = fill_missing_depth(camera, depth, mask, invalid, fill_radius)
    robot_depth = np.where(f.robot & ~f.missing, f.depth, np.float32(np.nan)).astype(np.float32)
    tmin = tile_min(f.obstacle_depth, TILE)
    for a in (f.obstacle_depth, f.robot, robot_depth, tmin):
        a.setflags(write=False)
    return DepthFrame(camera, f.obstacle_depth, f.robot, robot_depth, tmin, invalid, f.filled_pixels, f.unknown_pixels)


# ---------------------------------------------------------------------------------------------- query stage
def query_distances(
    frame: DepthFrame,
    centres: np.ndarray,
    radii: np.ndarray | float = 0.0,
    rho: float = 0.4,
    mode: str = "all",
    alpha: float = 6.0,
    model: str = "frustum",
    parallel: bool = False,
    direction_stride: int | str = "auto",
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
        direction_stride: modes ``"all"`` and ``"hybrid"``: the direction sum takes every
            ``direction_stride``-th pixel in each image direction; the distance still comes from every
            pixel, and is the same whatever the stride. ``"auto"`` (default): 1 below 640 pixels wide, 2
            at 640 (:func:`depthguard.kernels.records.direction_stride`: a lattice about 320 pixels wide).
    Returns:
        :class:`PointDistances` in the world frame (``obstacle_pixels``: the lattice's count times
        ``direction_stride²`` in modes ``"all"`` and ``"hybrid"``).
    Raises:
        ValueError: naming the argument, for a bad mode, model, stride, rho, alpha (a finite number), centres
            or radii (:func:`check_query`).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if model not in DISTANCE_MODELS:
        raise ValueError(f"model must be one of {DISTANCE_MODELS}, got {model!r}")
    c, r, rho, alpha = check_query(centres, radii, rho, alpha)
    cam = frame.camera
    kernel = query_many_parallel if parallel else query_many
    raw = kernel(
        frame.obstacle_depth,
        frame.tile_min,
        intrinsics(cam),
        query_params(rho, MODES.index(mode), alpha, frame.invalid == "conservative", TILE),
        DISTANCE_MODELS.index(model),
        np.ascontiguousarray(cam.R),
        np.ascontiguousarray(cam.t),
        np.ascontiguousarray(c),
        np.ascontiguousarray(r),
        1 if mode == "min" else resolve_stride(direction_stride, cam.width),
    )
    return to_world(cam, raw, r, rho)


@nb.njit(cache=True, nogil=True)
def _rows_to_world(raw, radii, rho, R, t):
    """:func:`to_world`'s arithmetic in one compiled call (the query's glue runs with the caches cold)."""
    n = raw.shape[0]
    dist = np.empty(n)
    direction = np.empty((n, 3))
    nearest = np.empty((n, 3))
    count = np.empty(n, np.int64)
    for i in range(n):
        count[i] = np.int64(raw[i, 7])
        if not raw[i, 0] < rho + radii[i]:
            dist[i] = np.inf
            direction[i, :] = np.nan
            nearest[i, :] = np.nan
            continue
        dist[i] = max(raw[i, 0] - radii[i], 0.0)
        for j in range(3):  # V_R = R^T V_C; x_w = R^T (x_c - t)
            direction[i, j] = raw[i, 1] * R[0, j] + raw[i, 2] * R[1, j] + raw[i, 3] * R[2, j]
            nearest[i, j] = (raw[i, 4] - t[0]) * R[0, j] + (raw[i, 5] - t[1]) * R[1, j] + (raw[i, 6] - t[2]) * R[2, j]
    return dist, direction, nearest, count


def to_world(cam: Camera, raw: np.ndarray, radii: np.ndarray, rho: float) -> PointDistances:
    """Kernel output rows (camera frame, distances from the sphere centres; see
    :mod:`depthguard.kernels.hits`) -> world-frame :class:`PointDistances` of N spheres of ``radii``:
    distance ``max(d - r, 0)`` where ``d < rho + r``, else inf (direction and nearest point NaN)."""
    return PointDistances(
        *_rows_to_world(raw, np.ascontiguousarray(radii, dtype=float), float(rho), cam.R, np.asarray(cam.t, float))
    )
