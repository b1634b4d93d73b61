"""Timing helpers shared by the benchmarks and ``depthguard distance --repeat``.

Machine-speed reference. Absolute figures depend on the machine (a second 2-core machine with another CPU
measured about 60 % of the figures of BENCHMARKS.md). Every benchmark therefore also times, in the same
run, :func:`reference_speed`: a fixed brute-force numba kernel (the nearest back-projected pixel of a
fixed 640x480 depth frame to each of 4 fixed points, every pixel visited, one thread) and reports each
figure's ratio to it (:func:`with_reference`): ``vs_reference = hz_median / reference hz_median``, i.e.
how many of the measured operations run in the time of one reference run. Ratios compare across
machines far better than absolute rates (both scale with the core's speed; memory-bound and branchy code
scale somewhat differently, so expect a few tens of percent, not a factor of two).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable

import numba as nb
import numpy as np

__all__ = ["time_calls", "machine_info", "reference_speed", "with_reference", "REFERENCE_KERNEL"]

REFERENCE_KERNEL = (
    "brute force: nearest back-projected pixel of a fixed 640x480 depth frame to each of 4 fixed points, "
    "every pixel visited, one thread (depthguard.bench.timing.reference_speed)"
)


def time_calls(fn: Callable[[], object], repeat: int, warmup: int = 3) -> dict[str, float]:
    """Call ``fn`` ``warmup`` times, then ``repeat`` times, timing each call with ``perf_counter``.

    Returns:
        ``{"us_median", "us_p99", "hz_median", "n"}`` (microseconds; Hz = 1e6 / median).
    """
    if repeat < 1:
        raise ValueError(f"repeat must be >= 1, got {repeat}")
    for _ in range(warmup):
        fn()
    times = np.empty(repeat)
    for i in range(repeat):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    us = times * 1e6
    med = float(np.median(us))
    return {"us_median": med, "us_p99": float(np.percentile(us, 99)), "hz_median": 1e6 / med, "n": int(repeat)}


def machine_info() -> dict[str, object]:
    """Facts about the machine that ran a benchmark."""
    import numba

    info: dict[str, object] = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "numpy": np.__version__,
        "numba": numba.__version__,
    }
    try:  # how loaded the machine was: figures from a shared machine are inflated
        info["load_average_1min"] = os.getloadavg()[0]
    except OSError:  # pragma: no cover - not on every platform
        pass
    return info


# ------------------------------------------------------------------------------------ machine-speed reference
@nb.njit(cache=True, nogil=True, error_model="numpy")
def _nearest_pixel_kernel(depth, fx, fy, cx, cy, points, out):  # pragma: no cover (compiled)
    """out[i] = min over pixels of |points[i] - X(u, v)|, X the back-projected pixel centre (metres)."""
    H, W = depth.shape
    a = np.empty(W)
    for u in range(W):
        a[u] = (u + 0.5 - cx) / fx
    for i in range(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        best = np.inf
        for v in range(H):
            b = (v + 0.5 - cy) / fy
            for u in range(W):
                z = depth[v, u]
                x = a[u] * z - px
                y = b * z - py
                d2 = x * x + y * y + (z - pz) * (z - pz)
                if d2 < best:
                    best = d2
        out[i] = np.sqrt(best)


def _reference_frame() -> tuple[np.ndarray, np.ndarray]:
    """The fixed 640x480 frame (a tilted wall with a smooth bump, metres) and the 4 fixed points."""
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    depth = 2.5 + 0.001 * (u - 320) + 0.4 * np.exp(-((u - 300) ** 2 + (v - 200) ** 2) / 8000.0)
    s = np.linspace(-0.4, 0.4, 4)
    points = np.stack([s, 0.5 * s, 1.8 + 0.2 * s], axis=1)
    return depth.astype(np.float32), points


def reference_speed(repeat: int = 15) -> dict[str, object]:
    """Time the fixed brute-force reference kernel (see the module docstring) on this machine, now.

    Returns:
        ``{"kernel", "us_median", "us_p99", "hz_median", "n"}``.
    """
    depth, points = _reference_frame()
    out = np.empty(len(points))
    _nearest_pixel_kernel(depth, 525.0, 525.0, 319.5, 239.5, points, out)  # compile / load from cache
    t = time_calls(lambda: _nearest_pixel_kernel(depth, 525.0, 525.0, 319.5, 239.5, points, out), repeat)
    return {"kernel": REFERENCE_KERNEL, **t}


def with_reference(entry: dict, reference: dict) -> dict:
    """``entry`` (with ``hz_median``) plus ``vs_reference = hz_median / reference["hz_median"]``."""
    return {**entry, "vs_reference": float(entry["hz_median"]) / float(reference["hz_median"])}
