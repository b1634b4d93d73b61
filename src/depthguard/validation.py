"""Input validators (``check_*``) that raise ``ValueError`` naming the field and the expected form."""

from __future__ import annotations

import ipaddress
import math
import re

import numpy as np

__all__ = [
    "is_host",
    "check_positive",
    "check_finite_array",
    "check_rotation",
    "check_points",
    "is_numeric_nest",
    "check_float_depth",
    "check_query",
]


_HOST_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_\-]*(\.[A-Za-z0-9_][A-Za-z0-9_\-]*)*")


def is_host(text: object) -> bool:
    """Whether ``text`` is an IPv4 or IPv6 address (IPv6 with an optional ``%zone``) or a host name: labels of
    letters, digits, ``_`` and ``-`` joined by single dots, none empty and none starting with ``-`` (so not
    ``-a``, ``.a``, ``a.``, ``a..b``). What a Zenoh endpoint and a certificate's alternative name can hold."""
    if not isinstance(text, str):
        return False
    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        return bool(_HOST_NAME.fullmatch(text))


def is_real_scalar(value: object) -> bool:
    """True if ``value`` is one real number: a Python or numpy int or float, not a bool (nor a string, an array
    or a complex number). The type test that the input checks share; finiteness is left to the caller."""
    return not isinstance(value, bool | np.bool_) and isinstance(value, int | float | np.integer | np.floating)


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
        elif not is_real_scalar(v):
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


#: metres: the largest coordinate or radius a query point may have. Beyond, it comes from a wrong unit or
#: transform, and the distance kernels' arithmetic (squared norms, pixel and cell indices) would overflow
#: and could report "nothing within reach" for a point in the shadow of an obstacle.
MAX_COORDINATE = 1e9


def check_points(centres: object, radii: object, name: str = "points") -> tuple[np.ndarray, np.ndarray]:
    """Return (N, 3) centres and (N,) non-negative radii as float arrays, or raise (also for a coordinate or
    radius beyond :data:`MAX_COORDINATE`)."""
    c = check_finite_array(centres, (-1, 3), f"{name} centres")
    r = check_finite_array(radii, (-1,), f"{name} radii")
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"{name}: {c.shape[0]} centres but {r.shape[0]} radii")
    if np.any(r < 0):
        raise ValueError(f"{name} radii must be >= 0")
    if c.size and not (np.abs(c).max() <= MAX_COORDINATE and r.max() <= MAX_COORDINATE):
        raise ValueError(
            f"{name} centres and radii must lie within {MAX_COORDINATE:g} m (metres, world frame), got up to"
            f" {max(np.abs(c).max(), r.max()):g}"
        )
    return c, r


def check_float_depth(depth: np.ndarray, name: str = "depth") -> np.ndarray:
    """``depth`` (an array) unless its dtype is not a float one: ``ValueError`` naming ``name``. An integer
    image is most likely millimetres (a 16-bit driver image), which read as metres would place every obstacle
    1000 times too far."""
    if depth.dtype.kind != "f":
        raise ValueError(
            f"{name} must be a float image in metres, got dtype {depth.dtype}: convert a 16-bit millimetre image "
            "with depthguard.kernels.depthimage.metres_or_nan(depth, 1000.0) (read as metres it would place "
            "every obstacle 1000 times too far)"
        )
    return depth


def _real(value: object, name: str, what: str) -> float:
    """``value`` as a float if it is a real number (not a bool), else ``ValueError`` naming ``name``."""
    try:
        if isinstance(value, bool | np.bool_) or np.ndim(value) != 0:
            raise TypeError
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be {what}, got {value!r}") from None


def check_query(
    centres: object, radii: object, rho: object, alpha: object
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The checks of the query arguments shared by :func:`query_distances` and the fused query: ``ValueError``
    naming the bad one (``rho`` a finite number > 0; ``alpha`` a finite number, so that the eq. 9 weights are
    numbers; ``centres`` a finite (N, 3) array or one (3,) point; ``radii`` (N,) or one number, finite and
    >= 0). Returns ``(centres, radii, rho, alpha)`` as float arrays and floats."""
    rho_f = _real(rho, "rho", "a positive number of metres")
    if not (math.isfinite(rho_f) and rho_f > 0):
        raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
    alpha_f = _real(alpha, "alpha", "a finite number")
    if not math.isfinite(alpha_f):
        raise ValueError(f"alpha must be a finite number, got {alpha!r}")
    try:
        c = np.atleast_2d(np.asarray(centres, dtype=float))
        r = np.asarray(radii, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"points centres and radii must be numbers, got {centres!r} and {radii!r}") from None
    if c.ndim == 2 and r.ndim <= 1 and r.size == 1:
        r = np.broadcast_to(r.reshape(-1), (c.shape[0],))
    c, r = check_points(c, r)
    return c, r, rho_f, alpha_f


def real_number(value: object, name: str, what: str) -> float:
    """``value`` as a float if it is a real number (not a bool or a string), else ``ValueError`` naming it."""
    if isinstance(value, str | bytes):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return _real(value, name, what)


def positive_number(value: object, name: str) -> float:
    """``value`` as a float if it is a finite number > 0 (not a bool or a string), else ``ValueError`` naming it."""
    x = real_number(value, name, "a positive finite number")
    if not 0.0 < x < math.inf:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return x


def positive_numbers(value: object, n: int, name: str) -> np.ndarray:
    """(n,) floats from one number or (n,) numbers, all finite and > 0 (no bools or strings), else ValueError."""
    a = np.asarray(value, float) if is_numeric_nest(value) else None
    if a is None or a.shape not in ((), (n,)) or not (np.all(np.isfinite(a)) and np.all(a > 0)):
        raise ValueError(f"{name} must be finite numbers > 0, one value or ({n},), got {value!r}")
    return np.broadcast_to(a, (n,)).copy()


def numeric_vector(x: object, n: int, name: str) -> np.ndarray:
    """``x`` as a finite float (n,) array, or ``ValueError`` naming it (also for strings and bools)."""
    if not is_numeric_nest(x):
        raise ValueError(f"{name} must be a numeric array of shape ({n},), got {x!r}")
    return check_finite_array(x, (n,), name)


def real_array(value: object, name: str, form: str = "an array") -> np.ndarray:
    """``value`` as a C-contiguous float64 array (a copy), or ``ValueError`` naming ``name`` unless it holds real
    numbers: not bools, complex numbers, strings or ragged nests (numpy would cast them or fail unnamed)."""
    try:
        if not is_numeric_nest(value):
            raise TypeError
        return np.array(value, dtype=np.float64, order="C")
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be {form} of real numbers (not bools, strings or complex)") from None
