"""The ``sim`` node: the simulated cell as a robot driver and camera drivers would appear on ROS 2.

It runs the scenario's MuJoCo cell on the wall clock and publishes what real drivers publish: the joint
states (``sensor_msgs/JointState``, every physics catch-up step, at most the controller rate), each camera's
raw depth image (``sensor_msgs/Image`` 32FC1, at the camera rate) and the task's desired end-effector
velocity; it takes the joint command (``sensor_msgs/JointState`` on ``/depthguard/joint_command``) from the
nodes allowed by the cell file.

**Driver-side watchdog**: when no command has arrived for ``watchdog`` seconds (default 0.05 s), the driver
holds the arm where it is (servo to the current position, zero velocity), as a ros2_control driver must do
when DepthGuard dies; it resumes following commands as soon as they come back.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.io.joint_state_cdr import joint_state_cdr
from depthguard.io.rmw_zenoh import QOS_SENSOR_DATA
from depthguard.nodes.common import JsonLog, StopFlag, Topics, now_s, open_node

__all__ = ["run_sim_node", "joint_command"]


def joint_command(msg, names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(q, qdot)`` of a ``sensor_msgs/JointState`` joint command in the driver's joint order ``names``.

    The message's joints are matched by name, in any order, as a ros2_control driver does (by position only
    when the message names none; :func:`depthguard.io.ros2.joints_in_order`). Raises ``ValueError`` for a
    command that lacks a joint, names one twice, has no velocities, or is not finite: the driver keeps its
    last command and its watchdog holds the arm once that is ``watchdog`` seconds old.
    """
    q, qd = ros2.joints_in_order(msg, names)
    if qd is None:
        raise ValueError("joint command: no velocities")
    return q, qd


def run_sim_node(
    cell: CellFile,
    scenario: str,
    *,
    quick: bool = False,
    duration: float | None = None,
    watchdog: float = 0.05,
    log: str | None = None,
    stop: StopFlag | None = None,
    **node_kw,
) -> dict:
    """Run until ``duration`` (s, wall clock; None = until SIGTERM). Returns counters."""
    from depthguard.runner import open_source

    stop = stop if stop is not None else StopFlag()
    jl = JsonLog(log)
    src = open_source(f"sim:{scenario}", cell, _names(cell), quick=quick)
    sim, names = src.cell, list(src.joint_names)
    top = Topics.of(cell)
    node = open_node(cell, "sim", **node_kw)
    latch = _CommandLatch(names, watchdog)
    allowed = set(cell.network.get("publishers", ["controller"])) if cell.network else None
    sub = node.subscribe(top.command, "sensor_msgs/msg/JointState", latch.on_cmd, allowed=allowed)
    pub_js = node.publisher(top.joint_states, "sensor_msgs/msg/JointState")
    pub_task = node.publisher(top.task, "geometry_msgs/msg/Vector3Stamped")
    pub_img = {c.name: node.publisher(top.raw[c.name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA) for c in cell.cameras}
    dt = src.control_dt
    frame_period = 1.0 / float(cell.cameras[0].rate)
    t0 = now_s()
    t_phys, next_frame, frames, held, n_js = 0.0, 0.0, 0, 0, 0
    try:
        while not stop and (duration is None or now_s() - t0 < duration):
            wall = now_s()
            t = wall - t0
            q_cmd, qd_cmd, is_held = latch.command(wall, sim.q())
            held += is_held
            n = int(min(max((t - t_phys) / dt, 1), 50))
            sim.update_people(t)
            sim.step(q_cmd, qd_cmd, n)
            t_phys += n * dt
            stamp = now_s()
            q, qd = sim.q(), sim.qd()
            pub_js.put_cdr(joint_state_cdr(stamp, names, q, qd))
            n_js += 1
            xd = src.task.velocity(src.kin.evaluate(q).centres[0])  # the task's desired end-effector velocity
            pub_task.publish(ros2.vector3_stamped_msg(stamp, "world", xd))
            if t >= next_frame:
                next_frame = max(next_frame + frame_period, t)
                _publish_frames(sim, src.cams, cell, pub_img, jl)
                frames += 1
            jl.write(ev="js", t=stamp, qd_max=float(np.max(np.abs(qd))), held=bool(is_held))
            spare = dt - (now_s() - wall)
            if spare > 0:
                time.sleep(spare)
    finally:
        out = {"frames": frames, "joint_states": n_js, "held_cycles": held, "dropped": dict(sub.dropped)}
        out["rejected_publishers"] = sorted(sub.rejected_publishers)
        out["unlisted_publishers"] = sorted(sub.unlisted_publishers)
        node.close()
        src.close()
        jl.close()
    return out


class _CommandLatch:
    """The driver's newest joint command (from its subscription's thread) and its watchdog."""

    def __init__(self, names: list[str], watchdog: float) -> None:
        self.names, self.watchdog = names, float(watchdog)
        self.lock = threading.Lock()
        self.q: np.ndarray | None = None
        self.qd: np.ndarray | None = None
        self.t = -np.inf  # receive time of the newest command, s

    def on_cmd(self, msg, att, recv_ns) -> None:
        q, qd = joint_command(msg, self.names)  # (a ValueError: refused, counted by the subscription)
        with self.lock:
            self.q, self.qd, self.t = q, qd, recv_ns * 1e-9

    def command(self, wall: float, q_now: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """``(q, qdot, held)`` to servo to at wall time ``wall`` (s): the newest command, or, when none came
        within the watchdog, the arm held where it is (``q_now``, zero velocity)."""
        with self.lock:
            q, qd, t = self.q, self.qd, self.t
        if q is None or wall - t > self.watchdog:
            return q_now, np.zeros(len(self.names)), True
        return q, qd, False


def _publish_frames(sim, cams: list, cell: CellFile, pub_img: dict, jl: JsonLog) -> None:
    """Every camera's raw depth image (32FC1) of the cell as it is now, one stamp for all."""
    sim.forward()
    ts = now_s()
    for c, cam in zip(cell.cameras, cams, strict=True):
        depth = cam.capture(sim.data)
        pub_ns = pub_img[c.name].publish(ros2.image_msg(ts, c.frame_id or c.name, depth, "32FC1"))
        jl.write(ev="frame", camera=c.name, stamp=ts, pub=pub_ns * 1e-9)


def _names(cell: CellFile) -> tuple[str, ...]:
    from depthguard.runner.chain import load_cell_robot

    return load_cell_robot(cell).joint_names
