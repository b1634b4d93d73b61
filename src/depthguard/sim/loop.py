"""The three-rate simulation (``docs/conventions.md``, "The three rates"), in simulated time.

* frame stage, every ``frame_period`` (1/30 s): each simulated Kinect takes a depth image of the cell;
  the self-filter removes the robot using the *measured* joint positions and the controller's model;
  the distance stage's frame data is updated (``prepare_frame`` or fusion ``update``);
* distance stage, every ``distance_period`` (3 ms, 333 Hz): control points from the measured joints,
  distances to the latest frame data, the end effector's repulsive vector (eq. 7, optional pivot);
* control stage, every ``control_dt`` (1 ms): task velocity, avoidance controller, joint command; the
  physics steps 1 ms with that command.

People and boxes move by their scripts at the physics rate. Ground truth (``mj_geomDistance``) is read
after every physics step for the metrics only. Wall-clock time of every stage call is measured too.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from depthguard.sim.cell import Cell
from depthguard.sim.depthcam import KinectSim
from depthguard.sim.pipeline import Controller, DistanceStage, Kinematics, filter_margin, self_filter
from depthguard.sim.pointtruth import PointClearance
from depthguard.sim.truth import TrueClearance

__all__ = ["Task", "LoopConfig", "SimLog", "run_loop"]


@dataclass
class Task:
    """End-effector task through Cartesian points (ICRA'12 §VI): ``kind`` "points", "cycle" or "hold".

    ``points``: visit ``waypoints`` (K, 3) in order at ``speed`` m/s; ``cycle``: the same, repeated;
    ``hold``: stay at ``waypoints[0]``.
    """

    kind: str
    waypoints: np.ndarray
    speed: float = 0.4
    tol: float = 0.02
    kp: float = 3.0
    index: int = 0
    reached: int = 0
    start: np.ndarray | None = None

    def velocity(self, x: np.ndarray) -> np.ndarray:
        """Desired end-effector velocity (3,) m/s at position ``x``; advances through the waypoints."""
        if self.start is None:
            self.start = np.asarray(x, float).copy()
        wp = self.waypoints
        if self.kind != "hold" and self.index < len(wp) and np.linalg.norm(wp[self.index] - x) < self.tol:
            self.reached += 1
            self.index += 1
            if self.kind == "cycle":
                self.index %= len(wp)
        if self.kind == "hold":
            target = wp[0]
        elif self.index >= len(wp):
            target = wp[-1]
        else:
            target = wp[self.index]
        e = target - x
        n = float(np.linalg.norm(e))
        if n < 1e-9:
            return np.zeros(3)
        return e / n * min(self.speed, self.kp * n)

    def path(self) -> np.ndarray:
        """The nominal path (polyline) as (P, 3): start, then the waypoints (once around for a cycle)."""
        pts = [self.start] if self.start is not None and self.kind != "hold" else []
        pts += list(self.waypoints if self.kind != "hold" else self.waypoints[:1])
        if self.kind == "cycle":
            pts.append(self.waypoints[0])
        return np.array(pts)


@dataclass
class LoopConfig:
    duration: float = 10.0
    control_dt: float = 0.001
    frame_period: float = 1.0 / 30.0
    distance_period: float = 0.003
    avoid: bool = True
    rho: float = 0.4
    vmax: float = 2.0
    alpha: float = 6.0
    pivot: bool = False
    dv_max: float = 0.5
    pivot_c: float = 5.0
    log_every: int = 10  # control steps between logged rows (10 ms)
    progress: bool = False
    label: str = ""
    bound_samples: int = 24  # distance calls compared with the measured bound (0: none; sim.measured_bound)


@dataclass
class SimLog:
    """What a run recorded (rows every ``log_every`` control steps unless said otherwise)."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    ee: list = field(default_factory=list)
    ee_ref: list = field(default_factory=list)  # the task's current target
    xdot_cmd: list = field(default_factory=list)
    elbow: list = field(default_factory=list)
    true_min: list = field(default_factory=list)
    true_links: list = field(default_factory=list)
    true_dynamic: list = field(default_factory=list)  # clearance to people and boxes only
    eval_min: list = field(default_factory=list)
    eval_points: list = field(default_factory=list)
    v_ee: list = field(default_factory=list)
    centres: list = field(default_factory=list)
    status: list = field(default_factory=list)
    # every control step
    step_true_min: list = field(default_factory=list)
    # wall-clock timings, seconds
    wall_distance: list = field(default_factory=list)
    wall_control: list = field(default_factory=list)
    wall_frame: list = field(default_factory=list)
    wall_camera: list = field(default_factory=list)
    t_distance: list = field(default_factory=list)
    frames: list = field(default_factory=list)  # (t, [uint16 mm depth per camera]) for the recorder
    # every distance-stage call: evaluated distance, synchronous true clearance and declared tolerance per
    # control point, flattened (see depthguard.sim.accuracy)
    acc_t: list = field(default_factory=list)
    acc_eval: list = field(default_factory=list)
    acc_true: list = field(default_factory=list)
    acc_tol: list = field(default_factory=list)
    acc_excluded_groups: tuple = ()  # geom groups left out of the truth (a background model's)
    # a few distance calls: their row in acc_* and the measured bound per control point (NaN where the true
    # clearance is >= rho; depthguard.sim.measured_bound)
    bound_row: list = field(default_factory=list)
    bound: list = field(default_factory=list)
    bound_spacing: float = 0.0
    nearest_obstacle: dict = field(default_factory=dict)
    links: list = field(default_factory=list)
    point_names: tuple = ()
    wall_total: float = 0.0


class _Progress:
    def __init__(self, total: float, label: str, enabled: bool) -> None:
        self.total, self.label, self.enabled = total, label, enabled
        self.last = -1
        self.t0 = time.perf_counter()

    def update(self, t: float) -> None:
        if not self.enabled:
            return
        pct = int(100 * t / self.total)
        n = pct // 4
        if n == self.last:
            return
        self.last = n
        el = time.perf_counter() - self.t0
        sys.stderr.write(f"\r{self.label:<28} [{'#' * n}{'.' * (25 - n)}] {pct:3d}%  sim {t:5.1f}s  wall {el:5.1f}s")
        sys.stderr.flush()
        if pct >= 100:
            sys.stderr.write("\n")


def _to_mm(depth: np.ndarray) -> np.ndarray:
    """A depth image for the recording: uint16 millimetres (0 = no reading), at most 320 pixels wide."""
    step = max(1, depth.shape[1] // 320)
    d = np.asarray(depth, float)[::step, ::step] * 1000.0
    return np.clip(np.round(np.nan_to_num(d, nan=0.0)), 0, 65535).astype("<u2")


def run_loop(
    cell: Cell,
    cams: list[KinectSim],
    kin: Kinematics,
    stage: DistanceStage,
    ctrl: Controller,
    task: Task,
    cfg: LoopConfig,
    record_frames_every: int = 3,
    view=None,
) -> SimLog:
    """Run the cell for ``cfg.duration`` s of simulated time. Returns the :class:`SimLog`.

    ``view``: a :class:`depthguard.viz.live.LiveView` fed with each frame set (and the octree, with that
    backend), each distance call and every tenth control cycle; it only stores references, its own thread
    draws.
    """
    pivot = None
    if cfg.pivot:
        from depthguard.pivot import PivotFilter

        pivot = PivotFilter(dv_max=cfg.dv_max, c=cfg.pivot_c)
    truth = TrueClearance(cell)
    # (the accuracy truth is the full cell: the repulsion's distances see the images as measured, even where
    # a monitor's background model removes the empty cell from its own distances)
    ptruth = PointClearance(cell)
    snap = ptruth.snapshot(cell.data)
    noise = max((getattr(c, "noise_coeff", 0.0) for c in cams), default=0.0)
    log = SimLog(links=truth.links, point_names=tuple(kin.names), acc_excluded_groups=ptruth.excluded_groups)
    n_steps = int(round(cfg.duration / cfg.control_dt))
    frame_every = cfg.frame_period
    next_frame, next_dist = 0.0, 0.0
    # (t of their frames, distances to the controller, V_ee, directions, distances within ρ, the monitor's
    # distances and directions or None)
    latest = None
    t_frames = 0.0
    frame_count = 0
    prog = _Progress(cfg.duration, cfg.label, cfg.progress)
    # the elbow (joint A4) is the last control point on the upper arm (lwr_link_3)
    elbow_idx = [i for i, n in enumerate(kin.names) if n.startswith("lwr_link_3")][-1:]
    bound_every = _bound_every(cams, cfg)
    bound_frame = None
    t_start = time.perf_counter()
    status: dict = {}
    xdot = np.zeros(3)
    for k in range(n_steps):
        t = k * cfg.control_dt
        cell.update_people(t)
        q_meas = cell.q()
        # ---------------------------------------------------------------- frame stage (30 Hz)
        if t >= next_frame - 1e-9:
            next_frame += frame_every
            depths, masks, margins = _frame_stage(cell, cams, kin, stage, q_meas, log)
            if bound_every and frame_count % bound_every == 0:
                bound_frame = (depths, masks, margins, q_meas.copy())
            t_frames = t  # the distances from these frames are as old as the frames (as in depthguard run)
            snap = ptruth.snapshot(cell.data)  # the obstacles as this frame saw them (metrics only)
            every = record_frames_every if depths[0].shape[1] <= 320 else 2 * record_frames_every
            if frame_count % every == 0:
                log.frames.append((t, [_to_mm(d) for d in depths]))
            frame_count += 1
            if view is not None:
                _show_frames(view, stage, depths, masks)
        # ---------------------------------------------------------------- distance stage (333 Hz)
        if t >= next_dist - 1e-9 and stage.ready:
            next_dist += cfg.distance_period
            w0 = time.perf_counter()
            cp, res, V, dists, dirs, mon = _distance_call(stage, kin, q_meas, cfg, pivot)
            log.wall_distance.append(time.perf_counter() - w0)
            log.t_distance.append(t)
            latest = (t_frames, dists, V, dirs, np.asarray(res.distance, float), *mon)
            # metrics only: the synchronous truth for these spheres (depthguard.sim.accuracy)
            log.acc_t.append(t)
            log.acc_eval.extend(np.asarray(res.distance, float))
            log.acc_true.extend(ptruth.evaluate(cp.centres, cp.radii, snap)[0])
            log.acc_tol.extend(stage.tolerance(cp.centres, noise))
            if view is not None:
                view.set_distances(cp.centres, cp.radii, res.distance, res.direction)
            if bound_frame is not None:
                _log_bound(log, cams, kin, bound_frame, cp, log.acc_true[-len(cp.radii) :], cfg.rho)
                bound_frame = None
        # ---------------------------------------------------------------- control stage (1 kHz)
        w0 = time.perf_counter()
        cp = kin.evaluate(q_meas)
        x = cp.centres[0]
        xdot = task.velocity(x)
        if latest is not None:
            mon = {} if latest[5] is None else {"monitor_distances": latest[5], "monitor_directions": latest[6]}
            q_cmd, qd_cmd, status = ctrl.step(
                t, q_meas, cell.qd(), xdot, cp, latest[1], latest[3], latest[0], cfg.avoid, **mon
            )
        else:
            q_cmd, qd_cmd, status = ctrl.step(t, q_meas, cell.qd(), xdot, cp, None, None, -1.0, cfg.avoid)
        log.wall_control.append(time.perf_counter() - w0)
        if view is not None and k % 10 == 0:
            view.set_joints(q_meas)
            view.set_status(status.get("status", "-"))
        cell.step(q_cmd, qd_cmd)
        # ---------------------------------------------------------------- truth (metrics only)
        per_link, tmin, name, _ = truth.evaluate()
        log.step_true_min.append(tmin)
        if not tmin > 0:  # (a NaN truth counts, as in the metrics)
            log.nearest_obstacle[name] = log.nearest_obstacle.get(name, 0) + 1
        if k % cfg.log_every == 0:
            elbow = cp.centres[elbow_idx[0]] if elbow_idx else cell.data.xpos[5]
            _log_sample(log, t, q_meas, cp, xdot, elbow, latest, task, cfg.avoid, status)
            log.true_min.append(tmin)
            log.true_links.append(per_link)
            log.true_dynamic.append(truth.last_dynamic)
            prog.update(t)
    prog.update(cfg.duration)
    log.wall_total = time.perf_counter() - t_start
    return log


BOUND_SPACING = 0.01  # m, lattice of the measured bound


def _show_frames(view, stage, depths: list, masks: list) -> None:
    """Hand a frame set to the live view, and the octree when the stage is the octree backend's."""
    view.set_frames(depths, masks)
    backend = getattr(stage, "backend", None)
    if backend is not None and hasattr(backend, "frame"):
        view.set_octree(backend.frame)


def _bound_every(cams: list, cfg: LoopConfig) -> int:
    """Every how many frames a distance call is compared with the measured bound (0: never; only depth
    cameras of the project's camera model are sampled)."""
    from depthguard.camera import Camera

    if cfg.bound_samples <= 0 or not cams or not all(isinstance(getattr(c, "camera", None), Camera) for c in cams):
        return 0
    return max(1, int(cfg.duration / cfg.frame_period) // cfg.bound_samples)


def _log_bound(log: SimLog, cams: list, kin: Kinematics, frame, cp, truth, rho: float) -> None:
    """The measured bound of the spheres whose true clearance is below rho (metrics only)."""
    from depthguard.robot.interior import interior_capsules
    from depthguard.sim.measured_bound import measured_bound, measured_views, robot_meshes

    depths, masks, margins, q = frame
    truth = np.asarray(truth, float)
    near = truth < rho
    out = np.full(len(truth), np.nan)
    if near.any():
        views = measured_views([c.camera for c in cams], depths, [np.asarray(m, bool) for m in masks])
        caps = interior_capsules(kin.model, q)
        c, r = np.asarray(cp.centres)[near], np.asarray(cp.radii)[near]
        margin = float(max(margins))
        meshes = robot_meshes(kin.model, q, margin) if kin.model.geometry.n_triangles else None
        out[near] = measured_bound(views, c, r, rho, caps, margin, spacing=BOUND_SPACING, meshes=meshes)
    log.bound_row.append(len(log.acc_t) - 1)
    log.bound.append(out)
    log.bound_spacing = BOUND_SPACING


def _frame_stage(cell: Cell, cams: list[KinectSim], kin: Kinematics, stage: DistanceStage, q_meas, log: SimLog):
    """One frame set: capture every camera, self-filter at the measured joints, update the distance stage;
    logs the camera and frame-stage wall times. Returns ``(depth images, robot masks, self-filter margins)``."""
    cell.forward()
    w0 = time.perf_counter()
    depths = [c.capture(cell.data) for c in cams]
    w1 = time.perf_counter()
    margins = [filter_margin(c.camera, q_meas, kin, getattr(c, "noise_coeff", 0.0)) for c in cams]
    masks = [self_filter(c.camera, d, q_meas, kin, margin=m) for c, d, m in zip(cams, depths, margins, strict=True)]
    stage.update(depths, masks, q_meas, kin.model, margins)
    log.wall_camera.append(w1 - w0)
    log.wall_frame.append(time.perf_counter() - w1)
    return depths, masks, margins


def _distance_call(stage: DistanceStage, kin: Kinematics, q_meas, cfg: LoopConfig, pivot):
    """One distance-stage call at the measured joints: ``(control points, PointDistances within ρ, V_R of the
    end effector (3,), distances (N,) and directions (N, 3) for the controller, (monitor distances (N,),
    monitor directions (N, 3)))``: ρ's answers, and beyond ρ those of the monitor's longer range (if any);
    with the pivot, the end effector's direction turned. The monitor's pair is ``(None, None)`` unless the stage
    has distances of its own for the monitor (``query_monitor``: the frames without the empty cell)."""
    from depthguard.repulsion import repulsive_vectors

    cp = kin.evaluate(q_meas)
    res = stage.query(cp.centres, cp.radii)
    V = repulsive_vectors(res, cfg.vmax, cfg.rho, cfg.alpha)[0]
    far = stage.query_far(cp.centres, cp.radii, res) if getattr(stage, "ssm_range", None) else res
    dists, dirs = np.asarray(far.distance, float), np.array(far.direction, dtype=float)
    if pivot is not None:
        # the pivot turns V_R (keeping its norm): hand the controller the turned direction
        V = pivot.step(V, cfg.distance_period)
        nv = float(np.linalg.norm(V))
        if nv > 1e-12 and np.isfinite(res.distance[0]):
            dirs[0] = V / nv
    mon = (None, None)
    if hasattr(stage, "query_monitor"):
        m = stage.query_monitor(cp.centres, cp.radii)
        mon = (np.asarray(m.distance, float), np.array(m.direction, dtype=float))
    return cp, res, V, dists, dirs, mon


def _log_sample(log: SimLog, t: float, q_meas, cp, xdot, elbow, latest, task: Task, avoid: bool, status: dict) -> None:
    """One logged sample of the robot, the task and the latest distances (``latest``: the loop's tuple)."""
    log.t.append(t)
    log.q.append(q_meas)
    log.ee.append(cp.centres[0].copy())
    tgt = task.waypoints[min(task.index, len(task.waypoints) - 1)] if task.kind != "hold" else task.waypoints[0]
    log.ee_ref.append(np.asarray(tgt, float).copy())
    log.xdot_cmd.append(xdot + (latest[2] if (latest is not None and avoid) else 0.0))
    log.elbow.append(np.array(elbow, float))
    d = latest[4] if latest is not None else np.full(len(cp.centres), np.inf)
    log.eval_min.append(float(np.min(d)))
    log.eval_points.append(d.copy())
    log.v_ee.append(latest[2].copy() if latest is not None else np.zeros(3))
    log.centres.append(cp.centres.copy())
    log.status.append({k: v for k, v in status.items() if k != "xdot_c"})
