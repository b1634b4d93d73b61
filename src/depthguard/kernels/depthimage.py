"""Depth samples as received (a ROS 2 ``sensor_msgs/Image``) to metres, in one pass.

``image_to_depth`` (:mod:`depthguard.io.ros2`) runs at camera rate on every camera's frame in the distance
node's receive path; numpy's masked assignment took about 0.2 ms per 640x480 image, this kernel 0.04 ms.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["metres_or_nan"]

_F32_TINY = float(np.finfo(np.float32).tiny)  # the smallest normal float32, 1.2e-38
_F32_MAX = float(np.finfo(np.float32).max)  # 3.4e38


@nb.njit(cache=True, nogil=True)
def _metres_or_nan(src, divisor, out):
    nan = np.float32(np.nan)
    for i in range(src.size):
        x = np.float32(src[i]) / divisor
        out[i] = x if (x > 0.0 and x < np.inf) else nan


def metres_or_nan(samples: np.ndarray, divisor: float = 1.0) -> np.ndarray:
    """(H, W) float32: ``float32(samples) / float32(divisor)`` where that is > 0 and finite, NaN elsewhere (no
    reading).

    Args:
        samples: (H, W) float32 (metres, ``divisor`` 1) or uint16 (millimetres, ``divisor`` 1000) depth
            samples, any byte order and layout (a numpy array).
        divisor: units per metre: a finite number > 0 that float32 holds (1.2e-38 .. 3.4e38). Refused otherwise
            (``ValueError``): 0, a negative, NaN or inf divisor, or one that float32 rounds to 0 or inf, turned
            every sample into NaN, a camera that silently saw nothing.
    """
    if not isinstance(samples, np.ndarray):
        raise ValueError(f"depth samples must be a numpy array (float32 or uint16), got {type(samples).__name__}")
    native = samples.dtype.newbyteorder("=")
    if native not in (np.float32, np.uint16):
        raise ValueError(f"depth samples must be float32 or uint16, got {samples.dtype}")
    f = float("nan")
    if isinstance(divisor, int | float | np.integer | np.floating) and not isinstance(divisor, bool):
        try:
            f = float(divisor)
        except OverflowError:  # (an int beyond float range)
            f = float("inf")
    if not _F32_TINY <= f <= _F32_MAX:  # (False for NaN; float32 would make 0, a subnormal or inf of the rest)
        raise ValueError(
            f"divisor (units per metre) must be a finite number > 0 in float32's range (1.2e-38 .. 3.4e38), "
            f"got {divisor!r}"
        )
    src = np.ascontiguousarray(samples, dtype=native)
    out = np.empty(src.shape, np.float32)
    _metres_or_nan(src.reshape(-1), np.float32(f), out.reshape(-1))
    return out
