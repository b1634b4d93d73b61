"""Explicit checks of one cycle's inputs (the first stage of every control cycle).

Rules (docs/conventions.md, safety principles): whatever a cycle is given, it never raises; anything
malformed stops the robot.

* ``STOP_INVALID_INPUT``: a time stamp that is not a finite number (a string, a bool or an array is none),
  ``t`` earlier than the previous cycle's ``t``, ``t_joints`` or ``t_distances`` more than one period ``dt``
  after ``t``; ``q``, ``qdot`` or ``xdot_d`` missing, of the wrong shape, not real numbers (strings, bools,
  complex numbers) or not finite; ``distances``/``directions`` of the wrong shape or not real numbers, a NaN
  or -inf distance, a non-finite direction paired with a finite distance; the same for the optional
  ``monitor_distances``/``monitor_directions`` (speed and separation monitoring's own distances), and one of
  those two given without the other.
* ``STOP_STALE_JOINTS``: ``t - t_joints > joint_timeout``.
* ``STOP_STALE_DISTANCES``: distances or directions missing (None), or ``t - t_distances >
  distance_timeout``.

A +inf distance means "nothing within rho": it is valid and its direction is ignored (set to 0).
"""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np
from numba import njit

from depthguard.control.types import ControllerConfig, CycleInput, CycleStatus

__all__ = ["CheckedInput", "check_inputs", "as_vector"]


class CheckedInput(NamedTuple):
    """The verdict on one cycle's inputs and whatever of them is usable.

    Attributes:
        status: ``OK`` or the stop status (module docstring).
        t: the cycle time, s (NaN if not a finite number).
        q: (n,) float64 joint positions, or None if missing or malformed.
        qdot: (n,) float64 joint velocities, or None.
        xdot_d: (m,) desired task velocity, or None.
        distances: (N,) float64 (finite or +inf), or None.
        directions: (N, 3) float64 C-contiguous, finite (0 where the distance is +inf), or None.
        monitor_distances, monitor_directions: the same for the monitor's distances; ``distances`` and
            ``directions`` themselves when the input gave none.
    """

    status: CycleStatus
    t: float
    q: np.ndarray | None
    qdot: np.ndarray | None
    xdot_d: np.ndarray | None
    distances: np.ndarray | None
    directions: np.ndarray | None
    monitor_distances: np.ndarray | None = None
    monitor_directions: np.ndarray | None = None


def _time(x: object) -> float:
    """A finite float time stamp, or NaN for anything else (None, str, bool, inf, arrays...)."""
    if isinstance(x, (bool, np.bool_, str, bytes, bytearray, np.ndarray)):  # (float() would parse "1.5", b"1")
        return math.nan
    try:
        v = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def as_vector(x: object, shape: tuple[int, ...], finite: bool = True) -> np.ndarray | None:
    """``x`` as a writable float64 C-contiguous array of ``shape`` (all finite if ``finite``), else None.

    Writable: a read-only array (a ROS message's ``position`` decoded in place is one) is another type for
    the compiled kernels, which would compile it at its first use, inside the control loop (5 s at the
    first resume of the controller node on a new machine); so it is copied."""
    if x is None:
        return None
    if _plain_array(x):
        a = x  # the usual case, without a copy
    else:
        try:
            raw = np.asarray(x)
            if not _real_numbers(raw):  # strings, bools, complex numbers are not numbers of this kind
                return None
            a = np.array(raw, dtype=np.float64, order="C")  # (a copy: writable)
        except (TypeError, ValueError, OverflowError):
            return None
    if a.shape != shape:
        return None
    if finite and not _all_finite(a.reshape(-1)):
        return None
    return a


def _real_numbers(a: np.ndarray) -> bool:
    """``a`` holds real numbers only: integer or float dtype, or objects that are all real numbers (not
    bools). Strings ("0.1") and bools would convert to floats, complex numbers would lose their imaginary part."""
    if a.dtype.kind in "iuf":
        return True
    if a.dtype.kind != "O":
        return False
    return all(isinstance(e, numbers.Real) and not isinstance(e, (bool, np.bool_)) for e in a.flat)


def _plain_array(x: object) -> bool:
    """``x`` is a writable float64 C-contiguous array (what :func:`as_vector` returns as it is)."""
    return type(x) is np.ndarray and x.dtype == np.float64 and x.flags.carray  # (C-contiguous, aligned, writable)


def _plain(x: object, n: int) -> bool:
    """``x`` is a writable float64 C-contiguous (n,) array (what :func:`as_vector` would return as it is)."""
    return _plain_array(x) and x.shape == (n,)  # type: ignore[union-attr]


@njit(cache=True, nogil=True)
def _finite3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> int:
    """Bit 0, 1, 2 set when ``a``, ``b``, ``c`` (1-D) are all finite."""
    return int(_all_finite(a)) | (int(_all_finite(b)) << 1) | (int(_all_finite(c)) << 2)


@njit(cache=True, nogil=True)
def _all_finite(a: np.ndarray) -> bool:
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return False
    return True


@njit(cache=True, nogil=True)
def _distances_valid(d: np.ndarray, dirs: np.ndarray) -> tuple[bool, np.ndarray]:
    """``(valid, directions)``. Invalid: a NaN or -inf distance, or a non-finite direction with a finite
    distance. ``directions`` is ``dirs`` itself when every distance is finite, else a copy with the rows of
    +inf distances set to 0 (their direction is ignored)."""
    some_inf = False
    for k in range(d.shape[0]):
        if d[k] == np.inf:
            some_inf = True
        elif not np.isfinite(d[k]):
            return False, dirs
        elif not (np.isfinite(dirs[k, 0]) and np.isfinite(dirs[k, 1]) and np.isfinite(dirs[k, 2])):
            return False, dirs
    if not some_inf:
        return True, dirs
    out = dirs.copy()
    for k in range(d.shape[0]):
        if d[k] == np.inf:
            out[k, 0], out[k, 1], out[k, 2] = 0.0, 0.0, 0.0
    return True, out


def _check_distances(d_in: object, dirs_in: object, N: int) -> tuple[bool, np.ndarray | None, np.ndarray | None]:
    """``(valid, distances, directions)``; distances/directions None when missing or invalid."""
    if d_in is None or dirs_in is None:
        return True, None, None
    if _plain(d_in, N) and _plain_array(dirs_in) and dirs_in.shape == (N, 3):  # type: ignore[union-attr]
        d, dirs = d_in, dirs_in  # (what as_vector returns for them)
    else:
        d = as_vector(d_in, (N,), finite=False)
        dirs = as_vector(dirs_in, (N, 3), finite=False)
    if d is None or dirs is None:
        return False, None, None
    valid, dirs = _distances_valid(d, dirs)
    if not valid:
        return False, None, None
    return True, d, dirs


def _check_pair(d_in: object, dirs_in: object, N: int) -> tuple[bool, np.ndarray | None, np.ndarray | None]:
    """:func:`_check_distances` for a pair that must be given whole (the monitor's): one alone is invalid."""
    if d_in is None or dirs_in is None:
        return False, None, None
    return _check_distances(d_in, dirs_in, N)


def check_inputs(inp: object, n: int, N: int, m: int, cfg: ControllerConfig, t_prev: float) -> CheckedInput:
    """Check one cycle's inputs (module docstring); never raises.

    Args:
        inp: the :class:`CycleInput` (anything else is invalid).
        n: joints; N: control points; m: task dimension; cfg: the controller configuration.
        t_prev: the previous cycle's time, s (-inf at start).
    """
    if not isinstance(inp, tuple) or len(inp) not in (8, len(CycleInput._fields)):
        return CheckedInput(CycleStatus.STOP_INVALID_INPUT, math.nan, None, None, None, None, None)
    t_in, q_in, qd_in, tj_in, xd_in, d_in, dirs_in, td_in = inp[:8]
    md_in, mdirs_in = inp[8:] if len(inp) > 8 else (None, None)
    t, tj, td = _time(t_in), _time(tj_in), _time(td_in)
    if _plain(q_in, n) and _plain(qd_in, n) and _plain(xd_in, m):  # the usual case: one compiled check
        ok = _finite3(q_in, qd_in, xd_in)
        q, qdot, xdot_d = (q_in if ok & 1 else None), (qd_in if ok & 2 else None), (xd_in if ok & 4 else None)
    else:
        q = as_vector(q_in, (n,))
        qdot = as_vector(qd_in, (n,))
        xdot_d = as_vector(xd_in, (m,))
    d_ok, dist, dirs = _check_distances(d_in, dirs_in, N)
    m_ok, mdist, mdirs = (True, dist, dirs) if md_in is None and mdirs_in is None else _check_pair(md_in, mdirs_in, N)
    status = CycleStatus.OK
    times_ok = not (math.isnan(t) or math.isnan(tj) or math.isnan(td))
    if (
        not times_ok
        or t < t_prev
        or tj > t + cfg.dt
        or td > t + cfg.dt
        or q is None
        or qdot is None
        or xdot_d is None
        or not d_ok
        or not m_ok
    ):
        status = CycleStatus.STOP_INVALID_INPUT
    elif not t - tj <= cfg.joint_timeout:
        status = CycleStatus.STOP_STALE_JOINTS
    elif dist is None or not t - td <= cfg.distance_timeout:
        status = CycleStatus.STOP_STALE_DISTANCES
    return CheckedInput(status, t, q, qdot, xdot_d, dist, dirs, mdist, mdirs)
