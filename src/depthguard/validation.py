"""Input validators (``check_*``) that raise ``ValueError`` naming the field and the expected form."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["check_positive", "check_finite_array", "check_rotation", "check_points", "is_numeric_nest"]


def is_numeric_nest(value: object) -> bool:
    """True if ``value`` is a real number or nested lists / tuples of them (or a numeric numpy array): the JSON
    or TOML form of a vector or matrix. Strings and booleans are not numbers here, although numpy would
    convert ``"1.5"`` and ``true`` to floats."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, list | tuple):
            stack.extend(v)
        elif isinstance(v, np.ndarray):
            if v.dtype.kind not in "iuf":
                return False
        elif isinstance(v, bool | np.bool_) or not isinstance(v, int | float | np.integer | np.floating):
            return False
    return True


def check_positive(value: object, name: str) -> float:
    """Return ``value`` as a float, or raise if it is not a finite number > 0."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return x


def check_finite_array(value: object, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Return ``value`` as a float array of ``shape`` (-1 = any length), a copy, or raise."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == shape:
        # fast path of the control-rate callers (about 2 µs instead of 5): a sum is finite only if every
        # element is (NaN and inf propagate; a finite sum that overflows falls through to the full check)
        if math.isfinite(value.sum()):
            return value.copy()
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a numeric array of shape {shape}, got {value!r}") from None
    if arr.ndim != len(shape) or any(s != -1 and a != s for a, s in zip(arr.shape, shape, strict=True)):
        raise ValueError(f"{name} must have shape {shape}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def check_rotation(value: object, name: str, tol: float = 1e-6) -> np.ndarray:
    """Return ``value`` as a (3, 3) rotation matrix, or raise unless ``R R^T = I`` and ``det R = +1``."""
    R = check_finite_array(value, (3, 3), name)
    with np.errstate(over="ignore", invalid="ignore"):  # (huge entries: inf or NaN, refused below)
        err = np.abs(R @ R.T - np.eye(3)).max()
    if not err <= tol:
        raise ValueError(f"{name} must be orthonormal (R R^T = I); max deviation is {err:.3g}")
    if np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a proper rotation (det = +1), got det = {np.linalg.det(R):.3f}")
    return R


def check_points(centres: object, radii: object, name: str = "points") -> tuple[np.ndarray, np.ndarray]:
    """Return (N, 3) centres and (N,) non-negative radii as float arrays, or raise."""
    c = check_finite_array(centres, (-1, 3), f"{name} centres")
    r = check_finite_array(radii, (-1,), f"{name} radii")
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"{name}: {c.shape[0]} centres but {r.shape[0]} radii")
    if np.any(r < 0):
        raise ValueError(f"{name} radii must be >= 0")
    return c, r
