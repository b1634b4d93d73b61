"""The hole-filling window minimum (docs/conventions.md, "Missing depth"), shared by the frame stages.

A missing pixel takes the minimum valid, non-robot depth of its ``(2 r + 1)²`` window (clipped at the image
border). The window minimum is separable: the minimum over the rows ``v - r .. v + r`` of each row's
minimum over ``u - r .. u + r``, or the other way round. The column minima (over ``v - r .. v + r``) are
computed for the whole image in three passes of whole rows (van Herk / Gil-Werman: prefix and suffix minima
over blocks of ``2 r + 1`` rows, then one comparison per pixel), whatever ``r``, in vector instructions;
each hole then reads the ``2 r + 1`` column minima of its row. Sparse holes read their windows directly.

Every kernel here clips ``r`` to ``0 .. max(H, W)`` first (:func:`_clip_radius`; the window is clipped at the
border, so this changes no result): ``2 r + 1`` of an int64 ``r`` near 2**62 wraps negative, which left the
column minima uninitialised memory (a hole took -3e33 m or any other value) and, near 2**63, divided the most
negative integer by -1 (SIGFPE: the process died).

At 640x480 with 5 % holes and r = 4 (the ``ral-hexagon`` principal frame) the direct reads took 1.7 ms and
the whole preparation of the frame went from 2.0 to 0.6 ms (BENCHMARKS.md, stop 43, "Frame stage: separable
hole filling, ...").
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["column_window_min", "column_minima_if_dense", "window_min_at", "use_column_minima"]


@nb.njit(cache=True, nogil=True, inline="always")
def _lesser(dst, x, y):
    """``dst[u] = min(x[u], y[u])`` (rows of one image; a form that numba turns into vector instructions)."""
    for u in range(dst.shape[0]):
        a = x[u]
        b = y[u]
        dst[u] = a if a < b else b


@nb.njit(cache=True, nogil=True, inline="always")
def _clip_radius(r, H, W):
    """``r`` clipped to ``0 .. max(H, W)``: the same clipped windows, and no int64 overflow in ``2 r + 1``."""
    return max(0, min(r, max(H, W)))


@nb.njit(cache=True, nogil=True)
def column_window_min(val, r, out, g, h):
    """``out[v, u] = min(val[max(0, v - r) : v + r + 1, u])`` for (H, W) float32 ``val``, without NaN (van
    Herk / Gil-Werman over blocks of ``2 r + 1`` rows: prefix minima ``g`` and suffix minima ``h`` of each
    block, then ``min(h[first row], g[last row])`` of the window; whole rows at a time). ``g``, ``h``: (H, W)
    float32 scratch; ``out`` may be ``val`` itself."""
    H, W = val.shape
    r = _clip_radius(r, H, W)
    w = 2 * r + 1
    for b0 in range(0, H, w):
        b1 = min(H, b0 + w)
        g[b0, :] = val[b0]
        for v in range(b0 + 1, b1):
            _lesser(g[v], val[v], g[v - 1])
        h[b1 - 1, :] = val[b1 - 1]
        for v in range(b1 - 2, b0 - 1, -1):
            _lesser(h[v], val[v], h[v + 1])
    for v in range(H):
        s = max(0, v - r)
        e = min(H - 1, v + r)
        if s // w != e // w:
            _lesser(out[v], h[s], g[e])
        elif s % w == 0:
            out[v, :] = g[e]  # (a window clipped at the top, inside the first block)
        else:
            out[v, :] = h[s]  # (clipped at the bottom, inside the last block)


@nb.njit(cache=True, nogil=True, inline="always")
def window_min_at(val, colmin, dense, v, u, r):
    """The window minimum of pixel (v, u): from the column minima ``colmin`` (:func:`column_window_min`)
    when ``dense``, else from ``val`` directly (``r``: any int, clipped as :func:`_clip_radius`)."""
    H, W = val.shape
    r = _clip_radius(r, H, W)
    best = np.float32(np.inf)
    if dense:
        for uu in range(max(0, u - r), min(W, u + r + 1)):
            best = min(best, colmin[v, uu])
        return best
    for vv in range(max(0, v - r), min(H, v + r + 1)):
        for uu in range(max(0, u - r), min(W, u + r + 1)):
            best = min(best, val[vv, uu])
    return best


@nb.njit(cache=True, nogil=True, inline="always")
def use_column_minima(holes, H, W, r):
    """Whether the column minima (three vectorised passes over the image) cost less than reading each hole's
    window (measured: a pass costs about a tenth of a read per pixel)."""
    r = _clip_radius(r, H, W)
    return holes * (2 * r + 1) * (2 * r + 1) > H * W // 3


@nb.njit(cache=True, nogil=True)
def column_minima_if_dense(val, holes, r):
    """``(dense, colmin)`` for :func:`window_min_at` with ``holes`` holes in (H, W) ``val``: the column minima
    in fresh arrays when :func:`use_column_minima`, else a (1, 1) placeholder."""
    H, W = val.shape
    dense = use_column_minima(holes, H, W, r)
    colmin = np.empty((H, W) if dense else (1, 1), np.float32)
    if dense:
        column_window_min(val, r, colmin, np.empty((H, W), np.float32), np.empty((H, W), np.float32))
    return dense, colmin
