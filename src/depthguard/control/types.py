"""The avoidance controller's configuration, cycle inputs, cycle outputs and status codes.

Units are SI (m, s, rad); frames and sign conventions are those of docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

__all__ = ["CycleStatus", "ControllerConfig", "CycleInput", "CycleOutput"]


class CycleStatus(IntEnum):
    """Outcome of one cycle (ruckig style: an explicit code instead of exceptions)."""

    OK = 0  #: task executed at full scale
    SCALED = 1  #: constraints active: the task was scaled down by SNS (scale < 1)
    STOP_STALE_DISTANCES = 2  #: distances missing (None) or older than the timeout: jerk-limited stop
    STOP_STALE_JOINTS = 3  #: joint state older than the timeout: jerk-limited stop
    #: an input is malformed: NaN, -inf or a wrong shape in q, qdot, xdot_d, distances or directions
    #: (a non-finite direction with a finite distance), a non-finite time stamp, a time stamp from the
    #: future or a cycle time that went backwards: jerk-limited stop
    STOP_INVALID_INPUT = 4
    ERROR_OTG = 5  #: Ruckig failed: this cycle brakes with the fallback jerk-limited stop
    #: inputs valid again after a stop, but for less than ``resume_time`` in a row: still stopping
    STOP_RESUME_WAIT = 6
    STOP_INTERNAL_ERROR = 7  #: an unexpected exception inside the cycle: jerk-limited stop
    #: a camera reported a fault (frozen, covered, moved: :mod:`depthguard.robot.health`); the faulty camera
    #: is named in :attr:`AvoidanceController.sensor_fault`: jerk-limited stop, resume latch afterwards
    STOP_SENSOR_FAULT = 8
    #: speed and separation monitoring: the separation is below the protective separation distance even
    #: at rest (ISO/TS 15066): jerk-limited stop until the monitor's hysteresis releases it
    STOP_PROTECTIVE = 9

    @property
    def stopping(self) -> bool:
        """True for every status whose cycle commands a stop (target velocity 0)."""
        return self not in (CycleStatus.OK, CycleStatus.SCALED)


@dataclass(frozen=True)
class ControllerConfig:
    """Controller parameters (SI units). Defaults follow ICRA'12 Exp. 1-3 where the paper gives them.

    Attributes:
        dt: control period, s (1 kHz).
        rho_ee, alpha_ee, v_rep_max: end-effector repulsion (eq. 7): 0.4 m, 6, 2 m/s (Exp. 1).
        rho_body, alpha_body: body constraints (eqs. 12-14).
        contact_distance: distance at which motion towards an obstacle is denied, m.
        velocity_scale: fraction of the model's joint velocity limits that the controller may use.
        a_max, j_max: joint acceleration (rad/s^2) and jerk (rad/s^3) limits, scalar or (n,).
        position_margin: stop this far inside the joint position limits, rad.
        distance_timeout: distances older than this trigger the safe stop, s (3 frames at 30 Hz).
        joint_timeout: joint states older than this trigger the safe stop, s.
        dls_eps, dls_lambda_max: damped least squares below this singular value / largest damping.
        synchronization: Ruckig synchronization, "none" (default), "time" or "phase". With "none" every
            joint brakes and accelerates on its own time-optimal profile; "time"/"phase" stretch the faster
            joints' profiles to finish together, which slows their braking below the acceleration limit
            that the position-limit bounds assume (a test drove a joint past its limit that way).
        avoidance: "repulsion" (the papers: end-effector repulsion and body bounds), "ssm" (speed and
            separation monitoring, ISO/TS 15066, scaling the task, plus the body bounds) or "both".
        ssm: the :class:`depthguard.control.ssm.SsmConfig` (None = its defaults) when SSM is on.
        stop_evades: with ``avoidance`` "both", a protective stop halts the task but the end effector's
            repulsion (eq. 10) may still move the arm *away* from what approaches, within the body bounds
            (eqs. 12-14: each point's speed towards its obstacle is limited, to zero at contact); a cycle
            whose time-optimal step would bring the end effector nearer takes the phase-synchronized step
            (:func:`depthguard.control.step.generate`). False: the plain jerk-limited stop, as in "ssm"
            mode. A person who walks into a stopped arm is then hit.
        resume_time: after any stop, motion resumes only once every input has been valid (and fresh)
            for this long in a row, s (cycles in a row and elapsed time both count); until then the
            cycle reports ``STOP_RESUME_WAIT`` and keeps stopping.
    """

    dt: float = 0.001
    rho_ee: float = 0.4
    alpha_ee: float = 6.0
    v_rep_max: float = 2.0
    rho_body: float = 0.4
    alpha_body: float = 6.0
    contact_distance: float = 0.0
    velocity_scale: float = 1.0
    a_max: float | tuple[float, ...] = 10.0
    j_max: float | tuple[float, ...] = 500.0
    position_margin: float = 0.02
    distance_timeout: float = 0.1
    joint_timeout: float = 0.005
    dls_eps: float = 0.02
    dls_lambda_max: float = 0.05
    synchronization: str = "none"
    resume_time: float = 0.1
    avoidance: str = "repulsion"
    ssm: object | None = None
    stop_evades: bool = True


class CycleInput(NamedTuple):
    """Inputs of one cycle.

    Every field is checked each cycle; anything malformed gives ``STOP_INVALID_INPUT`` (never an
    exception). Time stamps must be finite; ``t_joints`` and ``t_distances`` may lie at most one period
    ``dt`` in the future of ``t``, and ``t`` must not go backwards from one cycle to the next.

    Attributes:
        t: current time, s.
        q: (n,) measured joint positions, rad (None = missing).
        qdot: (n,) measured joint velocities, rad/s (used only to start the generator).
        t_joints: time stamp of ``q``, s.
        xdot_d: (3,) desired end-effector linear velocity, m/s (ICRA'12 Exp.: m = 3).
        distances: (N,) per control point (the order of the :class:`ControlPointSet`, end effector
            first), distance from the sphere surface, m; +inf = nothing within rho (its direction is then
            ignored); NaN and -inf are invalid; None = missing (``STOP_STALE_DISTANCES``).
        directions: (N, 3) unit repulsive directions, from the obstacle towards the point; finite
            wherever the distance is finite.
        t_distances: time stamp of the distances, s.
        monitor_distances: (N,) or None: the distances that speed and separation monitoring uses, when
            they differ from ``distances`` (those of the repulsion and the body bounds): the same frames
            with the cell's commissioned background (room, table, fixtures) removed, so that the monitor
            sees people and unknown space only while the repulsion keeps avoiding everything. Same rules
            and time stamp as ``distances``; None = the monitor uses ``distances``.
        monitor_directions: (N, 3) or None, the directions of ``monitor_distances`` (both or neither).
    """

    t: float
    q: np.ndarray | None
    qdot: np.ndarray | None
    t_joints: float
    xdot_d: np.ndarray
    distances: np.ndarray | None
    directions: np.ndarray | None
    t_distances: float
    monitor_distances: np.ndarray | None = None
    monitor_directions: np.ndarray | None = None


class CycleOutput(NamedTuple):
    """Result of one cycle.

    Attributes:
        qdot_cmd: (n,) joint velocity to command for the next period, rad/s (jerk-limited unless
            ``bound_limited``); always within ``[qdot_min, qdot_max]``.
        q_cmd: (n,) joint position reached by the command after one period, rad.
        qddot_cmd: (n,) joint acceleration, rad/s^2.
        status: :class:`CycleStatus`.
        scale: SNS task scale in [0, 1] (0 while stopping).
        qdot_target: (n,) SNS velocity given to Ruckig as target, rad/s (0 while stopping).
        qdot_min, qdot_max: (n,) the cycle's velocity bounds, rad/s: v_max, the position-limit braking
            bounds and (when the distances are valid) the body bounds.
        xdot_c: (3,) commanded end-effector velocity (eq. 10), m/s.
        bound_limited: True when a bound shrank faster than the jerk limit can follow, so the bound won:
            ``qdot_cmd`` was set to it, breaking the acceleration or jerk limit in this cycle.
        ssm: the speed and separation monitor's output of this cycle (None when SSM is off or stopping).
    """

    qdot_cmd: np.ndarray
    q_cmd: np.ndarray
    qddot_cmd: np.ndarray
    status: CycleStatus
    scale: float
    qdot_target: np.ndarray
    qdot_min: np.ndarray
    qdot_max: np.ndarray
    xdot_c: np.ndarray
    bound_limited: bool = False
    ssm: object | None = None  #: the cycle's :class:`depthguard.control.ssm.SsmOutput` when SSM is on
