"""2-D laser scanner: a fan of rays in one plane (SAPHARI D4.1.1 §3.2, the generic ray-based sensor model).

Scanner frame S: x forward, y left, z up; the rays lie in the plane z = 0, ray ``i`` at the angle
``angle_min + i * angle_increment`` from x towards y. Its pose follows the camera convention
``P_S = R P_W + t`` (:mod:`depthguard.camera`). Readings follow ROS REP 117:

* a finite range in ``[range_min, range_max]``: the first object on the ray;
* ``+inf`` (or any value above ``range_max``): no object within ``range_max``, the ray is free up to it;
* ``-inf`` (or a positive value below ``range_min``): an object nearer than ``range_min``;
* NaN or 0: no reading. A missing reading never frees anything: the ray counts as blocked at
  ``range_min`` (unknown space behind it), the project's conservative missing-data policy.

Each reading stands for its whole beam sector ``[angle - inc/2, angle + inc/2]`` in the plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from depthguard.validation import check_finite_array, check_positive, check_rotation

__all__ = ["LaserScanner", "scan_obstacle_ranges", "scan_points", "scan_robot_rays"]


@dataclass(frozen=True)
class LaserScanner:
    """A 2-D laser scanner (SICK S300-like defaults: 270°, 0.5° steps = 541 rays, 0.1-8 m).

    Attributes:
        R: (3, 3) rotation world -> scanner, ``P_S = R P_W + t``.
        t: (3,) translation, metres.
        angle_min: angle of ray 0, rad.
        angle_increment: angle between rays, rad (> 0).
        n_rays: number of rays.
        range_min, range_max: valid range, metres.
    """

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angle_min: float = -0.75 * math.pi
    angle_increment: float = 0.5 * math.pi / 180.0
    n_rays: int = 541
    range_min: float = 0.1
    range_max: float = 8.0

    def __post_init__(self) -> None:
        R = check_rotation(self.R, "scanner field 'R'")
        t = check_finite_array(self.t, (3,), "scanner field 't'")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        a0 = float(self.angle_min)
        if not math.isfinite(a0):
            raise ValueError(f"scanner field 'angle_min' must be finite, got {self.angle_min!r}")
        object.__setattr__(self, "angle_min", a0)
        inc = check_positive(self.angle_increment, "scanner field 'angle_increment'")
        object.__setattr__(self, "angle_increment", inc)
        n = self.n_rays
        if isinstance(n, bool) or not float(n).is_integer() or n < 1:
            raise ValueError(f"scanner field 'n_rays' must be a positive integer, got {n!r}")
        object.__setattr__(self, "n_rays", int(n))
        if (n - 1) * inc >= 2 * math.pi:
            raise ValueError("scanner rays must span less than a full turn ((n_rays - 1) * angle_increment < 2 pi)")
        rmin = check_positive(self.range_min, "scanner field 'range_min'")
        rmax = check_positive(self.range_max, "scanner field 'range_max'")
        if rmax <= rmin:
            raise ValueError(f"scanner field 'range_max' ({rmax}) must be larger than 'range_min' ({rmin})")
        object.__setattr__(self, "range_min", rmin)
        object.__setattr__(self, "range_max", rmax)

    @property
    def position(self) -> np.ndarray:
        """(3,) scanner origin in the world frame, metres."""
        return -self.R.T @ self.t

    @property
    def angles(self) -> np.ndarray:
        """(n_rays,) ray angles, rad."""
        return self.angle_min + self.angle_increment * np.arange(self.n_rays)

    def directions(self) -> np.ndarray:
        """(n_rays, 3) unit ray directions in the world frame."""
        a = self.angles
        d_s = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
        return d_s @ self.R

    def with_pose(self, R: np.ndarray, t: np.ndarray) -> LaserScanner:
        """A copy with another pose (``P_S = R P_W + t``)."""
        return LaserScanner(R, t, self.angle_min, self.angle_increment, self.n_rays, self.range_min, self.range_max)

    def check_ranges(self, ranges: object) -> np.ndarray:
        """(n_rays,) float64 copy of a scan, or ``ValueError`` naming the expected shape."""
        arr = np.asarray(ranges, dtype=float)
        if arr.shape != (self.n_rays,):
            raise ValueError(f"scan ranges have shape {arr.shape}, expected ({self.n_rays},) from the scanner")
        return arr.copy()


def scan_obstacle_ranges(scanner: LaserScanner, ranges: object) -> np.ndarray:
    """(n_rays,) range at which each ray is blocked (REP 117 cases above); ``inf`` = free to ``range_max``."""
    r = scanner.check_ranges(ranges)
    out = r.copy()
    missing = np.isnan(r) | (r == 0)
    out[missing | (r == -np.inf) | ((r > 0) & (r < scanner.range_min))] = scanner.range_min
    out[r > scanner.range_max] = np.inf
    return out


def scan_points(scanner: LaserScanner, ranges: object) -> tuple[np.ndarray, np.ndarray]:
    """World hit points (K, 3) of the valid readings in ``[range_min, range_max]`` and their ray indices (K,)."""
    r = scanner.check_ranges(ranges)
    ok = np.isfinite(r) & (r >= scanner.range_min) & (r <= scanner.range_max)
    idx = np.nonzero(ok)[0]
    return scanner.position + scanner.directions()[idx] * r[idx, None], idx


def scan_robot_rays(
    scanner: LaserScanner, ranges: object, a: np.ndarray, b: np.ndarray, radius: np.ndarray, margin: float = 0.03
) -> np.ndarray:
    """(n_rays,) bool: rays whose hit point lies on the robot (within ``margin`` of a capsule ``a``-``b``
    (L, 3) of ``radius`` (L,), world frame, less 1e-12 m for rounding), the scanner's self-filter."""
    r = scanner.check_ranges(ranges)
    out = np.zeros(scanner.n_rays, dtype=bool)
    ok = np.isfinite(r) & (r > 0)
    if not ok.any() or len(a) == 0:
        return out
    p = scanner.position + scanner.directions()[ok] * r[ok, None]  # (K, 3)
    a = np.ascontiguousarray(a, dtype=float)
    ab = np.ascontiguousarray(b, dtype=float) - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    # less a picometre: the kernel's roundings (a few 1e-15 m) differ from numpy's einsum, so a ray is
    # the robot's here only where the numpy formula says so too (fewer robot rays: never less obstacle)
    out[ok] = _near_capsules(p, a, ab, L2, np.asarray(radius, float) + margin - _ROUNDING_SLACK)
    return out


_ROUNDING_SLACK = 1e-12  # m


@nb.njit(cache=True, nogil=True)
def _near_capsules(p, a, ab, L2, lim):
    """(K,) bool: whether each point of ``p`` (K, 3) lies within ``lim`` (L,) of some segment ``a`` + s ``ab``
    (L, 3), s in [0, 1], ``L2`` (L,) the segments' squared lengths (> 0), all in metres (the projection
    clipped to the segment, then the Euclidean distance)."""
    K, L = p.shape[0], a.shape[0]
    out = np.zeros(K, np.bool_)
    for k in range(K):
        for m in range(L):
            w0, w1, w2 = p[k, 0] - a[m, 0], p[k, 1] - a[m, 1], p[k, 2] - a[m, 2]
            s = min(max((w0 * ab[m, 0] + w1 * ab[m, 1] + w2 * ab[m, 2]) / L2[m], 0.0), 1.0)
            d0 = p[k, 0] - (a[m, 0] + s * ab[m, 0])
            d1 = p[k, 1] - (a[m, 1] + s * ab[m, 1])
            d2 = p[k, 2] - (a[m, 2] + s * ab[m, 2])
            if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) <= lim[m]:
                out[k] = True
                break
    return out
