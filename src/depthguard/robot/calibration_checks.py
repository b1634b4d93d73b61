"""The checks of :func:`depthguard.robot.calibration.calibrate_extrinsics`'s input before any fitting: the
frames' image sizes and joint states, the settings (``ValueError`` naming the frame or the setting), and how
many of the poses are distinct arm poses (fewer than 5: refused)."""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera

__all__ = ["SAME_POSE_RAD"]

SAME_POSE_RAD = 0.05  # rad (m for a prismatic joint): poses nearer than this in every joint are one pose


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
    for name in ("min_inlier_fraction", "min_observability"):
        v = opts[name]
        if not (np.isfinite(v) and 0 <= v <= 1):
            raise ValueError(f"{name} must be a number in [0, 1], got {v}")
    for name in ("max_points_per_pose", "iterations"):
        if int(opts[name]) < (1 if name == "max_points_per_pose" else 0):
            raise ValueError(f"{name} must be a positive integer, got {opts[name]}")
