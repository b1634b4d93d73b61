"""The controller node: the avoidance controller at the cell's control rate on Zenoh.

Subscribes the joint states, the task velocity and the distances (these only from the nodes named in the
cell file's ``network.publishers``; with a background, also the monitor's own ``monitor_distances``, used
only together with the distances of the same stamp, else the monitor takes the distances themselves, the
safe side); every period it runs one cycle of
:class:`~depthguard.control.AvoidanceController` on the wall clock and publishes the joint command
(``sensor_msgs/JointState`` on ``/depthguard/joint_command``, every cycle), the ros2_control forms
(``std_msgs/Float64MultiArray`` velocities and ``trajectory_msgs/JointTrajectory``, every 10th cycle) and the
controller status (every 10th cycle and on every change).

Safety: the controller's own stale-data rules do the work. When distances stop (a camera or the distance
node died, the network is partitioned) their stamp ages past ``distance_timeout`` and the controller brakes
the arm jerk-limited (``STOP_STALE_DISTANCES``); the node keeps running and the arm resumes once fresh
distances have been valid for ``resume_time``. Duplicated, reordered and stale samples never reach it
(:mod:`depthguard.io.zenoh_transport`).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.io.joint_state_cdr import joint_state_cdr
from depthguard.nodes.common import JsonLog, StopFlag, Topics, now_s, open_node

__all__ = ["run_controller_node"]


class _Inputs:
    """The controller's newest inputs, written by the Zenoh callbacks under one lock.

    ``joint_names``: the robot model's joints; joint states are matched by name, in any order (a
    ros2_control ``joint_state_broadcaster`` orders them by its own configuration), and must carry
    velocities. ``names``: the control points' names, in the controller's order. A distances message for other points
    (another number, order or names: a distance node with another cell file) is refused with ``ValueError``,
    which its subscription counts (``refused by the node``): its distances would otherwise be applied to the
    wrong points. The last good distances then go stale and the controller stops the arm.
    """

    def __init__(
        self, joint_names: list[str] | tuple[str, ...], N: int, names: list[str] | tuple[str, ...] | None = None
    ) -> None:
        self.joint_names, self.N = list(joint_names), N
        self.names = None if names is None else [str(x) for x in names]
        self.lock = threading.Lock()
        self.st: dict = {"q": None, "qd": None, "tj": -np.inf, "xd": np.zeros(3), "d": None, "dirs": None}
        self.st.update(td=-np.inf, dpub=None, md=None, mdirs=None, tm=np.nan)

    def on_js(self, msg, att, recv_ns) -> None:
        q, qd = ros2.joints_in_order(msg, self.joint_names)  # (by name, in the model's order; ValueError: refused)
        if qd is None:
            raise ValueError("JointState without velocities: the controller needs them")
        with self.lock:
            self.st.update(q=q, qd=qd, tj=ros2.to_seconds(msg.header.stamp))

    def on_task(self, msg, att, recv_ns) -> None:
        with self.lock:
            self.st["xd"] = np.array([msg.vector.x, msg.vector.y, msg.vector.z], float)

    def _pair(self, msg) -> tuple[np.ndarray, np.ndarray]:
        from depthguard.runner.chain import controller_arrays

        got = [str(p.name) for p in msg.points]
        if len(got) != self.N or (self.names is not None and got != self.names):
            want = self.names if self.names is not None else f"{self.N} points"
            raise ValueError(f"distances for control points {got[:12]}, expected {want} (another cell file?)")
        d = [p.distance for p in msg.points]
        return controller_arrays(d, [[p.direction.x, p.direction.y, p.direction.z] for p in msg.points], self.N)

    def on_dist(self, msg, att, recv_ns) -> None:
        d, dirs = self._pair(msg)
        with self.lock:
            self.st.update(d=d, dirs=dirs, td=ros2.to_seconds(msg.header.stamp), dpub=att.stamp_ns * 1e-9)

    def on_monitor(self, msg, att, recv_ns) -> None:
        d, dirs = self._pair(msg)
        with self.lock:
            self.st.update(md=d, mdirs=dirs, tm=ros2.to_seconds(msg.header.stamp))

    def cycle_input(self, s: dict, t: float):
        """The :class:`~depthguard.control.cycle.CycleInput` of a snapshot ``s`` of :attr:`st` at ``t``: the
        monitor's distances only when they come from the same frame set (stamp) as the distances."""
        from depthguard.control.cycle import CycleInput

        mon = (s["md"], s["mdirs"]) if s["md"] is not None and s["tm"] == s["td"] else (None, None)
        return CycleInput(t, s["q"], s["qd"], s["tj"], s["xd"], s["d"], s["dirs"], s["td"], *mon)


def run_controller_node(
    cell: CellFile, *, duration: float | None = None, log: str | None = None, stop: StopFlag | None = None, **kw
) -> dict:
    """Run the controller node until ``duration`` s or SIGTERM; returns counters and cycle times."""
    from depthguard.control.cycle import AvoidanceController
    from depthguard.control.warmup import warm_up
    from depthguard.runner.chain import _controller_config, cell_control_points, load_cell_robot

    stop = stop if stop is not None else StopFlag()
    jl = JsonLog(log)
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    config = _controller_config(cell)
    w0 = time.perf_counter()
    jl.write(ev="warm_up", statuses=warm_up(points, config, model), s=time.perf_counter() - w0)
    ctrl = AvoidanceController(points, config)
    N = points.n_points
    top = Topics.of(cell)
    node = open_node(cell, "controller", **kw)
    inp = _Inputs(model.joint_names, N, points.names)
    subs = _subscribe(node, top, inp, cell)
    pub_cmd = node.publisher(top.command, "sensor_msgs/msg/JointState")
    pub_arr = node.publisher(top.command_array, "std_msgs/msg/Float64MultiArray")
    pub_traj = node.publisher(top.command_trajectory, "trajectory_msgs/msg/JointTrajectory")
    pub_st = node.publisher(top.status, "depthguard_msgs/msg/ControllerStatus")
    names = list(model.joint_names)
    dt = config.dt
    cycles, last_status, last_dpub = 0, None, None
    statuses: dict[str, int] = {}
    cycle_wall: list[float] = []
    t_start = now_s()
    next_t = t_start
    try:
        while not stop and (duration is None or now_s() - t_start < duration):
            w0 = time.perf_counter()
            t = now_s()
            with inp.lock:
                s = dict(inp.st)
            out = ctrl.step(inp.cycle_input(s, t))
            p = pub_cmd.put_cdr(joint_state_cdr(t, names, out.q_cmd, out.qdot_cmd)) * 1e-9  # (its fast path)
            name = out.status.name
            statuses[name] = statuses.get(name, 0) + 1
            if s["dpub"] is not None and s["dpub"] != last_dpub:
                last_dpub = s["dpub"]
                jl.write(ev="command", dist_pub=last_dpub, pub=p, status=name)
            if cycles % 10 == 0 or name != last_status:
                pub_st.publish(ros2.status_msg(t, name, out.scale))
                jl.write(ev="status", t=t, status=name, qd_max=float(np.max(np.abs(out.qdot_cmd))))
                last_status = name
            if cycles % 10 == 0:
                pub_arr.publish(ros2.float64_array_msg(out.qdot_cmd))
                pub_traj.publish(ros2.joint_trajectory_msg(t, names, out.q_cmd, out.qdot_cmd, dt))
            cycles += 1
            cycle_wall.append(time.perf_counter() - w0)
            next_t += dt
            spare = next_t - now_s()
            if spare > 0:
                time.sleep(spare)
            elif spare < -0.1:
                next_t = now_s()  # fell far behind (overloaded machine): do not try to catch up
    finally:
        out_d = _report(cycles, statuses, cycle_wall, subs)
        node.close()
        jl.close()
    return out_d


def _subscribe(node, top: Topics, inp: _Inputs, cell: CellFile) -> list:
    """The controller's subscriptions, the distances' first: distances and the monitor's distances only from
    the cell's ``network.publishers``; joint states and the task from anyone."""
    allowed = set(cell.network.get("publishers", ["distance"])) if cell.network else None
    sub_d = node.subscribe(top.distances, "depthguard_msgs/msg/ControlPointDistances", inp.on_dist, allowed=allowed)
    return [
        sub_d,
        node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", inp.on_js),
        node.subscribe(top.task, "geometry_msgs/msg/Vector3Stamped", inp.on_task),
        node.subscribe(top.monitor_distances, sub_d.typename, inp.on_monitor, allowed=allowed),
    ]


def _report(cycles: int, statuses: dict, cycle_wall: list[float], subs: list) -> dict:
    """The node's final report: cycles, statuses, cycle times (ms) and what its subscriptions dropped."""
    cw = np.asarray(cycle_wall) * 1e3
    sub_d = subs[0]
    return {
        "cycles": cycles,
        "statuses": statuses,
        "cycle_ms_median": float(np.median(cw)) if cw.size else None,
        "cycle_ms_p99": float(np.percentile(cw, 99)) if cw.size else None,
        "dropped": dict(sub_d.dropped),  # (the distances')
        "dropped_by_topic": {x.topic: dict(x.dropped) for x in subs if x.dropped},
        "missed_by_topic": {x.topic: x.missed for x in subs if x.missed},  # (samples that never came)
        "rejected_publishers": sorted(sub_d.rejected_publishers),
        "unlisted_publishers": sorted(sub_d.unlisted_publishers),
    }
