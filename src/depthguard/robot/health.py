"""Sensor health: a camera that was bumped, covered or frozen must not pass as a valid one.

:class:`CameraHealth` checks every frame of one camera and names the fault:

* ``"frozen"``: ``frozen_frames`` consecutive frames identical to the bit while their stamps advance (a
  real depth sensor's noise makes two identical frames practically impossible; a hung driver repeats one);
* ``"covered"``: more than ``covered_fraction`` of the pixels missing or nearer than the near limit (a hand
  or a cloth on the lens);
* ``"moved"``: the arm is the live calibration check. Where the robot model predicts the arm (its capsule
  surface projected with the calibrated extrinsics, eroded so that a small calibration error does not count),
  the camera must see the arm or something in front of it; seeing *through* it (deeper than the predicted
  surface by ``see_through``) on more than ``moved_fraction`` of those pixels, ``moved_frames`` frames in a row,
  means the camera no longer looks where the cell file says.

A fault stays until ``clear_frames`` healthy frames in a row have passed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from depthguard.camera import Camera

__all__ = ["CameraHealth", "predicted_robot_depth"]


def predicted_robot_depth(camera: Camera, model, q: np.ndarray, spacing: float = 0.01) -> np.ndarray:
    """(H, W) depth of the robot's capsule surface as the camera would see it (inf where no robot)."""
    from depthguard.robot.calibration import capsule_surface_points

    a, b, r = model.link_capsules(np.asarray(q, float))
    pts, _ = capsule_surface_points(a, b, r, spacing)
    pc = camera.world_to_camera(pts)
    pc = pc[pc[:, 2] > 1e-6]
    u = np.floor(camera.fx * pc[:, 0] / pc[:, 2] + camera.cx).astype(np.int64)
    v = np.floor(camera.fy * pc[:, 1] / pc[:, 2] + camera.cy).astype(np.int64)
    ok = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    depth = np.full(camera.shape, np.inf)
    np.minimum.at(depth, (v[ok], u[ok]), pc[ok, 2])
    return depth


@dataclass
class CameraHealth:
    """Per-frame health check of one camera (module docstring). Call :meth:`check` once per frame.

    Attributes:
        camera: the calibrated camera; name: its name (for messages).
        model: the robot model (for the "moved" check); None disables that check.
    """

    camera: Camera
    name: str
    model: object | None = None
    frozen_frames: int = 3
    covered_fraction: float = 0.8
    see_through: float = 0.1
    moved_fraction: float = 0.5
    moved_frames: int = 3
    min_robot_pixels: int = 200
    erode: int = 3
    clear_frames: int = 3
    fault: str | None = None
    _last: np.ndarray | None = field(default=None, repr=False)
    _same: int = 0
    _moved: int = 0
    _healthy: int = 0

    def check(self, depth: np.ndarray, q: np.ndarray | None = None) -> str | None:
        """Check one frame (H, W) m (NaN/0 = no reading) taken at joint positions ``q``; returns the fault
        ("frozen", "covered", "moved") or None when the camera is healthy."""
        d = np.asarray(depth, dtype=np.float32)
        now = self._frame_fault(d, q)
        if now is not None:
            self.fault, self._healthy = now, 0
        elif self.fault is not None:
            self._healthy += 1
            if self._healthy >= self.clear_frames:
                self.fault = None
        return self.fault

    def _frame_fault(self, d: np.ndarray, q: np.ndarray | None) -> str | None:
        same = self._last is not None and self._last.shape == d.shape and np.array_equal(self._last, d, equal_nan=True)
        self._same = self._same + 1 if same else 0
        self._last = d.copy()
        if self._same >= self.frozen_frames - 1:
            return "frozen"
        valid = np.isfinite(d) & (d >= self.camera.min_depth)
        if 1.0 - valid.mean() > self.covered_fraction:
            return "covered"
        if self.model is not None and q is not None and self._sees_through(d, q):
            self._moved += 1
        else:
            self._moved = 0
        return "moved" if self._moved >= self.moved_frames else None

    def _sees_through(self, d: np.ndarray, q: np.ndarray) -> bool:
        from scipy.ndimage import binary_erosion

        pred = predicted_robot_depth(self.camera, self.model, q)
        robot = binary_erosion(np.isfinite(pred), iterations=self.erode)
        seen = robot & np.isfinite(d)
        if seen.sum() < self.min_robot_pixels:
            return False  # too little of the arm in view to judge
        through = seen & (d > pred + self.see_through)
        return bool(through.sum() > self.moved_fraction * seen.sum())
