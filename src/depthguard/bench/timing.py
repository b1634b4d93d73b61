"""Timing helpers shared by the benchmarks and ``depthguard distance --repeat``."""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable

import numpy as np

__all__ = ["time_calls", "machine_info"]


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

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "numpy": np.__version__,
        "numba": numba.__version__,
    }
