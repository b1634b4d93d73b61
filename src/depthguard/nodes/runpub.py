"""``depthguard run --transport zenoh``: the one-process runner's topics published on Zenoh (node ``run``).

A sink with the recorder's hooks (:mod:`depthguard.runner.run`): the raw depth images (``sensor_msgs/Image``
32FC1) and joint states as the drivers would publish them, the robot masks, the distances, the joint command
(``sensor_msgs/JointState`` every tick, ``Float64MultiArray`` / ``JointTrajectory`` every 10th) and the
controller status (every 10th tick and on change). Stamps are wall-clock: the run's start plus the source's
clock, so that a ROS 2 consumer sees ordinary stamps.
"""

from __future__ import annotations

from typing import Any

from depthguard.io import ros2
from depthguard.io.cellfile import CellFile
from depthguard.io.joint_state_cdr import joint_state_cdr
from depthguard.io.rmw_zenoh import QOS_SENSOR_DATA
from depthguard.io.ros2 import mask_msg
from depthguard.nodes.common import Topics, now_s, open_node

__all__ = ["ZenohRunPublisher"]


class ZenohRunPublisher:
    """Publishes a run's inputs and outputs on Zenoh in the rmw_zenoh format."""

    def __init__(self, cell: CellFile, chain: Any, *, domain: int | None = None, connect: list[str] | None = None):
        self.cell, self.chain = cell, chain
        self.top = Topics.of(cell)
        self.node = open_node(cell, "run", domain=domain, connect=connect)
        n = self.node
        self.p_img = {
            c.name: n.publisher(self.top.raw[c.name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA) for c in cell.cameras
        }
        self.p_mask = {
            c.name: n.publisher(self.top.mask[c.name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA) for c in cell.cameras
        }
        self.p_js = n.publisher(self.top.joint_states, "sensor_msgs/msg/JointState")
        self.p_dist = n.publisher(self.top.distances, "depthguard_msgs/msg/ControlPointDistances")
        self.p_mon = n.publisher(self.top.monitor_distances, "depthguard_msgs/msg/ControlPointDistances")
        self.p_cmd = n.publisher(self.top.command, "sensor_msgs/msg/JointState")
        self.p_arr = n.publisher(self.top.command_array, "std_msgs/msg/Float64MultiArray")
        self.p_traj = n.publisher(self.top.command_trajectory, "trajectory_msgs/msg/JointTrajectory")
        self.p_st = n.publisher(self.top.status, "depthguard_msgs/msg/ControllerStatus")
        self.t0 = now_s()
        self.count: dict[str, int] = {}
        self._k = 0
        self._last_status = None

    def _put(self, what: str, pub, msg) -> None:
        """Publish ``msg`` (a message, or CDR bytes ready to put) and count it under ``what``."""
        if isinstance(msg, bytes):
            pub.put_cdr(msg)
        else:
            pub.publish(msg)
        self.count[what] = self.count.get(what, 0) + 1

    def inputs(self, tick, frames) -> None:
        if frames is not None:
            for c, d in zip(self.cell.cameras, frames, strict=True):
                self._put(
                    "images",
                    self.p_img[c.name],
                    ros2.image_msg(self.t0 + tick.t_frames, c.frame_id or c.name, d, "32FC1"),
                )
        if tick.q is not None:
            js = joint_state_cdr(self.t0 + tick.t_joints, self.chain.joint_names, tick.q, tick.qdot)
            self._put("joint_states", self.p_js, js)

    def masks(self, t: float, masks) -> None:
        for c, m in zip(self.cell.cameras, masks, strict=True):
            self._put("masks", self.p_mask[c.name], mask_msg(self.t0 + t, c.frame_id or c.name, m))

    def query(self, t: float, res, cps) -> None:
        msg = ros2.query_msg(self.t0 + t, cps.names, cps.centres, cps.radii, res, rho=self.chain.rho)
        self._put("distances", self.p_dist, msg)
        mon = self.chain.latest_monitor  # (with a background: SSM's own distances, same frames)
        if mon is not None:
            rng = getattr(self.chain.stage.monitor, "ssm_range", None) or self.chain.rho  # (the monitor's range)
            mmsg = ros2.query_msg(self.t0 + t, cps.names, cps.centres, cps.radii, mon, rho=rng)
            self._put("monitor_distances", self.p_mon, mmsg)

    def command(self, t: float, out) -> None:
        names, ts = self.chain.joint_names, self.t0 + t
        self._put("commands", self.p_cmd, joint_state_cdr(ts, names, out.q_cmd, out.qdot_cmd))
        if self._k % 10 == 0:
            self.p_arr.publish(ros2.float64_array_msg(out.qdot_cmd))
            self.p_traj.publish(ros2.joint_trajectory_msg(ts, names, out.q_cmd, out.qdot_cmd, self.chain.config.dt))
        if self._k % 10 == 0 or out.status.name != self._last_status:
            self._put("status", self.p_st, ros2.status_msg(ts, out.status.name, out.scale))
            self._last_status = out.status.name
        self._k += 1

    def close(self) -> None:
        self.node.close()
