"""What every DepthGuard node shares: names, ports, topics, the Zenoh session of a cell, stopping cleanly.

Node names of a cell (in this order; node *k* listens on ``network.base_port + k`` of ``network.host``):
``sim``, one per camera (the camera's name), ``distance``, ``controller``, ``monitor``, ``run``, ``view``.
Every node connects to all the others' ports and to ``network.connect`` (the ROS 2 router by default), so
DepthGuard's nodes talk peer to peer on loopback without a router and a ROS 2 system sees them through it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from depthguard.camera import Camera
from depthguard.io.cellfile import PER_NODE, CellFile, node_names, node_tls_files, per_node_certificates
from depthguard.io.ros2 import TASK_TOPIC

__all__ = [
    "node_names",
    "open_node",
    "node_certificate",
    "node_access_control",
    "PER_NODE",
    "Topics",
    "camera_at_size",
    "StopFlag",
    "JsonLog",
    "json_line",
    "now_s",
    "JOINT_RING",
    "wait_reading",
]

#: A frame is self-filtered (camera nodes) or corrected for the robot's interior (distance node) only with
#: joint states at most this far (s) from its stamp.
MAX_JOINT_SKEW = 0.05

#: Joint states kept between two reads by a node that needs them once per frame (0.4 s at 1 kHz).
JOINT_RING = 400


def wait_reading(ev: threading.Event, ring: Any, every: float = 0.005) -> bool:
    """Wait up to ``every`` s for ``ev`` (a frame came), reading what waits in ``ring`` (a ``pull``
    :class:`~depthguard.io.zenoh_transport.Subscription`, the joint states) before and after: so that a node
    that needs the joint states once per frame is not woken for each of them while it computes. Returns
    whether ``ev`` is set."""
    ring.drain()
    got = ev.wait(every)
    ring.drain()
    return got


def _endpoint(cell: CellFile, port: int) -> str:
    net = cell.network
    proto = "tls" if net.get("tls_certificate") else "tcp"
    host = net.get("host", "127.0.0.1")
    host = f"[{host}]" if ":" in host else host
    return f"{proto}/{host}:{port}"


def open_node(cell: CellFile, name: str, *, domain: int | None = None, connect: list[str] | None = None):
    """The :class:`~depthguard.io.zenoh_transport.ZenohNode` of node ``name`` of ``cell``.

    Args:
        domain: ROS domain id (default: the cell file's ``network.domain``).
        connect: extra endpoints (default: the cell file's ``network.connect``).
    """
    from depthguard.io.zenoh_transport import ZenohNode

    names = node_names(cell)
    if name not in names:
        raise ValueError(f"node name must be one of {names}, got {name!r}")
    net = cell.network or {"base_port": 7460, "connect": ["tcp/127.0.0.1:7447"], "domain": 0}
    base = int(net["base_port"])
    idx = names.index(name)
    listen = [_endpoint(cell, base + idx)]
    peers = [_endpoint(cell, base + k) for k in range(len(names)) if k != idx]
    extra = list(net["connect"]) if connect is None else list(connect)
    dom = int(net.get("domain", 0)) if domain is None else int(domain)
    tls, acl = None, None
    if net.get("tls_certificate"):
        crt, key = node_certificate(net, name)
        tls = {
            "root_ca_certificate": net["tls_root_ca"],
            "listen_certificate": crt,
            "listen_private_key": key,
            "connect_certificate": crt,
            "connect_private_key": key,
            "enable_mtls": True,
        }
        if per_node_certificates(net):
            acl = node_access_control(cell, dom)
    return ZenohNode(name, domain=dom, listen=listen, connect=peers + extra, tls=tls, access_control=acl)


def node_certificate(net: dict[str, Any], name: str) -> tuple[str, str]:
    """Node ``name``'s certificate and private key (paths) from a cell's ``[network]`` table: the same pair
    for every node, or, with ``{node}`` in the paths, the node's own pair, whose certificate must have the
    node's name as its common name (Zenoh's access control identifies the node by it)."""
    from depthguard.io.zenoh_acl import certificate_common_name

    crt, key = node_tls_files(net, name)
    if not per_node_certificates(net):
        return crt, key
    for k, path in (("tls_certificate", crt), ("tls_private_key", key)):
        if not Path(path).is_file():
            raise ValueError(f"network.{k}: node {name!r} has no file {path}")
    cn = certificate_common_name(crt)
    if cn != name:
        raise ValueError(
            f"network.tls_certificate: {crt} has the common name {cn!r}; with one certificate per node it"
            f" must be the node's name {name!r} (Zenoh's access control identifies the node by it)"
        )
    return crt, key


def node_access_control(cell: CellFile, domain: int) -> dict[str, Any]:
    """Zenoh's ACL section for a node of ``cell`` (:mod:`depthguard.io.zenoh_acl`): only the certificates
    named in ``network.publishers`` may publish distances and joint commands."""
    from depthguard.io.rmw_zenoh import topic_keyexpr
    from depthguard.io.zenoh_acl import access_control

    open_, protected = Topics.of(cell).typed()
    keys = [[topic_keyexpr(domain, t, ty) for t, ty in group] for group in (open_, protected)]
    return access_control(keys[0], keys[1], list(cell.network.get("publishers", ["distance", "controller"])))


@dataclasses.dataclass(frozen=True)
class Topics:
    """The topics of a cell's nodes (see the README table)."""

    joint_states: str
    task: str
    command: str
    command_trajectory: str
    command_array: str
    distances: str
    monitor_distances: str
    status: str
    raw: dict[str, str]
    depth: dict[str, str]
    mask: dict[str, str]

    @classmethod
    def of(cls, cell: CellFile) -> Topics:
        t = cell.topics
        return cls(
            joint_states=t["joint_states"],
            task=TASK_TOPIC,
            command="/depthguard/joint_command",
            command_trajectory=t["command"],
            command_array=t["command_array"],
            distances=t["distances"],
            monitor_distances=t["monitor_distances"],
            status=t["status"],
            raw={c.name: c.topic or f"/{c.name}/depth/image_raw" for c in cell.cameras},
            depth={c.name: f"/depthguard/{c.name}/depth" for c in cell.cameras},
            mask={c.name: f"/depthguard/{c.name}/robot_mask" for c in cell.cameras},
        )

    def typed(self) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
        """``(open, protected)``: the ``(topic, ROS type)`` pairs that the nodes exchange; the protected
        ones (distances and joint commands) only the cell's ``network.publishers`` may publish."""
        img = "sensor_msgs/msg/Image"
        open_ = [
            (self.joint_states, "sensor_msgs/msg/JointState"),
            (self.task, "geometry_msgs/msg/Vector3Stamped"),
            (self.status, "depthguard_msgs/msg/ControllerStatus"),
            *[(t, img) for group in (self.raw, self.depth, self.mask) for t in group.values()],
        ]
        dist = "depthguard_msgs/msg/ControlPointDistances"
        protected = [
            (self.distances, dist),
            (self.monitor_distances, dist),
            (self.command, "sensor_msgs/msg/JointState"),
            (self.command_array, "std_msgs/msg/Float64MultiArray"),
            (self.command_trajectory, "trajectory_msgs/msg/JointTrajectory"),
        ]
        return open_, protected


def camera_at_size(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` at another image size with the same field of view (intrinsics scaled)."""
    if (width, height) == (camera.width, camera.height):
        return camera
    sx, sy = width / camera.width, height / camera.height
    if abs(sx - sy) > 1e-6:
        raise ValueError(f"image {width}x{height} is not a scaled {camera.width}x{camera.height} image")
    return dataclasses.replace(
        camera, width=width, height=height, fx=camera.fx * sx, fy=camera.fy * sy, cx=camera.cx * sx, cy=camera.cy * sy
    )


class StopFlag:
    """Set by SIGTERM / SIGINT (or :meth:`set`): nodes finish their loop, close their session and exit 0."""

    def __init__(self) -> None:
        self._ev = threading.Event()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: self._ev.set())
            signal.signal(signal.SIGINT, lambda *_: self._ev.set())

    def set(self) -> None:
        self._ev.set()

    def __bool__(self) -> bool:
        return self._ev.is_set()

    def wait(self, s: float) -> bool:
        return self._ev.wait(s)


def _finite_or_none(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite_or_none(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite_or_none(x) for x in v]
    return v


def json_line(rec: dict) -> str:
    """One strict JSON object (RFC 8259) on one line: NaN and ±inf, which Python writes as the non-standard
    ``NaN`` / ``Infinity`` that strict parsers refuse, become ``null``, as in the distances' JSON (README).
    numpy numbers become floats."""
    try:
        return json.dumps(rec, default=float, allow_nan=False)
    except ValueError:  # (a non-finite number somewhere: the rare path)
        return json.dumps(_finite_or_none(json.loads(json.dumps(rec, default=float))), allow_nan=False)


class JsonLog:
    """JSON-lines log file (one object per line, flushed), or nothing when ``path`` is None."""

    def __init__(self, path: str | Path | None) -> None:
        self._f = open(path, "a", encoding="utf-8") if path else None  # noqa: SIM115
        self._lock = threading.Lock()

    def write(self, **rec: Any) -> None:
        if self._f is None:
            return
        with self._lock:
            self._f.write(json_line(rec) + "\n")
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()


def now_s() -> float:
    """Wall-clock time, s since the Unix epoch: the clock of every stamp between nodes."""
    return time.time()


def realtime_scheduling(priority: int | None) -> str:
    """Ask for ``SCHED_FIFO`` at ``priority`` (1-99) for the calling thread and the threads it starts later
    (call it before the Zenoh session opens); returns what the thread runs with, for the node's summary.

    A refusal (no ``CAP_SYS_NICE``, a container, not Linux) is not an error: the node runs with the default
    policy and the returned text says why (``docs/nodes.md``, "Latency and CPUs")."""
    if priority is None:
        return "SCHED_OTHER"
    if isinstance(priority, bool) or not isinstance(priority, int) or not 1 <= priority <= 99:
        raise ValueError(f"--rt-priority must be an integer in [1, 99] (SCHED_FIFO), got {priority!r}")
    if not hasattr(os, "sched_setscheduler"):
        return f"SCHED_OTHER (SCHED_FIFO {priority} refused: not available on this system)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return f"SCHED_OTHER (SCHED_FIFO {priority} refused: {exc.strerror or exc})"
    got = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority  # (what the thread runs with now)
    return f"SCHED_FIFO {got[1]}" if got[0] == os.SCHED_FIFO else f"policy {got[0]} (SCHED_FIFO {priority} not taken)"


@contextlib.contextmanager
def realtime(priority: int | None) -> Iterator[str]:
    """:func:`realtime_scheduling` for the length of a ``with`` block (yields its text); the calling thread's
    previous policy and priority come back afterwards."""
    before = (os.sched_getscheduler(0), os.sched_getparam(0)) if hasattr(os, "sched_getscheduler") else None
    try:
        yield realtime_scheduling(priority)
    finally:
        if before is not None:
            try:
                os.sched_setscheduler(0, *before)
            except OSError:
                pass
