"""``depthguard run``: one runner for the whole chain on any source, recorded as ROS 2 messages.

Per tick of the source (:mod:`depthguard.runner.sources`): a new frame set goes through the frame stage
(self-filter, distance-stage update); a distance query runs every ``distance.period`` seconds of the source's
clock (``--fast``: deterministic) or on every tick once that period has passed in wall-clock time
(``--realtime``, paced to the source's clock); the controller runs once per tick and its joint command goes
back to the source.

The recording (``recording.mcap`` in ``--out``, profile ``ros2``) holds the **inputs** (depth images as
``32FC1`` metres so that a replay is bit-exact, ``CameraInfo``, ``/tf_static``, ``/joint_states``, the task
velocity) and the **outputs** (self-filter masks as ``mono8``, per-point distances, markers, the joint command
as ``sensor_msgs/JointState``, ``trajectory_msgs/JointTrajectory`` and ``std_msgs/Float64MultiArray``, and the
controller status). ``--source bag:DIR/recording.mcap`` replays it.

A ros2_control driver that takes these commands must stop the arm by itself when they stop arriving (a
watchdog on the robot side): DepthGuard is a process that can die.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.runner.bag import TASK_TOPIC
from depthguard.runner.chain import Chain

__all__ = ["run_chain", "RunLog"]


class RunLog:
    """What a run produced, in memory (for tests and the summary): per tick ``t``, ``q_cmd``, ``qdot_cmd``,
    ``status``; per query ``t_query`` and ``distances`` (N,)."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.q_cmd: list[np.ndarray] = []
        self.qdot_cmd: list[np.ndarray] = []
        self.status: list[str] = []
        self.t_query: list[float] = []
        self.distances: list[np.ndarray] = []
        self.wall_query: list[float] = []
        self.frames = 0
        self.faults: Counter = Counter()  # "camera: fault" -> frames


def _usable_q(q: np.ndarray | None, n: int) -> bool:
    """``q`` is an (n,) array of finite joint positions."""
    return q is not None and np.shape(q) == (n,) and bool(np.all(np.isfinite(q)))


class _Recorder:
    def __init__(self, path: Path, chain: Chain, cell: CellFile) -> None:
        from depthguard.io.mcap_ros2 import Ros2McapWriter
        from depthguard.sim.recorder import camera_tf

        self.w = Ros2McapWriter(path)
        self.chain, self.cell = chain, cell
        tfs = [  # a camera carried by a link hangs on that link (its pose then follows the joint states)
            (parent, c.frame_id, *camera_tf(cam.R, cam.t))
            for c, cam, parent in zip(cell.cameras, chain.local_cameras, chain.parents, strict=True)
        ]
        self.w.write(cell.topics["tf_static"], "tf2_msgs/msg/TFMessage", ros2.tf_msg(0.0, tfs), 0.0)
        self.last_marker = -np.inf

    def inputs(self, tick, frames) -> None:
        w, cell = self.w, self.cell
        if frames is not None:
            for c, cam, d in zip(cell.cameras, self.chain.cameras, frames, strict=True):
                w.write(c.topic, "sensor_msgs/msg/Image", ros2.image_msg(tick.t_frames, c.frame_id, d, "32FC1"), tick.t)
                w.write(
                    c.info_topic,
                    "sensor_msgs/msg/CameraInfo",
                    ros2.camera_info_msg(tick.t_frames, c.frame_id, cam),
                    tick.t,
                )
        vs = ros2.vector3_stamped_msg(tick.t, "world", tick.xdot_d)
        w.write(TASK_TOPIC, "geometry_msgs/msg/Vector3Stamped", vs, tick.t)
        if tick.q is not None:
            js = ros2.joint_state_msg(tick.t_joints, self.chain.joint_names, tick.q, tick.qdot)
            w.write(cell.topics["joint_states"], "sensor_msgs/msg/JointState", js, tick.t)

    def masks(self, t: float, masks) -> None:
        for c, m in zip(self.cell.cameras, masks, strict=True):
            img = ros2.mask_msg(t, c.frame_id, m)
            self.w.write(f"/depthguard/{c.name}/robot_mask", "sensor_msgs/msg/Image", img, t)

    def query(self, t: float, res, cps) -> None:
        """The distances (and the monitor's, with a background); markers at most every 0.05 s of the source."""
        markers = t - self.last_marker >= 0.05
        self.last_marker = t if markers else self.last_marker
        topics = self.cell.topics
        msg = ros2.query_msg(t, cps.names, cps.centres, cps.radii, res, rho=self.chain.rho)
        self.w.write(topics["distances"], "depthguard_msgs/msg/ControlPointDistances", msg, t)
        mon = self.chain.latest_monitor  # (with a background: SSM's own distances, same frames)
        if mon is not None:
            rng = getattr(self.chain.stage.monitor, "ssm_range", None) or self.chain.rho  # (the monitor's range)
            mmsg = ros2.query_msg(t, cps.names, cps.centres, cps.radii, mon, rho=rng)
            self.w.write(topics["monitor_distances"], "depthguard_msgs/msg/ControlPointDistances", mmsg, t)
        if markers:
            d, dirs = np.asarray(res.distance, float), np.asarray(res.direction, float)
            mk = ros2.markers_msg(t, cps.centres, cps.radii, d, dirs, self.chain.rho)
            self.w.write(topics["markers"], "visualization_msgs/msg/MarkerArray", mk, t)

    def command(self, t: float, out) -> None:
        topics, names = self.cell.topics, self.chain.joint_names
        js = ros2.joint_state_msg(t, names, out.q_cmd, out.qdot_cmd)
        self.w.write("/depthguard/joint_command", "sensor_msgs/msg/JointState", js, t)
        dt = self.chain.config.dt
        jt = ros2.joint_trajectory_msg(t, names, out.q_cmd, out.qdot_cmd, dt)
        self.w.write(topics["command"], "trajectory_msgs/msg/JointTrajectory", jt, t)
        self.w.write(topics["command_array"], "std_msgs/msg/Float64MultiArray", ros2.float64_array_msg(out.qdot_cmd), t)
        st = ros2.status_msg(t, out.status.name, out.scale)
        self.w.write(topics["status"], "depthguard_msgs/msg/ControllerStatus", st, t)

    def close(self) -> None:
        self.w.close()


def _progress(t: float, total: float, last: list[int], label: str) -> None:
    pct = int(100 * min(t / total, 1.0)) if total > 0 else 100
    if pct // 4 != last[0]:
        last[0] = pct // 4
        sys.stderr.write(f"\r{label:<24} [{'#' * (pct // 4)}{'.' * (25 - pct // 4)}] {pct:3d}%  t {t:6.2f} s")
        sys.stderr.flush()


def _frame_stage(chain: Chain, tick, q_ok: bool, log: RunLog, sinks: list[Any]) -> None:
    """A new frame set through the chain's frame stage; the masks to the sinks. A joint state that is missing,
    of the wrong size or not finite cannot place the robot: no frame stage with it (the controller gets it as
    it is and stops: STOP_INVALID_INPUT). The frames are filtered with ``tick.q_frames`` when the source gives
    it (a bag: the joint state nearest to the frames' stamps), else with ``tick.q``."""
    if tick.frames is None:
        return
    q = getattr(tick, "q_frames", None)
    q, q_ok = (tick.q, q_ok) if q is None else (q, _usable_q(q, len(chain.joint_names)))
    if not q_ok:
        if q is not None:
            log.faults["joint state: not finite or wrong size"] += 1
        return
    masks = chain.on_frames(tick.frames, q, tick.t_frames)
    log.frames += 1
    log.faults.update(f"{k}: {v}" for k, v in chain.faults.items())
    for s in sinks:
        s.masks(tick.t, masks)


def _distance_query(chain: Chain, tick, log: RunLog, sinks: list[Any]) -> None:
    """One distance query at the tick's joint positions; its result to the log and the sinks."""
    w0 = time.perf_counter()
    res = chain.query(tick.t, tick.q)
    log.wall_query.append(time.perf_counter() - w0)
    log.t_query.append(tick.t)
    log.distances.append(np.asarray(res.distance, float).copy())
    if sinks:
        cps = chain.points.evaluate(tick.q)
        for s in sinks:
            s.query(tick.t, res, cps)


def _control(chain: Chain, source: Any, tick, log: RunLog, sinks: list[Any]) -> None:
    """One controller cycle; its joint command back to the source and to the log and the sinks."""
    out = chain.control(tick.t, tick.q, tick.qdot, tick.t_joints, tick.xdot_d)
    source.command(out.q_cmd, out.qdot_cmd)
    log.t.append(tick.t)
    log.q_cmd.append(np.asarray(out.q_cmd, float).copy())
    log.qdot_cmd.append(np.asarray(out.qdot_cmd, float).copy())
    log.status.append(out.status.name)
    for s in sinks:
        s.command(tick.t, out)


def _summary(log: RunLog, wall0: float, recording: Path | None) -> dict[str, Any]:
    wq = np.asarray(log.wall_query)
    summary: dict[str, Any] = {
        "frames": log.frames,
        "commands": len(log.t),
        "distance_hz_median": float(1.0 / np.median(wq)) if wq.size else None,
        "statuses": dict(Counter(log.status)),
        "sensor_faults": dict(log.faults),
        "duration_s": float(log.t[-1] - log.t[0]) if log.t else 0.0,
        "wall_s": round(time.perf_counter() - wall0, 3),
    }
    if recording is not None:
        summary["recording"] = str(recording)
    return summary


def run_chain(
    cell: CellFile,
    source: Any,
    chain: Chain,
    *,
    realtime: bool = False,
    out_dir: str | Path | None = None,
    progress: bool = False,
    label: str = "run",
    log: RunLog | None = None,
    sinks: list[Any] | None = None,
) -> dict[str, Any]:
    """Drive ``chain`` with every tick of ``source``; record to ``out_dir/recording.mcap`` if given.

    ``sinks``: more consumers with the recorder's hooks (``inputs``, ``masks``, ``query(t, res, cps)``,
    ``command``, ``close``): the Zenoh publisher of ``--transport zenoh``, the live view of ``--view``.

    Returns the summary: ``frames``, ``commands``, ``distance_hz_median``, ``statuses`` (count per status
    name), ``duration_s`` (source time), ``wall_s``.
    """
    log = log if log is not None else RunLog()
    sinks = list(sinks or [])
    recording = None
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        recording = Path(out_dir) / "recording.mcap"
        sinks.insert(0, _Recorder(recording, chain, cell))
    period = float(cell.distance["period"])
    next_query = -np.inf
    wall0 = time.perf_counter()
    t_first = None
    bar = [-1]
    if realtime:  # (every kernel of the controller's cycle loaded before the loop: no first use inside it)
        chain.warm_up()
    try:
        for tick in source.ticks():
            t_first = tick.t if t_first is None else t_first
            if realtime:
                lag = (tick.t - t_first) - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)
            log.faults.update(f"{k}: {v}" for k, v in tick.faults.items())  # source faults (dropped stream...)
            for s in sinks:
                s.inputs(tick, tick.frames)
            q_ok = _usable_q(tick.q, len(chain.joint_names))
            _frame_stage(chain, tick, q_ok, log, sinks)
            if chain.ready and q_ok and tick.t >= next_query - 1e-9:
                next_query = tick.t + period if next_query == -np.inf else next_query + period
                _distance_query(chain, tick, log, sinks)
            _control(chain, source, tick, log, sinks)
            if progress:
                _progress(tick.t - t_first, getattr(source, "duration", 0.0), bar, label)
    finally:
        for s in sinks:
            s.close()
        source.close()
        if progress:
            sys.stderr.write("\n")
    return _summary(log, wall0, recording)
