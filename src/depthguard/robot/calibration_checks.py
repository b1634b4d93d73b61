"""The checks of :func:`depthguard.robot.calibration.calibrate_extrinsics`: its input before any fitting (the
frames' image sizes and joint states, the settings: ``ValueError`` naming the frame or the setting; how many of
the poses are distinct arm poses, fewer than 5: refused) and, after the fit, whether the robot surface seen
fixes the camera pose (:func:`observability_refusal`)."""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera

__all__ = [
    "SAME_POSE_RAD",
    "MIN_OBSERVABILITY",
    "MIN_CAMERA_OBSERVABILITY",
    "pose_observability",
    "observability_refusal",
]

SAME_POSE_RAD = 0.05  # rad (m for a prismatic joint): poses nearer than this in every joint are one pose
MIN_OBSERVABILITY = 0.01  # below: a direction of the camera pose that the robot surface seen does not fix
#: Below: the robot seen fixes the camera's position poorly (about the camera centre). On simulated 160x120
#: Kinect views around the LWR (six random poses), views aimed at the arm gave 0.0012-0.011 (errors 0.2-9.5 mm),
#: views aimed beside it 0.0003-0.004, and the accepted results 12 and 18 mm off were at 0.0003 and 0.0004.
MIN_CAMERA_OBSERVABILITY = 0.0008
_TWIST_NAMES = (*(f"rotation about world {a}" for a in "xyz"), *(f"translation along world {a}" for a in "xyz"))


def pose_observability(points: np.ndarray, normals: np.ndarray, centre: np.ndarray | None = None) -> tuple[float, str]:
    """How well measured surface points (P, 3) with unit normals (P, 3) fix a rigid motion of the sensor: the
    smallest eigenvalue of the point-to-plane Gauss-Newton matrix ``J^T J / P`` with the rows
    ``[((s - c) x n) / L, n]``, rotations taken about ``c`` (``centre``: the camera centre (3,); None: the
    points' centroid) and scaled by the points' RMS distance ``L`` from it, so that a rotation counts by the
    motion it gives there: the mean squared normal displacement of the points per unit of motion of the
    weakest direction (0 for straight parallel links sliding along their axes). Returns it and that
    direction's name (its largest component); ``(0, "every direction")`` with fewer than 6 points."""
    s, n = np.asarray(points, float), np.asarray(normals, float)
    if len(s) < 6:
        return 0.0, "every direction"
    c = s.mean(axis=0) if centre is None else np.asarray(centre, float)
    L = max(float(np.sqrt(np.mean(np.sum((s - c) ** 2, axis=1)))), 1e-6)
    J = np.hstack([np.cross(s - c, n) / L, n])
    w, v = np.linalg.eigh(J.T @ J / len(s))
    return float(w[0]), _TWIST_NAMES[int(np.argmax(np.abs(v[:, 0])))]


def observability_refusal(
    points: np.ndarray, normals: np.ndarray, camera_centre: np.ndarray, min_observability: float, min_at_camera: float
) -> str | None:
    """The refusal message of a fit whose seen robot surface (points, normals: (P, 3) in the world) leaves the
    camera pose undetermined, else None: :func:`pose_observability` about the points' centroid below
    ``min_observability`` (a direction the surface does not fix at all), or about the camera centre (3,) below
    ``min_at_camera`` (the robot small or at the image's edge: turning the camera and shifting it so that the
    seen surface stays in place are hard to tell apart, and the camera's position error goes unseen)."""
    obs, weakest = pose_observability(points, normals)
    if not obs >= min_observability:
        return (
            f"refused: degenerate geometry: the robot surface seen in these poses does not fix the camera"
            f" pose along {weakest} (observability {obs:.4f}, min {min_observability:g}), so any error there"
            " goes unseen; add poses that turn the arm's links in other directions"
        )
    obs, _ = pose_observability(points, normals, camera_centre)
    if not obs >= min_at_camera:
        return (
            f"refused: the robot seen fixes the camera's position poorly (observability about the camera"
            f" {obs:.5f}, min {min_at_camera:g}): the robot is small in the image or at its edge, where a turn of"
            " the camera and a shift keep the seen surface in place; aim the camera so that the arm fills more"
            " of the image, nearer its centre"
        )
    return None


def _distinct_poses(qs: list) -> int:
    """How many of the joint states ``qs`` are distinct arm poses: greedily, a pose within ``SAME_POSE_RAD`` of
    an earlier distinct one in every joint counts as that one."""
    kept: list[np.ndarray] = []
    for q in qs:
        qa = np.asarray(q, float)
        if all(np.max(np.abs(qa - k)) >= SAME_POSE_RAD for k in kept):
            kept.append(qa)
    return len(kept)


def _check_inputs(camera: Camera, frames, model, opts: dict) -> None:
    """``ValueError`` naming the frame or the setting: depth images of ``camera.shape``, finite joint states of
    the model's length, positive finite correspondence distances (``fine`` not empty) and thresholds."""
    n_joints = len(getattr(model, "joint_names", ())) or None
    for i, (depth, q) in enumerate(frames):
        shape = np.shape(depth)
        if shape != tuple(camera.shape):
            raise ValueError(
                f"calibration frame {i}: depth image of shape {shape}, expected (height, width) = {camera.shape}"
                " from the camera"
            )
        qa = np.asarray(q, float)
        if qa.ndim != 1 or (n_joints is not None and qa.shape[0] != n_joints):
            raise ValueError(f"calibration frame {i}: joint state of shape {qa.shape}, expected ({n_joints},)")
        if not np.all(np.isfinite(qa)):
            raise ValueError(f"calibration frame {i}: the joint state is not finite: {qa.tolist()}")
    if len(opts["fine"]) == 0:
        raise ValueError("fine: at least one fine correspondence distance is needed")
    for name in ("coarse", "fine"):
        bands = np.asarray(opts[name], float)
        if not np.all(np.isfinite(bands) & (bands > 0)):
            raise ValueError(f"{name}: correspondence distances must be positive finite metres, got {opts[name]}")
    for name in ("spacing", "inlier_distance", "max_rmse"):
        v = opts[name]
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive finite number, got {v}")
    for name in ("min_inlier_fraction", "min_observability", "min_camera_observability"):
        v = opts[name]
        if not (np.isfinite(v) and 0 <= v <= 1):
            raise ValueError(f"{name} must be a number in [0, 1], got {v}")
    for name in ("max_points_per_pose", "iterations"):
        if int(opts[name]) < (1 if name == "max_points_per_pose" else 0):
            raise ValueError(f"{name} must be a positive integer, got {opts[name]}")
