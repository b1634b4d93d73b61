"""Adapters between the simulator and the pipeline pieces (robot model, self-filter, distances, fusion).

The simulated loop talks only to this module. Each adapter uses the project's real implementation
when it is installed (``depthguard.robot``, ``depthguard.depthspace``, ``depthguard.depthgrid``) and
otherwise a small stand-in from :mod:`depthguard.sim._standins`, so the simulator keeps working while
those pieces are built. :func:`backends` says which one is in use; the run's metrics record it.

The pipeline sees only what a real system sees: the depth images, the joint positions and the
controller's own robot model. Nothing here reads the simulator's state.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from depthguard.camera import Camera

__all__ = ["Kinematics", "self_filter", "DistanceStage", "backends", "PointDistances"]

try:  # the lead's depth-space module
    from depthguard.depthspace import PointDistances, prepare_frame, query_distances

    _HAVE_DEPTHSPACE = True
except ImportError:  # pragma: no cover - only before depthspace lands
    from depthguard.sim._standins import PointDistances, prepare_frame, query_distances  # type: ignore

    _HAVE_DEPTHSPACE = False

try:
    from depthguard.depthgrid import DepthGridFusion  # type: ignore[attr-defined]

    _HAVE_GRID = True
except ImportError:
    from depthguard.sim._standins import VoxelFusion as DepthGridFusion  # type: ignore

    _HAVE_GRID = False

try:
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    _HAVE_ROBOT = True
except ImportError:
    _HAVE_ROBOT = False

try:
    from depthguard.robot.selffilter import self_filter as _robot_self_filter  # type: ignore

    _HAVE_SELFFILTER = True
except ImportError:
    _HAVE_SELFFILTER = False

try:
    from depthguard.control.cycle import AvoidanceController as _ProjectController
    from depthguard.control.cycle import ControllerConfig, CycleInput

    _HAVE_CONTROL = True
except ImportError:
    _HAVE_CONTROL = False


def backends() -> dict[str, str]:
    """Which implementation each pipeline piece uses ("project" or "sim stand-in")."""
    f = {True: "project", False: "sim stand-in"}
    return {
        "distance": f[_HAVE_DEPTHSPACE],
        "fusion": f[_HAVE_GRID],
        "robot_model": f[_HAVE_ROBOT],
        "self_filter": f[_HAVE_SELFFILTER and _HAVE_ROBOT],
        "controller": f[_HAVE_CONTROL and _HAVE_ROBOT],
    }


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
        if _HAVE_ROBOT:
            self.model = load_lwr4()
            counts = {} if preset == "ee" else preset
            self.points = ControlPointSet.build(self.model, counts, ee_radius)
            self.names = self.points.names
            self.q_min, self.q_max = np.asarray(self.model.q_min), np.asarray(self.model.q_max)
            self.v_max = np.asarray(self.model.v_max)
            self._impl = None
        else:
            from depthguard.sim._standins import MjKinematics

            self._impl = MjKinematics(preset, ee_radius)
            self.names = self._impl.names
            self.q_min, self.q_max, self.v_max = self._impl.q_min, self._impl.q_max, self._impl.v_max

    @property
    def n(self) -> int:
        return len(self.q_min)

    def evaluate(self, q: np.ndarray) -> CPState:
        """Control points at ``q`` (n,) rad, end effector first."""
        if self._impl is not None:
            return self._impl.evaluate(q)
        s = self.points.evaluate(q)
        return CPState(s.centres, s.radii, s.jacobians, tuple(s.names))

    def capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World capsules (a (L, 3), b (L, 3), radius (L,)) of the robot at ``q``."""
        if self._impl is not None:
            return self._impl.capsules(q)
        return self.model.link_capsules(q)


def self_filter(
    camera: Camera, depth: np.ndarray, q: np.ndarray, kin: Kinematics, pad: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Robot pixels of a depth image from the controller's model: ``(mask (H, W) bool, robot_depth (H, W))``.

    Uses the robot package's self-filter when installed; otherwise ray casts the model's capsules
    (inflated by ``pad`` m) through every pixel centre and marks the pixels whose measurement is at or
    behind the robot surface (minus ``pad``), or missing, where the robot is.
    """
    if _HAVE_SELFFILTER and kin._impl is None:
        res = _robot_self_filter(camera, depth, q, kin.model)
        return res[0], res[1]
    from depthguard.sim._standins import capsule_self_filter

    a, b, r = kin.capsules(q)
    return capsule_self_filter(camera, depth, a, b, r + pad, pad)


class Controller:
    """The 1 kHz avoidance controller: the project's (``depthguard.control``) or the sim stand-in.

    Args:
        kin: the controller's model and control points.
        q0: (n,) initial joint positions.
        rho, vmax, alpha: end-effector repulsion (eq. 7). rho_body, alpha_body: body constraints (eqs. 12-14).
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
    ) -> None:
        self.kin = kin
        self.n = kin.n
        self.project = _HAVE_CONTROL and kin._impl is None
        self.distance_timeout = distance_timeout
        if self.project:
            cfg = ControllerConfig(
                dt=dt,
                rho_ee=rho,
                alpha_ee=alpha,
                v_rep_max=vmax,
                rho_body=rho_body,
                alpha_body=alpha_body,
                distance_timeout=distance_timeout,
            )
            self._c = _ProjectController(kin.points, cfg)
        else:
            from depthguard.sim.controller import AvoidanceController, ControlParams

            self._c = AvoidanceController(
                kin.q_min,
                kin.q_max,
                kin.v_max,
                q0,
                ControlParams(rho_body=rho_body, alpha_body=alpha_body, stale_timeout=distance_timeout),
                dt,
            )
        self.vmax, self.rho, self.alpha = vmax, rho, alpha

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
    ) -> tuple[np.ndarray, dict]:
        """One cycle. ``distances`` (N,) / ``directions`` (N, 3) from the distance stage (None = none yet);
        with ``avoid=False`` the robot ignores them (no repulsion, no body constraints, no stale stop).
        Returns the joint position command (n,), velocity command (n,) and a status dict."""
        N = len(cp.radii)
        if not avoid:
            distances, directions, t_distances = np.full(N, np.inf), np.zeros((N, 3)), t
        if self.project:
            if distances is None:
                distances, directions = np.full(N, np.nan), np.zeros((N, 3))
            directions = np.where(np.isfinite(directions), directions, 0.0)
            out = self._c.step(CycleInput(t, q, qd, t, xdot, distances, directions, t_distances))
            return out.q_cmd, out.qdot_cmd, {"status": out.status.name, "scale": out.scale, "xdot_c": out.xdot_c}
        stale = distances is None or (t - t_distances) > self.distance_timeout
        if distances is None:
            q_cmd, st = self._c.step(q, cp.jacobians[0], xdot, None, None, None, None, True, avoid)
        else:
            d0 = distances[0]
            V = np.zeros(3)
            if np.isfinite(d0):
                mag = self.vmax / (1.0 + np.exp((d0 * 2.0 / self.rho - 1.0) * self.alpha))
                V = mag * np.nan_to_num(directions[0])
            q_cmd, st = self._c.step(
                q, cp.jacobians[0], xdot, V, cp.jacobians[1:], distances[1:], directions[1:], stale, avoid
            )
        st["status"] = "STOP_STALE_DISTANCES" if st.get("stale") else ("OK" if st.get("scale", 1) >= 1 else "SCALED")
        return q_cmd, self._c.qd_cmd.copy(), st


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
