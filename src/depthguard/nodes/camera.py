"""A camera node: one camera's frame stage (source -> self-filter -> frame preparation) on Zenoh.

Subscribes the camera's raw depth image (``sensor_msgs/Image`` 16UC1 mm or 32FC1 m, from the ``sim`` node or
any ROS 2 camera driver on rmw_zenoh) and the joint states; removes the robot's own pixels with the joint
positions nearest the frame's stamp and publishes the prepared frame: the depth (32FC1, the raw frame's
stamp) on ``/depthguard/<camera>/depth`` and the robot mask (mono8, 255 = robot) on
``/depthguard/<camera>/robot_mask``. Only the newest frame is processed (a slow node skips frames, it never
queues them); a frame without joint states within 50 ms of its stamp is not published. Every frame's sensor
health is checked (:class:`FrameGate`): while the camera is frozen, covered or moved, its frames are withheld,
so the distances go stale and the controller stops.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque

import numpy as np

from depthguard.camera import Camera
from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.io.rmw_zenoh import QOS_SENSOR_DATA
from depthguard.io.ros2 import mask_msg
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
from depthguard.robot.health import CameraHealth

__all__ = ["run_camera_node", "mask_msg", "prepare_frame", "prepare_frame_at", "FrameGate", "HealthWorker"]


def prepare_frame(msg, cam0, cc, model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One raw ``sensor_msgs/Image`` prepared as the node publishes it: ``(depth, mask)``
    (:func:`prepare_frame_at`, without the camera)."""
    return prepare_frame_at(msg, cam0, cc, model, q)[1:]


def prepare_frame_at(msg, cam0, cc, model, q: np.ndarray) -> tuple[Camera, np.ndarray, np.ndarray]:
    """One raw ``sensor_msgs/Image`` prepared as the node publishes it: ``(camera, depth, mask)``, the camera at
    the image's size and where it was at this frame, the depth (H, W) in metres (NaN = no reading) and the
    robot mask (H, W) bool, self-filtered at joint positions ``q``.

    ``cam0``: the camera (in its parent link's frame when the robot carries it); ``cc``: its cell-file entry;
    ``model``: the robot. Raises ``ValueError`` for an image that cannot be used: not a depth encoding, fewer
    bytes than its size says, or a size that is not a scaled image of the camera's.
    """
    from depthguard.robot.selffilter import self_filter
    from depthguard.runner.carried import carried_camera

    depth = ros2.image_to_depth(msg)
    cam = camera_at_size(cam0, depth.shape[1], depth.shape[0])
    if cc.parent != "world":  # carried by the robot: where the link was at this frame
        cam = carried_camera(cam, model, q, cc.parent)
    kw = {}
    if cc.noise_coeff > 0:  # the margin covers the depth noise (runner.chain.self_filter_margins)
        from depthguard.sim.pipeline import model_filter_margin

        kw["margin"] = model_filter_margin(cam, q, model, cc.noise_coeff)
    return cam, depth, np.asarray(self_filter(cam, depth, q, model, with_depth=False, **kw)[0])


class FrameGate:
    """Sensor health of one camera node (:class:`~depthguard.robot.health.CameraHealth`, docs/real-cell.md §7):
    a frame is published only while the camera is healthy, so a frozen, covered or moved camera stops sending
    and the distances go stale: the controller stops within ``distance_timeout`` (``STOP_STALE_DISTANCES``).

    Each frame is checked after it is published (or withheld), off the frame's latency path: a fault that
    the frame itself shows withholds the frames after it until ``clear_frames`` healthy frames in a row
    have passed. :attr:`withheld` counts the frames withheld per fault; :meth:`after` returns the change
    (``"frozen"``, ..., or ``"healthy"``) when the state changes, else None.
    """

    def __init__(self, name: str, model) -> None:
        self.name, self.model = name, model
        self.health: CameraHealth | None = None
        self.withheld: dict[str, int] = {}
        self.failed: str | None = None  # (a check that raised: the gate stays shut, the safe side)

    @property
    def open(self) -> bool:
        """Whether the next frame may be published."""
        return self.failed is None and (self.health is None or self.health.fault is None)

    def withhold(self, why: str | None = None) -> None:
        """Count a frame not published because of the current fault (or ``why``)."""
        f = why or self.failed or (self.health.fault if self.health is not None else None) or "unknown"
        self.withheld[f] = self.withheld.get(f, 0) + 1

    def after(self, cam: Camera, depth: np.ndarray, q: np.ndarray, stamp: float) -> str | None:
        """Check the frame ``depth`` (H, W) m seen by ``cam`` at joint positions ``q`` and time ``stamp`` (s)."""
        if self.health is None or self.health.camera.shape != cam.shape:
            self.health = CameraHealth(cam, self.name, self.model)
        self.health.camera = cam  # (a carried camera moves with its link)
        before = self.health.fault
        now = self.health.check(depth, q, stamp)
        return None if now == before else (now or "healthy")


class HealthWorker:
    """Runs a :class:`FrameGate`'s checks on a thread of its own at a low CPU priority (nice ``NICE``, Linux),
    off the frame's latency path: a check costs about 4.5 ms at 640x480 (mostly the arm's predicted depth for
    the "moved" test) and would otherwise take CPU from the distance node just when the frames it waits for
    arrive. The newest frame waits in a one-slot mailbox: a check that falls behind skips frames (a frozen
    stream still repeats one image, and the stamps still advance). A check that falls more than
    ``MAX_BEHIND`` frames behind (:attr:`behind`: a starved thread) must not let frames through unchecked:
    the node withholds them ("health check behind") until it catches up. ``on_change(state, stamp)`` is
    called on the worker's thread at each change of state; a check that raises shuts the gate for good."""

    NICE = 10  # (weight 110 against 1024: it yields to the distance node, and is not starved by it)
    MAX_BEHIND = 3  # frames submitted and not yet checked

    def __init__(self, gate: FrameGate, on_change) -> None:
        self.gate, self.on_change = gate, on_change
        self._slot: tuple | None = None
        self._closed = False
        self.checked = 0  # frames checked so far
        self.submitted = 0  # frames handed over so far
        self.native_id: int | None = None  # the worker thread's id (for its priority)
        self._cv = threading.Condition()
        self._thread = threading.Thread(target=self._run, name=f"health-{gate.name}", daemon=True)
        self._thread.start()

    def submit(self, cam: Camera, depth: np.ndarray, q: np.ndarray, stamp: float) -> None:
        """Hand over a frame for checking (replaces one not yet checked)."""
        with self._cv:
            self._slot = (cam, depth, q, stamp)
            self.submitted += 1
            self._cv.notify()

    @property
    def behind(self) -> bool:
        """Whether the checks lag more than ``MAX_BEHIND`` frames behind the frames handed over."""
        return self.submitted - self.checked > self.MAX_BEHIND

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify()
        self._thread.join(5.0)

    def _run(self) -> None:
        import os

        self.native_id = threading.get_native_id()
        try:
            os.setpriority(os.PRIO_PROCESS, self.native_id, self.NICE)
        except (OSError, AttributeError):  # (not Linux: the default priority)
            pass
        while True:
            with self._cv:
                while self._slot is None and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                job, self._slot = self._slot, None
            try:
                change = self.gate.after(*job)
            except Exception as exc:  # noqa: BLE001 - reported, and the gate stays shut
                self.gate.failed = change = f"health check failed ({type(exc).__name__}: {exc})"
            with self._cv:
                self.checked = self.submitted - (self._slot is not None)  # (skipped frames count as checked)
            if change is not None:
                self.on_change(change, job[3])


def _reporting_worker(gate: FrameGate, jl: JsonLog) -> HealthWorker:
    """The gate's :class:`HealthWorker`, each change written to the log (``sensor_health``) and said on stderr."""

    def said(change: str, stamp: float) -> None:
        jl.write(ev="sensor_health", camera=gate.name, state=change, stamp=stamp)
        tail = "" if change == "healthy" else ": frames withheld"
        print(f"depthguard {gate.name}: camera {change}{tail}", file=sys.stderr)

    return HealthWorker(gate, said)


def _joint_state_at(joint_states: list, t: float) -> np.ndarray | None:
    """The joint positions of the ``(stamp, q)`` pair nearest to ``t`` (s), None when none lies within
    ``MAX_JOINT_SKEW``."""
    if not joint_states:
        return None
    tj, q = min(joint_states, key=lambda x: abs(x[0] - t))
    return q if abs(tj - t) <= MAX_JOINT_SKEW else None


def run_camera_node(
    cell: CellFile,
    name: str,
    *,
    duration: float | None = None,
    log: str | None = None,
    stop: StopFlag | None = None,
    **kw,
) -> dict:
    """Run camera node ``name`` until ``duration`` s or SIGTERM; returns counters."""
    from depthguard.runner.carried import check_camera_parents
    from depthguard.runner.chain import load_cell_robot

    cc = {c.name: c for c in cell.cameras}.get(name)
    if cc is None:
        raise ValueError(f"camera node name must be one of {[c.name for c in cell.cameras]}, got {name!r}")
    stop = stop if stop is not None else StopFlag()
    jl = JsonLog(log)
    model = load_cell_robot(cell)
    check_camera_parents(cell, model)
    heap = keep_freed_memory()  # (each frame's images reuse the pages of the last)
    cam0 = cc.build()  # (in its parent link's frame when the robot carries it)
    top = Topics.of(cell)
    node = open_node(cell, name, **kw)
    joints: deque = deque(maxlen=400)
    latest: dict = {"msg": None}
    ev = threading.Event()
    lock = threading.Lock()

    def on_js(msg, att, recv_ns):
        q, _ = ros2.joints_in_order(msg, model.joint_names)  # (by name; ValueError: refused and counted)
        with lock:
            joints.append((ros2.to_seconds(msg.header.stamp), q))

    def on_image(msg, att, recv_ns):
        with lock:
            latest["msg"], latest["pub"] = msg, att.stamp_ns
        ev.set()

    # (the joint states wait in a ring, read between frames: no thread wakes for each of them)
    sub_js = node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", on_js, pull=JOINT_RING)
    sub = node.subscribe(top.raw[name], "sensor_msgs/msg/Image", on_image)
    pub_d = node.publisher(top.depth[name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA)
    pub_m = node.publisher(top.mask[name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA)
    done = skipped = 0
    gate = FrameGate(name, model)
    worker = _reporting_worker(gate, jl)
    t_start = time.time()
    try:
        while not stop and (duration is None or time.time() - t_start < duration):
            if not wait_reading(ev, sub_js):
                continue
            ev.clear()
            with lock:
                msg, pub_in = latest["msg"], latest["pub"]
                js = list(joints)
            t = ros2.to_seconds(msg.header.stamp)
            q = _joint_state_at(js, t)
            if q is None:
                skipped += 1
                continue
            try:
                cam, depth, mask = prepare_frame_at(msg, cam0, cc, model, q)
            except ValueError as exc:
                jl.write(ev="bad_frame", error=str(exc))
                skipped += 1
                continue
            if gate.open and not worker.behind:
                fid = msg.header.frame_id
                p1 = pub_d.publish(ros2.image_msg(t, fid, depth, "32FC1"))
                pub_m.publish(mask_msg(t, fid, mask))
                done += 1
                jl.write(ev="prepared", stamp=t, pub_raw=pub_in * 1e-9, pub=p1 * 1e-9)
            else:
                gate.withhold(None if not gate.open else "health check behind")
            worker.submit(cam, depth, q, t)
    finally:
        out = {"frames": done, "skipped": skipped, "dropped": dict(sub.dropped), "freed_memory": heap}
        worker.close()
        out["withheld"] = dict(gate.withheld)  # (frames not published: the camera's sensor fault)
        out["missed"] = {s.topic: s.missed for s in (sub, sub_js) if s.missed}  # (lost, or out of a full ring)
        node.close()
        jl.close()
    return out
