"""The ``view`` node: :class:`depthguard.viz.live.LiveView` fed from a cell's nodes on Zenoh."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from depthguard.viz.live import LiveView

__all__ = ["run_view_node"]


def run_view_node(
    cell_path: str,
    *,
    port: int = 8080,
    duration: float | None = None,
    domain: int | None = None,
    connect: list[str] | None = None,
    stop: Any = None,
) -> dict[str, Any]:
    """The ``view`` node: the live view of a cell's nodes on Zenoh (prepared frames, masks, joint states,
    distances, status). Returns what it saw: ``draws``, ``frames``, ``distances``, ``status``, and ``skipped``
    (the updates or parts of one it could not draw, by kind: :attr:`LiveView.skipped`)."""
    from depthguard.io import ros2
    from depthguard.io.cellfile import read_cell
    from depthguard.nodes.common import StopFlag, Topics, open_node
    from depthguard.runner.chain import cell_control_points, load_cell_robot

    cell = read_cell(cell_path)
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    view = LiveView(cell, model, points, [c.build() for c in cell.cameras], port=port)
    top = Topics.of(cell)
    node = None
    names = [c.name for c in cell.cameras]
    frames: dict[str, np.ndarray] = {}
    masks: dict[str, np.ndarray] = {}
    lock = threading.Lock()

    def on_js(msg, att, recv_ns):
        view.set_joints(ros2.joints_in_order(msg, model.joint_names)[0])

    def on_depth(n):
        def cb(msg, att, recv_ns):
            with lock:
                frames[n] = ros2.image_to_depth(msg)
                if len(frames) == len(names):
                    view.set_frames([frames[k] for k in names], [masks.get(k) for k in names])

        return cb

    def on_mask(n):
        def cb(msg, att, recv_ns):
            with lock:
                masks[n] = ros2.image_to_mask(msg)

        return cb

    def on_dist(msg, att, recv_ns):
        P = msg.points
        view.set_distances(
            [[p.centre.x, p.centre.y, p.centre.z] for p in P], [p.radius for p in P],
            [p.distance for p in P], [[p.direction.x, p.direction.y, p.direction.z] for p in P],
        )  # fmt: skip

    stop = stop if stop is not None else StopFlag()
    try:  # (whatever fails here, the session and the web server close: neither keeps the process alive)
        node = open_node(cell, "view", domain=domain, connect=connect)
        node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", on_js)
        for n in names:
            node.subscribe(top.depth[n], "sensor_msgs/msg/Image", on_depth(n))
            node.subscribe(top.mask[n], "sensor_msgs/msg/Image", on_mask(n))
        node.subscribe(top.distances, "depthguard_msgs/msg/ControlPointDistances", on_dist)
        node.subscribe(
            top.status, "depthguard_msgs/msg/ControllerStatus", lambda m, a, t: view.set_status(str(m.status))
        )
        print(f"depthguard view: http://127.0.0.1:{port}", flush=True)
        t0 = time.time()
        while not stop and (duration is None or time.time() - t0 < duration):
            stop.wait(0.2)
    finally:
        if node is not None:
            node.close()
        view.close()
    return {
        "draws": view.draws,
        "frames": len(view.times["frames"]),
        "distances": len(view.times["queries"]),
        "status": view.state["status"],
        "skipped": dict(view.skipped),
    }
