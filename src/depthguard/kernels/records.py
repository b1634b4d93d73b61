"""Typed parameter records of the distance kernels (numba accepts named tuples as arguments).

A record travels by value into the compiled code, where its fields are read like local variables, so
grouping the parameters costs nothing at run time and keeps every kernel signature short.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "Intrinsics",
    "QueryParams",
    "intrinsics",
    "query_params",
    "direction_stride",
    "DIRECTION_WIDTH",
    "MODE_MIN",
    "MODE_ALL",
    "MODE_HYBRID",
]

MODE_MIN, MODE_ALL, MODE_HYBRID = 0, 1, 2


class Intrinsics(NamedTuple):
    """The principal (or only) camera: pinhole intrinsics (pixels), image size, near limit (metres)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near_limit: float


class QueryParams(NamedTuple):
    """One query: radius of surveillance ρ (m), mode (0 min, 1 all, 2 hybrid), eq. 9 shape factor α,
    ``unseen``: space outside the field of view and nearer than the near limit counts as an obstacle,
    ``tile``: the tile size (pixels) of the tile minima. (The direction lattice's stride travels as an
    argument of its own, :func:`direction_stride`.)"""

    rho: float
    mode: int
    alpha: float
    unseen: bool
    tile: int


def intrinsics(camera) -> Intrinsics:
    """The :class:`Intrinsics` record of a :class:`depthguard.camera.Camera`."""
    return Intrinsics(
        float(camera.fx),
        float(camera.fy),
        float(camera.cx),
        float(camera.cy),
        int(camera.width),
        int(camera.height),
        float(camera.min_depth),
    )


def query_params(rho: float, mode: int, alpha: float, unseen: bool, tile: int) -> QueryParams:
    """A :class:`QueryParams` record with the field types the kernels are compiled for."""
    return QueryParams(float(rho), int(mode), float(alpha), bool(unseen), int(tile))


DIRECTION_WIDTH = 320  # pixels: the "auto" direction lattice is about this wide


def direction_stride(stride: int | str, width: int) -> int:
    """The pixel stride of the direction sum (modes ``all`` and ``hybrid``): in those modes the direction
    sum takes the pixels ``u % stride == 0 and v % stride == 0`` only, and the other pixels compete for
    the nearest distance only (``stride = 1``: every pixel).

    ``"auto"``: ``max(1, width // DIRECTION_WIDTH)`` (1 up to 639 pixels wide, 2 at 640), so that the
    mean direction of RA-L'16 eq. 11 (and the eq. 9 sum) is taken over a lattice about 320 pixels wide
    whatever the camera's resolution; an integer >= 1 as given. The distance always comes from every
    pixel.
    """
    if isinstance(stride, str):
        if stride != "auto":
            raise ValueError(f"direction_stride must be 'auto' or an integer >= 1, got {stride!r}")
        return max(1, int(width) // DIRECTION_WIDTH)
    if isinstance(stride, bool) or not isinstance(stride, int | np.integer) or stride < 1:
        raise ValueError(f"direction_stride must be 'auto' or an integer >= 1, got {stride!r}")
    return int(stride)


def empty_out(n: int) -> np.ndarray:  # pragma: no cover - trivial
    """Output rows of N points (see :mod:`depthguard.kernels.hits`)."""
    return np.empty((n, 10))
