"""Adapters between the simulator and the pipeline pieces (robot model, self-filter, distances, fusion,
controller).

The simulated loop talks only to this module, which calls the project's own implementations
(``depthguard.robot``, ``depthguard.depthspace``, ``depthguard.depthgrid``, ``depthguard.control``).
The pipeline sees only what a real system sees: the depth images, the joint positions and the
controller's own robot model. Nothing here reads the simulator's state.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from depthguard.camera import Camera
from depthguard.control.cycle import AvoidanceController, ControllerConfig, CycleInput
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import PointDistances, prepare_frame, query_distances
from depthguard.robot.control_points import ControlPointSet
from depthguard.robot.model import load_lwr4
from depthguard.robot.selffilter import self_filter as _robot_self_filter

__all__ = ["Kinematics", "self_filter", "DistanceStage", "Controller", "PointDistances"]


class CPState(NamedTuple):
    """Control points: centres (N, 3) m, radii (N,) m, jacobians (N, 3, n), names; point 0 = end effector."""

    centres: np.ndarray
    radii: np.ndarray
    jacobians: np.ndarray
    names: tuple[str, ...]


class Kinematics:
    """The controller's robot model: control points (preset), end effector, capsules, limits.

    Args:
        preset: control-point preset, "ee" (end effector only), "icra-exp3" or "ral-9".
        ee_radius: radius of the end-effector sphere, m.
    """

    def __init__(self, preset: str = "ral-9", ee_radius: float = 0.06) -> None:
        self.preset = preset
        self.model = load_lwr4()
        counts = {} if preset == "ee" else preset
        self.points = ControlPointSet.build(self.model, counts, ee_radius)
        self.names = self.points.names
        self.q_min, self.q_max = np.asarray(self.model.q_min), np.asarray(self.model.q_max)
        self.v_max = np.asarray(self.model.v_max)

    @property
    def n(self) -> int:
        return len(self.q_min)

    def evaluate(self, q: np.ndarray) -> CPState:
        """Control points at ``q`` (n,) rad, end effector first."""
        s = self.points.evaluate(q)
        return CPState(s.centres, s.radii, s.jacobians, tuple(s.names))

    def capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World capsules (a (L, 3), b (L, 3), radius (L,)) of the robot at ``q``."""
        return self.model.link_capsules(q)


def self_filter(
    camera: Camera, depth: np.ndarray, q: np.ndarray, kin: Kinematics, pad: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Robot pixels of a depth image from the controller's model: ``(mask (H, W) bool, robot_depth (H, W))``.

    ``pad`` is kept for the callers' signature; the robot package's self-filter uses its own margin.
    """
    res = _robot_self_filter(camera, depth, q, kin.model)
    return res[0], res[1]


class Controller:
    """The 1 kHz avoidance controller (``depthguard.control``).

    Args:
        kin: the controller's model and control points.
        q0: (n,) initial joint positions.
        rho, vmax, alpha: end-effector repulsion (eq. 7). rho_body, alpha_body: body constraints (eqs. 12-14).
        ssm: speed and separation monitoring on top of the repulsion (``avoidance="both"``), with
            ``ssm_config`` (a :class:`depthguard.control.ssm.SsmConfig`, None = its defaults);
            ``avoidance_mode`` overrides the controller's mode ("repulsion", "ssm" or "both").
    """

    def __init__(
        self,
        kin: Kinematics,
        q0: np.ndarray,
        rho: float,
        vmax: float,
        alpha: float,
        rho_body: float,
        alpha_body: float,
        dt: float = 1e-3,
        distance_timeout: float = 0.1,
        ssm: bool = False,
        ssm_config: object | None = None,
        avoidance_mode: str | None = None,
    ) -> None:
        self.kin = kin
        self.n = kin.n
        self.distance_timeout = distance_timeout
        cfg = ControllerConfig(
            dt=dt,
            rho_ee=rho,
            alpha_ee=alpha,
            v_rep_max=vmax,
            rho_body=rho_body,
            alpha_body=alpha_body,
            distance_timeout=distance_timeout,
            avoidance=avoidance_mode or ("both" if ssm else "repulsion"),
            ssm=ssm_config,
        )
        self._c = AvoidanceController(kin.points, cfg)
        self.vmax, self.rho, self.alpha = vmax, rho, alpha
        self.last_output = None  # the latest CycleOutput (its .ssm holds the monitor's output when SSM is on)

    def step(
        self,
        t: float,
        q: np.ndarray,
        qd: np.ndarray,
        xdot: np.ndarray,
        cp: CPState,
        distances: np.ndarray | None,
        directions: np.ndarray | None,
        t_distances: float,
        avoid: bool = True,
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """One cycle. ``distances`` (N,) / ``directions`` (N, 3) from the distance stage (None = none yet);
        with ``avoid=False`` the robot ignores them (no repulsion, no body constraints, no stale stop).
        Returns the joint position command (n,), velocity command (n,) and a status dict."""
        N = len(cp.radii)
        if not avoid:
            distances, directions, t_distances = np.full(N, np.inf), np.zeros((N, 3)), t
        if distances is None:
            distances, directions = np.full(N, np.nan), np.zeros((N, 3))
        directions = np.where(np.isfinite(directions), directions, 0.0)
        out = self._c.step(CycleInput(t, q, qd, t, xdot, distances, directions, t_distances))
        self.last_output = out
        return out.q_cmd, out.qdot_cmd, {"status": out.status.name, "scale": out.scale, "xdot_c": out.xdot_c}


class DistanceStage:
    """Frame stage + distance stage for one or several cameras.

    With one camera: ``prepare_frame`` per frame and ``query_distances`` per query (depth space).
    With several: depth-grid fusion (``update`` per frame set, ``query`` per query).

    Args:
        cameras: the cameras, principal first.
        rho: radius of surveillance, m. mode: "min", "all" or "hybrid". alpha: eq. 7 shape factor.
        workspace: (xmin, xmax, ymin, ymax, zmin, zmax) m, for fusion.
    """

    def __init__(
        self,
        cameras: list[Camera],
        rho: float,
        mode: str = "hybrid",
        alpha: float = 6.0,
        workspace: tuple[float, ...] = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5),
        dd: float = 0.01,
    ) -> None:
        self.cameras = list(cameras)
        self.rho, self.mode, self.alpha = float(rho), mode, float(alpha)
        self.frames = None
        self.fusion = None
        if len(self.cameras) > 1:
            self.fusion = DepthGridFusion(self.cameras, dd=dd, workspace=workspace)

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray]) -> None:
        """Frame stage: take one depth image and robot mask per camera."""
        if self.fusion is not None:
            self.fusion.update(depths, masks)
        else:
            self.frames = [prepare_frame(self.cameras[0], depths[0], masks[0])]

    @property
    def ready(self) -> bool:
        return self.frames is not None or (self.fusion is not None and getattr(self.fusion, "ready", True))

    def query(self, centres: np.ndarray, radii: np.ndarray) -> PointDistances:
        """Distance stage: distances of the control spheres to the obstacles."""
        if self.fusion is not None:
            return self.fusion.query(centres, radii, rho=self.rho, mode=self.mode, alpha=self.alpha)
        return query_distances(self.frames[0], centres, radii, rho=self.rho, mode=self.mode, alpha=self.alpha)
