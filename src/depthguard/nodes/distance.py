"""The distance node: fusion of the prepared frames and the distance queries (RA-L'16 §V-VI) on Zenoh.

Subscribes every camera node's prepared depth and robot mask (paired by stamp) and the joint states. When
every camera has delivered a frame since the last query, it updates the distance stage (depth space for one
camera, depth grid for several) and queries the control spheres at the newest joint positions; the result
goes out as ``depthguard_msgs/ControlPointDistances`` on the cell's ``distances`` topic, **stamped with the
oldest frame's stamp** (the age of the data, which the controller's stale-data timeout checks). With SSM and a
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
from depthguard.nodes.common import MAX_JOINT_SKEW, JsonLog, StopFlag, Topics, camera_at_size, open_node

__all__ = ["run_distance_node", "frame_set_cameras"]

_UNPAIRED_MAX = 32  # frames kept per camera while their depth or mask is missing


def _mask_from_msg(msg) -> np.ndarray:
    if str(msg.encoding) != "mono8":
        raise ValueError(f"robot mask must be a mono8 Image, got {msg.encoding!r}")
    h, w = int(msg.height), int(msg.width)
    raw = np.asarray(msg.data, np.uint8)
    step = int(msg.step) or w
    if raw.size < step * h:
        raise ValueError(f"robot mask {w}x{h} holds {raw.size} bytes: too few")
    return raw[: step * h].reshape(h, step)[:, :w] > 0


class _FrameSets:
    """Pairs each camera's prepared depth and mask by stamp; :attr:`ev` is set when every camera has one."""

    def __init__(self, names: list[str], n_joints: int) -> None:
        self.names, self.n_joints = names, n_joints
        self.lock, self.ev = threading.Lock(), threading.Event()
        self.depth: dict[str, dict] = {n: {} for n in names}
        self.mask: dict[str, dict] = {n: {} for n in names}
        self.recv: dict[str, dict] = {n: {} for n in names}  # stamp -> the later receive time (s) of the pair
        self.ready: dict[str, tuple] = {}
        self.joint: dict = {"q": None}
        self.joints: deque = deque(maxlen=400)  # (stamp s, q): the joint state of each frame set

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
                self.mask[n][t] = _mask_from_msg(msg)
                self._pair(n, t, att.stamp_ns * 1e-9, recv_ns)

        return cb

    def on_js(self, msg, att, recv_ns) -> None:
        q = np.asarray(msg.position, float)
        if q.shape == (self.n_joints,) and np.all(np.isfinite(q)):
            with self.lock:
                self.joint["q"] = q
                self.joints.append((ros2.to_seconds(msg.header.stamp), q))

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
    from depthguard.runner.chain import carried_camera

    cams = [camera_at_size(c, d.shape[1], d.shape[0]) for c, d in zip(cams0, depths, strict=True)]
    for k, link in carried:
        if q_cams.get(k) is None:
            return None
        cams[k] = carried_camera(cams[k], model, q_cams[k], link)
    return cams


def _frame_set_distances(stage, cell: CellFile, cams, points, depths, masks, q_frames, q):
    """Update ``stage`` with one frame set (robot-interior corrections at the frames' joint state
    ``q_frames``, none without one) and query the control spheres at the newest joint positions ``q``:
    ``(control points, distances up to the monitor's range, the monitor's own distances or None)``."""
    from depthguard.runner.chain import self_filter_margins

    margins = None if q_frames is None else self_filter_margins(cell, cams, q_frames, points.model)
    stage.update(depths, masks, q_frames, points.model, *([margins] if margins is not None else []))
    cps = points.evaluate(q)
    res = stage.query(cps.centres, cps.radii)
    res = stage.query_far(cps.centres, cps.radii, res)  # SSM: beyond rho too (docs/ssm.md)
    monitor = getattr(stage, "query_monitor", None)  # (with a background: SSM's own distances)
    return cps, res, (monitor(cps.centres, cps.radii) if monitor is not None else None)


def run_distance_node(
    cell: CellFile, *, duration: float | None = None, log: str | None = None, stop: StopFlag | None = None, **kw
) -> dict:
    """Run the distance node until ``duration`` s or SIGTERM; returns counters."""
    from depthguard.runner.chain import (
        cell_control_points,
        cell_distance_stage,
        check_camera_parents,
        check_chain_support,
        load_cell_robot,
    )

    check_chain_support(cell)
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
    fs = _FrameSets(names, len(model.joint_names))
    lock, ev, ready, joint, on_js, on_depth, on_mask = (
        fs.lock,
        fs.ev,
        fs.ready,
        fs.joint,
        fs.on_js,
        fs.on_depth,
        fs.on_mask,
    )

    subs = [node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", on_js)]
    for n in names:
        subs.append(node.subscribe(top.depth[n], "sensor_msgs/msg/Image", on_depth(n)))
        subs.append(node.subscribe(top.mask[n], "sensor_msgs/msg/Image", on_mask(n)))
    pub = node.publisher(top.distances, "depthguard_msgs/msg/ControlPointDistances")
    pub_mon = node.publisher(top.monitor_distances, "depthguard_msgs/msg/ControlPointDistances")
    stage, stage_sizes = None, []
    queries = 0
    t_start = time.time()
    try:
        while not stop and (duration is None or time.time() - t_start < duration):
            if not ev.wait(0.05):
                continue
            with lock:
                ev.clear()
                if len(ready) < len(names) or joint["q"] is None:
                    continue
                sets = [ready.pop(n) for n in names]
                q = joint["q"].copy()
                q_frames = fs.q_at(sets[0][0])  # the robot where the principal frame saw it
                q_cams = {k: fs.q_at(sets[k][0]) for k, _ in carried}
            depths, masks = [s[1] for s in sets], [s[2] for s in sets]
            sizes = [np.shape(d) for d in depths]
            if stage is None or carried or sizes != stage_sizes:  # (a camera may change its resolution)
                cams = frame_set_cameras(cams0, depths, model, carried, q_cams)
                if cams is None:
                    jl.write(ev="skipped", reason="no joint state for a carried camera's frame")
                    stage = None  # no distances from this frame set: they go stale, the controller stops
                    continue
                stage, stage_sizes = cell_distance_stage(cell, cams), sizes
            t_start_compute = time.time()
            w0 = time.perf_counter()
            try:
                cps, res, mres = _frame_set_distances(stage, cell, cams, points, depths, masks, q_frames, q)
            except ValueError as exc:  # a malformed frame set (a mask of another size...): no distances from it
                jl.write(ev="skipped", reason=str(exc))
                stage = None
                continue
            w1 = time.perf_counter()
            t_data = min(s[0] for s in sets)
            p = pub.publish(ros2.query_msg(t_data, points.names, cps.centres, cps.radii, res, rho=rho)) * 1e-9
            if mres is not None:
                rng = getattr(stage.monitor, "ssm_range", None) or rho  # (the monitor's range)
                pub_mon.publish(ros2.query_msg(t_data, points.names, cps.centres, cps.radii, mres, rho=rng))
            queries += 1
            jl.write(
                ev="distances", stamp=t_data, frame_pub=max(s[3] for s in sets), recv=max(s[4] for s in sets),
                start=t_start_compute, pub=p, compute=w1 - w0,
            )  # fmt: skip
    finally:
        out = {"queries": queries, "dropped": {s.topic: dict(s.dropped) for s in subs if s.dropped}}
        out["shared_memory_samples"] = {s.topic: [s.shm_received, s.received] for s in subs}
        jl.write(ev="summary", **out)
        node.close()
        jl.close()
    return out
