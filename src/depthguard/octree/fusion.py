"""Obstacle octree from several sensors (SAPHARI D4.1.1 §3.2): per-sensor sets and their fusion.

    O(t) = ∪_i ( C(t) ∩ ( P_i ∪ (O_i \\ ∪_{j≠i} F_j) ) )

A measured obstacle point always stays; space occupied or occluded by an obstacle for sensor ``i`` stays
unless another sensor sees it free. Two modes:

* ``"saphari"``: exactly the formula; space that no sensor observes is free (the deliverable's choice, its
  sensors do not cover all around the platform). A 2-D scanner's free sectors count as free nodes (its
  "no overhanging objects" assumption).
* ``"conservative"`` (default of ``depthguard distance --backend octree``): also every node of C(t) that no
  sensor sees free and that is neither occupied/occluded by an obstacle nor hidden by the robot is an
  obstacle ("unseen"), like the depth space's unknown space. A node counts as seen free only if a sensor
  sees its whole volume free, which a 2-D scanner never does, so scanners only add obstacles here.

In both modes space hidden *only by the robot* (R_i and no O_i) is free, as SAPHARI §3.2 says and as the
depth grid does (a documented limit). Missing readings never free a node (cameras: the project's
missing-depth policy of :func:`depthguard.depthspace.prepare_frame`; scanners: REP 117, see
:mod:`depthguard.octree.scanner`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numba as nb
import numpy as np

from depthguard.camera import Camera
from depthguard.depthspace import check_depth_policy
from depthguard.octree.grid import VoxelBox
from depthguard.octree.pyramids import camera_pyramids
from depthguard.octree.scanner import LaserScanner, scan_obstacle_ranges, scan_points
from depthguard.octree.sets import _levels as _mask_levels
from depthguard.octree.sets import (
    bin_depth_points,
    bin_points,
    camera_sets_from_pyramids,
    combine_cleared,
    mark_overlaps,
    mask_pyramid,
    scanner_sets,
)

__all__ = ["MODES", "CameraObservation", "ScanObservation", "OctreeFrame", "sensor_sets", "fuse", "reach_mask"]

MODES = ("conservative", "saphari")
FREE, OCCUPIED, OCCLUDED, UNSEEN = 0, 1, 2, 3  # node kinds of OctreeFrame.kind


@dataclass(frozen=True)
class CameraObservation:
    """One depth image: ``depth`` (H, W) metres (0/NaN/inf = no reading); ``mask`` (H, W) bool robot pixels
    (e.g. from :func:`depthguard.robot.selffilter.self_filter`) or None."""

    camera: Camera
    depth: np.ndarray
    mask: np.ndarray | None = None


@dataclass(frozen=True)
class ScanObservation:
    """One 2-D scan: ``ranges`` (n_rays,) metres (REP 117); ``robot`` (n_rays,) bool rays that hit the robot
    (e.g. from :func:`depthguard.octree.scanner.scan_robot_rays`) or None."""

    scanner: LaserScanner
    ranges: np.ndarray
    robot: np.ndarray | None = None


class OctreeFrame(NamedTuple):
    """The fused obstacle nodes of one frame of all sensors.

    Attributes:
        box: the node lattice.
        occupied: (nx, ny, nz) bool, the obstacle set O(t) (plus unseen nodes in conservative mode).
        kind: (nx, ny, nz) uint8: 0 free or outside C(t), 1 occupied (holds a measured point),
            2 occluded, 3 unseen (conservative mode only).
        mask: (nx, ny, nz) bool, the candidate nodes (C(t), or the whole box without a robot state).
        flags: (S, nx, ny, nz) uint8 per-sensor flags (bits V=1, P=2, O=4, R=8, F=16), 0 outside ``mask``.
        mode: the fusion mode.
    """

    box: VoxelBox
    occupied: np.ndarray
    kind: np.ndarray
    mask: np.ndarray
    flags: np.ndarray
    mode: str

    def counts(self) -> dict[str, int]:
        """Numbers of occupied, occluded and unseen nodes."""
        return {k: int(np.count_nonzero(self.kind == v)) for k, v in (("occupied", 1), ("occluded", 2), ("unseen", 3))}


def reach_mask(box: VoxelBox, reach) -> np.ndarray:
    """(nx, ny, nz) bool: the nodes of ``box`` that overlap a reachable cell of ``reach`` (a
    :class:`~depthguard.octree.reach.ReachabilityGrid`, on any lattice)."""
    out = np.zeros(box.shape, dtype=bool)
    mark_overlaps(
        reach.reachable, np.ascontiguousarray(reach.box.origin), float(reach.box.res),
        np.ascontiguousarray(box.origin), float(box.res), np.array(box.shape, np.int64), out,
    )  # fmt: skip
    return out


def sensor_sets(
    box: VoxelBox,
    mask: np.ndarray,
    obs: CameraObservation | ScanObservation,
    invalid: str = "conservative",
    fill_radius: int = 4,
    mp=None,
) -> np.ndarray:
    """(nx, ny, nz) uint8 flags V, P, O, R, F of one sensor's frame for the nodes of ``mask`` (bool over
    ``box``); ``mp`` is the mask's :func:`~depthguard.octree.sets.mask_pyramid` (computed when None)."""
    if isinstance(obs, CameraObservation):
        cam = obs.camera
        d, robot = check_depth_policy(cam, obs.depth, obs.mask, invalid, fill_radius)
        d = np.ascontiguousarray(d)
        robot = np.zeros(cam.shape, bool) if robot is None else np.ascontiguousarray(robot, dtype=bool)
        # fill_missing_depth and robot_blocking_depth straight into the pyramids that camera_sets builds
        lo, neg, rob, *layout = camera_pyramids(
            d, robot, int(fill_radius), np.float32(cam.min_depth), invalid == "conservative"
        )
        flags = camera_sets_from_pyramids(mask, box, cam, (lo, *layout), neg, rob, mp)
        bin_depth_points(cam, d, robot, box, mask, flags)
        return flags
    if isinstance(obs, ScanObservation):
        sc = obs.scanner
        blocked = scan_obstacle_ranges(sc, obs.ranges)
        rob = np.zeros(sc.n_rays, bool) if obs.robot is None else np.asarray(obs.robot, dtype=bool)
        if rob.shape != (sc.n_rays,):
            raise ValueError(f"scan robot mask has shape {rob.shape}, expected ({sc.n_rays},)")
        robot_range = np.where(rob, blocked, np.inf)
        obstacle_range = np.where(rob, np.inf, blocked)
        if invalid == "ignore":  # only on explicit request: missing readings are free
            r = np.asarray(obs.ranges, dtype=float)
            obstacle_range[np.isnan(r) | (r == 0)] = np.inf
        flags = scanner_sets(mask, box, sc, obstacle_range, robot_range)
        pts, idx = scan_points(sc, obs.ranges)
        bin_points(pts[~rob[idx]], box, mask, flags)
        return flags
    raise ValueError(f"observation must be a CameraObservation or a ScanObservation, got {type(obs).__name__}")


@nb.njit(cache=True, nogil=True)
def robot_blocking_depth(robot, missing, depth, near):
    """(H, W) float32 depth at which each pixel is blocked by the robot: its reading on a robot pixel (the
    near limit where the reading is missing), inf on every other pixel."""
    H, W = robot.shape
    out = np.empty((H, W), np.float32)
    for v in range(H):
        for u in range(W):
            out[v, u] = (near if missing[v, u] else depth[v, u]) if robot[v, u] else np.inf
    return out


@lru_cache(maxsize=4)
def _pool(workers: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="octree-sensor")


@lru_cache(maxsize=8)
def _whole_box(shape: tuple[int, int, int]):
    """The all-True mask of a box shape and its pyramid (read-only, shared)."""
    mask = np.ones(shape, dtype=bool)
    mask.setflags(write=False)
    return mask, mask_pyramid(mask, _mask_levels(shape))


def _reach_array(reach, shape) -> np.ndarray:
    mask = np.ascontiguousarray(reach, dtype=bool)
    if mask.shape != shape:
        raise ValueError(f"reach mask has shape {mask.shape}, expected the box's {shape}")
    return mask


def fuse(
    box: VoxelBox,
    observations: list,
    reach: np.ndarray | Callable[[], np.ndarray | None] | None = None,
    mode: str = "conservative",
    invalid: str = "conservative",
    fill_radius: int = 4,
    workers: int | None = None,
) -> OctreeFrame:
    """Fuse one frame of every sensor into the obstacle nodes O(t) (module docstring).

    Args:
        box: the node lattice (node size 0.02-0.1 m).
        observations: :class:`CameraObservation` and :class:`ScanObservation` items, world-frame poses; an
            item may also be a callable without arguments that returns one (e.g. a camera's observation
            with its self-filter, :func:`depthguard.robot.selffilter.self_filter_tasks`), called on the
            sensors' threads, so that its preparation runs beside the other sensors' sets.
        reach: (nx, ny, nz) bool C(t) on ``box`` (see :func:`reach_mask`), or None for the whole box; or a
            callable that returns one of these (e.g. the ``result`` of a reachability grid that a thread is
            still computing): it is called once the sensors' sets are done, which are then computed over
            the whole box. The flags inside C(t) are the same either way (a node's flags depend on the
            sensors only), so this only lets C(t) be computed beside the sensors.
        mode: ``"conservative"`` or ``"saphari"``.
        invalid: missing-depth policy of the cameras (``"conservative"``; ``"ignore"`` only on request).
        fill_radius: hole-filling radius of the cameras, pixels.
        workers: threads for the sensors' sets (SAPHARI ran them in parallel processes; the numba kernels
            release the GIL); default: the number of CPUs, at most the number of sensors. 1 = serial.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not observations:
        raise ValueError("observations: give at least one camera or scanner frame")
    later = reach if callable(reach) else None
    if reach is None or later is not None:
        mask, mp = _whole_box(box.shape)
    else:
        mask = _reach_array(reach, box.shape)
        mp = mask_pyramid(mask, _mask_levels(box.shape))
    n_work = min(len(observations), workers if workers is not None else (os.cpu_count() or 1))

    def sets(o) -> tuple[np.ndarray, bool]:
        o = o() if callable(o) else o
        return sensor_sets(box, mask, o, invalid, fill_radius, mp), isinstance(o, ScanObservation)

    parts = list(_pool(n_work).map(sets, observations)) if n_work > 1 else [sets(o) for o in observations]
    flags = np.stack([f for f, _ in parts])
    clear = False
    if later is not None:
        got = later()
        mask = _whole_box(box.shape)[0] if got is None else _reach_array(got, box.shape)
        clear = got is not None  # the sets were computed over the whole box: zero them outside C(t)
    # conservative mode: a 2-D scan never sees a node's whole volume free (its F bits dropped)
    drop_f = np.array([scan and mode == "conservative" for _, scan in parts], dtype=bool)
    kind = np.empty(box.shape, np.uint8)
    combine_cleared(flags, mask, mode == "conservative", kind, clear, drop_f)
    return OctreeFrame(box, kind != FREE, kind, mask, flags, mode)


@nb.njit(cache=True, nogil=True)
def clear_outside(flags, mask):
    """Zero the (S, nx, ny, nz) flags of the nodes outside ``mask`` (nx, ny, nz)."""
    S = flags.shape[0]
    nx, ny, nz = mask.shape
    for s in range(S):
        for i in range(nx):
            for j in range(ny):
                for k in range(nz):
                    if not mask[i, j, k]:
                        flags[s, i, j, k] = 0
