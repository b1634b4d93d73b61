"""The processing chain of a cell, independent of where the data comes from: self-filter, distances,
controller (the three stages of the papers), built from a cell file.

:class:`Chain` is what ``depthguard run`` drives with the ticks of a source (simulated cell, ROS 2 bag, live
camera): :meth:`Chain.on_frames` at camera rate, :meth:`Chain.query` at the distance rate, :meth:`Chain.control`
at the control rate.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from depthguard.camera import Camera
from depthguard.control.cycle import AvoidanceController, ControllerConfig, CycleInput, CycleOutput
from depthguard.depthspace import PointDistances
from depthguard.io.background import BackgroundFile
from depthguard.io.cellfile import CellError, CellFile, ssm_range
from depthguard.robot.control_points import ControlPointSet
from depthguard.robot.health import CameraHealth
from depthguard.robot.model import RobotModel, load_lwr4
from depthguard.robot.selffilter import self_filter
from depthguard.robot.shapes import Shape
from depthguard.robot.spheres import shape_cover
from depthguard.runner.carried import check_camera_parents, place_carried

__all__ = [
    "Chain",
    "load_cell_robot",
    "cell_control_points",
    "cell_distance_stage",
    "cell_background",
    "background_applied",
    "self_filter_margins",
    "check_chain_support",
    "controller_arrays",
]


def _attachment_shapes(cell: CellFile) -> list[Shape]:
    """The cell file's ``[[robot.attachments]]`` as shapes fixed to links."""
    return [
        Shape(
            link=a.link,
            kind=a.shape,
            size=tuple(a.size),
            mesh=None if a.mesh is None else str(a.mesh),
            xyz=tuple(a.xyz),
            rpy=tuple(a.rpy),
            name=a.name,
        )  # fmt: skip
        for a in cell.robot.attachments
    ]


def load_cell_robot(cell: CellFile) -> RobotModel:
    """The robot model named by the cell file (a shipped model or a URDF path), with its attachments (tools,
    payloads: the self-filter removes them)."""
    r = cell.robot
    model = load_lwr4() if r.model == "lwr4" else RobotModel.from_urdf(Path(r.urdf), ee_frame=r.ee_frame)
    for i, shape in enumerate(_attachment_shapes(cell)):
        try:
            model.attach(shape)
        except ValueError as exc:
            raise CellError(f"{cell.path}: robot.attachments[{i}] ('{shape.name}'): {exc}") from None
    return model


def cell_control_points(cell: CellFile, model: RobotModel) -> ControlPointSet:
    """The control points the cell file names for ``model`` (``"ee"``: the end effector only), plus its
    explicit ``[[robot.spheres]]``, plus spheres that contain each of the model's attachments
    (:func:`depthguard.robot.spheres.shape_cover`; a tool that no control point covers would be unprotected;
    ``"auto"`` covers them already)."""
    r = cell.robot
    preset = r.control_points
    points = ControlPointSet.build(model, {} if preset == "ee" else preset, r.ee_radius)
    extra = [(f"{s.link}/sphere{i}", s.link, s.position, s.radius) for i, s in enumerate(r.spheres)]
    if preset != "auto":
        for shape in model.attachments:
            covers = enumerate(zip(*shape_cover(shape), strict=True))
            extra += [(f"{shape.name}/{j}", shape.link, c, rr) for j, (c, rr) in covers]
    if not extra:
        return points
    try:
        return points.with_spheres(extra)
    except ValueError as exc:
        raise CellError(f"{cell.path}: robot.spheres: {exc}") from None


def _controller_config(cell: CellFile) -> ControllerConfig:
    c = cell.controller
    values = dict(
        dt=1.0 / float(c["rate"]),
        rho_ee=float(c["rho_ee"]),
        alpha_ee=float(c["alpha"]),
        v_rep_max=float(c["v_rep_max"]),
        rho_body=float(c["rho_body"]),
        alpha_body=float(c["alpha"]),
        velocity_scale=float(c["velocity_scale"]),
        a_max=float(c["a_max"]),
        j_max=float(c["j_max"]),
        distance_timeout=float(c["distance_timeout"]),
        joint_timeout=float(c["joint_timeout"]),
        resume_time=float(c["resume_time"]),
    )
    if c["ssm"]:  # speed and separation monitoring with the repulsion (docs/ssm.md); +inf means "nothing
        # within the range of the distances", so the monitor takes it as that range (SsmConfig.sensing_range)
        from depthguard.control.ssm import SsmConfig

        values.update(avoidance="both", ssm=SsmConfig(sensing_range=ssm_range(cell)))
    known = {f.name for f in dataclasses.fields(ControllerConfig)}
    return ControllerConfig(**{k: v for k, v in values.items() if k in known})


_BACKGROUNDS: dict[tuple[str, int], BackgroundFile] = {}  # (path, mtime_ns) -> file (stages are rebuilt often)


def background_applied(cell: CellFile) -> str | None:
    """The background file (resolved path) that the chain applies: ``[controller] background`` with
    ``ssm = true``; None otherwise (without SSM the repulsion sees the whole scene, the table included)."""
    ref = cell.controller.get("background")
    return ref if ref is not None and cell.controller["ssm"] else None


def cell_background(cell: CellFile, cameras: list[Camera]) -> tuple[list[np.ndarray], list[float]] | None:
    """Per camera of ``cameras`` (the cell file's order), the background rule's threshold (H, W) and far range
    (:mod:`depthguard.robot.background`) from the cell's background file, when :func:`background_applied`;
    a background of another image size than the camera's raises :class:`CellError` naming the key. None for
    a stage of other cameras than the cell's (``calibrate``'s effect of one camera alone)."""
    from pathlib import Path

    from depthguard.io.background import read_background
    from depthguard.robot.background import far_range

    path = background_applied(cell)
    if path is None or len(cameras) != len(cell.cameras):
        return None
    key = (path, Path(path).stat().st_mtime_ns)
    if key not in _BACKGROUNDS:
        try:
            _BACKGROUNDS[key] = read_background(path)
        except ValueError as exc:
            raise CellError(f"{cell.path}: controller.background: {exc}") from None
    bg = _BACKGROUNDS[key]
    thresholds = bg.thresholds()
    out = []
    for cc, cam in zip(cell.cameras, cameras, strict=True):
        k = bg.names.index(cc.name)
        w, h = bg.size(k)
        if (w, h) != (cam.width, cam.height):
            raise CellError(
                f"{cell.path}: controller.background '{cell.raw['controller']['background']}': camera '{cc.name}'"
                f" is {w}x{h} there but {cam.width}x{cam.height} in this run: commission the cell at the run's"
                " image size (a simulated --quick run is at the scenario's quick resolution)"
            )
        out.append(thresholds[k])
    return out, [far_range(c) for c in cameras]


def self_filter_margins(cell: CellFile, cameras: list[Camera], q: np.ndarray, model: RobotModel) -> list[float] | None:
    """Per camera, the self-filter margin (m) at joint positions ``q``: with a camera ``noise_coeff`` c > 0 in
    the cell file, max(3 cm, 5 c z²) at the robot's farthest depth in that camera
    (:func:`depthguard.sim.pipeline.model_filter_margin`, as the simulated cell does; robot pixels measured
    more than the margin in front of the robot stay obstacles: phantoms inside the control spheres); None
    when no camera gives one (the self-filter's own 3 cm everywhere, the distance stage's default)."""
    if not any(cc.noise_coeff > 0 for cc in cell.cameras):
        return None
    from depthguard.sim.pipeline import model_filter_margin

    return [model_filter_margin(c, q, model, cc.noise_coeff) for cc, c in zip(cell.cameras, cameras, strict=True)]


def cell_distance_stage(cell: CellFile, cameras: list[Camera]):
    """The distance stage (:class:`depthguard.sim.pipeline.DistanceStage`) with every ``[distance]`` setting
    of the cell file: rho, mode, missing-depth policy, hole filling, depth-grid step, workspace and the
    direction lattice; with ``ssm = true`` and a ``[controller] background``, two distance sets on the same
    frames (:class:`depthguard.robot.background.MonitorBackgroundStage`, docs/ssm.md): its ``query`` answers
    on the images as measured (the repulsion and the body bounds keep avoiding the table and the fixtures)
    and its ``query_monitor`` on the images with the background applied (what the empty cell explains reads
    as free space: speed and separation monitoring sees people and unknown space only)."""
    from depthguard.robot.background import MonitorBackgroundStage

    stage = _distance_stage(cell, cameras)
    bg = cell_background(cell, cameras)
    if bg is None:
        return stage
    return MonitorBackgroundStage(_distance_stage(cell, cameras, with_ssm_range=False), stage, *bg)


def _distance_stage(cell: CellFile, cameras: list[Camera], with_ssm_range: bool = True):
    from depthguard.sim.pipeline import DistanceStage

    d = cell.distance
    try:
        return DistanceStage(
            list(cameras), rho=float(d["rho"]), mode=d["mode"], alpha=float(cell.controller["alpha"]),
            workspace=tuple(d["workspace"]), dd=float(d["grid_dd"]), invalid=d["invalid"],
            fill_radius=int(d["fill_radius"]), direction_stride=d["direction_stride"],
            ssm_range=ssm_range(cell) if with_ssm_range else None,
        )  # fmt: skip
    except ValueError as exc:
        raise CellError(f"{cell.path}: distance: {exc}") from None


def check_chain_support(cell: CellFile) -> None:
    """Refuse what the chain (``depthguard run``, the nodes, the live view) cannot do yet, instead of
    running something else: ``distance.backend = "octree"`` (the scenarios and ``depthguard distance`` have
    it; the chain computes depth-space / depth-grid distances only)."""
    if cell.distance["backend"] != "depthspace":
        raise CellError(
            f"{cell.path}: distance.backend = {cell.distance['backend']!r} is not available in `depthguard run`"
            " and the nodes yet (only 'depthspace': depth space for one camera, the depth grid for several);"
            " the octree backend runs in `depthguard scenario --backend octree` and `depthguard distance`"
        )


class Chain:
    """Self-filter -> distance stage -> controller for one cell.

    Args:
        cell: the cell file.
        cameras: the cameras (principal first) with the intrinsics and poses in use (a source may resolve
            them from CameraInfo / TF / the device); a camera carried by a link has its pose in that link's
            frame.
        model: the robot model; ``points``: its control points (default: the cell file's preset).
        parents: per camera, ``"world"`` or the robot link that carries it (default: the cell file's
            ``parent``). A carried camera's world pose is set at every frame set from the frames' joint
            state (:meth:`on_frames`), and the distance stage is rebuilt for it (the depth grid's stored
            map depends on the cameras' poses: about 20 ms for two 640x480 cameras).
    Attributes:
        cameras: the cameras in the world frame, as of the latest frame set.
        local_cameras: the cameras as given (a carried camera's pose in its link's frame).
    """

    def __init__(
        self,
        cell: CellFile,
        cameras: list[Camera],
        model: RobotModel,
        points: ControlPointSet | None = None,
        parents: list[str] | None = None,
    ) -> None:
        check_chain_support(cell)
        self.cell = cell
        self.cameras = list(cameras)
        self.local_cameras = list(cameras)
        self.parents = list(parents) if parents is not None else [c.parent for c in cell.cameras]
        self._carried = check_camera_parents(cell, model, self.parents)
        self.model = model
        points = cell_control_points(cell, model) if points is None else points
        self.points = points
        d = cell.distance
        self.rho, self.alpha = float(d["rho"]), float(cell.controller["alpha"])
        self.stage = cell_distance_stage(cell, self.cameras)
        self.config = _controller_config(cell)
        self.controller = AvoidanceController(points, self.config)
        self.latest: tuple[float, PointDistances] | None = None
        self.latest_monitor: PointDistances | None = None  # (the monitor's own, with a background)
        self.masks: list[np.ndarray] | None = None
        self.t_frames: float | None = None
        self.health = [CameraHealth(c, cc.name, model) for c, cc in zip(self.cameras, cell.cameras, strict=True)]
        self.faults: dict[str, str] = {}

    def warm_up(self) -> None:
        """Load every kernel of the controller's cycle before a real-time loop
        (:func:`depthguard.control.warmup.warm_up`, 0.4-0.6 s with the kernel cache filled)."""
        from depthguard.control.warmup import warm_up

        warm_up(self.points, self.config, self.model)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.model.joint_names

    def on_frames(self, depths: list[np.ndarray], q: np.ndarray, t_frames: float | None = None) -> list[np.ndarray]:
        """Frame stage: health check and self-filter of every camera's depth (H, W) m at the joint positions
        ``q``; returns the robot masks (H, W) bool. A faulty camera stops the controller
        (``STOP_SENSOR_FAULT``, :attr:`faults` names it)."""
        self.faults = {
            h.name: f"image of shape {np.shape(d)}, expected {c.shape}"
            for h, c, d in zip(self.health, self.cameras, depths, strict=True)
            if np.ndim(d) != 2 or np.shape(d) != c.shape
        }
        if self.faults:  # (a driver that changed its resolution mid-run): stop, keep the last good frames
            self.controller.set_sensor_fault("; ".join(f"{k}: {v}" for k, v in self.faults.items()))
            return self.masks if self.masks is not None else [np.zeros(c.shape, dtype=bool) for c in self.cameras]
        if self._carried:
            self._place_carried_cameras(q)
        for h, d in zip(self.health, depths, strict=True):
            fault = h.check(d, q, t_frames)  # (a frame set whose stamp does not advance is not a new frame)
            if fault is not None:
                self.faults[h.name] = fault
        self.controller.set_sensor_fault(
            "; ".join(f"{k}: {v}" for k, v in self.faults.items()) if self.faults else None
        )
        margins = self_filter_margins(self.cell, self.cameras, q, self.model)  # None: the 3 cm default
        if margins is None:
            masks = [
                np.asarray(self_filter(c, d, q, self.model, with_depth=False)[0])
                for c, d in zip(self.cameras, depths, strict=True)
            ]
        else:
            masks = [
                np.asarray(self_filter(c, d, q, self.model, margin=m, with_depth=False)[0])
                for c, d, m in zip(self.cameras, depths, margins, strict=True)
            ]
        # with the joint state, the principal camera's robot pixels and the secondary cameras' robot windows
        # come from the robot's inner capsules (robot.interior; no phantom zeros behind the arm)
        self.stage.update(depths, masks, q, self.model, *([margins] if margins is not None else []))
        self.masks = masks
        self.t_frames = t_frames
        return masks

    def _place_carried_cameras(self, q: np.ndarray) -> None:
        """World pose of every camera carried by a link at joint positions ``q`` (:mod:`depthguard.runner.carried`)."""
        self.cameras[:] = place_carried(self.local_cameras, self._carried, self.model, q)  # (in place: shared)
        for i, _ in self._carried:
            self.health[i].camera = self.cameras[i]
        self.stage = cell_distance_stage(self.cell, self.cameras)

    @property
    def ready(self) -> bool:
        return self.masks is not None

    def query(self, t: float, q: np.ndarray) -> PointDistances:
        """Distance stage at ``t``: control spheres at ``q`` against the latest frames."""
        cps = self.points.evaluate(q)
        res = self.stage.query(cps.centres, cps.radii)
        res = self.stage.query_far(cps.centres, cps.radii, res)  # SSM: beyond rho too (docs/ssm.md)
        # with a background: the monitor's distances from the same frames without the empty cell
        monitor = getattr(self.stage, "query_monitor", None)
        self.latest_monitor = monitor(cps.centres, cps.radii) if monitor is not None else None
        # the distances are as old as the frames they come from: a camera that stops sending makes them
        # stale (STOP_STALE_DISTANCES after distance_timeout), however often they are recomputed
        self.latest = (t if self.t_frames is None else min(t, self.t_frames), res)
        return res

    def control(
        self, t: float, q: np.ndarray | None, qdot: np.ndarray | None, t_joints: float, xdot_d: np.ndarray
    ) -> CycleOutput:
        """Control stage: one cycle of the avoidance controller with the latest distances."""
        N = self.points.n_points
        md = mdirs = None  # (the monitor's own distances, with a background; else it takes the repulsion's)
        if self.latest is None:
            d, dirs, td = None, None, t  # no distances yet: STOP_STALE_DISTANCES (a finite stamp)
        else:
            td, res = self.latest
            d, dirs = controller_arrays(res.distance, res.direction, N)
            if self.latest_monitor is not None:
                md, mdirs = controller_arrays(self.latest_monitor.distance, self.latest_monitor.direction, N)
        return self.controller.step(CycleInput(t, q, qdot, t_joints, xdot_d, d, dirs, td, md, mdirs))


def controller_arrays(distance, direction, N: int) -> tuple[np.ndarray, np.ndarray]:
    """``(distances (N,), directions (N, 3))`` for :class:`CycleInput` from a query's (or a message's)
    distances and directions, the direction of every non-finite distance set to 0 (ignored there); wrongly
    shaped ones are passed on as they are (the controller's input check stops on them)."""
    d = np.asarray(distance, dtype=float)
    dirs = np.asarray(direction, dtype=float)
    return d, (np.where(np.isfinite(d)[:, None], dirs, 0.0) if dirs.shape == (N, 3) else dirs)
