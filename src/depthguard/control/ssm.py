"""Speed and separation monitoring (ISO/TS 15066 §5.5.4, now ISO 10218-2:2025) on measured distances.

DepthGuard is not a safety-rated device: this monitor slows and stops the robot through its own
controller; a certified system must implement the final protective stop.

The protective separation distance of control point k (ISO/TS 15066 eq. 1), with every term explicit:

``S_p,k = S_h + S_r,k + S_s,k + C + Z_d + Z_r``

* ``S_h = v_h (T_r + T_s)``: the person keeps approaching during the reaction time ``T_r`` and the robot's
  stopping time ``T_s``. ``v_h`` follows ISO 13855 §6.2 when the person's speed is not measured:
  2.0 m/s where the resulting ``S_p`` is at most 0.5 m, else 1.6 m/s with ``S_p >= 0.5 m``; a measured
  obstacle speed replaces it but never below ``v_h_floor``.
* ``S_r,k = v_r,k T_r``: the robot keeps its commanded motion during ``T_r``; ``v_r,k`` is the speed of the
  point *towards* the obstacle, ``max(0, -u_k . J_k qdot)`` with ``u_k`` the repulsive direction (from the
  obstacle towards the point).
* ``S_s,k``: the point's path while the controller's jerk-limited stop (Ruckig, velocity mode, per-joint
  time-optimal) brings the joints to rest: :mod:`depthguard.control.braking` (an upper bound, any direction).
* ``T_r`` = max(camera period, ``a``) + processing + communication + control period, counted from the
  capture of the frames that the distances come from (``a``: their age). A person who starts to approach
  right after a capture is in the next frame, one period later; data older than that (a late frame)
  stretches the wait to its age. (Until 2026-12-02: camera period + ... + ``a``, which counted the wait for
  the next frame twice once the distances were dated by their frames.)
* ``C``: intrusion distance; ``Z_d``: sensor uncertainty; ``Z_r``: robot position uncertainty.

Reported for *now*, not for the capture: over the age ``a`` the person may already have closed ``v_h a``
and the point ``v_r,k a``, so the output's separation is ``S_k - (v_h + v_r,k) a`` (a lower bound of the
separation now) and its ``S_p,k`` the same amount smaller (the budget from now on). Their difference, and so
every decision, is that of the test ``S_k >= S_p,k`` above; but the reported pair compares directly with the
true separation at the moment of the decision (``S_true(now) >= S_p`` whenever the inputs hold).

The allowed speed scale is the largest ``s`` in [0, 1] with ``S_k >= S_p,k(s)`` for every point, where the
robot is assumed to move at ``max(|qdot|, s |qdot_nominal|)`` per joint (the current motion persists
during the reaction time). ``S_p`` grows with ``s``, so bisection finds it. ``s = 0`` (even the current
motion is too fast) is a protective stop; it ends only when every point's separation exceeds its
``S_p`` at rest by ``hysteresis``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from depthguard.control.ssm_kernels import _update

__all__ = ["MonitorState", "SsmConfig", "SsmOutput", "SsmMonitor", "protective_separation", "reaction_time"]


class MonitorState(IntEnum):
    """State of the separation monitor."""

    MONITOR_OK = 0  #: full speed allowed
    REDUCED = 1  #: speed scaled down so that S >= S_p holds
    PROTECTIVE_STOP = 2  #: S < S_p even at rest: jerk-limited stop until the separation is back


@dataclass(frozen=True)
class SsmConfig:
    """SSM parameters (SI units), with the source of each default.

    Attributes:
        v_h_near, v_h_far, near_limit: ISO 13855 §6.2 approach speeds: 2.0 m/s where S_p <= 0.5 m,
            1.6 m/s beyond (and then S_p >= 0.5 m).
        v_h_floor: a measured obstacle speed is never taken below this, m/s (ISO 13855 walking speed).
        camera_period: depth camera frame period, s (30 Hz Kinect / RealSense).
        processing_latency: self-filter + distance stage latency, s (the simulated cell measures 2-6 ms
            at 640x480; 10 ms leaves room on a loaded machine).
        communication_latency: transport between the stages, s (0 in one process).
        control_period: one controller cycle, s (1 kHz).
        intrusion: C, m. ISO 13855 §6.3 gives C = 8 (d - 14) mm for a detection capability d <= 40 mm; the
            depth-space distance is measured to the seen surface itself, and hole filling (4 px) lets a
            finger of d = 20 mm go unseen at 3 m, hence 8 (20 - 14) = 48 mm -> 0.05 m.
        sensor_uncertainty: Z_d, m: 3 sigma of the Kinect depth noise at 3 m (Khoshelham & Elberink 2012:
            sigma = 1.43e-3 z^2 m -> 3.9 cm) plus the distance bound's declared tolerance (1 cm) -> 0.05 m.
        robot_uncertainty: Z_r, m: joint encoder and kinematic calibration error at the tool, 0.01 m.
        hysteresis: a protective stop ends when S >= S_p + hysteresis for every point, m.
        sensing_range: the range of the distance query (its rho), m: a distance of +inf ("nothing within
            rho") is a lower bound of ``sensing_range``, not of infinity, and is taken as that. inf (the
            default) trusts +inf; set it to the query's rho whenever ``S_p`` can exceed rho.
    """

    v_h_near: float = 2.0
    v_h_far: float = 1.6
    near_limit: float = 0.5
    v_h_floor: float = 1.6
    camera_period: float = 1.0 / 30.0
    processing_latency: float = 0.01
    communication_latency: float = 0.0
    control_period: float = 0.001
    intrusion: float = 0.05
    sensor_uncertainty: float = 0.05
    robot_uncertainty: float = 0.01
    hysteresis: float = 0.05
    sensing_range: float = float("inf")

    def __post_init__(self) -> None:
        if not self.sensing_range > 0:
            raise ValueError(f"SsmConfig.sensing_range must be > 0 (inf allowed), got {self.sensing_range!r}")
        for name, val in self.__dict__.items():
            if name == "sensing_range":
                continue
            if not (np.isfinite(val) and val >= 0):
                raise ValueError(f"SsmConfig.{name} must be a finite number >= 0, got {val!r}")
        if self.v_h_near <= 0 or self.v_h_far <= 0:
            raise ValueError("SsmConfig.v_h_near and v_h_far must be > 0")

    @property
    def constant_terms(self) -> float:
        """C + Z_d + Z_r, m."""
        return self.intrusion + self.sensor_uncertainty + self.robot_uncertainty


SSM_RANGE = 0.6  # m: default range of the monitor's distances, above S_p at the scenarios' task speeds (docs/ssm.md)


def reaction_time(cfg: SsmConfig, data_age: float = 0.0) -> float:
    """T_r from the capture of the data, s: max(camera period, age of the distances) + processing +
    communication + control period. A person who starts to approach just after a capture is seen in the next
    frame, one period later; data older than a period (a late or lost frame) stretches that wait to its age."""
    return max(cfg.camera_period, data_age) + cfg.processing_latency + cfg.communication_latency + cfg.control_period


def protective_separation(
    v_h: float, T_r: float, T_s: float, v_r: float, S_s: float, C: float, Z_d: float, Z_r: float
) -> float:
    """ISO/TS 15066 eq. 1 with constant speeds: ``v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r``, m."""
    return v_h * (T_r + T_s) + v_r * T_r + S_s + C + Z_d + Z_r


class SsmOutput(NamedTuple):
    """One monitor update.

    Attributes:
        scale: allowed speed scale in [0, 1].
        state: :class:`MonitorState`.
        binding: index of the binding control point (smallest margin), -1 if none is within reach.
        separation: (N,) separation now, ``S_k - (v_h + v_r,k) a``: the measured one less what the obstacle and
            the point may have closed over the distances' age ``a``, m (inf = nothing seen).
        s_p: (N,) protective separation distance from now at the allowed scale (less the same amount), m.
        margin: (N,) ``S_k - S_p,k``, m.
        stop_time: T_s at the allowed scale, s.
        reaction_time: T_r, s.
        stop_ended: True on the update where a protective stop ends.
    """

    scale: float
    state: MonitorState
    binding: int
    separation: np.ndarray
    s_p: np.ndarray
    margin: np.ndarray
    stop_time: float
    reaction_time: float
    stop_ended: bool


def _as_f64(x: object) -> np.ndarray:
    """``x`` as a float64 C-contiguous array (itself when it is one already)."""
    if type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous:
        return x
    return np.ascontiguousarray(x, dtype=np.float64)


@dataclass
class SsmMonitor:
    """Per-cycle speed and separation monitor for a control-point set (module docstring).

    Attributes:
        lengths: (N, n) chain lengths of the points (:func:`depthguard.control.braking.chain_lengths`), m.
        a_max, j_max: (n,) the controller's joint acceleration and jerk limits.
        config: :class:`SsmConfig`.
    """

    lengths: np.ndarray
    a_max: np.ndarray
    j_max: np.ndarray
    config: SsmConfig = SsmConfig()

    def __post_init__(self) -> None:
        self.lengths = np.ascontiguousarray(self.lengths, dtype=float)
        N, n = self.lengths.shape
        self.a_max = np.broadcast_to(np.asarray(self.a_max, dtype=float), (n,)).copy()
        self.j_max = np.broadcast_to(np.asarray(self.j_max, dtype=float), (n,)).copy()
        if not (np.all(self.a_max > 0) and np.all(self.j_max > 0)):
            raise ValueError("SsmMonitor: a_max and j_max must be > 0")
        self.stopped = False
        self._prm_of: SsmConfig | None = None  # (the kernel's parameters are cached per configuration)

    def update(
        self,
        jacobians: np.ndarray,
        qdot: np.ndarray,
        qddot: np.ndarray,
        qdot_nominal: np.ndarray,
        distances: np.ndarray,
        directions: np.ndarray,
        data_age: float = 0.0,
        obstacle_speed: np.ndarray | None = None,
    ) -> SsmOutput:
        """One update.

        Args:
            jacobians: (N, 3, n) positional Jacobians of the control points, m/rad.
            qdot, qddot: (n,) current joint velocity (rad/s) and acceleration (rad/s^2).
            qdot_nominal: (n,) the joint velocity the task asks for at full scale, rad/s.
            distances: (N,) lower bounds of the separation from each point's sphere, m; inf = nothing
                within range (taken as ``config.sensing_range``); NaN counts as 0 (unknown: stop).
            directions: (N, 3) repulsive unit directions (obstacle -> point); non-finite or zero rows, and the
                rows of +inf distances, count as pointing straight at the obstacle along the motion (worst case).
            data_age: age of the distances, s, from the capture of their frames (T_r covers it from the
                capture; the outputs are shifted to now by it, module docstring).
            obstacle_speed: (N,) measured speed of each point's nearest obstacle, m/s, or None (ISO 13855).

        A wrong shape raises ValueError naming the argument; a non-finite motion (``qdot``, ``qddot``,
        ``qdot_nominal``, ``jacobians``) is a protective stop.
        """
        age, T_r, prm, v_h = self.kernel_inputs(data_age, obstacle_speed)
        c = _as_f64
        N, n = self.lengths.shape
        jacobians, qdot, qddot, qdot_nominal = c(jacobians), c(qdot), c(qddot), c(qdot_nominal)
        distances, directions = c(distances), c(directions)
        for name, arr, shape in (
            ("jacobians", jacobians, (N, 3, n)), ("qdot", qdot, (n,)), ("qddot", qddot, (n,)),
            ("qdot_nominal", qdot_nominal, (n,)), ("distances", distances, (N,)), ("directions", directions, (N, 3)),
            ("obstacle_speed", v_h, (N,)),
        ):  # fmt: skip
            if arr.shape != shape:  # (the kernel does not check bounds: a short array would be read past its end)
                raise ValueError(f"SsmMonitor.update: {name} must have shape {shape}, got {arr.shape}")
        dist, sp = np.empty(N), np.empty(N)
        cfg = self.config
        s, stopped, stop_ended, T_s, binding = _update(
            jacobians, qdot, qddot, qdot_nominal, distances, directions, float(cfg.sensing_range),
            self.lengths, self.a_max, self.j_max, v_h, prm, self.stopped, float(cfg.hysteresis), dist, sp, age,
        )  # fmt: skip
        return self.finish(s, stopped, stop_ended, T_s, binding, dist, sp, dist - sp, T_r)

    def kernel_inputs(self, data_age: float, obstacle_speed: np.ndarray | None = None) -> tuple:
        """What :func:`_update` needs besides the state: ``(age, T_r, prm, v_h)``: the data's age (s;
        negative -> 0, non-finite -> 1000 s), the reaction time (s), the parameter vector and the measured
        obstacle speeds (-1 = not measured). For compiled callers (:mod:`depthguard.control.plan_kernel`)."""
        cfg = self.config
        age = float(data_age)
        age = max(age, 0.0) if math.isfinite(age) else 1e3
        T_r = reaction_time(cfg, age)
        if self._prm_of is not cfg:  # the configuration's constant part of the kernel's parameters, once
            self._prm = np.array([0.0, cfg.constant_terms, cfg.v_h_near, cfg.v_h_far, cfg.near_limit, cfg.v_h_floor])
            self._prm_of, self._no_speed = cfg, -np.ones(self.lengths.shape[0])
        prm = self._prm.copy()
        prm[0] = T_r
        v_h = self._no_speed if obstacle_speed is None else np.nan_to_num(np.asarray(obstacle_speed, float), nan=1e3)
        return age, T_r, prm, v_h

    def finish(
        self, s: float, stopped: bool, stop_ended: bool, T_s: float, binding: int, dist: np.ndarray,
        sp: np.ndarray, margin: np.ndarray, T_r: float,
    ) -> SsmOutput:  # fmt: skip
        """The output of :func:`_update`'s results (``s`` = -1: stopped), keeping the latched stop."""
        self.stopped = bool(stopped)
        scale = max(s, 0.0)
        if stopped:
            state = MonitorState.PROTECTIVE_STOP
        else:
            state = MonitorState.MONITOR_OK if scale >= 1.0 else MonitorState.REDUCED
        return SsmOutput(scale, state, int(binding), dist, sp, margin, T_s, T_r, bool(stop_ended))

    def reset(self) -> None:
        """Forget a latched protective stop."""
        self.stopped = False
