"""Analytic scenes: exact ray casting of solid primitives into depth images, and exact distances.

Used for ground truth in tests, for the demo and for the benchmarks. Each primitive is a solid
(sphere, capsule, oriented box, half-space). Rendering casts one ray through each pixel centre
(``p_x = u + 0.5``, ``docs/conventions.md``) and stores the depth ``z_C`` of the first hit, NaN where nothing is hit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from depthguard.camera import Camera
from depthguard.validation import check_finite_array, check_rotation

__all__ = ["Sphere", "Capsule", "Box", "HalfSpace", "Scene", "render_depth"]

_INF = np.inf


def _set_vector(obj: object, name: str) -> np.ndarray:
    """Field ``name`` of primitive ``obj`` as a finite (3,) float array (stored back), else ``ValueError`` naming
    it. A NaN centre or normal would make every ray's hit NaN, and ``np.minimum`` in :class:`Scene` passes NaN
    on: one bad primitive would blank the whole ground-truth image."""
    a = check_finite_array(getattr(obj, name), (3,), f"{type(obj).__name__} field '{name}' (metres)")
    a.setflags(write=False)
    object.__setattr__(obj, name, a)
    return a


def _set_radius(obj: object, name: str = "radius") -> float:
    """Field ``name`` of ``obj`` as a finite float >= 0 in metres (stored back), else ``ValueError`` naming it
    (a negative radius rendered as its absolute value while its distance grew by it)."""
    raw = getattr(obj, name)
    try:
        r = float(raw) if not isinstance(raw, bool) else float("nan")
    except (TypeError, ValueError, OverflowError):
        r = float("nan")
    if not (np.isfinite(r) and r >= 0.0):
        raise ValueError(f"{type(obj).__name__} field '{name}' must be a finite number >= 0 (metres), got {raw!r}")
    object.__setattr__(obj, name, r)
    return r


@dataclass(frozen=True)
class Sphere:
    """Solid sphere: ``center`` (3,) m, ``radius`` m."""

    center: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        _set_vector(self, "center")
        _set_radius(self)

    def ray_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Ray parameter of the first hit for rays ``o + s d`` (d: (N, 3)), inf if none (s >= 0)."""
        oc = o - self.center
        b = d @ oc
        a = np.einsum("ij,ij->i", d, d)
        c = oc @ oc - self.radius**2
        disc = b * b - a * c
        hit = disc >= 0
        sq = np.sqrt(np.where(hit, disc, 0.0))
        s0 = (-b - sq) / a
        s1 = (-b + sq) / a
        s = np.where(s0 >= 0, s0, np.where(s1 >= 0, 0.0, _INF))
        return np.where(hit, s, _INF)

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance from (N, 3) points to the solid, 0 inside."""
        return np.maximum(np.linalg.norm(np.asarray(p) - self.center, axis=-1) - self.radius, 0.0)


@dataclass(frozen=True)
class Capsule:
    """Solid capsule: segment ``a``-``b`` (3,) m swept by a sphere of ``radius`` m."""

    a: np.ndarray
    b: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        _set_vector(self, "a")
        _set_vector(self, "b")
        _set_radius(self)

    def _closest_on_segment(self, p: np.ndarray) -> np.ndarray:
        ab = self.b - self.a
        denom = max(float(ab @ ab), 1e-18)
        s = np.clip((np.asarray(p) - self.a) @ ab / denom, 0.0, 1.0)
        return self.a + s[..., None] * ab

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance from (N, 3) points to the solid, 0 inside."""
        p = np.asarray(p, dtype=float)
        return np.maximum(np.linalg.norm(p - self._closest_on_segment(p), axis=-1) - self.radius, 0.0)

    def ray_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First-hit ray parameter (inf if none): min over the cylinder body and the two end spheres."""
        best = np.minimum(Sphere(self.a, self.radius).ray_hit(o, d), Sphere(self.b, self.radius).ray_hit(o, d))
        ab = self.b - self.a
        L = np.linalg.norm(ab)
        if L < 1e-12:
            return best
        w = ab / L
        oa = o - self.a
        d_perp = d - np.outer(d @ w, w)
        oa_perp = oa - (oa @ w) * w
        A = np.einsum("ij,ij->i", d_perp, d_perp)
        B = d_perp @ oa_perp
        C = oa_perp @ oa_perp - self.radius**2
        disc = B * B - A * C
        ok = (disc >= 0) & (A > 1e-18)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        A_safe = np.where(A > 1e-18, A, 1.0)
        for s in ((-B - sq) / A_safe, (-B + sq) / A_safe):
            along = (oa @ w) + s * (d @ w)
            good = ok & (s >= 0) & (along >= 0) & (along <= L)
            best = np.where(good, np.minimum(best, s), best)
        if C <= 0 and 0 <= oa @ w <= L:  # ray origin inside the body
            best = np.zeros_like(best)
        return best


@dataclass(frozen=True)
class Box:
    """Solid oriented box: ``center`` (3,), ``half_extents`` (3,) m, rotation ``R`` (3, 3) box -> world."""

    center: np.ndarray
    half_extents: np.ndarray
    R: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        _set_vector(self, "center")
        h = _set_vector(self, "half_extents")
        if np.any(h < 0):
            raise ValueError(f"Box field 'half_extents' must be >= 0 (metres), got {h.tolist()}")
        R = check_rotation(self.R, "Box field 'R' (box -> world)")
        R.setflags(write=False)
        object.__setattr__(self, "R", R)

    def _local(self, p: np.ndarray) -> np.ndarray:
        return (np.asarray(p, dtype=float) - self.center) @ self.R

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance from (N, 3) points to the solid, 0 inside."""
        q = np.abs(self._local(p)) - self.half_extents
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1)

    def closest_point(self, p: np.ndarray) -> np.ndarray:
        """(N, 3) closest points of the solid box to (N, 3) points."""
        q = np.clip(self._local(p), -self.half_extents, self.half_extents)
        return q @ self.R.T + self.center

    def ray_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First-hit ray parameter by the slab method, inf if none."""
        ol = (o - self.center) @ self.R
        dl = d @ self.R
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / dl
            t1 = (-self.half_extents - ol) * inv
            t2 = (self.half_extents - ol) * inv
        t1 = np.where(np.isnan(t1), -_INF, t1)
        t2 = np.where(np.isnan(t2), _INF, t2)
        tmin = np.max(np.minimum(t1, t2), axis=1)
        tmax = np.min(np.maximum(t1, t2), axis=1)
        hit = tmax >= np.maximum(tmin, 0.0)
        return np.where(hit, np.maximum(tmin, 0.0), _INF)


@dataclass(frozen=True)
class HalfSpace:
    """Solid half-space ``{x : n.(x - point) <= 0}``: a wall or floor whose free side is along ``normal``."""

    point: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        _set_vector(self, "point")
        n = _set_vector(self, "normal")
        if not n.any():
            raise ValueError("HalfSpace field 'normal' must be a non-zero (3,) vector, got (0, 0, 0)")
        n = n / np.abs(n).max()  # (scaled first: the norm of a 1e-200 normal underflows to 0)
        object.__setattr__(self, "_unit_normal", n / np.linalg.norm(n))

    def _n(self) -> np.ndarray:
        return self._unit_normal

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance from (N, 3) points to the solid, 0 inside."""
        return np.maximum((np.asarray(p, dtype=float) - self.point) @ self._n(), 0.0)

    def ray_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = self._n()
        h = (o - self.point) @ n
        if h <= 0:
            return np.zeros(len(d))
        dn = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -h / dn
        return np.where(dn < 0, s, _INF)


Primitive = Sphere | Capsule | Box | HalfSpace


@dataclass(frozen=True)
class Scene:
    """A list of solid primitives in the world frame."""

    primitives: tuple[Primitive, ...]

    def distance(self, p: np.ndarray) -> np.ndarray:
        """True Euclidean distance from (N, 3) points to the union of the solids (inf for an empty scene)."""
        p = np.atleast_2d(np.asarray(p, dtype=float))
        out = np.full(len(p), _INF)
        for prim in self.primitives:
            out = np.minimum(out, prim.distance(p))
        return out

    def ray_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        out = np.full(len(d), _INF)
        for prim in self.primitives:
            out = np.minimum(out, prim.ray_hit(o, d))
        return out


def render_depth(camera: Camera, scene: Scene, max_range: float | None = None) -> np.ndarray:
    """Exact depth image of ``scene``: one ray through each pixel centre.

    Args:
        camera: the camera (its pose gives the ray origin and directions).
        scene: solid primitives in the world frame.
        max_range: depths beyond this (default ``camera.max_depth``) become NaN (no reading); metres, > 0
            (``inf``: no limit).
    Returns:
        (H, W) float64 depth ``z_C`` in metres, NaN where nothing is hit within range (0 where the camera is inside
        a solid).
    """
    if max_range is not None:
        number = isinstance(max_range, int | float | np.integer | np.floating) and not isinstance(max_range, bool)
        if not (number and max_range > 0):  # (False for NaN)
            raise ValueError(f"max_range must be a number of metres > 0 (inf: no limit) or None, got {max_range!r}")
    dirs_c = camera.pixel_ray_directions().reshape(-1, 3)  # z = 1, so the ray parameter is the depth
    dirs_w = camera.vector_to_world(dirs_c)
    s = scene.ray_hit(camera.position, dirs_w)
    limit = camera.max_depth if max_range is None else max_range
    s = np.where(s <= limit, s, np.nan)
    s[np.isinf(s)] = np.nan  # (no hit: inf, which max_range = inf let through)
    return s.reshape(camera.shape)
