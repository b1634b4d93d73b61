"""Kinematics of robot-mounted sensors: world positions, optical axes and point Jacobians in one call.

A :class:`SensorArray` takes a :class:`~depthguard.robot.model.RobotModel` and
:class:`~depthguard.sensors.mount.SensorMount` s. Each mount is converted once into its parent joint's
frame, so that one forward-kinematics pass (:meth:`RobotModel.joint_kinematics`, compiled) serves every
sensor and the end effector: for a point ``p`` fixed to a link, ``J_p = J_lin + J_ang x p`` over the
joints that support the link (WORLD-frame spatial Jacobian), the ``d p_sk / d q`` of SAPHARI eq. 5.7.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from depthguard.robot.fk import fixed_directions, fixed_points
from depthguard.robot.model import RobotModel
from depthguard.sensors.mount import check_mounts

__all__ = ["SensorState", "SensorArray"]


class SensorState(NamedTuple):
    """Sensors at one configuration (world frame).

    Attributes:
        positions: (N, 3) sensor points p_sk, m.
        axes: (N, 3) unit optical axes v_dk.
        jacobians: (N, 3, n) positional Jacobians d p_sk / d q.
        ee_position: (3,) end-effector point, m.
        ee_jacobian: (3, n) its positional Jacobian.
    """

    positions: np.ndarray
    axes: np.ndarray
    jacobians: np.ndarray
    ee_position: np.ndarray
    ee_jacobian: np.ndarray


class SensorArray:
    """Sensors mounted on a robot (and the end-effector point), evaluated together.

    Args:
        model: the robot.
        mounts: the sensors; each ``link`` must be a frame of ``model``.
        ee_point: (3,) end-effector point in the model's ``ee_frame``, m (default its origin).
    """

    def __init__(self, model: RobotModel, mounts: object, ee_point: np.ndarray | None = None) -> None:
        self.model = model
        self.mounts = check_mounts(mounts)
        n = len(self.mounts) + 1
        self._joint = np.zeros(n, dtype=np.int64)
        self._p = np.zeros((n, 3))
        self._a = np.zeros((n, 3))
        frames = [(m.link, np.asarray(m.position, float), np.asarray(m.axis, float)) for m in self.mounts]
        ee = np.zeros(3) if ee_point is None else np.asarray(ee_point, float)
        frames.append((model.ee_frame, ee, np.array([1.0, 0.0, 0.0])))
        for k, (link, p, a) in enumerate(frames):
            fr = model.model.frames[model.frame_id(link)]
            M = fr.placement
            self._joint[k] = int(fr.parentJoint)
            self._p[k] = M.rotation @ p + M.translation
            self._a[k] = M.rotation @ a
        self._mask = np.array([model.joint_support_mask(j) for j in self._joint], dtype=bool)  # (N+1, n)
        self.max_range = np.array([m.max_range for m in self.mounts])

    @property
    def n_sensors(self) -> int:
        return len(self.mounts)

    def evaluate(self, q: np.ndarray) -> SensorState:
        """Positions, axes and Jacobians of the sensors and of the end effector at ``q`` (n,)."""
        m = self.model
        qa = np.asarray(q, dtype=float)
        if qa.shape != (m.n_dof,) or not np.isfinite(qa).all():
            qa = m.check_q(q)  # raises with the field named
        H, Jw = m.joint_kinematics(qa)  # (njoints, 4, 4), (6, n) WORLD
        pos, Jp = fixed_points(H, self._joint, self._p, Jw, self._mask)  # J_p = J_lin + J_ang x p, masked
        ax = fixed_directions(H, self._joint, self._a)
        return SensorState(pos[:-1], ax[:-1], Jp[:-1], pos[-1], Jp[-1])
