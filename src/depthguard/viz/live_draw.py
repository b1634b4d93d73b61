"""What the live view draws, as plain arrays and strings (no viser): colours of the cameras, the robot pixels,
the octree's node kinds and the control spheres by distance, the panel's nearest-distance text, and the
decimated world points of a depth image. :mod:`depthguard.viz.live` puts them on the page."""

from __future__ import annotations

from typing import Any

import numpy as np

from depthguard.camera import Camera

__all__ = ["CAMERA_COLOURS", "ROBOT_PIXELS", "OCTREE_COLOURS", "UNKNOWN_DISTANCE"]

#: Point-cloud colour of camera k (RGB 0-255).
CAMERA_COLOURS = [(40, 120, 255), (0, 190, 190), (250, 160, 0), (140, 90, 255)]
ROBOT_PIXELS = (255, 0, 220)
#: Colour of the octree's node kinds (depthguard.octree.fusion: 1 occupied, 2 occluded, 3 unseen).
OCTREE_COLOURS = {"occupied": (1, (230, 30, 30)), "occluded": (2, (255, 150, 40)), "unseen": (3, (120, 120, 130))}
#: Colour of a control sphere whose distance is unknown (NaN): never the green of "safe".
UNKNOWN_DISTANCE = (150, 150, 150)


def _distance_rgb(d: float, rho: float) -> tuple[int, int, int]:
    """Colour of a control sphere at distance ``d`` (m): red at contact (``d <= 0``, ``-inf`` included),
    yellow at ``rho / 2``, green at ``rho`` and beyond (``inf``: nothing within range); grey
    (:data:`UNKNOWN_DISTANCE`) when ``d`` is NaN (unknown)."""
    d = float(d)
    if np.isnan(d):
        return UNKNOWN_DISTANCE
    f = 1.0 if d == np.inf else 0.0 if d == -np.inf else float(np.clip(d / max(rho, 1e-9), 0.0, 1.0))
    return (int(255 * min(1.0, 2.0 * (1.0 - f))), int(255 * min(1.0, 2.0 * f)), 0)


def _nearest_text(d: np.ndarray | None) -> str:
    """The panel's nearest distance: ``-`` without control points, ``inf`` when nothing is within range,
    ``unknown`` when a distance is NaN (or ``d`` is None: the distances did not match), with the smallest
    known distance beside it."""
    if d is None:
        return "unknown (distances do not match the control points)"
    d = np.asarray(d, float).ravel()
    if d.size == 0:
        return "-"
    known = d[~np.isnan(d)]
    m = None if known.size == 0 else float(np.min(known))
    txt = "-" if m is None else "inf" if m == np.inf else "-inf" if m == -np.inf else f"{m:.3f} m"
    if known.size < d.size:
        return f"unknown ({d.size - known.size} of {d.size} NaN; smallest known {txt})"
    return txt


def _stride(width: int, stride: int | None) -> int:
    """The decimation of a depth image ``width`` pixels wide: ``stride``, or about 160 points per row."""
    return max(1, int(stride)) if stride else max(1, round(width / 160))


def _cloud_points(cam: Camera, depth: Any, mask: Any, stride: int | None) -> tuple[np.ndarray, np.ndarray]:
    """The world points of every ``s``-th pixel of a depth image (``s``: :func:`_stride`) with a finite
    positive depth: ``(environment, robot)`` float32 arrays, robot where ``mask`` is set. ``depth`` may be a
    scaled image of ``cam`` (same field of view). Raises ``ValueError`` when ``depth`` is not 2-D, is not a
    scaled image of ``cam``, or ``mask`` is not of its shape. The image is decimated before it is converted."""
    from depthguard.nodes.common import camera_at_size

    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth image of shape {depth.shape}, not 2-D")
    h, w = depth.shape
    if h == 0 or w == 0:
        e = np.zeros((0, 3), np.float32)
        return e, e
    s = _stride(w, stride)
    d = np.asarray(depth[::s, ::s], float)
    c = camera_at_size(cam, w, h)
    if mask is None:
        m = np.zeros(d.shape, bool)
    else:
        mask = np.asarray(mask)
        if mask.shape != depth.shape:
            raise ValueError(f"mask of shape {mask.shape} for a depth image of shape {depth.shape}")
        m = np.asarray(mask[::s, ::s], bool)
    v, u = np.mgrid[0:h:s, 0:w:s]
    ok = np.isfinite(d) & (d > 0)
    env, rob = ok & ~m, ok & m
    pts = c.unproject(u[ok] + 0.5, v[ok] + 0.5, d[ok])
    return pts[env[ok]].astype(np.float32), pts[rob[ok]].astype(np.float32)
