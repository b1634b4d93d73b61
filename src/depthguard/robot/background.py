"""The background rule of speed and separation monitoring: the empty cell's depth per pixel, and which
pixels of a frame it explains (one implementation for the simulated cell's
:class:`depthguard.sim.background.BackgroundFilter` and the runner's commissioned background,
``depthguard commission`` / ``[controller] background``, docs/ssm.md).

The rule, per camera and pixel: with the background depth ``b`` (m; NaN or inf where the empty cell gave no
reading) and the tolerance ``tol(b) = 3 c b² + q + margin`` (``c``: the camera's axial noise coefficient,
σ = c z²; ``q``: its depth quantization; ``margin``: extra, default 1 cm), a pixel that is not a robot pixel
and whose measured depth ``d`` satisfies ``d >= b - tol(b)`` is background: it reads as the camera's far
range (free space in front of it, as in the empty cell). A missing reading (NaN) is never background, a pixel
without background never is, and robot pixels are left as they are (the self-filter handles them).

Why the far range and not a mask: a missing pixel surrounded by masked pixels would have no valid neighbour to
be filled from and would become unknown space (an obstacle at the near limit); as free space at the far range
it stays what the empty cell showed, and a missing pixel next to a person is still filled with the person's
nearer depth.

Limit: anything within ``tol`` of the background (a hand lying flat on the table) is hidden.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "BACKGROUND_SIGMAS",
    "BACKGROUND_MARGIN",
    "background_tolerance",
    "background_threshold",
    "apply_background",
    "far_range",
    "BackgroundStage",
    "MonitorBackgroundStage",
]

#: Standard deviations of the depth noise within which a reading counts as the background.
BACKGROUND_SIGMAS = 3.0
#: Extra tolerance on top of the noise and the quantization, m.
BACKGROUND_MARGIN = 0.01


def background_tolerance(background, noise_coeff: float, quantization: float, margin: float = BACKGROUND_MARGIN):
    """``3 c b² + q + margin`` (m) per pixel of the background depth ``b`` (same shape and dtype)."""
    b = np.asarray(background)
    return BACKGROUND_SIGMAS * noise_coeff * b * b + quantization + margin


def background_threshold(
    background, noise_coeff: float, quantization: float, margin: float = BACKGROUND_MARGIN
) -> np.ndarray:
    """(H, W) float32: the depth at or beyond which a pixel is background, ``b - tol(b)``; +inf where the
    background ``b`` (H, W, m) is not finite (never background)."""
    b = np.asarray(background)
    tol = background_tolerance(b, noise_coeff, quantization, margin)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(b), b - tol, np.inf).astype(np.float32)


def apply_background(depth, mask, threshold, far: float) -> np.ndarray:
    """A new (H, W) depth image: every pixel that is not a robot pixel (``mask`` (H, W) bool) and reads at or
    behind ``threshold`` (:func:`background_threshold`) reads ``far`` (m) instead; NaN stays NaN (no reading is
    never background), robot pixels and nearer readings stay as measured. The dtype of ``depth`` is kept."""
    d = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        bg = (d >= threshold) & ~np.asarray(mask, bool)
    return np.where(bg, np.asarray(far, d.dtype), d)


def far_range(camera) -> float:
    """The depth a background pixel reads: the camera's ``max_depth``, 10 m when it has none."""
    m = float(camera.max_depth)
    return m if np.isfinite(m) else 10.0


class BackgroundStage:
    """Wraps a distance stage (:class:`depthguard.sim.pipeline.DistanceStage`): ``update`` applies the background
    (:func:`apply_background`) to every camera's depth image, then updates the wrapped stage; everything else is
    the wrapped stage's.

    Args:
        stage: the distance stage.
        thresholds: per camera (same order as the stage's), (H, W) :func:`background_threshold`.
        far: per camera, the depth a background pixel reads (:func:`far_range`).
    """

    def __init__(self, stage, thresholds: list[np.ndarray], far: list[float]) -> None:
        if len(thresholds) != len(far):
            raise ValueError(f"{len(thresholds)} background thresholds for {len(far)} far ranges")
        self.stage = stage
        self.thresholds = [np.asarray(t, np.float32) for t in thresholds]
        self.far = [float(f) for f in far]

    def __getattr__(self, name: str):
        return getattr(self.stage, name)

    def applied(self, depths: list[np.ndarray], masks: list[np.ndarray]) -> list[np.ndarray]:
        """The frame set with the background applied (new images; one per camera)."""
        rules = zip(depths, masks, self.thresholds, self.far, strict=True)
        return [apply_background(d, m, thr, far) for d, m, thr, far in rules]

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray], *args, **kwargs) -> None:
        self.stage.update(self.applied(depths, masks), masks, *args, **kwargs)


class MonitorBackgroundStage(BackgroundStage):
    """Two distance stages on the same frames (docs/ssm.md, "Two distance sets"): ``stage`` takes the images as
    measured, so the repulsion and the body bounds keep avoiding everything (the table and the fixtures
    included); ``monitor`` takes them with the background applied, so that speed and separation monitoring
    sees people and unknown space only. ``update`` feeds both; ``query`` and every other attribute are
    ``stage``'s; :meth:`query_monitor` answers from ``monitor`` (up to its ``ssm_range``). Costs a second
    frame stage and a second query per cycle.

    Args:
        stage: the distance stage of the repulsion (no ``ssm_range`` needed).
        monitor: a second distance stage, same cameras, for the monitor (with its ``ssm_range``).
        thresholds, far: as :class:`BackgroundStage`.
    """

    def __init__(self, stage, monitor, thresholds: list[np.ndarray], far: list[float]) -> None:
        super().__init__(stage, thresholds, far)
        self.monitor = monitor

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray], *args, **kwargs) -> None:
        self.stage.update(depths, masks, *args, **kwargs)
        self.monitor.update(self.applied(depths, masks), masks, *args, **kwargs)

    def query_monitor(self, centres: np.ndarray, radii: np.ndarray):
        """The monitor's distances (a :class:`~depthguard.depthspace.PointDistances`) for spheres ``centres``
        (N, 3), ``radii`` (N,) m: the monitor stage's query at ρ, and beyond ρ up to its ``ssm_range``."""
        res = self.monitor.query(centres, radii)
        return self.monitor.query_far(centres, radii, res) if getattr(self.monitor, "ssm_range", None) else res
