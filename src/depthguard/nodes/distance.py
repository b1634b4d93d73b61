"""The distance node: fusion of the prepared frames and the distance queries (RA-L'16 §V-VI) on Zenoh.

Subscribes every camera node's prepared depth and robot mask (paired by stamp) and the joint states. When
every camera has delivered a frame since the last query, it updates the distance stage (depth space for one
camera, depth grid for several) and queries the control spheres at the newest joint positions; the result
goes out as ``depthguard_msgs/ControlPointDistances`` on the cell's ``distances`` topic, **stamped with the
oldest of the frames' stamps and the stamp of the joint state used** (the age of the data, which the
controller's stale-data timeout checks). With SSM and a
``[controller] background`` the monitor's own distances (the same frames without the empty cell, docs/ssm.md)
follow on ``monitor_distances`` with the same stamp.
"""

from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.nodes.common import (
    JOINT_RING,
    MAX_JOINT_SKEW,
    JsonLog,
    StopFlag,
    Topics,
    camera_at_size,
    open_node,
    wait_reading,
)
from depthguard.nodes.memory import keep_freed_memory

__all__ = ["run_distance_node", "frame_set_cameras", "FrameSetWork"]

_UNPAIRED_MAX = 32  # frames kept per camera while their depth or mask is missing


class _FrameSets:
    """Pairs each camera's prepared depth and mask by stamp; :attr:`ev` is set when every camera has one.
    ``names``: the cameras; ``joint_names``: the robot model's joints (joint states are matched by name)."""

    def __init__(self, names: list[str], joint_names: list[str] | tuple[str, ...]) -> None:
        self.names, self.joint_names = names, list(joint_names)
        self.lock, self.ev = threading.Lock(), threading.Event()
        self.depth: dict[str, dict] = {n: {} for n in names}
        self.mask: dict[str, dict] = {n: {} for n in names}
        self.recv: dict[str, dict] = {n: {} for n in names}  # stamp -> the later receive time (s) of the pair
        self.ready: dict[str, tuple] = {}
        self.joint: dict = {"q": None, "t": -np.inf}  # the newest joint positions and their stamp (s)
        self.joints: deque = deque(maxlen=JOINT_RING)  # (stamp s, q): the joint states of the frame sets
        self.t_ready = 0.0  # when the newest frame set became complete (s since the epoch)
        self.taken_ready = 0.0  # when the frame set that :meth:`take` returned last became complete

    def _pair(self, n: str, t: float, pub: float, recv_ns: int) -> None:
        depth, mask, recv = self.depth[n], self.mask[n], self.recv[n]
        recv[t] = max(recv.get(t, 0.0), recv_ns * 1e-9)
        if t in depth and t in mask:
            self.ready[n] = (t, depth.pop(t), mask.pop(t), pub, recv.pop(t))
            for d in (depth, mask, recv):
                for k in [k for k in d if k < t]:
                    d.pop(k)
        for d in (depth, mask, recv):  # a camera whose depths or masks stop coming: keep the newest few
            while len(d) > _UNPAIRED_MAX:
                d.pop(min(d))
            if len(self.ready) == len(self.names):
                self.t_ready = time.time()
                self.ev.set()

    def on_depth(self, n: str):
        def cb(msg, att, recv_ns):
            t = ros2.to_seconds(msg.header.stamp)
            with self.lock:
                self.depth[n][t] = ros2.image_to_depth(msg)
                self._pair(n, t, att.stamp_ns * 1e-9, recv_ns)

        return cb

    def on_mask(self, n: str):
        def cb(msg, att, recv_ns):
            t = ros2.to_seconds(msg.header.stamp)
            with self.lock:
                self.mask[n][t] = ros2.image_to_mask(msg)
                self._pair(n, t, att.stamp_ns * 1e-9, recv_ns)

        return cb

    def on_js(self, msg, att, recv_ns) -> None:
        q, _ = ros2.joints_in_order(msg, self.joint_names)  # (by name; ValueError: refused and counted)
        t = ros2.to_seconds(msg.header.stamp)
        with self.lock:
            self.joint.update(q=q, t=t)
            self.joints.append((t, q))

    def take(self, carried: list) -> tuple | None:
        """The next frame set, once every camera has one and a joint state has come: ``(sets, q, t_data,
        q_frames, q_cams)``, each set ``(stamp, depth, mask, published, received)`` in camera order, ``q`` the
        newest joint positions, ``q_frames`` / ``q_cams`` those of the principal frame / of each carried camera's
        frame (:meth:`q_at`); else None.

        ``t_data``, the stamp that the distances carry, is the oldest of the frames' stamps and the stamp of
        ``q``: the control spheres are placed at ``q``, so distances computed from joint positions that stopped
        coming (a joint-state publisher gone silent or partitioned from this node alone) age like distances
        from old frames, and the controller's stale-data timeout stops the arm."""
        with self.lock:
            self.ev.clear()
            if len(self.ready) < len(self.names) or self.joint["q"] is None:
                return None
            sets = [self.ready.pop(n) for n in self.names]
            self.taken_ready = self.t_ready
            q, t_q = self.joint["q"].copy(), self.joint["t"]
            q_frames = self.q_at(sets[0][0])  # the robot where the principal frame saw it
            q_cams = {k: self.q_at(sets[k][0]) for k, _ in carried}
        return sets, q, min(min(s[0] for s in sets), t_q), q_frames, q_cams

    def q_at(self, t: float) -> np.ndarray | None:
        """The joint state nearest to stamp ``t`` (s), None if none lies within ``MAX_JOINT_SKEW`` (call
        under :attr:`lock`)."""
        if not self.joints:
            return None
        tj, q = min(self.joints, key=lambda x: abs(x[0] - t))
        return q if abs(tj - t) <= MAX_JOINT_SKEW else None


def frame_set_cameras(cams0: list, depths: list, model, carried: list, q_cams: dict) -> list | None:
    """The cameras of one frame set in the world frame: each one at the size of its image, and each one that
    the robot carries (``carried``: ``(index, link)``) where its link was at the joint state of its frame
    (``q_cams[index]``); None when such a joint state is missing."""
    from depthguard.runner.carried import carried_camera

    cams = [camera_at_size(c, d.shape[1], d.shape[0]) for c, d in zip(cams0, depths, strict=True)]
    for k, link in carried:
        if q_cams.get(k) is None:
            return None
        cams[k] = carried_camera(cams[k], model, q_cams[k], link)
    return cams


def _frame_set_distances(stage, cell: CellFile, cams, points, depths, masks, q_frames, q, marks=None):
    """Update ``stage`` with one frame set (robot-interior corrections at the frames' joint state
    ``q_frames``, none without one) and query the control spheres at the newest joint positions ``q``:
    ``(control points, distances up to the monitor's range, the monitor's own distances or None)``.
    ``marks``: a list, to which the ``time.perf_counter()`` at the end of the update is appended."""
    from depthguard.runner.chain import self_filter_margins

    margins = None if q_frames is None else self_filter_margins(cell, cams, q_frames, points.model)
    stage.update(depths, masks, q_frames, points.model, *([margins] if margins is not None else []))
    if marks is not None:
        marks.append(time.perf_counter())
    cps = points.evaluate(q)
    res = stage.query(cps.centres, cps.radii)
    res = stage.query_far(cps.centres, cps.radii, res)  # SSM: beyond rho too (docs/ssm.md)
    monitor = getattr(stage, "query_monitor", None)  # (with a background: SSM's own distances)
    return cps, res, (monitor(cps.centres, cps.radii) if monitor is not None else None)


class FrameSetWork:
    """The distance node's work on one frame set, apart from Zenoh: the cameras at the frames' sizes (and where
    a carried camera's link was), the distance stage (rebuilt when a size changes, kept otherwise) and the
    distances (:func:`_frame_set_distances`).

    :meth:`distances` raises ``ValueError`` for a frame set that cannot be used: an image whose size is not a
    scaled camera image, a mask of another size than its depth... The stage is then forgotten, so that the
    next frame set starts from a clean one; the node skips the set, its distances go stale and the controller
    stops the arm until good frame sets come again.
    """

    def __init__(self, cell: CellFile, cams0: list, points, carried: list) -> None:
        self.cell, self.cams0, self.points, self.carried = cell, cams0, points, carried
        self.stage, self.sizes, self.cams = None, [], None

    def distances(self, depths: list, masks: list, q_frames, q_cams: dict, q, marks=None) -> tuple | None:
        """``(control points, distances, the monitor's distances or None)`` of one frame set (depths (H, W)
        metres, masks (H, W) bool, one per camera), or None when a carried camera's joint state is missing.
        ``marks``: as :func:`_frame_set_distances`."""
        from depthguard.runner.chain import cell_distance_stage

        try:
            sizes = [np.shape(d) for d in depths]
            if self.stage is None or self.carried or sizes != self.sizes:  # (a camera may change its resolution)
                self.stage = None
                cams = frame_set_cameras(self.cams0, depths, self.points.model, self.carried, q_cams)
                if cams is None:
                    return None
                self.stage, self.sizes, self.cams = cell_distance_stage(self.cell, cams), sizes, cams
            return _frame_set_distances(
                self.stage, self.cell, self.cams, self.points, depths, masks, q_frames, q, marks
            )
        except ValueError:
            self.stage = None
            raise


def run_distance_node(
    cell: CellFile, *, duration: float | None = None, log: str | None = None, stop: StopFlag | None = None, **kw
) -> dict:
    """Run the distance node until ``duration`` s or SIGTERM; returns counters."""
    from depthguard.runner.carried import check_camera_parents
    from depthguard.runner.chain import cell_control_points, check_chain_support, load_cell_robot

    check_chain_support(cell)
    heap = keep_freed_memory()  # (the images of one frame set reuse the pages of the last)
    stop = stop if stop is not None else StopFlag()
    jl = JsonLog(log)
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    carried = check_camera_parents(cell, model)
    d = cell.distance
    rho = float(d["rho"])
    cams0 = [c.build() for c in cell.cameras]
    names = [c.name for c in cell.cameras]
    top = Topics.of(cell)
    node = open_node(cell, "distance", **kw)
    fs = _FrameSets(names, model.joint_names)

    # the joint states (at the driver's rate, 500-1000 Hz) wait in a ring and are read between frame sets, in
    # this thread: no Python thread wakes for each of them while the distance stage computes
    sub_js = node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", fs.on_js, pull=JOINT_RING)
    subs = [sub_js]
    for n in names:
        subs.append(node.subscribe(top.depth[n], "sensor_msgs/msg/Image", fs.on_depth(n)))
        subs.append(node.subscribe(top.mask[n], "sensor_msgs/msg/Image", fs.on_mask(n)))
    pub = node.publisher(top.distances, "depthguard_msgs/msg/ControlPointDistances")
    pub_mon = node.publisher(top.monitor_distances, "depthguard_msgs/msg/ControlPointDistances")
    work = FrameSetWork(cell, cams0, points, carried)
    queries = 0
    t_start = time.time()
    try:
        while not stop and (duration is None or time.time() - t_start < duration):
            if not wait_reading(fs.ev, sub_js):
                continue
            got_set = fs.take(carried)
            if got_set is None:
                continue
            sets, q, t_data, q_frames, q_cams = got_set
            depths, masks = [s[1] for s in sets], [s[2] for s in sets]
            t_start_compute = time.time()
            marks = [time.perf_counter()]
            try:
                got = work.distances(depths, masks, q_frames, q_cams, q, marks)
            except ValueError as exc:  # a malformed frame set (a mask of another size...): no distances from it
                jl.write(ev="skipped", reason=str(exc))
                continue
            if got is None:
                jl.write(ev="skipped", reason="no joint state for a carried camera's frame")
                continue  # (no distances from this frame set: they go stale, the controller stops)
            cps, res, mres = got
            w0, w1 = marks[0], time.perf_counter()
            p = pub.publish(ros2.query_msg(t_data, points.names, cps.centres, cps.radii, res, rho=rho)) * 1e-9
            if mres is not None:
                rng = getattr(work.stage.monitor, "ssm_range", None) or rho  # (the monitor's range)
                pub_mon.publish(ros2.query_msg(t_data, points.names, cps.centres, cps.radii, mres, rho=rng))
            queries += 1
            jl.write(
                ev="distances", stamp=t_data, frame_pub=max(s[3] for s in sets), recv=max(s[4] for s in sets),
                ready=fs.taken_ready, start=t_start_compute, pub=p, compute=w1 - w0,
                update=marks[1] - w0 if len(marks) > 1 else None,
            )  # fmt: skip
    finally:
        out = {
            "queries": queries,
            "dropped": {s.topic: dict(s.dropped) for s in subs if s.dropped},
            "missed": {s.topic: s.missed for s in subs if s.missed},  # (never came: lost, or out of a full ring)
            "freed_memory": heap,
        }
        out["shared_memory_samples"] = {s.topic: [s.shm_received, s.received] for s in subs}
        jl.write(ev="summary", **out)
        node.close()
        jl.close()
    return out
