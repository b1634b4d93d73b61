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

A fault stays until ``clear_frames`` healthy frames in a row have passed. With stamps (:meth:`CameraHealth.check`),
only frames whose stamps advance count: a repeated or reordered stamp neither makes a stream frozen nor
clears a fault (a driver that repeats one frame with one stamp is caught by the distances' timeout: they are
as old as their frames); a NaN or infinite stamp is the fault ``"stamp"``, an image of another shape or an
integer one the fault ``"image"``.
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
        frozen_frames (>= 2), moved_frames, clear_frames, min_robot_pixels, erode (>= 1, >= 1, >= 0, >= 0):
        counts; covered_fraction, moved_fraction: fractions in [0, 1); see_through: m, >= 0. Other values
        (NaN among them, which would disable a check) raise ``ValueError`` naming the field.
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
    _stamp: float | None = field(default=None, repr=False)
    _same: int = 0
    _moved: int = 0
    _healthy: int = 0

    def __post_init__(self) -> None:
        counts = {"frozen_frames": 2, "moved_frames": 1, "clear_frames": 1, "min_robot_pixels": 0, "erode": 0}
        for key, low in counts.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < low:
                raise ValueError(f"camera health {key} must be an integer >= {low}, got {v!r}")
        for key, hi in (("covered_fraction", 1.0), ("moved_fraction", 1.0), ("see_through", np.inf)):
            v = getattr(self, key)
            if not (isinstance(v, int | float | np.number) and 0 <= float(v) < hi):
                raise ValueError(f"camera health {key} must be a number in [0, {hi}), got {v!r}")

    def check(self, depth: np.ndarray, q: np.ndarray | None = None, stamp: float | None = None) -> str | None:
        """Check one frame (H, W) float m (NaN/0 = no reading) taken at joint positions ``q`` and time ``stamp``
        (s; None: unknown, every call is a new frame); returns the fault ("frozen", "covered", "moved",
        "image", "stamp") or None when the camera is healthy.

        Stamps (docs/real-cell.md §7): a frame whose stamp does not advance past the last one (repeated,
        reordered, stale) is not a new frame: it counts neither towards "frozen" nor "moved" nor as a healthy
        frame (the run of healthy frames that clears a fault starts again), and is still checked for
        "covered". A NaN or infinite stamp is the fault "stamp"; an image that is not a 2-D float image of the
        camera's size is the fault "image" (neither raises)."""
        try:
            d = np.asarray(depth)
            ok = d.dtype.kind == "f" and d.shape == self.camera.shape
        except Exception:  # (ragged nested lists and the like)
            ok = False
        if not ok:
            return self._latch("image")
        d = d.astype(np.float32)
        if stamp is not None:
            try:
                t = float(stamp)
            except (TypeError, ValueError):
                t = float("nan")
            if not np.isfinite(t):
                return self._latch("stamp")
            if self._stamp is not None and t <= self._stamp:  # not a new frame
                if self._covered(d):
                    return self._latch("covered")
                self._healthy = 0
                return self.fault
            self._stamp = t
        return self._latch(self._frame_fault(d, q))

    def _latch(self, now: str | None) -> str | None:
        """A fault ``now`` latches; ``clear_frames`` healthy frames in a row clear it."""
        if now is not None:
            self.fault, self._healthy = now, 0
        elif self.fault is not None:
            self._healthy += 1
            if self._healthy >= self.clear_frames:
                self.fault, self._healthy = None, 0
        return self.fault

    def _covered(self, d: np.ndarray) -> bool:
        """More than ``covered_fraction`` of the pixels missing (NaN, ±inf, <= 0) or nearer than the near limit
        (exact in integers: ``missing * den > num * pixels`` with ``covered_fraction = num / den``)."""
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d > 0) & (d >= self.camera.min_depth)
        missing = int(d.size - np.count_nonzero(valid))
        num, den = float(self.covered_fraction).as_integer_ratio()
        return missing * den > num * int(d.size)

    def _frame_fault(self, d: np.ndarray, q: np.ndarray | None) -> str | None:
        # (bit for bit, as the docstring says: one memcmp-like pass over uint32 views; ``d`` is this call's own
        # float32 copy, so it is kept as it is)
        last = self._last
        same = last is not None and last.shape == d.shape and np.array_equal(last.view(np.uint32), d.view(np.uint32))
        self._same = self._same + 1 if same else 0
        self._last = d
        if self._same >= self.frozen_frames - 1:
            return "frozen"
        if self._covered(d):
            return "covered"
        if q is not None:  # (a joint state with NaN or inf cannot be judged: as without one)
            qa = np.asarray(q)
            q = qa if qa.ndim == 1 and qa.dtype.kind in "fiu" and np.all(np.isfinite(qa)) else None
        if self.model is not None and q is not None and self._sees_through(d, q):
            self._moved += 1
        else:
            self._moved = 0
        return "moved" if self._moved >= self.moved_frames else None

    def _sees_through(self, d: np.ndarray, q: np.ndarray) -> bool:
        from scipy.ndimage import binary_erosion

        pred = predicted_robot_depth(self.camera, self.model, q)
        robot = _eroded(np.isfinite(pred), self.erode, binary_erosion)
        seen = robot & np.isfinite(d)
        if seen.sum() < self.min_robot_pixels:
            return False  # too little of the arm in view to judge
        through = seen & (d > pred + self.see_through)
        return bool(through.sum() > self.moved_fraction * seen.sum())


def _eroded(mask: np.ndarray, iterations: int, binary_erosion) -> np.ndarray:
    """``binary_erosion(mask, iterations=iterations)`` (H, W) bool, computed on the box around the True pixels
    only, padded by ``iterations + 1`` pixels (inside the image): outside that box every pixel is False before
    and after, so the result is the same as on the whole image (the image's border counts as False in both).
    ``iterations = 0`` is no erosion (scipy's own ``iterations < 1`` would erode until nothing changes, which
    leaves no pixel to judge and so silently disabled the "moved" check)."""
    if iterations == 0:
        return mask.copy()
    out = np.zeros(mask.shape, dtype=bool)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return out
    p = iterations + 1
    v0, v1 = max(rows[0] - p, 0), min(rows[-1] + p + 1, mask.shape[0])
    u0, u1 = max(cols[0] - p, 0), min(cols[-1] + p + 1, mask.shape[1])
    out[v0:v1, u0:u1] = binary_erosion(mask[v0:v1, u0:u1], iterations=iterations)
    return out
