"""How a node that handles images every frame asks the C allocator to keep the memory it frees.

A distance or camera node allocates the same large buffers at every frame: each received image is copied out
of Zenoh (``to_bytes``, 1.2 MB for a 640x480 32FC1 depth), decoded, converted to metres. glibc serves blocks
this large with ``mmap`` by default, or gives freed heap memory back to the system, so every new buffer
starts on fresh pages and faults each one in. On the 2-core CI VM that was about 0.5 ms of the last image's
decoding per frame set (BENCHMARKS.md, stop 44). :func:`keep_freed_memory` asks glibc (``mallopt``) to serve
blocks up to 64 MiB from the heap and not to give freed memory back below 1 GiB, as real-time programs do:
the buffers of one frame reuse the pages of the last. The process then keeps its peak heap (a few tens of MB
for a node here) instead of returning it.
"""

from __future__ import annotations

import ctypes
import sys

__all__ = ["keep_freed_memory"]

# glibc's malloc.h
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(mmap_threshold: int = 64 << 20, trim_threshold: int = 1 << 30) -> str:
    """Ask glibc to serve blocks below ``mmap_threshold`` bytes from the heap and to keep up to
    ``trim_threshold`` bytes of freed memory at its top (``mallopt``). Returns what the node got, for its
    summary: ``"kept"``, or why not (not Linux, not glibc, refused). Never raises."""
    if not sys.platform.startswith("linux"):
        return f"not kept: {sys.platform} has no glibc mallopt"
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return "not kept: the C library has no mallopt (not glibc)"
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    if not (mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold))):
        return "not kept: mallopt refused the thresholds"
    return "kept"
