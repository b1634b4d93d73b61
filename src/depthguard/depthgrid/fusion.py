"""On-line fusion of several depth cameras through the depth grid (RA-L'16 §VI-VII).

The principal camera (the first one) defines the depth grid; every query walks the principal camera's
region of surveillance, pixel by pixel, with the cases of RA-L'16 §VI:

i.   the pixel's obstacle (and its gray area) lies beyond ``d_p + ρ``: nothing to do;
ii.  the principal camera sees the obstacle at ``d_o >= d_p``: the distance to the pixel frustum from
     ``d_o`` on, no other camera needed;
iii. ``d_o < d_p`` (or the pixel is unknown): the cells of the pixel from ``d_o`` on are searched nearest
     to P first (alternating outward from the cell nearest P) and the first cell that the other cameras
     do not clear is the obstacle;
iv.  (§VII) a robot pixel at ``d_r``: nothing lies before ``d_r``; the cells from ``r(d_r)`` on are checked
     with the other cameras as in case iii (the paper starts at ``r(d_r) + 1``; we also check the rest of
     the cell holding the robot surface, which costs one cell and misses nothing). Here an obstacle needs
     a witness: a cell is occupied only if at least one other camera is involved and none clears it, so
     with one camera the space behind the robot stays unseen, exactly as in the single-camera module
     (otherwise every control sphere would touch the phantom space right behind its own link). A robot
     pixel without a reading is searched from the near limit.

The search along a column visits cells by their depth gap to the point of the ray nearest P and stops at
the first occupied cell or where the frustum bound reaches the current limit (ρ, or in ``"min"`` mode
the best distance so far; tiles of 16x16 pixels are pruned by their own bound, nearest tile first in
``"min"`` mode). Free space is skipped in blocks: first an 8-cell block shared by the whole tile (one
footprint test for 256 columns), then an 8-cell and a 2-cell block of the column, then single cells. A
cleared block contains each of its cells' footprints and far depths, so the answers are exactly those
of the cell-by-cell search.

Shadows (a person between the principal camera and the robot makes almost every pixel near the robot a
case-iii pixel). Before its columns, each tile tries its whole *depth chunk* at once: the cells that any
of its column searches can reach (ray points within the search bound T of P, so within a window of the
tile-centre ray, and no nearer than the tile's smallest start depth), as one frustum piece per secondary
camera; if that fails, its two halves. When every cell of the chunk is cleared, a column can only find
its first segment (the cell of a measured surface, occupied without a vote, or the unseen space before
``d_min``), and a robot column nothing, so robot columns are skipped; and when moreover the tile has no
case-ii pixel (no surface beyond P) and a lower bound of the distance to its first segments exceeds T,
the whole tile is skipped without visiting its pixels (only for such tiles are the chunk's blocks
decided eagerly, one by one after a failed half; elsewhere they stay lazy, which is cheaper where
obstacles are near). Runs of cleared tile blocks are crossed in one step. The footprint tests of blocks
and chunks read the votes through a per-frame min pyramid (``_kernels.rect_sees_past``), which answers
exactly as the pixel loop. All of this only skips cells that the per-cell rule clears, so the answers are
unchanged (``tests/test_depthgrid_search.py`` compares the column search with a cell-by-cell search, and
the query with and without the chunk tests, with a blocker in front of the principal camera and robot
masks).

The vote (docs/conventions.md, conservative). Secondary camera k clears (calls free) a cell only when the cell
lies entirely in front of camera k and inside its image and *every* pixel of its footprint measures a
depth ``d_o^k > d_end^k``, the cell's *far* depth in camera k. The paper's test ``d_o^k < d_start^k``
(obstacle confirmed only in front of the cell's near depth) would clear a cell that contains the very
surface camera k sees (``d_start <= d_o^k <= d_end``); ``tests/test_depthgrid_fusion.py`` shows such a
case. A missing pixel of camera k never clears a cell, whether or not valid pixels lie near it (it is
never filled: a small dark object with no reading in front of a far background must not clear the cell
it occupies); a cell that is not involved for camera k
(partly outside its image or behind it) gets no vote from k. A cell is occupied when no involved camera
clears it, so with one camera the result is the single-camera result.

Robot pixels. In the principal camera: case iv. In a secondary camera a robot pixel never confirms an
obstacle (docs/conventions.md: the robot is not an obstacle to itself), so it counts as seeing past (default,
``robot_occludes=False``): space hidden by the robot from *every* other camera is treated as free, the
documented limit of the method (RA-L'16 §VI: occlusions cannot be removed in general). With
``robot_occludes=True`` a secondary robot pixel counts as an obstacle at the robot's depth: it never
clears what lies behind the robot, which is safe but keeps phantom obstacles right behind the robot links
(every control sphere then touches them), so it is not the default.

Cells the principal camera measured. The cell that contains the principal camera's measured surface
``d_o`` is occupied without a vote (the paper asks the other cameras for it too): a measured surface is
real, and a secondary camera whose frame lags or whose calibration is off by a pixel must not erase it.
Space before ``d_min`` and beyond ``d_max`` is outside the grid; no other camera can clear it, so the
principal camera's gray area there stays an obstacle, as for one camera.

Point-to-cell distance (RA-L'16 eqs. 5-7), safe form. For the pixel-centre ray ``r = (a, b, 1)`` and the
occupied depth interval ``[z0, z1]``: ``s* = clamp(P.r / r.r, z0, z1)``, ``d_ray = |P - s* r|``,
``D = max(0, d_ray - h min(z1, d_p + d_ray))`` with ``h = ½ sqrt(fx⁻² + fy⁻²)``: every frustum point at
depth z lies within ``h z`` of the ray point at depth z, so D never exceeds the distance to anything in
the cell. (The literal eqs. 5-7 evaluate the pixel edge at the depth of P and over-estimate off-axis.)

Declared tolerance (:meth:`DepthGridFusion.tolerance`): the fused distance is a lower bound of the true
distance up to ``Δd`` plus the sampling of one ray per pixel (one pixel footprint of the principal and of
the coarsest secondary camera at the point's depth), plus the cameras' own depth noise; it never falls
more than one cell length plus the frustum slack below the distance to the space that no camera has
seen. Space outside the principal camera's field of view or nearer than its near limit counts as an
obstacle (docs/conventions.md), as for one camera: the principal camera must see the whole space of interest
(RA-L'16 §I, assumption 1).

Speed (2 Kinect-like cameras, 640x480, 345 depth cells, 9 spheres, ρ = 0.4, one thread of a shared 2-core
machine): about 1.3 kHz in ``"all"`` mode and 7.5 kHz in ``"min"`` mode; ``update`` about 2.5 ms per frame
pair (with the min pyramid). See ``depthguard.bench.grid``. In the ``ral-shadow`` scenario (a person
between the principal camera and the robot), the slowest recorded query takes about 18 ms in
``"hybrid"`` mode and 7.5 ms in ``"min"`` mode (52 and 35 ms before the chunk tests); a point with no
obstacle within ρ costs 0.15-0.7 ms (2-5 ms before). See BENCHMARKS.md.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from depthguard.camera import Camera
from depthguard.depthgrid import _kernels as K
from depthguard.depthgrid.grid import DepthGrid
from depthguard.depthgrid.gridmap import GridMap
from depthguard.depthspace import (
    INVALID_POLICIES,
    MODES,
    TILE,
    PointDistances,
    prepare_frame,
    query_distances,
    tile_min,
)
from depthguard.validation import check_points

__all__ = ["DepthGridFusion", "fused_distances"]


@nb.njit(cache=True, inline="always")
def _filled(depth, missing, robot, has_mask, v, u, r):
    """Hole filling (``docs/conventions.md``), as :func:`depthguard.depthspace.prepare_frame`: the minimum valid,
    non-robot depth in the (2r+1)^2 window around (v, u); inf when there is none."""
    H, W = depth.shape
    best = np.inf
    for vv in range(max(0, v - r), min(H, v + r + 1)):
        for uu in range(max(0, u - r), min(W, u + r + 1)):
            if not missing[vv, uu] and not (has_mask and robot[vv, uu]) and depth[vv, uu] < best:
                best = depth[vv, uu]
    return best


@nb.njit(cache=True)
def _prepare_principal(depth, robot, has_mask, fill_radius, near_limit, conservative, start, kind):
    """One pass over the principal image: start depth and kind of every pixel (see ``_kernels``)."""
    H, W = depth.shape
    missing = np.empty((H, W), dtype=np.bool_)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            missing[v, u] = not (d > 0.0 and d < np.inf)
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
                best = _filled(depth, missing, robot, has_mask, v, u, fill_radius)
                if best < np.inf:
                    start[v, u] = best
                    kind[v, u] = K.KIND_SURFACE
                else:
                    start[v, u] = near_limit
                    kind[v, u] = K.KIND_UNKNOWN


@nb.njit(cache=True)
def _prepare_secondary(depth, robot, has_mask, conservative, robot_occludes, margin, out):
    """One pass over a secondary image: the depth each pixel sees up to (its vote, see ``_kernels``).

    A missing pixel is never filled here: it votes 0 (it clears nothing), so that a small dark object with
    no reading in front of a far background cannot clear the cell it occupies. Hole filling is for the
    principal camera only (where a filled pixel is an obstacle, never free space).
    """
    H, W = depth.shape
    missing = np.empty((H, W), dtype=np.bool_)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            missing[v, u] = not (d > 0.0 and d < np.inf)
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


class DepthGridFusion:
    """Distances from control spheres to obstacles seen by several depth cameras (RA-L'16).

    Args:
        cameras: the cameras; the first one is the principal camera and must see the whole space of
            interest (RA-L'16 §I, assumption 1). Any number >= 1.
        dd: depth quantisation Δd of the grid, metres (eq. 4).
        workspace: ``(xmin, xmax, ymin, ymax, zmin, zmax)`` world box (metres) that sets ``d_min`` and the
            number of depth cells (§VIII); ``None``: the principal camera's ``[min_depth, max_depth]``.
        map_mode: ``"onthefly"`` (default) or ``"stored"`` (:class:`GridMap`; identical answers).
        cache_dir: disk cache of a stored map (``None``: ``~/.cache/depthguard/depthgrid``; ``False``: off).
        fill_radius: hole-filling radius in pixels of the principal camera, whose image is prepared
            exactly as :func:`depthguard.depthspace.prepare_frame` does (``docs/conventions.md``); 0: every
            hole is unknown. Missing pixels of the secondary cameras are never filled (they clear nothing).
        robot_occludes: see the module docstring (default ``False``, as docs/conventions.md).
        vote_margin: a secondary camera clears a cell only if it measures at least this much (metres)
            beyond the cell's far depth; 0 (default) as in the paper, about twice the depth noise of the
            secondary cameras for extra safety against noisy readings behind a surface.
        parallel: spread the control points over numba's threads (``prange``). Off by default: a query
            takes tens to hundreds of microseconds, and on a loaded machine waking a second thread can
            cost milliseconds (measured on the 2-core benchmark machine).

    Usage: :meth:`update` once per set of frames, then :meth:`query` as often as needed, from one thread
    (``update`` rewrites the per-frame images in place; the object is not thread-safe).
    """

    def __init__(
        self,
        cameras: list[Camera],
        dd: float = 0.01,
        workspace: tuple[float, float, float, float, float, float] | None = None,
        map_mode: str = "onthefly",
        cache_dir=None,
        fill_radius: int = 4,
        robot_occludes: bool = False,
        parallel: bool = False,
        vote_margin: float = 0.0,
    ) -> None:
        cameras = list(cameras)
        if not cameras:
            raise ValueError("cameras: at least one camera is needed (the first one is the principal camera)")
        for i, c in enumerate(cameras):
            if not isinstance(c, Camera):
                raise ValueError(f"cameras[{i}] must be a depthguard.camera.Camera, got {type(c).__name__}")
        self.cameras = cameras
        self.grid = DepthGrid.from_workspace(cameras[0], dd, workspace)
        self.map = GridMap(self.grid, cameras[1:], map_mode, cache_dir)
        if isinstance(fill_radius, bool) or not isinstance(fill_radius, int | np.integer) or fill_radius < 0:
            raise ValueError(f"fill_radius must be an integer >= 0, got {fill_radius!r}")
        self.fill_radius = int(fill_radius)
        self.robot_occludes = bool(robot_occludes)
        self.parallel = bool(parallel)
        if not (np.isfinite(vote_margin) and vote_margin >= 0):
            raise ValueError(f"vote_margin must be a number of metres >= 0, got {vote_margin!r}")
        self.vote_margin = float(vote_margin)
        n = max(1, len(cameras) - 1)
        hm = max([c.height for c in cameras[1:]], default=1)
        wm = max([c.width for c in cameras[1:]], default=1)
        self._votes = np.zeros((n, hm, wm), dtype=np.float32)
        self._pyr_meta, npyr = K.pyramid_layout(hm, wm)
        self._pyr = np.zeros((n, npyr), dtype=np.float32)  # block minima of the votes (see _kernels)
        cam0 = cameras[0]
        self._start = np.full(cam0.shape, np.inf, dtype=np.float32)
        self._kind = np.zeros(cam0.shape, dtype=np.uint8)
        self._tmin = tile_min(self._start, TILE)
        self._tmax = K.tile_max_start(self._start, self._kind, TILE)
        self._chunks = True  # per-tile chunk tests (False: the plain block-by-block search, for tests)
        self._invalid = "conservative"
        self._ready = False
        self.last_cells = np.zeros(0, dtype=np.int64)  # per point: column searches (cases iii/iv)
        self.last_votes = np.zeros(0, dtype=np.int64)  # per point: cell and block votes taken

    # ------------------------------------------------------------------ frame stage
    def update(
        self,
        depths: list[np.ndarray],
        masks: list[np.ndarray | None] | None = None,
        invalid: str = "conservative",
    ) -> None:
        """Take one depth image per camera (per frame, camera rate).

        Args:
            depths: one (H, W) depth image per camera, ``z_C`` in metres; 0, NaN and inf mean no reading.
            masks: ``None`` or one entry per camera: ``None`` or an (H, W) bool robot mask (True = robot
                pixel; the depth image holds the robot's depth there, so ``d_r`` is known).
            invalid: missing-depth policy, ``"conservative"`` (default) or ``"ignore"`` (docs/conventions.md).
        """
        if invalid not in INVALID_POLICIES:
            raise ValueError(f"invalid must be one of {INVALID_POLICIES}, got {invalid!r}")
        if len(depths) != len(self.cameras):
            raise ValueError(f"depths: got {len(depths)} images for {len(self.cameras)} cameras")
        if masks is None:
            masks = [None] * len(self.cameras)
        if len(masks) != len(self.cameras):
            raise ValueError(f"masks: got {len(masks)} entries for {len(self.cameras)} cameras")
        conservative = invalid == "conservative"
        for k, (cam, depth, mask) in enumerate(zip(self.cameras, depths, masks, strict=True)):
            d = np.ascontiguousarray(cam.check_image(depth, "depth"), dtype=np.float32)
            has_mask = mask is not None
            robot = (
                np.ascontiguousarray(cam.check_image(mask, "mask"), dtype=np.bool_)
                if has_mask
                else np.zeros((1, 1), dtype=np.bool_)
            )
            if k == 0:
                _prepare_principal(
                    d,
                    robot,
                    has_mask,
                    self.fill_radius,
                    np.float32(cam.min_depth),
                    conservative,
                    self._start,
                    self._kind,
                )
            else:
                _prepare_secondary(
                    d,
                    robot,
                    has_mask,
                    conservative,
                    self.robot_occludes,
                    np.float32(self.vote_margin),
                    self._votes[k - 1, : cam.height, : cam.width],
                )
        self._tmin = tile_min(self._start, TILE)
        self._tmax = K.tile_max_start(self._start, self._kind, TILE)
        K.build_pyramid(self._votes, self._pyr_meta, self._pyr)
        self._invalid = invalid
        self._ready = True

    # ------------------------------------------------------------------ distance stage
    def query(
        self,
        centres: np.ndarray,
        radii: np.ndarray | float = 0.0,
        rho: float = 0.4,
        mode: str = "all",
        alpha: float = 6.0,
    ) -> PointDistances:
        """Fused distances from N control spheres to the obstacles (RA-L'16 §VI, eq. 11).

        Args:
            centres: (N, 3) sphere centres, world frame, metres.
            radii: (N,) sphere radii, metres (or one number).
            rho: radius of surveillance ρ, metres, measured from the sphere surface.
            mode: ``"min"``, ``"all"`` (ICRA'12 eq. 9) or ``"hybrid"`` (RA-L'16 eq. 11).
            alpha: shape factor of the eq. 9 weights.
        Returns:
            :class:`depthguard.depthspace.PointDistances` (world frame); ``distance`` is a lower bound
            of the true clearance within :meth:`tolerance`.
        """
        if not self._ready:
            raise RuntimeError("DepthGridFusion.query: call update() with a set of frames first")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if not (np.isfinite(rho) and rho > 0):
            raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
        c = np.atleast_2d(np.asarray(centres, dtype=float))
        r = np.broadcast_to(np.asarray(radii, dtype=float), (c.shape[0],))
        c, r = check_points(c, r)
        cam = self.cameras[0]
        g = self.grid
        kernel = K.query_many if self.parallel else K.query_many_serial
        raw = kernel(
            np.ascontiguousarray(cam.R),
            np.ascontiguousarray(cam.t),
            np.ascontiguousarray(c),
            np.ascontiguousarray(r),
            float(rho),
            MODES.index(mode),
            float(alpha),
            self._start,
            self._kind,
            self._tmin,
            self._tmax,
            TILE,
            self._chunks,
            cam.fx,
            cam.fy,
            cam.cx,
            cam.cy,
            float(cam.min_depth),
            self._invalid == "conservative",
            g.d_min,
            g.dd,
            g.n_cells,
            *self.map.kernel_args(),
            self._votes,
            self._pyr,
            self._pyr_meta,
        )
        self.last_cells = raw[:, 8].astype(np.int64)
        self.last_votes = raw[:, 9].astype(np.int64)
        found = raw[:, 0] < rho + r
        dist = np.where(found, np.maximum(raw[:, 0] - r, 0.0), np.inf)
        direction = np.where(found[:, None], cam.vector_to_world(raw[:, 1:4]), np.nan)
        nearest = np.where(found[:, None], cam.camera_to_world(np.nan_to_num(raw[:, 4:7])), np.nan)
        return PointDistances(dist, direction, nearest, raw[:, 7].astype(np.int64))

    def tolerance(self, centres: np.ndarray, rho: float = 0.4) -> np.ndarray:
        """Declared tolerance (metres) of the fused distance at each of N centres: Δd + pixel footprints.

        The fused distance never exceeds the true clearance by more than this: one depth cell ``Δd``
        plus one pixel footprint of the principal camera at depth ``d_p + ρ`` and one of the secondary
        camera with the coarsest pixels there (each camera samples one ray per pixel, so a surface can
        hide up to a pixel away from the sampled rays). On the other side the fused distance is a lower
        bound of the distance to the space that no camera has seen, within one cell and the pixel
        frustum slack ``2 h (d_p + ρ)`` (:func:`depthguard.depthspace.lower_bound_slack`).
        """
        c = np.atleast_2d(np.asarray(centres, dtype=float))
        cam0 = self.cameras[0]
        z0 = np.maximum(cam0.world_to_camera(c)[:, 2], 0.0) + rho
        tol = self.grid.dd + z0 / min(cam0.fx, cam0.fy)
        sec = np.zeros(len(c))
        for cam in self.cameras[1:]:
            zk = np.maximum(cam.world_to_camera(c)[:, 2], 0.0) + rho
            sec = np.maximum(sec, zk / min(cam.fx, cam.fy))
        return tol + sec

    @property
    def map_nbytes(self) -> int:
        """Memory of the off-line map, bytes."""
        return self.map.nbytes


def fused_distances(
    cameras: list[Camera],
    depths: list[np.ndarray],
    masks: list[np.ndarray | None] | None,
    centres: np.ndarray,
    radii: np.ndarray | float,
    rho: float = 0.4,
    mode: str = "all",
    invalid: str = "conservative",
    dd: float = 0.01,
    workspace: tuple[float, float, float, float, float, float] | None = None,
    map_mode: str = "onthefly",
) -> PointDistances:
    """One-shot fused distances for the command line (``depthguard distance`` with several cameras).

    With one camera this is :func:`depthguard.depthspace.query_distances`; with two or more it builds a
    :class:`DepthGridFusion` (the first camera is the principal one), updates it once and queries it.
    """
    cameras = list(cameras)
    if len(cameras) == 1:
        frame = prepare_frame(cameras[0], depths[0], None if masks is None else masks[0], invalid=invalid)
        return query_distances(frame, centres, radii, rho=rho, mode=mode)
    fusion = DepthGridFusion(cameras, dd=dd, workspace=workspace, map_mode=map_mode)
    fusion.update(depths, masks, invalid=invalid)
    return fusion.query(centres, radii, rho=rho, mode=mode)
