"""The octree distance backend as a stage of the simulated loop (:func:`depthguard.sim.loop.run_loop`): same
interface as :class:`depthguard.sim.pipeline.DistanceStage` (``update(depths, masks)``, ``ready``,
``query(centres, radii)``), plus the platform's laser scanners and the reachability grid C(t)."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import numpy as np

from depthguard.depthspace import PointDistances
from depthguard.octree.backend import OctreeBackend
from depthguard.octree.fusion import CameraObservation, ScanObservation
from depthguard.octree.grid import VoxelBox
from depthguard.octree.reach import ChainSweep, ReachabilityGrid, reachability_grid
from depthguard.octree.reach_reuse import ReachReuse
from depthguard.octree.scanner import scan_robot_rays
from depthguard.robot.reach import chain_sweep

__all__ = ["OctreeStage"]


@lru_cache(maxsize=1)
def _reach_worker() -> ThreadPoolExecutor:
    """One thread for the reachability grid, which overlaps the scans and the sensors' sets (its kernels
    release the GIL)."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="octree-reach")


class OctreeStage:
    """Frame stage (reachability, per-sensor sets, fusion) and distance stage (spheres to occupied nodes).

    Args:
        cell: the simulated cell (its ``data`` for the scans, ``q()`` for the robot state).
        cameras: the depth cameras, world frame.
        box: the octree's node box.
        reach_model: the :class:`~depthguard.robot.model.RobotModel` whose reachability gives C(t), or None
            (the whole box counts).
        reach_q: ``q_arm -> q`` of ``reach_model`` (e.g. prepends the base coordinates); identity if None.
        reach_offset: (3,) world position of ``reach_model``'s origin (its world frame shifted by it).
        lasers: :class:`~depthguard.sim.laser.LaserSim` scanners.
        scan_capsules: ``q_arm -> (a, b, r)`` robot capsules for the scanners' self-filter.
        mode: ``"saphari"`` or ``"conservative"``.
        rho, dist_mode, alpha: as :class:`~depthguard.sim.pipeline.DistanceStage`.
        horizon, reach_res: reachability horizon (s) and cell size (m).
        reach_slack: s; C(t) is computed with ``horizon + reach_slack`` and reused by the next frames while
            it provably covers them (:mod:`depthguard.octree.reach_reuse`); 0: a new grid every frame
            unless the robot stands exactly still.
        keep_every: keep a snapshot (octree, reachability) of every ``keep_every``-th frame for the recording.
    """

    def __init__(
        self,
        cell,
        cameras,
        box: VoxelBox,
        reach_model=None,
        reach_q=None,
        reach_offset=(0.0, 0.0, 0.0),
        lasers=(),
        scan_capsules=None,
        mode: str = "saphari",
        rho: float = 0.4,
        dist_mode: str = "hybrid",
        alpha: float = 6.0,
        horizon: float = 0.5,
        reach_res: float = 0.09,
        reach_slack: float = 0.1,
        keep_every: int = 15,
    ) -> None:
        self.cell = cell
        self.cameras = list(cameras)
        self.backend = OctreeBackend(box, mode=mode)
        self.reach_model = reach_model
        self.reach_q = reach_q or (lambda q: q)
        self.reach_offset = np.asarray(reach_offset, float)
        self.lasers = list(lasers)
        self.scan_capsules = scan_capsules
        self.rho, self.dist_mode, self.alpha = float(rho), dist_mode, float(alpha)
        self.horizon, self.reach_res = float(horizon), float(reach_res)
        self.reuse = ReachReuse.for_model(reach_model, horizon, reach_slack) if reach_model is not None else None
        self._reuse_mask: np.ndarray | None = None  # C(t) on the octree's nodes, of the grid in reuse
        self.keep_every = int(keep_every)
        self.times: dict[str, list[float]] = {k: [] for k in ("reachability", "laser", "scan_filter", "fusion")}
        self.times["distance"] = []
        self.update_wall: list[float] = []  # seconds per update (the reachability overlaps the scans)
        self.snapshots: list[tuple[float, np.ndarray, ReachabilityGrid | None]] = []
        self.counts: list[dict] = []
        self._n = 0
        self.reach: ReachabilityGrid | None = None

    def _reachability(self, chain: ChainSweep) -> ReachabilityGrid:
        g = reachability_grid(chain, horizon=self.reuse.grid_horizon, res=self.reach_res)
        box = VoxelBox(g.box.origin + self.reach_offset, g.box.res, g.box.shape)
        return g._replace(box=box)

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray], *_: object) -> None:
        """Frame stage: one depth image and robot mask per camera; the scans are taken here (the depth
        stage's extra arguments, joints, model and margins, are not needed: the octree has its own)."""
        q = self.cell.q()

        t_start = time.perf_counter()
        pending, qr = None, None
        reused = self.reuse is not None and self._reuse_mask is not None and self.reuse.covers(self.reach_q(q))
        if self.reach_model is not None and not reused:
            t0 = time.perf_counter()
            qr = self.reach_q(q)
            chain = chain_sweep(self.reach_model, qr)  # the model's kinematics: this thread only
            t_chain = time.perf_counter() - t0

            def timed_reach():
                t = time.perf_counter()
                return self._reachability(chain), t_chain + time.perf_counter() - t

            pending = _reach_worker().submit(timed_reach)
        t1 = time.perf_counter()
        scans = [las.capture(self.cell.data) for las in self.lasers]
        t2 = time.perf_counter()
        obs = [CameraObservation(c, d, m) for c, d, m in zip(self.cameras, depths, masks, strict=True)]
        if scans:
            a, b, r = self.scan_capsules(q)
            for las, s in zip(self.lasers, scans, strict=True):
                obs.append(ScanObservation(las.scanner, s, scan_robot_rays(las.scanner, s, a, b, r)))
        t3 = time.perf_counter()
        t_reach = 0.0
        if not reused:
            self.reach = None

        def reach():  # called by the fusion once the sensors' sets are done (they do not need C(t))
            self.reach, t = pending.result()
            nonlocal t_reach
            t_reach = t
            return self.reach

        in_use = self._reuse_mask  # (the same path as a fresh grid's: the sets first, C(t) after them)
        frame = self.backend.update(obs, (lambda: in_use) if reused else (reach if pending is not None else None))
        if pending is not None:
            self.reuse.store(qr, self.reach)
            self._reuse_mask = frame.mask
        t4 = time.perf_counter()
        # the reachability's own time (it ran beside the scans and the sets; frames that reuse a grid take
        # none and are not counted), the scans, their filter, the fusion (and the wait for the reachability)
        if pending is not None:
            self.times["reachability"].append(t_reach)
        for k, v in (("laser", t2 - t1), ("scan_filter", t3 - t2), ("fusion", t4 - t3)):
            self.times[k].append(v)
        self.update_wall.append(t4 - t_start)
        self.counts.append(frame.counts())
        if self._n % self.keep_every == 0:
            self.snapshots.append((float(self.cell.data.time), frame.kind.copy(), self.reach))
        self._n += 1

    @property
    def ready(self) -> bool:
        return self.backend.ready

    def query(self, centres: np.ndarray, radii: np.ndarray) -> PointDistances:
        """Distance stage: control spheres to the occupied nodes."""
        t0 = time.perf_counter()
        res = self.backend.query(centres, radii, rho=self.rho, mode=self.dist_mode)
        self.times["distance"].append(time.perf_counter() - t0)
        return res

    def stage_ms(self) -> dict[str, float]:
        """Median milliseconds per stage."""
        return {k: round(1e3 * float(np.median(v)), 3) for k, v in self.times.items() if v}

    def tolerance(self, centres: np.ndarray, noise_coeff: float = 0.0) -> np.ndarray:
        """Declared over-report tolerance (N,) m: 0.01 m (the node-box lower bound, issue contract) plus three
        standard deviations of the depth noise ``noise_coeff z²`` at ``z + ρ`` in each camera."""
        c = np.atleast_2d(np.asarray(centres, float))
        noise = np.zeros(len(c))
        for cam in self.cameras:
            z = np.maximum(cam.world_to_camera(c)[:, 2], 0.0) + self.rho
            noise = np.maximum(noise, 3.0 * noise_coeff * z * z)
        return 0.01 + noise
