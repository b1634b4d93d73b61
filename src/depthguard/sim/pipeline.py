"""Adapters between the simulator and the pipeline pieces (robot model, self-filter, distances, fusion,
controller).

The simulated loop talks only to this module, which calls the project's own implementations
(``depthguard.robot``, ``depthguard.depthspace``, ``depthguard.depthgrid``, ``depthguard.control``).
The pipeline sees only what a real system sees: the depth images, the joint positions and the
controller's own robot model. Nothing here reads the simulator's state.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np

from depthguard.camera import Camera
from depthguard.control.cycle import AvoidanceController, ControllerConfig, CycleInput
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import PointDistances, prepare_frame, query_distances
from depthguard.kernels.records import direction_stride as resolve_stride
from depthguard.robot.control_points import ControlPointSet, ControlPointState
from depthguard.robot.interior import interior_capsules, principal_robot_pixels, robot_windows
from depthguard.robot.robots import load_robot
from depthguard.robot.selffilter import self_filter as _robot_self_filter
from depthguard.sidethread import usable_cpus

__all__ = [
    "Kinematics",
    "self_filter",
    "filter_margin",
    "model_filter_margin",
    "DistanceStage",
    "Controller",
    "PointDistances",
]

SELF_FILTER_MARGIN = 0.03  # m, the self-filter's default capsule inflation (robot.selffilter)
NOISE_SIGMAS = 5.0  # the margin also covers this many standard deviations of the depth noise at the robot


def filter_margin(camera: Camera, q: np.ndarray, kin: Kinematics, noise_coeff: float = 0.0) -> float:
    """Self-filter margin (m) for ``camera``: the default 3 cm, or more where the depth noise is larger.

    A robot surface point measured more than the margin in front of its capsule is kept as an obstacle,
    and every such point lies inside a control sphere: a phantom contact. With axial noise of standard
    deviation ``noise_coeff z²`` (Kinect v1: 1.4 mm at 1 m, 11 mm at 2.8 m) and tens of thousands of robot
    pixels per frame, 4-sigma outliers happen every few frames; the margin covers ``NOISE_SIGMAS`` sigmas
    at the robot's farthest depth in this camera (the capsule ends plus radius).
    """
    return model_filter_margin(camera, q, kin.model, noise_coeff)


def model_filter_margin(camera: Camera, q: np.ndarray, model, noise_coeff: float = 0.0) -> float:
    """:func:`filter_margin` for a robot ``model`` (:class:`~depthguard.robot.model.RobotModel`; the chain of
    ``depthguard run`` with a camera's ``noise_coeff`` from the cell file)."""
    a, b, r = model.link_capsules(q)
    z = np.maximum(camera.world_to_camera(a)[:, 2], camera.world_to_camera(b)[:, 2]) + r
    zmax = float(np.max(z)) if len(z) else 0.0
    return max(SELF_FILTER_MARGIN, NOISE_SIGMAS * float(noise_coeff) * zmax * zmax)


class Kinematics:
    """The controller's robot model: control points, end effector, limits.

    Args:
        preset: control-point preset: "ee" (end effector only), "icra-exp3", "ral-9" (the shipped LWR) or
            "auto" (spheres covering every moving link's real geometry, any robot).
        ee_radius: radius of the end-effector sphere, m.
        robot: robot name (:func:`depthguard.robot.robots.load_robot`): "lwr4", "panda", "ur5", ...
        auto_spheres: most spheres per link of the "auto" preset.
    """

    def __init__(
        self, preset: str = "ral-9", ee_radius: float = 0.06, robot: str = "lwr4", auto_spheres: int = 3
    ) -> None:
        self.model = load_robot(robot)
        counts = {} if preset == "ee" else preset
        self.points = ControlPointSet.build(self.model, counts, ee_radius, auto_spheres=auto_spheres)
        self.names = self.points.names
        self.q_min, self.q_max = np.asarray(self.model.q_min), np.asarray(self.model.q_max)
        self.v_max = np.asarray(self.model.v_max)

    @property
    def n(self) -> int:
        return len(self.q_min)

    def evaluate(self, q: np.ndarray) -> ControlPointState:
        """Control points at ``q`` (n,), end effector first."""
        return self.points.evaluate(q)


def self_filter(
    camera: Camera, depth: np.ndarray, q: np.ndarray, kin: Kinematics, margin: float | None = None
) -> np.ndarray:
    """Robot pixels (H, W) bool of a depth image, from the controller's model at the measured ``q``;
    ``margin`` (m, default: the self-filter's 3 cm) inflates the geometry (see :func:`filter_margin`)."""
    if margin is None:
        return _robot_self_filter(camera, depth, q, kin.model, with_depth=False).mask
    return _robot_self_filter(camera, depth, q, kin.model, margin=float(margin), with_depth=False).mask


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
        cp: ControlPointState,
        distances: np.ndarray | None,
        directions: np.ndarray | None,
        t_distances: float,
        avoid: bool = True,
        monitor_distances: np.ndarray | None = None,
        monitor_directions: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """One cycle. ``distances`` (N,) / ``directions`` (N, 3) from the distance stage (None = none yet);
        with ``avoid=False`` the robot ignores them (no repulsion, no body constraints, no stale stop).
        ``monitor_distances`` / ``monitor_directions``: the speed and separation monitor's own distances
        (the same frames without the commissioned background; None = the monitor uses ``distances``).
        Returns the joint position command (n,), velocity command (n,) and a status dict."""
        N = len(cp.radii)
        if not avoid:
            distances, directions, t_distances = np.full(N, np.inf), np.zeros((N, 3)), t
            monitor_distances = monitor_directions = None
        if distances is None:
            distances, directions = np.full(N, np.nan), np.zeros((N, 3))
            monitor_distances = monitor_directions = None
        directions = np.where(np.isfinite(directions), directions, 0.0)
        if monitor_directions is not None:
            monitor_directions = np.where(np.isfinite(monitor_directions), monitor_directions, 0.0)
        inp = CycleInput(t, q, qd, t, xdot, distances, directions, t_distances, monitor_distances, monitor_directions)
        out = self._c.step(inp)
        self.last_output = out
        return out.q_cmd, out.qdot_cmd, {"status": out.status.name, "scale": out.scale, "xdot_c": out.xdot_c}


_SIDE: list = []
os.register_at_fork(after_in_child=_SIDE.clear)  # a forked child has no worker thread: it makes its own


#: The smallest principal image (pixels) whose depth-grid query is shared with the side thread. Measured on the
#: 2-core CI VM (``ral-hexagon`` frames, BENCHMARKS.md, stop 45): shared, the first query of a frame set took
#: 0.63 of its one-thread time at 640x480 and 0.64 at 320x240, but 0.99 at 160x120, and a repeated query
#: 1.48 times its one-thread time there (waking the worker costs more than half of the query saves).
SHARED_QUERY_MIN_PIXELS = 320 * 240


def _side_thread():
    """One worker thread for the frame stage's independent kernels, run on another CPU than the caller's
    (:class:`depthguard.sidethread.SideThread`; None on a single core)."""
    if (os.cpu_count() or 1) < 2:
        return None
    if not _SIDE:
        from depthguard.sidethread import SideThread

        _SIDE.append(SideThread("depthguard-frame"))
    return _SIDE[0]


class DistanceStage:
    """Frame stage + distance stage for one or several cameras.

    With one camera: ``prepare_frame`` per frame and ``query_distances`` per query (depth space).
    With several: depth-grid fusion (``update`` per frame set, ``query`` per query).

    Args:
        cameras: the cameras, principal first.
        rho: radius of surveillance, m. mode: "min", "all" or "hybrid". alpha: eq. 7 shape factor.
        direction_stride: pixels of the direction sum (modes all/hybrid; docs/conventions.md, "Direction
            lattice"): "auto" (default) or an integer >= 1.
        workspace: (xmin, xmax, ymin, ymax, zmin, zmax) m, for fusion.
        ssm_range: None, or the range (m, >= rho) of the distances handed to a speed and separation
            monitor (:meth:`query_far`): its protective distance can exceed ρ. Equal to rho: nothing to add.
    """

    def __init__(
        self,
        cameras: list[Camera],
        rho: float,
        mode: str = "hybrid",
        alpha: float = 6.0,
        workspace: tuple[float, ...] = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5),
        dd: float = 0.01,
        invalid: str = "conservative",
        fill_radius: int = 4,
        direction_stride: int | str = "auto",
        ssm_range: float | None = None,
    ) -> None:
        self.cameras = list(cameras)
        if ssm_range is not None and not ssm_range >= rho:
            raise ValueError(f"ssm_range must be None or >= rho = {rho}, got {ssm_range!r}")
        self.ssm_range = None if ssm_range is None or ssm_range == rho else float(ssm_range)
        self.rho, self.mode, self.alpha = float(rho), mode, float(alpha)
        resolve_stride(direction_stride, self.cameras[0].width)  # refuse a bad one here, not at the first query
        self.direction_stride = direction_stride
        self.invalid, self.fill_radius = invalid, fill_radius
        self.frames = None
        self.fusion = None
        self._updated = False
        if len(self.cameras) > 1:
            if invalid != "conservative":
                raise ValueError(
                    f"invalid = {invalid!r}: the depth grid (several cameras) treats a missing pixel as unknown"
                    " space only ('conservative')"
                )
            self.fusion = DepthGridFusion(self.cameras, dd=dd, workspace=workspace, fill_radius=fill_radius)

    def update(
        self,
        depths: list[np.ndarray],
        masks: list[np.ndarray],
        q: np.ndarray | None = None,
        model=None,
        margins: list[float] | None = None,
    ) -> None:
        """Frame stage: take one depth image and robot mask per camera.

        With several cameras, the measured joints ``q`` and the robot ``model`` (a :class:`RobotModel`), the
        principal camera's robot pixels are corrected first from the capsules inside the robot's collision
        geometry (:func:`depthguard.robot.interior.interior_capsules`: none for mesh links;
        :func:`depthguard.robot.interior.principal_robot_pixels`): case iv starts where a ray leaves the
        robot's inflated capsules, and a missing pixel whose ray misses the robot is a hole, not robot;
        the secondary cameras get their robot windows (``robot_windows``): the robot's own body, even
        where something in front of it hides it, holds no obstacle. ``margins`` (m, one per camera) are
        the self-filter margins the masks were made with (default 3 cm each, :func:`filter_margin`).
        """
        if self.fusion is not None:
            a, b, r = interior_capsules(model, q) if q is not None and model is not None else (None, None, [])
            if len(r):
                ms = list(margins) if margins is not None else [SELF_FILTER_MARGIN] * len(self.cameras)

                def secondary_windows() -> list:
                    sec = zip(self.cameras[1:], ms[1:], strict=True)
                    return [None, *(robot_windows(c, a, b, r, margin=m) for c, m in sec)]

                def principal(d, m):
                    return principal_robot_pixels(self.cameras[0], d, m, a, b, r, margin=ms[0])

                # the secondary cameras' part (windows, votes, pyramid) on a side thread, beside the principal
                # camera's (robot pixels, segments): disjoint arrays, kernels without the GIL
                side = _side_thread()
                with side.beside() if side is not None else contextlib.nullcontext() as ex:
                    self.fusion.update(depths, masks, windows=secondary_windows, side=ex, principal=principal)
            else:
                self.fusion.update(depths, masks)
        else:
            self.frames = [
                prepare_frame(self.cameras[0], depths[0], masks[0], invalid=self.invalid, fill_radius=self.fill_radius)
            ]
        self._updated = True

    @property
    def ready(self) -> bool:
        """True once a frame set has been taken (:meth:`update`)."""
        return self._updated

    def query(self, centres: np.ndarray, radii: np.ndarray) -> PointDistances:
        """Distance stage: distances of the control spheres to the obstacles."""
        kw = dict(rho=self.rho, mode=self.mode, alpha=self.alpha, direction_stride=self.direction_stride)
        if self.fusion is not None:
            return self._fused(centres, radii, kw)
        return query_distances(self.frames[0], centres, radii, **kw)

    def _fused(self, centres, radii, kw: dict) -> PointDistances:
        """The depth grid's query, shared with the side thread (``side=``) where the principal image has
        :data:`SHARED_QUERY_MIN_PIXELS` or more and this thread may use two CPUs or more (on one allowed CPU
        the two would only take turns)."""
        cam = self.cameras[0]
        big = cam.width * cam.height >= SHARED_QUERY_MIN_PIXELS
        side = _side_thread() if big and usable_cpus() >= 2 else None
        with side.beside() if side is not None else contextlib.nullcontext() as ex:
            return self.fusion.query(centres, radii, side=ex, **kw)

    def query_far(self, centres: np.ndarray, radii: np.ndarray, res: PointDistances) -> PointDistances:
        """The distances up to ``ssm_range`` for a speed and separation monitor: ``res`` (the :meth:`query`
        at ρ) where it found something, and where it found nothing a ``"min"`` query at ``ssm_range`` (the
        same lower bound, farther out; inf beyond it). Without ``ssm_range``: ``res``, unchanged."""
        far = ~np.isfinite(np.asarray(res.distance, float))
        if self.ssm_range is None or not far.any():
            return res
        c, r = np.atleast_2d(np.asarray(centres, float))[far], np.asarray(radii, float).reshape(-1)[far]
        kw = dict(rho=self.ssm_range, mode="min", alpha=self.alpha, direction_stride=self.direction_stride)
        more = self._fused(c, r, kw) if self.fusion is not None else query_distances(self.frames[0], c, r, **kw)
        merged = [np.array(a, copy=True) for a in res]
        for a, b in zip(merged, more, strict=True):
            a[far] = b
        return PointDistances(*merged)

    def tolerance(self, centres: np.ndarray, noise_coeff: float = 0.0) -> np.ndarray:
        """Declared tolerance (N,) m of :meth:`query` at ``centres`` (N, 3): how far an evaluated distance
        may exceed the true clearance. Fusion: :meth:`DepthGridFusion.tolerance`; one camera: one pixel
        footprint at ``d_p + ρ``. Plus three standard deviations of the depth noise ``noise_coeff z²``
        (m⁻¹) at ``d_p + ρ`` in each camera."""
        c = np.atleast_2d(np.asarray(centres, float))
        if self.fusion is not None:
            tol = self.fusion.tolerance(c, rho=self.rho)
        else:
            cam = self.cameras[0]
            tol = (np.maximum(cam.world_to_camera(c)[:, 2], 0.0) + self.rho) / min(cam.fx, cam.fy)
        noise = np.zeros(len(c))
        for cam in self.cameras:
            z = np.maximum(cam.world_to_camera(c)[:, 2], 0.0) + self.rho
            noise = np.maximum(noise, 3.0 * noise_coeff * z * z)
        return tol + noise
