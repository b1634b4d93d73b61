"""The background rule of speed and separation monitoring: the empty cell's depth per pixel, and which
pixels of a frame it explains (one implementation for the simulated cell's
:class:`depthguard.sim.background.BackgroundFilter` and the runner's commissioned background,
``depthguard commission`` / ``[controller] background``, docs/ssm.md).

The rule, per camera and pixel: with the background depth ``b`` (m; NaN or inf where the empty cell gave no
reading) and the tolerance ``tol(b) = 3 c b² + q + margin`` (``c``: the camera's axial noise coefficient,
σ = c z²; ``q``: its depth quantization; ``margin``: extra, default 1 cm), a pixel that is not a robot pixel
and whose measured depth ``d`` satisfies ``d >= b - tol(b)`` is background: it reads as the camera's far
range (free space in front of it, as in the empty cell). A missing reading (NaN, 0, negative, ±inf: the
readers' convention, docs/conventions.md) is never background, a pixel without background (``b`` NaN, ±inf
or <= 0) never is, and robot pixels are left as they are (the self-filter handles them). The threshold is
computed in float64 and rounded up to float32, so rounding never hides a reading nearer than the rule says;
``c``, ``q`` and ``margin`` must be finite numbers >= 0 (``ValueError`` otherwise).

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


def _check_params(noise_coeff: float, quantization: float, margin: float) -> tuple[float, float, float]:
    """The tolerance model's numbers as floats; ``ValueError`` naming the first that is not a finite number >= 0
    (an infinite or NaN one would hide every pixel or silently none)."""
    out = []
    for name, v in (("noise_coeff", noise_coeff), ("quantization", quantization), ("margin", margin)):
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = float("nan")
        if not (np.isfinite(x) and x >= 0):
            raise ValueError(f"background {name} must be a finite number >= 0, got {v!r}")
        out.append(x)
    return out[0], out[1], out[2]


def background_tolerance(background, noise_coeff: float, quantization: float, margin: float = BACKGROUND_MARGIN):
    """``3 c b² + q + margin`` (m, float64) per pixel of the background depth ``b`` (m, any shape); ``c``
    (m⁻¹), ``q`` and ``margin`` (m) finite numbers >= 0, else ``ValueError``."""
    c, q, m = _check_params(noise_coeff, quantization, margin)
    b = np.asarray(background, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        return BACKGROUND_SIGMAS * c * b * b + q + m


def background_threshold(
    background, noise_coeff: float, quantization: float, margin: float = BACKGROUND_MARGIN
) -> np.ndarray:
    """(H, W) float32: the depth (m) at or beyond which a pixel is background: the smallest float32 at or above
    the rule's ``b - tol(b)`` (exact: computed in float64 and, where float64 rounding could cross a float32
    step, in rational arithmetic), so a float32 reading is background exactly when the rule says and
    rounding never hides a nearer reading; +inf where the background ``b`` (H, W, m) is not a finite depth > 0
    (never background)."""
    c, q, m = _check_params(noise_coeff, quantization, margin)
    b = np.asarray(background, np.float64)
    tol = background_tolerance(b, c, q, m)
    with np.errstate(over="ignore", invalid="ignore"):
        t64 = b - tol
        t32 = t64.astype(np.float32)
        t32 = np.where(t32.astype(np.float64) < t64, np.nextafter(t32, np.float32(np.inf)), t32)
        has = np.isfinite(b) & (b > 0)
        # float64 rounding (a few ulps of |b| + tol) could put t64 on the other side of a float32 step
        near = has & (np.abs(t32.astype(np.float64) - t64) <= 8 * np.finfo(np.float64).eps * (np.abs(b) + tol))
    if near.any():
        t32 = _exact_steps(t32, b, near, c, q, m)
    return np.where(has, t32, np.float32(np.inf)).astype(np.float32)


def _exact_steps(t32: np.ndarray, b: np.ndarray, near: np.ndarray, c: float, q: float, m: float) -> np.ndarray:
    """``t32`` with the pixels ``near`` set to the smallest float32 >= ``b - (3 c b² + q + m)`` in rationals."""
    from fractions import Fraction

    out = np.array(t32, np.float32)
    fc, fq, fm = Fraction(c), Fraction(q), Fraction(m)
    for v in np.unique(b[near]):
        fb = Fraction(float(v))
        exact = fb - (Fraction(BACKGROUND_SIGMAS) * fc * fb * fb + fq + fm)
        t = np.float32(float(exact))  # (nearest; one step up if below)
        if Fraction(float(t)) < exact:
            t = np.nextafter(t, np.float32(np.inf))
        out[near & (b == v)] = t
    return out


def apply_background(depth, mask, threshold, far: float) -> np.ndarray:
    """A new (H, W) depth image: every pixel that is not a robot pixel (``mask`` (H, W) bool) and holds a
    reading (finite, > 0) at or behind ``threshold`` ((H, W) m, :func:`background_threshold`) reads ``far``
    (m, finite > 0) instead; no reading (NaN, 0, negative, ±inf) is never background and stays as it is, robot
    pixels and nearer readings stay as measured. ``depth`` is a float (H, W) image in m; its dtype is kept.
    Other shapes, an integer image or a bad ``far``: ``ValueError`` naming it."""
    d = np.asarray(depth)
    if d.ndim != 2 or d.dtype.kind != "f":
        raise ValueError(f"background: depth must be a 2-D float image in metres, got {d.dtype} of shape {d.shape}")
    m = np.asarray(mask)
    thr = np.asarray(threshold)
    for name, a in (("mask", m), ("threshold", thr)):
        if a.shape != d.shape:
            raise ValueError(f"background: {name} of shape {a.shape} for a depth image of shape {d.shape}")
    if m.dtype.kind not in "biu":
        raise ValueError(f"background: mask must be a bool image (True = robot pixel), got {m.dtype}")
    if thr.dtype.kind != "f":
        raise ValueError(f"background: threshold must be a float image in metres, got {thr.dtype}")
    try:
        f = float(far)
    except (TypeError, ValueError):
        f = float("nan")
    if not (np.isfinite(f) and f > 0):
        raise ValueError(f"background: far must be a finite depth > 0 m, got {far!r}")
    with np.errstate(invalid="ignore"):
        bg = (d >= thr) & (d > 0) & (d < np.inf)  # (a reading: finite and > 0)
        bg &= ~m if m.dtype == np.bool_ else m == 0
    return np.where(bg, np.asarray(f, d.dtype), d)


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
