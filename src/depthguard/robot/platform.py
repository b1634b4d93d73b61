"""Sensors on the mobile manipulator's platform (SAPHARI D4.1.1 §3.3): two depth cameras on a mast that watch
the arm, two 2-D laser scanners at opposite corners near the floor. Their world poses follow the base pose.

Platform frame: x forward, y left, z up, origin at the platform centre on the floor (the URDF
``data/omni_lwr4/omni_lwr4.urdf``: 0.80 x 0.60 x 0.40 m, the arm's base at the centre of its top).
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.camera import Camera, look_at
from depthguard.octree.scanner import LaserScanner

__all__ = ["base_pose", "platform_sensors", "CAMERA_MOUNTS", "SCANNER_MOUNTS"]

# (eye, target) in the platform frame: masts at the two rear corners, each looking across the arm
CAMERA_MOUNTS = (
    (np.array([-0.35, 0.28, 1.55]), np.array([0.75, -0.35, 0.75])),
    (np.array([-0.35, -0.28, 1.55]), np.array([0.75, 0.35, 0.75])),
)
# (position, yaw) in the platform frame: front-right and rear-left corners, 270° fans pointing outwards
SCANNER_MOUNTS = (
    (np.array([0.42, -0.32, 0.20]), -0.25 * math.pi),
    (np.array([-0.42, 0.32, 0.20]), 0.75 * math.pi),
)


def _check_base(q_base: object) -> tuple[float, float, float]:
    """(x, y, yaw) from the first three entries of a 1-D array, or ``ValueError`` naming ``q_base``."""
    try:
        q = np.asarray(q_base, dtype=float)
    except (TypeError, ValueError):
        q = None
    if q is None or q.ndim != 1 or q.shape[0] < 3 or not np.all(np.isfinite(q[:3])):
        raise ValueError(f"q_base must be a 1-D array of finite (x, y, yaw) (and any further joints), got {q_base!r}")
    return float(q[0]), float(q[1]), float(q[2])


def base_pose(q_base: np.ndarray, z0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World rotation (3, 3) and position (3,) of the platform frame for base coordinates (x, y, yaw); the
    floor under the platform is at height ``z0``; ``ValueError`` naming ``q_base`` or ``z0`` when not finite."""
    x, y, yaw = _check_base(q_base)
    try:
        z = float(z0)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        z = math.nan
    if not math.isfinite(z):
        raise ValueError(f"z0 must be a finite height in metres, got {z0!r}")
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([x, y, z])


def platform_sensors(
    q_base: np.ndarray, width: int = 640, height: int = 480, n_rays: int = 541, z0: float = 0.0
) -> tuple[list[Camera], list[LaserScanner]]:
    """World-frame cameras (Kinect v1-like, 0.5-4.5 m) and scanners (270°, 0.1-8 m) for the base at (x, y, yaw),
    floor at height ``z0``."""
    if isinstance(n_rays, bool) or not isinstance(n_rays, int | np.integer) or n_rays < 2:
        raise ValueError(f"n_rays must be an integer >= 2 (a fan of 270 degrees), got {n_rays!r}")
    Rb, pb = base_pose(q_base, z0)
    f = 525.0 * width / 640.0
    cams = []
    for eye, target in CAMERA_MOUNTS:
        R, t = look_at(Rb @ eye + pb, Rb @ target + pb)
        cams.append(
            Camera(width=width, height=height, fx=f, fy=f, cx=width / 2 - 0.5, cy=height / 2 - 0.5, R=R, t=t,
                   min_depth=0.5, max_depth=4.5)
        )  # fmt: skip
    scanners = []
    inc = 1.5 * math.pi / (n_rays - 1)
    for pos, yaw in SCANNER_MOUNTS:
        c, s = math.cos(yaw), math.sin(yaw)
        R_ps = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # scanner axes in the platform frame
        R_ws = Rb @ R_ps
        R = R_ws.T
        scanners.append(LaserScanner(R, -R @ (Rb @ pos + pb), -0.75 * math.pi, inc, n_rays, 0.1, 8.0))
    return cams, scanners
