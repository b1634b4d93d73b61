"""Self-filter: remove the robot from depth images (ICRA'12 §IV-B, Fig. 8; RA-L'16 §VII).

The robot's own collision geometry (:attr:`depthguard.robot.model.RobotModel.geometry`: meshes, boxes,
cylinders, spheres, capsules, and attached tools and payloads), inflated by ``margin``, is drawn into the
image with numba, without OpenGL: meshes by a triangle z-buffer rasteriser (:mod:`depthguard.robot._raster`),
whose vertices are moved out so that every face moves out by at least ``margin``; spheres and capsules by
exact ray casting (:mod:`depthguard.robot._capsule_raster`). Pixel rays pass through the pixel centres
(``p_x = u + 0.5``, ``docs/conventions.md``). Along each ray every shape occupies a depth interval
``[near, far]`` (for a non-convex mesh, from its first to its last surface).

Output (:class:`SelfFilterResult`):

* ``mask`` (H, W) bool, the pixels to remove:
  - a *measured* pixel whose depth lies inside a shape's interval, i.e. a 3-D point within ``margin`` of the
    robot (depth noise, calibration error and joint-state latency up to ``margin`` metres are tolerated);
  - a pixel *without reading* (0, NaN, inf) inside the inflated silhouette. A hole outside it, even right
    beside the robot, is not robot: it follows the missing-depth policy downstream (unknown space).
  A measured point in front of the inflated robot (a hand before the forearm) or behind it (background
  seen past a robot that has moved) is kept: it is not the robot.
* ``robot_depth`` (H, W) float: inside the inflated silhouette, the nearest depth ``z_C`` of the inflated
  robot, NaN elsewhere. It is a conservative (nearer) robot depth (RA-L'16 case iv). A camera inside the
  inflated robot (within ``margin`` of it, e.g. on a link) has it at 0 along every ray that starts inside a
  shape, and removes every measured point up to where the ray leaves that shape.

Limits: obstacles closer than ``margin`` to the robot are removed with it, and so are points in a
concavity of an open mesh between its first and last surface along the ray; mixed "flying" pixels at depth
edges outside the inflated robot are kept as obstacles. Nothing farther than ``margin`` from the
robot's surface is removed (issue 10): every inflated mesh vertex moves at most ``margin``; boxes and
convex meshes are drawn as their Minkowski sum with a polyhedral ball; a point between two parts of one
closed mesh (its winding number is 0) is kept. The price: near a non-convex mesh's sharp edges and corners
the tolerance for robot points shrinks (a face there moves out by ``margin / |o|``, ``o`` the smallest
offset that moves all of the vertex's faces by 1; at least ``margin / 2``; a cylinder's rims
``margin / sqrt(2)``); convex meshes keep at least 93 % of it everywhere, boxes 86 % at edges and corners.
A cylinder is drawn as the prism that circumscribes it (0.9 % of its radius out), so points up to that
much beyond the margin may go at the prism's side edges. Triangles are clipped at ``ZNEAR`` (1 mm) in front
of the camera. A camera inside an inflated shape has its rays start at depth 0; a camera outside a closed
shape that the near plane cuts has the rays through the cut start at ``ZNEAR`` (the cut's cross-section is
counted in, :func:`depthguard.robot._raster._near_plane_cap`; before, a camera up to 1 mm outside a shell
lost the entry of those rays and kept robot points behind it: a property test found one 0.19 mm outside a
Panda link's shell, robot points 2-4 cm away). Readings nearer than ``ZNEAR`` on such rays are kept (no
depth camera measures that near; its pixels without a reading inside the silhouette are robot).
"""

from __future__ import annotations

import functools
import threading
import warnings
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from depthguard.camera import Camera
from depthguard.robot._capsule_raster import capsule_kernel
from depthguard.robot._raster import finish_kernel, mesh_kernel

__all__ = [
    "SelfFilterResult",
    "self_filter",
    "self_filter_tasks",
    "self_filter_capsules",
    "render_capsules_depth",
    "render_robot_depth",
]

ZNEAR = 1e-3  # m: triangles are clipped at this depth


class SelfFilterResult(NamedTuple):
    """Self-filter output. ``mask``: (H, W) bool, True = robot (remove). ``robot_depth``: (H, W) float
    metres, conservative robot depth inside the inflated silhouette, NaN elsewhere (None when the filter
    was asked for the mask alone)."""

    mask: np.ndarray
    robot_depth: np.ndarray | None


_WORK = threading.local()
_NO_CAPSULES = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


def _work_buffers(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-thread (H, W) work buffers: near depth (inf), largest and smallest inverse depth of one shape
    (0, inf) and winding numbers (0) between calls."""
    bufs = getattr(_WORK, "bufs", None)
    if bufs is None or bufs[0].shape != shape:
        bufs = (np.full(shape, np.inf), np.zeros(shape), np.full(shape, np.inf), np.zeros(shape, np.int64))
        _WORK.bufs = bufs
    return bufs


def _capsules_in_camera(camera: Camera, a: np.ndarray, b: np.ndarray, radius: np.ndarray):
    a = np.ascontiguousarray(camera.world_to_camera(np.asarray(a, dtype=float).reshape(-1, 3)))
    b = np.ascontiguousarray(camera.world_to_camera(np.asarray(b, dtype=float).reshape(-1, 3)))
    r = np.ascontiguousarray(np.asarray(radius, dtype=float).reshape(-1))
    if not (len(a) == len(b) == len(r)):
        raise ValueError(f"capsules: {len(a)} a, {len(b)} b and {len(r)} radii must match")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(r)) and np.all(r >= 0)):
        raise ValueError("capsules must be finite with radii >= 0")
    return a, b, r


def _check(camera: Camera, depth: np.ndarray, margin: float, pad_px: int) -> np.ndarray:
    depth = camera.check_image(depth, "depth")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
    if isinstance(pad_px, bool) or int(pad_px) != pad_px or pad_px < 0:
        raise ValueError(f"pad_px must be an integer >= 0, got {pad_px!r}")
    if pad_px:
        warnings.warn(
            "pad_px is ignored: missing pixels outside the inflated silhouette are not robot (widen the "
            "silhouette with margin instead)",
            DeprecationWarning,
            stacklevel=3,
        )
    return depth


def _run(camera: Camera, depth: np.ndarray, margin: float, caps, meshes, with_depth: bool = True) -> SelfFilterResult:
    """Shared driver: capsules ``(A, B, R)`` in the camera frame and meshes ``(geometry, T)`` or None;
    ``with_depth=False``: the mask alone (``robot_depth`` None)."""
    d = np.ascontiguousarray(depth, dtype=np.float64)
    mask = np.zeros(camera.shape, dtype=np.bool_)
    robot_depth = np.full(camera.shape, np.nan) if with_depth else np.empty((0, 0))
    near, snear, sfar, wn = _work_buffers(camera.shape)
    ubox = np.array([1 << 30, -1, 1 << 30, -1], dtype=np.int64)
    cam = (camera.fx, camera.fy, camera.cx, camera.cy)
    A, B, R = caps
    if len(R):
        capsule_kernel(A, B, R, float(margin), *cam, d, mask, near, ubox, bool(with_depth))
    if meshes is not None:
        g, T = meshes
        infl = np.maximum(float(margin) - g.excess, g.slack)  # decimated: within margin of the original
        winding = (wn, g.face_planes, g.closed, g.watertight)
        mesh_kernel(g.V, g.O, g.F, g.vr, g.fr, T, infl, *cam, ZNEAR, d, mask, near, snear, sfar, *winding, ubox)
    finish_kernel(d, mask, near, robot_depth, ubox, bool(with_depth))
    return SelfFilterResult(mask, robot_depth if with_depth else None)


def self_filter_capsules(
    camera: Camera,
    depth: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    radius: np.ndarray,
    *,
    margin: float = 0.03,
    pad_px: int = 0,
) -> SelfFilterResult:
    """Self-filter for robot geometry given as world-frame capsules (the coarse description, or a baseline).

    Args:
        camera: the depth camera (pose and intrinsics).
        depth: (H, W) measured depth ``z_C`` in metres; 0, NaN or inf = no reading.
        a, b: (L, 3) capsule segment ends in the world frame, m; radius: (L,) m.
        margin: inflation of every capsule, m (>= 0): noise, calibration and latency tolerance.
        pad_px: ignored (deprecated; a hole beside the robot is not robot).
    Returns:
        :class:`SelfFilterResult` (see the module docstring).
    """
    d = _check(camera, depth, margin, pad_px)
    return _run(camera, d, margin, _capsules_in_camera(camera, a, b, radius), None)


class _DefaultModel:
    """The shipped LWR, loaded once, one instance per thread (a RobotModel is not thread-safe)."""

    _local = threading.local()

    @classmethod
    def get(cls):
        model = getattr(cls._local, "model", None)
        if model is None:
            from depthguard.robot.model import load_lwr4

            model = cls._local.model = load_lwr4()
        return model


def self_filter(
    camera: Camera,
    depth: np.ndarray,
    q: np.ndarray,
    model=None,
    *,
    margin: float = 0.03,
    pad_px: int = 0,
    with_depth: bool = True,
) -> SelfFilterResult:
    """Remove the robot at joint positions ``q`` (nq,) from ``depth`` (H, W), metres (0/NaN = no reading).

    ``model`` is a :class:`depthguard.robot.model.RobotModel` (default: the shipped LWR,
    :func:`depthguard.robot.model.load_lwr4`, one per thread); its collision geometry, attachments
    included, is removed. ``q`` has the model's full ``nq`` (e.g. a Panda's finger joints).
    ``margin`` (m, >= 0) inflates the geometry; ``pad_px`` is ignored (deprecated).
    Returns ``(mask (H, W) bool, robot_depth (H, W) float)`` as a :class:`SelfFilterResult`;
    ``with_depth=False``: the same mask, faster (capsules test measured pixels as points), and
    ``robot_depth`` None.
    """
    return _tasks([camera], [_check(camera, depth, margin, pad_px)], q, model, margin, with_depth)[0]()


def self_filter_tasks(
    cameras: list[Camera],
    depths: list[np.ndarray],
    q: np.ndarray,
    model=None,
    *,
    margin: float = 0.03,
    with_depth: bool = True,
) -> list[Callable[[], SelfFilterResult]]:
    """:func:`self_filter` of several cameras at one joint state, as one task per camera: the kinematics are
    computed here, once, on this thread (a model's kinematics are not shared between threads); each task
    (no arguments) draws the robot into its camera's image and may run on any thread (its kernels release
    the GIL). ``depths``: one (H, W) image per camera, metres; ``margin``, ``with_depth``: as
    :func:`self_filter`."""
    cameras, depths = list(cameras), list(depths)
    if len(cameras) != len(depths):
        raise ValueError(f"self-filter: {len(cameras)} cameras but {len(depths)} depth images")
    ds = [_check(c, d, margin, 0) for c, d in zip(cameras, depths, strict=True)]
    return _tasks(cameras, ds, q, model, margin, with_depth)


def _tasks(cameras: list[Camera], ds: list[np.ndarray], q: np.ndarray, model, margin: float, with_depth) -> list:
    """The per-camera tasks of checked depth images ``ds``; the kinematics here, once."""
    model = _DefaultModel.get() if model is None else model
    H, _ = model.joint_kinematics(model.check_q(q))  # (J+1, 4, 4) joint poses
    R, p = H[:, :3, :3], H[:, :3, 3]
    g = model.geometry
    world_caps = g.world_capsules(R, p) if len(g.cap_r) else None
    tasks = []
    for c, d in zip(cameras, ds, strict=True):
        caps = _capsules_in_camera(c, *world_caps) if world_caps is not None else _NO_CAPSULES
        meshes = (g, g.mesh_transforms(R, p, c.R, c.t)) if g.n_triangles else None
        tasks.append(functools.partial(_run, c, d, margin, caps, meshes, bool(with_depth)))
    return tasks


def render_robot_depth(camera: Camera, q: np.ndarray, model, *, margin: float = 0.0) -> np.ndarray:
    """(H, W) depth ``z_C`` (m) of the robot's geometry inflated by ``margin`` through each pixel centre,
    NaN where none."""
    return self_filter(camera, np.zeros(camera.shape), q, model, margin=margin).robot_depth


def render_capsules_depth(camera: Camera, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(H, W) depth ``z_C`` (m) of the capsules' first surface through each pixel centre, NaN where none."""
    return self_filter_capsules(camera, np.zeros(camera.shape), a, b, radius, margin=0.0).robot_depth
