"""The octree distance backend: one object that fuses sensor frames and answers distance queries, with the
same result type as the depth-space backend (:class:`depthguard.depthspace.PointDistances`)."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np

from depthguard.depthspace import PointDistances
from depthguard.octree.distance import capsule_distances, sphere_distances
from depthguard.octree.fusion import MODES, OctreeFrame, fuse, reach_mask
from depthguard.octree.grid import VoxelBox, check_res
from depthguard.validation import check_points

__all__ = ["OctreeBackend", "box_around_points"]


def box_around_points(centres: np.ndarray, radii: np.ndarray, rho: float, res: float) -> VoxelBox:
    """The node box that holds every node within ρ of N spheres (N, 3) / (N,): all that a query can see."""
    c, r = check_points(np.atleast_2d(np.asarray(centres, dtype=float)), np.atleast_1d(np.asarray(radii, float)))
    reach = float(rho) + float(r.max(initial=0.0)) + res
    return VoxelBox.around(c.min(axis=0) - reach, c.max(axis=0) + reach, check_res(res, "octree res"))


class OctreeBackend:
    """Fuse one frame of all sensors into an obstacle octree (:func:`depthguard.octree.fusion.fuse`) and query
    distances from control spheres or link capsules (:mod:`depthguard.octree.distance`).

    Args:
        box: the node lattice (node size 0.02-0.1 m), e.g. a box around the robot's close range.
        mode: ``"conservative"`` (unseen space is an obstacle) or ``"saphari"`` (unseen space is free).
        invalid, fill_radius: the cameras' missing-depth policy (:func:`depthguard.depthspace.prepare_frame`).
    """

    def __init__(self, box: VoxelBox, mode: str = "conservative", invalid: str = "conservative", fill_radius: int = 4):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        check_res(box.res, "octree res")
        self.box = box
        self.mode = mode
        self.invalid = invalid
        self.fill_radius = fill_radius
        self.frame: OctreeFrame | None = None

    def update(self, observations: list, reach=None) -> OctreeFrame:
        """Fuse one frame. ``reach``: a :class:`~depthguard.octree.reach.ReachabilityGrid` (C(t)), a bool mask
        over :attr:`box`, None (the whole box counts), or a :class:`concurrent.futures.Future` of one of
        these or a callable that returns one: the sensors' sets are then computed while it completes
        (:func:`~depthguard.octree.fusion.fuse`). A future's grid becomes the node mask on the thread that
        completes it (:meth:`_mask_when_done`). ``observations`` may hold tasks, as in ``fuse``.
        """
        if isinstance(reach, Future):
            later = self._mask_when_done(reach).result
            reach = later
        else:
            later = reach if callable(reach) else None
            reach = (lambda: self._mask(later())) if later is not None else self._mask(reach)
        self.frame = None  # a failed update leaves no answer
        self.frame = fuse(self.box, observations, reach, self.mode, self.invalid, self.fill_radius)
        return self.frame

    def _mask_when_done(self, pending: Future) -> Future:
        """A future of :meth:`_mask` of ``pending``'s result, computed by ``pending``'s own thread as it
        completes (or here, if it is done), beside the sensors' sets rather than after them; ``pending``'s
        exception, or one of the mask's, is re-raised by its ``result``."""
        out: Future = Future()

        def convert(done: Future) -> None:
            try:
                out.set_result(self._mask(done.result()))
            except BaseException as exc:  # handed to the caller through the future
                out.set_exception(exc)

        pending.add_done_callback(convert)
        return out

    def _mask(self, reach) -> np.ndarray | None:
        return reach if reach is None or isinstance(reach, np.ndarray) else reach_mask(self.box, reach)

    @property
    def ready(self) -> bool:
        return self.frame is not None

    def query(
        self, centres: np.ndarray, radii: np.ndarray | float = 0.0, rho: float = 0.4, mode: str = "min"
    ) -> PointDistances:
        """Distances from N control spheres (see :func:`~depthguard.octree.distance.sphere_distances`)."""
        if self.frame is None:
            raise ValueError("OctreeBackend.query: call update() with a sensor frame first")
        return sphere_distances(self.frame.occupied, self.box, centres, radii, rho=rho, mode=mode)

    def query_capsules(self, a: np.ndarray, b: np.ndarray, radii: np.ndarray, rho: float = 0.4) -> PointDistances:
        """Distances from L link capsules (see :func:`~depthguard.octree.distance.capsule_distances`)."""
        if self.frame is None:
            raise ValueError("OctreeBackend.query_capsules: call update() with a sensor frame first")
        return capsule_distances(self.frame.occupied, self.box, a, b, radii, rho=rho)
