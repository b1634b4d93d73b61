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

Where the code is (one concept per module): :mod:`~depthguard.depthgrid.frame_stage` (the per-frame
update: the principal camera's part and the secondary cameras' part, on two threads) with its kernels in
:mod:`~depthguard.depthgrid.frames`, :mod:`~depthguard.depthgrid.query` (the per-sphere, per-tile,
per-pixel walk with the cases above), :mod:`~depthguard.depthgrid.column` (case iii/iv column search,
nearest segment first, free space skipped in blocks), :mod:`~depthguard.depthgrid.chunks` (per-tile depth
chunks decided at once, whole tiles skipped in shadows), :mod:`~depthguard.depthgrid.votes` (the votes of
the secondary cameras on cells and blocks), :mod:`~depthguard.depthgrid.pyramid` (min pyramid of the vote
images), :mod:`~depthguard.depthgrid.footprint` (cell footprints, the stored map), and, shared with the
single-camera query, :mod:`depthguard.kernels` (region of surveillance, unseen space, aggregation). Block
and chunk skipping only skip cells that the per-cell rule clears, so the answers are those of the
cell-by-cell search (``tests/test_depthgrid_search.py``).

The vote (docs/conventions.md, conservative). Secondary camera k clears (calls free) a cell only when the cell
lies entirely in front of camera k and inside its image and *every* pixel of its footprint measures a
depth ``d_o^k > d_end^k``, the cell's *far* depth in camera k. The paper's test ``d_o^k < d_start^k``
(obstacle confirmed only in front of the cell's near depth) would clear a cell that contains the very
surface camera k sees (``d_start <= d_o^k <= d_end``); ``tests/test_depthgrid_fusion.py`` shows such a
case. A missing pixel of camera k never clears a cell, whether or not valid pixels lie near it (it is
never filled: a small dark object with no reading in front of a far background must not clear the cell
it occupies); a cell that is not involved for camera k
(partly outside its image or behind it) gets no vote from k. A cell is occupied when no involved camera
clears it, so with one camera the result is the single-camera result. Robot windows (``update(windows=)``,
optional): a pixel of camera k whose reading lies in front of the cell still passes when the cell's far
depth lies in the stretch of that pixel's ray filled by the robot's own (inflated) body
(``depthgrid.votes.pixel_sees_past``): a box in front of the arm does not make the arm's body an obstacle.

Robot pixels. In the principal camera: case iv. In a secondary camera a robot pixel never confirms an
obstacle (docs/conventions.md: the robot is not an obstacle to itself), so it counts as seeing past (default,
``robot_occludes=False``): space hidden by the robot from *every* other camera is treated as free, the
documented limit of the method (RA-L'16 §VI: occlusions cannot be removed in general). With
``robot_occludes=True`` a secondary robot pixel counts as an obstacle at the robot's depth: it never
clears what lies behind the robot, which is safe but keeps phantom obstacles right behind the robot links
(every control sphere then touches them), so it is not the default. With *several* secondary cameras, a
robot pixel of one does not see past a point that another one measures (``frames.limit_robot_votes``):
otherwise a third camera that sees the arm in front of a box would erase the box that the second camera
measures (the ``ral-hidden`` scene with ``--cameras 3`` collided, 1461 steps, before this rule).

Filled holes. A missing principal pixel within ``fill_radius`` of valid non-robot pixels is unknown from
the nearest of their depths (nothing lies before it, by the filling rule), not a measured surface: the
other cameras may clear its cells, which removes phantom surfaces in the air where the fill took a nearer
neighbour's depth (along the robot's silhouette, for instance).

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
obstacle within ρ costs 0.15-0.7 ms (2-5 ms before). See BENCHMARKS.md. With a second thread
(``query(side=...)``, which :class:`depthguard.sim.pipeline.DistanceStage` passes wherever there are two
CPUs) the ``ral-hexagon`` cell's query of its nine spheres takes 0.61-0.64 of its one-thread time (BENCHMARKS.md,
stop 45).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor

import numpy as np

from depthguard.camera import Camera
from depthguard.depthgrid.chunks import tile_bounds
from depthguard.depthgrid.frame_stage import update_principal, update_secondary
from depthguard.depthgrid.grid import DepthGrid
from depthguard.depthgrid.gridmap import GridMap
from depthguard.depthgrid.pyramid import pyramid_layout
from depthguard.depthgrid.query import query_many, query_many_parallel, query_part
from depthguard.depthgrid.records import ColumnCache, Grid, Principal, Votes, column_cache
from depthguard.depthspace import (
    INVALID_POLICIES,
    MODES,
    TILE,
    PointDistances,
    check_float_depth,
    check_query,
    to_world,
)
from depthguard.kernels.hits import merge_hits
from depthguard.kernels.records import direction_stride as resolve_stride
from depthguard.kernels.records import intrinsics, query_params
from depthguard.sidethread import run_parts

__all__ = ["DepthGridFusion"]

QUERY_PARTS = 4  # parts of the image (rows of tiles) of a query shared with a side thread (query(side=))


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

    Column cache: cell states decided by a frame set's queries are kept per principal pixel and reused by
    its later queries, answers unchanged (:class:`~depthguard.depthgrid.records.ColumnCache`, about 32 MB
    at 640x480, allocated at the first query); ``fusion.column_cache = False`` turns it off.

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
        c0 = cameras[0]
        if not 0.5 * float(np.hypot(1.0 / c0.fx, 1.0 / c0.fy)) < 1.0:  # (the column and chunk bounds need h < 1)
            raise ValueError(
                "cameras[0]: the depth grid needs pixels narrower than its distance bound allows,"
                f" 0.5 sqrt(1/fx^2 + 1/fy^2) < 1 (fx, fy above about 0.71 px), got fx={c0.fx}, fy={c0.fy}"
            )
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
        # three row blocks per secondary camera: the votes, then the robot windows' lo and hi (see
        # depthgrid.votes.pixel_sees_past and update(windows=...)); no window: lo = +inf, hi = -inf
        self._hm = hm
        self._votes = np.zeros((n, 3 * hm, wm), dtype=np.float32)
        self._votes[:, hm : 2 * hm] = np.inf
        self._votes[:, 2 * hm :] = -np.inf
        self._has_windows = False
        self._pyr_meta, npyr = pyramid_layout(hm, wm)
        self._pyr = np.zeros((n, npyr), dtype=np.float32)  # block minima of the votes (see depthgrid.pyramid)
        cam0 = cameras[0]
        self._start = np.full(cam0.shape, np.inf, dtype=np.float32)
        self._kind = np.zeros(cam0.shape, dtype=np.uint8)
        self._fill_scratch = np.empty((3, *cam0.shape), np.float32)  # (hole filling, depthgrid.frames)
        self._hole_at = np.empty(cam0.shape[0] * cam0.shape[1], np.int32)
        self._tmin, self._tmax = tile_bounds(self._start, self._kind, TILE)
        self._chunks = True  # per-tile chunk tests (False: the plain block-by-block search, for tests)
        # the cell states decided so far in this frame (depthgrid.column), shared by every query of it;
        # allocated at the first query, a new generation per frame
        self._cache: ColumnCache | None = None
        self._cache_off = column_cache(1, 1, int(self.grid.n_cells), on=False)
        self._gen = 1
        self.column_cache = True  # False: every query votes afresh (identical answers; tests, A/B)
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
        windows: list[tuple[np.ndarray, np.ndarray] | None] | Callable[[], list] | None = None,
        *,
        side: Executor | None = None,
        principal: Callable[[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]] | None = None,
    ) -> None:
        """Take one depth image per camera (per frame, camera rate).

        Args:
            depths: one (H, W) depth image per camera, ``z_C`` in metres; 0, NaN and inf mean no reading.
            masks: ``None`` or one entry per camera: ``None`` or an (H, W) bool robot mask (True = robot
                pixel; the depth image holds the robot's depth there, so ``d_r`` is known).
            invalid: missing-depth policy, ``"conservative"`` (default) or ``"ignore"`` (docs/conventions.md).
            windows: robot windows (:func:`depthguard.depthgrid.frames.write_windows`): along pixel (u, v)
                of camera k the robot's own body (its capsules inflated by the self-filter's margin) fills
                ``[lo, hi]`` (:func:`depthguard.robot.interior.robot_windows`). Camera k then also clears a
                cell at a pixel whose reading lies in front of the cell when
                the cell's far depth ``d_end`` lies in ``[lo, hi]``: the robot's body holds no obstacle
                (the self-filter's margin limit), even where a box hides it from camera k. The cleared
                part of the cell lies within one cell diameter (Δd and a principal pixel footprint) of
                that body. Or a callable that returns them (called where the secondary part runs).
            side: an executor (one worker thread): the secondary cameras' part (windows, votes, vote
                pyramid) runs there while the principal camera's part (segments and their tile bounds)
                runs on this thread. The two write disjoint arrays; the kernels release the GIL. The answers
                are the same as without it.
            principal: a callable ``(depth, mask) -> (depth, mask)`` applied to the principal camera's
                frame before its part (on this thread; :func:`depthguard.robot.interior.principal_robot_pixels`).
        """
        if invalid not in INVALID_POLICIES:
            raise ValueError(f"invalid must be one of {INVALID_POLICIES}, got {invalid!r}")
        if len(depths) != len(self.cameras):
            raise ValueError(f"depths: got {len(depths)} images for {len(self.cameras)} cameras")
        if masks is None:
            masks = [None] * len(self.cameras)
        if len(masks) != len(self.cameras):
            raise ValueError(f"masks: got {len(masks)} entries for {len(self.cameras)} cameras")
        if windows is not None and not callable(windows) and len(windows) != len(self.cameras):
            raise ValueError(f"windows: got {len(windows)} entries for {len(self.cameras)} cameras")
        for k, d in enumerate(depths):
            check_float_depth(np.asarray(d), f"depths[{k}]")
        conservative = invalid == "conservative"
        self._ready = False  # (until both parts are done: a failed update leaves no answer)

        def principal_part() -> None:
            d0, m0 = principal(depths[0], masks[0]) if principal is not None else (depths[0], masks[0])
            update_principal(self, d0, m0, conservative)

        if side is None:
            principal_part()
            update_secondary(self, depths, masks, conservative, windows)
        else:
            job = side.submit(update_secondary, self, depths, masks, conservative, windows)
            try:
                principal_part()
            finally:
                job.result()  # (raises the secondary part's error, if any)
        self._invalid = invalid
        self._gen += 1  # every cached cell state belongs to the frames before
        self._ready = True

    # ------------------------------------------------------------------ distance stage
    def query(
        self,
        centres: np.ndarray,
        radii: np.ndarray | float = 0.0,
        rho: float = 0.4,
        mode: str = "all",
        alpha: float = 6.0,
        direction_stride: int | str = "auto",
        *,
        side: Executor | None = None,
    ) -> PointDistances:
        """Fused distances from N control spheres to the obstacles (RA-L'16 §VI, eq. 11).

        Args:
            centres: (N, 3) sphere centres, world frame, metres.
            radii: (N,) sphere radii, metres (or one number).
            rho: radius of surveillance ρ, metres, measured from the sphere surface.
            mode: ``"min"``, ``"all"`` (ICRA'12 eq. 9) or ``"hybrid"`` (RA-L'16 eq. 11).
            alpha: shape factor of the eq. 9 weights.
            direction_stride: the principal pixels of the direction sum (modes ``"all"``, ``"hybrid"``),
                as :func:`depthguard.depthspace.query_distances`; the distance is the same whatever it is.
            side: an executor (one worker thread, as for :meth:`update`): the principal image's tile rows
                are dealt into ``QUERY_PARTS`` parts (:func:`~depthguard.depthgrid.query.sphere_hits`), which
                this thread and the worker take one by one (:func:`depthguard.sidethread.run_parts`), on one
                column cache. The distances and counts are those of the query on one thread; the direction
                sums are added in another order (last-bit differences), and of two pieces at exactly the
                same distance either may be the nearest. Ignored with ``parallel``.
        Returns:
            :class:`depthguard.depthspace.PointDistances` (world frame); ``distance`` is a lower bound
            of the true clearance within :meth:`tolerance`.
        Raises:
            ValueError: naming the argument, for a bad mode, stride, rho, alpha (a finite number), centres or
                radii (:func:`depthguard.depthspace.check_query`).
        """
        if not self._ready:
            raise RuntimeError("DepthGridFusion.query: call update() with a set of frames first")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        c, r, rho, alpha = check_query(centres, radii, rho, alpha)
        cam = self.cameras[0]
        g = self.grid
        stride = resolve_stride(direction_stride, cam.width)
        args = (
            np.ascontiguousarray(cam.R),
            np.ascontiguousarray(cam.t),
            np.ascontiguousarray(c),
            np.ascontiguousarray(r),
            query_params(rho, MODES.index(mode), alpha, self._invalid == "conservative", TILE),
            intrinsics(cam),
            Principal(self._start, self._kind, self._tmin, self._tmax),
            Grid(float(g.d_min), float(g.dd), int(g.n_cells)),
            self.map.kernel_args(),
            Votes(self._votes, self._pyr, self._pyr_meta, self._has_windows),
            self._chunks,
            self._frame_cache(),
            stride,
        )
        if side is not None and not self.parallel and len(c) > 0:
            parts = run_parts(lambda k: query_part(*args, k, QUERY_PARTS), QUERY_PARTS, side)
            raw = merge_hits(np.stack(parts), MODES.index(mode), stride)
        else:
            raw = (query_many_parallel if self.parallel else query_many)(*args)
        self.last_cells = raw[:, 8].astype(np.int64)
        self.last_votes = raw[:, 9].astype(np.int64)
        return to_world(cam, raw, r, rho)

    def _frame_cache(self) -> ColumnCache:
        """The column cache of the current frame set (a disabled one for the threaded query)."""
        if self.parallel or not self.column_cache:
            return self._cache_off
        if self._cache is None:
            self._cache = column_cache(*self.cameras[0].shape, int(self.grid.n_cells), tile=TILE)
        return self._cache._replace(gen=self._gen)

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
