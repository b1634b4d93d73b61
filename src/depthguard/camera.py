"""Pinhole depth camera: intrinsics, extrinsics, projection into depth space.

Conventions (``docs/conventions.md``, ICRA'12 eqs. 1-3, RA-L'16 eqs. 1-3):

* world frame W = robot base frame; a camera pose is ``P_C = R @ P_W + t`` (eq. 2);
* camera axes follow OpenCV: x right, y down, z forward;
* depth is ``z_C`` (along the optical axis), not the ray length;
* pixel ``(u, v)`` covers ``[u, u+1) x [v, v+1)``; a point projects to
  ``p_x = fx x_C / z_C + cx``, ``p_y = fy y_C / z_C + cy`` and lands in pixel
  ``(floor(p_x), floor(p_y))``. The ray through the centre of pixel u has ``p_x = u + 0.5``.

ROS ``CameraInfo`` (OpenCV, ``image_geometry``) and librealsense put the centre of pixel u at ``p_x = u``:
their principal point is half a pixel less than DepthGuard's (:func:`principal_point_from_opencv`,
:func:`principal_point_to_opencv` convert at every boundary).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from depthguard.errors import check_known_keys
from depthguard.validation import check_finite_array, check_positive, check_rotation, is_numeric_nest

__all__ = ["Camera", "look_at", "principal_point_from_opencv", "principal_point_to_opencv"]

#: DepthGuard's principal point minus OpenCV's (ROS CameraInfo, librealsense) for the same camera, pixels
OPENCV_PIXEL_OFFSET = 0.5


@dataclass(frozen=True)
class Camera:
    """A calibrated pinhole depth camera.

    Attributes:
        width, height: image size in pixels (> 0).
        fx, fy: focal lengths in pixels (the papers' ``f s_x``, ``f s_y``), > 0.
        cx, cy: principal point in pixels.
        R: (3, 3) rotation world -> camera (eq. 2), orthonormal with det +1.
        t: (3,) translation world -> camera in metres (eq. 2).
        min_depth, max_depth: valid measurement range in metres (Kinect v1: 0.5-4.5 m).
        depth_scale: metres per unit of a 16-bit depth PNG (0.001 = millimetres).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    min_depth: float = 0.3
    max_depth: float = 8.0
    depth_scale: float = 0.001

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            try:
                ok = not isinstance(value, bool) and float(value).is_integer() and 0 < value < 2**31
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise ValueError(f"camera field '{name}' must be a positive integer below 2**31, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy"):
            object.__setattr__(self, name, check_positive(getattr(self, name), f"camera field '{name}'"))
        for name in ("cx", "cy"):
            raw = getattr(self, name)
            try:
                value = float(raw)
            except (TypeError, ValueError, OverflowError):
                value = float("nan")
            if not np.isfinite(value):
                raise ValueError(f"camera field '{name}' must be a finite number, got {raw!r}")
            object.__setattr__(self, name, value)
        R = check_rotation(self.R, "camera field 'R'")
        t = check_finite_array(self.t, (3,), "camera field 't'")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "min_depth", check_positive(self.min_depth, "camera field 'min_depth'"))
        object.__setattr__(self, "max_depth", check_positive(self.max_depth, "camera field 'max_depth'"))
        if self.max_depth <= self.min_depth:
            raise ValueError(
                f"camera field 'max_depth' ({self.max_depth}) must be larger than 'min_depth' ({self.min_depth})"
            )
        object.__setattr__(self, "depth_scale", check_positive(self.depth_scale, "camera field 'depth_scale'"))

    # ------------------------------------------------------------------ frames
    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)`` as numpy arrays have it."""
        return (self.height, self.width)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix (ICRA'12 eq. 1)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def position(self) -> np.ndarray:
        """(3,) optical centre in the world frame, ``-R^T t`` in metres."""
        return -self.R.T @ self.t

    def world_to_camera(self, points_w: np.ndarray) -> np.ndarray:
        """Map (..., 3) world points to the camera frame (eq. 2)."""
        p = np.asarray(points_w, dtype=float)
        return p @ self.R.T + self.t

    def camera_to_world(self, points_c: np.ndarray) -> np.ndarray:
        """Map (..., 3) camera-frame points to the world frame (inverse of eq. 2)."""
        p = np.asarray(points_c, dtype=float)
        return (p - self.t) @ self.R

    def vector_to_world(self, vectors_c: np.ndarray) -> np.ndarray:
        """Rotate (..., 3) free vectors from camera to world: ``V_R = R^T V_C`` (ICRA'12 §IV)."""
        return np.asarray(vectors_c, dtype=float) @ self.R

    # ----------------------------------------------------------- depth space
    def project(self, points_w: np.ndarray) -> np.ndarray:
        """Project (..., 3) world points into depth space (eq. 3).

        Returns:
            (..., 3) array ``[p_x, p_y, d_p]``: continuous pixel coordinates and depth ``z_C`` in metres.
            Points with ``z_C <= 0`` (or NaN) get ``p_x = p_y = nan``; a point at ``z_C > 0`` gets a number or
            ``±inf`` (far outside the image), never NaN: ``x_C / z_C``, not ``x_C * (1 / z_C)``, which is
            ``0 * inf = nan`` on the axis at ``z_C`` below 1/DBL_MAX (5.6e-309 m).
        """
        pc = self.world_to_camera(points_w)
        z = pc[..., 2]
        zpos = np.where(z > 0, z, np.nan)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            px = self.fx * (pc[..., 0] / zpos) + self.cx
            py = self.fy * (pc[..., 1] / zpos) + self.cy
        return np.stack([px, py, z], axis=-1)

    def unproject(self, px: np.ndarray, py: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Map depth-space points back to the world frame (RA-L'16 eq. 3).

        Args:
            px, py: continuous pixel coordinates, broadcastable arrays.
            depth: depth ``z_C`` in metres, broadcastable with ``px``.
        Returns:
            (..., 3) world points in metres.
        """
        d = np.asarray(depth, dtype=float)
        x = (np.asarray(px, dtype=float) - self.cx) * d / self.fx
        y = (np.asarray(py, dtype=float) - self.cy) * d / self.fy
        return self.camera_to_world(np.stack(np.broadcast_arrays(x, y, d), axis=-1))

    def unproject_image(self, depth: np.ndarray) -> np.ndarray:
        """Back-project a whole (H, W) depth image through pixel centres to (H, W, 3) world points."""
        self.check_image(depth, "depth")
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return self.unproject(u + 0.5, v + 0.5, depth)

    def pixel_ray_directions(self) -> np.ndarray:
        """(H, W, 3) camera-frame ray directions through pixel centres, scaled so that ``z = 1``."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(float)
        return np.stack([(u + 0.5 - self.cx) / self.fx, (v + 0.5 - self.cy) / self.fy, np.ones_like(u)], axis=-1)

    def check_image(self, image: np.ndarray, name: str = "depth") -> np.ndarray:
        """Raise ``ValueError`` unless ``image`` is a 2-D array of shape ``(height, width)``."""
        arr = np.asarray(image)
        if arr.ndim != 2 or arr.shape != self.shape:
            raise ValueError(
                f"{name} image has shape {arr.shape}, expected (height, width) = {self.shape} from the camera"
            )
        return arr

    def pixel_footprint(self, depth: float) -> float:
        """Lateral size in metres of one pixel at ``depth`` (the larger of x and y)."""
        return float(depth) / min(self.fx, self.fy)

    # ------------------------------------------------------------- (de)serialise
    def to_dict(self) -> dict[str, Any]:
        """The camera JSON object (``docs/conventions.md``, "Camera file")."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "min_depth": self.min_depth,
            "max_depth": self.max_depth,
            "depth_scale": self.depth_scale,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Camera:
        """Build a camera from its JSON object (``docs/conventions.md``), naming any bad, missing or unknown field."""
        if not isinstance(data, dict):
            raise ValueError(f"camera JSON must be an object, got {type(data).__name__}")
        required = ("width", "height", "fx", "fy", "cx", "cy", "R", "t")
        missing = [k for k in required if k not in data]
        if missing:
            raise ValueError(f"camera JSON is missing field(s) {missing}; required: {list(required)}")
        known = [*required, "min_depth", "max_depth", "depth_scale"]
        check_known_keys(data, known, "camera JSON")  # a typo such as 'min_Depth' must not fall back to a default
        kwargs = dict(data)
        for k in ("width", "height", "fx", "fy", "cx", "cy", "min_depth", "max_depth", "depth_scale"):
            if k in kwargs and (isinstance(kwargs[k], bool) or not isinstance(kwargs[k], int | float)):
                raise ValueError(f"camera field '{k}' must be a number, got {kwargs[k]!r}")
        for k in ("R", "t"):  # (numpy would take "1" and true for numbers)
            if not is_numeric_nest(kwargs[k]):
                raise ValueError(f"camera field '{k}' must hold numbers only, got {kwargs[k]!r}")
        return cls(**kwargs)

    @classmethod
    def kinect_v1(cls, R: np.ndarray | None = None, t: np.ndarray | None = None, **overrides: Any) -> Camera:
        """A Kinect v1-like camera: 640x480, fx = fy = 525 (about 62.7° horizontal FOV), 0.5-4.5 m."""
        params: dict[str, Any] = dict(
            width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5, min_depth=0.5, max_depth=4.5
        )
        params.update(overrides)
        return cls(R=np.eye(3) if R is None else R, t=np.zeros(3) if t is None else t, **params)

    def with_pose(self, R: np.ndarray, t: np.ndarray) -> Camera:
        """A copy of this camera with another pose (eq. 2)."""
        d = self.to_dict()
        d.update(R=np.asarray(R), t=np.asarray(t))
        return Camera(**d)

    def strided(self, step: int) -> Camera:
        """The camera of ``image[::step, ::step]`` (every ``step``-th pixel kept, not averaged): size
        ``ceil(W / step) x ceil(H / step)``, focal lengths ``/ step``, and the principal point placed so that
        kept pixel j's centre casts the ray of the original pixel ``step * j``'s centre:
        ``cx' = (cx - 0.5) / step + 0.5`` (``cx / step`` would be a binned image's, half an original pixel off)."""
        if isinstance(step, bool) or not isinstance(step, int | np.integer) or not 1 <= step < 2**31:
            raise ValueError(f"step must be an integer >= 1 and below 2**31, got {step!r}")
        d = self.to_dict()
        d.update(
            width=-(-self.width // step), height=-(-self.height // step), fx=self.fx / step, fy=self.fy / step,
            cx=(self.cx - 0.5) / step + 0.5, cy=(self.cy - 0.5) / step + 0.5, R=self.R, t=self.t,
        )  # fmt: skip
        return Camera(**d)


def _vector3(value: object, name: str, what: str) -> np.ndarray:
    """``value`` as a finite (3,) float array, else ``ValueError`` naming ``look_at``'s argument ``name``."""
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        a = None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"look_at: '{name}' must be a finite (3,) {what}, got {value!r}")
    return a


def _unit(v: np.ndarray) -> np.ndarray:
    """(3,) ``v / |v|`` for finite non-zero ``v``, scaled by its largest component first: the norm of 1e-160 or
    1e200 components would underflow or overflow (a row of ``R`` 1e-5 off unit length, or a zero row)."""
    v = v / np.abs(v).max()
    return v / np.linalg.norm(v)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Extrinsics ``(R, t)`` (eq. 2) of a camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target and its y axis points "down", i.e. away from ``up``.

    Args:
        eye: (3,) camera centre in the world frame, metres, finite.
        target: (3,) point the optical axis goes through, metres, finite and not ``eye``.
        up: (3,) world direction that appears upwards in the image: finite, non-zero, any length, not parallel
            to ``target - eye`` (the angle between them must exceed about 1e-9 rad).
    Returns:
        ``R`` (3, 3) orthonormal with det +1 (to rounding) and ``t`` (3,) in metres, with ``P_C = R P_W + t``.
    Raises:
        ValueError: naming the argument, for a wrong shape, a non-finite value, ``eye == target``, a zero ``up``
            or an ``up`` parallel to the viewing direction.
    """
    eye = _vector3(eye, "eye", "point in metres")
    target = _vector3(target, "target", "point in metres")
    up = _vector3(up, "up", "direction")
    with np.errstate(over="ignore"):  # (named below instead of a numpy warning)
        z = target - eye
    if not np.all(np.isfinite(z)):
        raise ValueError(f"look_at: 'eye' and 'target' must be finite points in metres, got {eye} and {target}")
    if not z.any():
        raise ValueError("look_at: 'eye' and 'target' coincide")
    if not up.any():
        raise ValueError("look_at: 'up' must be a non-zero direction, got (0, 0, 0)")
    z = _unit(z)
    x = np.cross(z, _unit(up))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: 'up' is parallel to the viewing direction")
    x = _unit(x - (x @ z) * z)  # (Gram-Schmidt: for an up near the axis, x is off-orthogonal by 1e-16 / |x|)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes expressed in world
    return R, -R @ eye


def principal_point_from_opencv(cx: float, cy: float) -> tuple[float, float]:
    """DepthGuard's principal point (pixels; pixel centres at ``u + 0.5``) of a camera whose ROS ``CameraInfo``
    ``K`` or librealsense ``ppx, ppy`` say ``cx, cy`` (pixel centres at integers): ``(cx + 0.5, cy + 0.5)``.

    Taking them as they are shifts every ray by half a pixel (at 160x120 with a Kinect's field of view, about
    1 cm at 3 m sideways)."""
    return float(cx) + OPENCV_PIXEL_OFFSET, float(cy) + OPENCV_PIXEL_OFFSET


def principal_point_to_opencv(cx: float, cy: float) -> tuple[float, float]:
    """The ROS ``CameraInfo`` / OpenCV principal point (pixels) of DepthGuard's ``cx, cy``: ``(cx - 0.5, cy - 0.5)``
    (inverse of :func:`principal_point_from_opencv`)."""
    return float(cx) - OPENCV_PIXEL_OFFSET, float(cy) - OPENCV_PIXEL_OFFSET
