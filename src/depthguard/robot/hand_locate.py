"""The hand position from a depth image (SAPHARI D4.1.1 §6.2, step 2 of Algorithm 1; see
:mod:`depthguard.robot.contact_point` for the whole algorithm and what the hand tracker assumes).

The depth image, after the self-filter, keeps only the *foreground* (:func:`foreground_mask`): pixels with a
reading nearer than a background depth image by more than ``bg_margin`` (people and whatever they carry),
robot pixels removed. The depth-space distance from spheres along the robot's capsule axes gives the nearest
foreground obstacle point; its pixel's measured 3-D point seeds the hand, and the hand is the centroid of the
foreground points within ``hand_radius`` of that seed (:func:`locate_hands`).
"""

from __future__ import annotations

import math
import operator
from dataclasses import fields, replace
from typing import NamedTuple

import numpy as np

from depthguard.camera import Camera
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.robot._contact_kernels import (
    _box_kernel,
    _foreground_kernel,
    _masked_window,
)

_F64 = np.dtype(np.float64)
_F32_F64 = (np.dtype(np.float32), _F64)
_CAMERA_FIELDS = tuple(f.name for f in fields(Camera))

__all__ = ["HandObservation", "foreground_mask", "image_box", "locate_hands"]


def foreground_mask(
    depth: np.ndarray,
    background: np.ndarray,
    robot_mask: np.ndarray,
    bg_margin: float | np.ndarray,
    erode: bool = True,
    box: tuple[int, int, int, int] | None = None,
) -> np.ndarray:
    """(H, W) bool: readings nearer than the background by more than ``bg_margin`` m (scalar or (H, W)),
    robot excluded; with ``erode`` a 4-neighbour erosion removes isolated pixels (depth noise that
    escaped the self-filter), which a hand, a blob of many pixels, survives.

    A background pixel without reading (NaN/0) admits any reading in front of it. With ``box``
    ``(u0, u1, v0, v1)`` (e.g. :func:`image_box`) only that part is computed (clipped to the image); the rest
    is False.

    ``background`` and ``robot_mask`` must have the shape of ``depth`` and ``bg_margin`` must be a finite number
    >= 0 or an (H, W) array of them (within ``box``): a NaN or infinite margin would hide every person;
    anything else raises ``ValueError`` naming the argument (O(1), plus one min/max pass over a margin image).
    """
    H, W = _image_shape(depth, "depth")
    if np.asarray(depth).dtype.kind != "f":  # (an integer image in millimetres would compare with metres)
        raise ValueError(f"foreground_mask: depth must be a float image in metres, got {np.asarray(depth).dtype}")
    for name, a in (("background", background), ("robot_mask", robot_mask)):
        if np.shape(a) != (H, W):
            raise ValueError(f"foreground_mask: {name} must be an (H, W) = {(H, W)} image, got shape {np.shape(a)}")
    u0, u1, v0, v1 = _clip_box(box, W, H)
    win = (slice(v0, v1), slice(u0, u1))
    d = np.asarray(depth[win], np.float32)
    bg = np.asarray(background[win], np.float32)
    margin = _check_bg_margin(bg_margin, (H, W), win)
    m = _window_margin(margin, d.shape) if bg.shape == d.shape else None
    rm = np.asarray(robot_mask[win], bool) if m is not None else None
    if rm is not None and rm.shape == d.shape:  # one compiled pass, the same mask
        fg = np.empty(d.shape, bool)
        c = np.ascontiguousarray  # (contiguous windows: the kernel runs about twice as fast)
        _foreground_kernel(c(d), c(bg), c(rm), *m, bool(erode), fg)
    else:
        ok = np.isfinite(d) & (d > 0)
        bg_f = np.where(np.isfinite(bg) & (bg > 0), bg, np.inf)
        with np.errstate(invalid="ignore"):
            fg = ok & (d < bg_f - margin) & ~np.asarray(robot_mask[win], bool)
        if erode:
            e = fg.copy()
            e[1:] &= fg[:-1]
            e[:-1] &= fg[1:]
            e[:, 1:] &= fg[:, :-1]
            e[:, :-1] &= fg[:, 1:]
            fg = e
    if box is None:
        return fg
    out = np.zeros((H, W), bool)
    out[win] = fg
    return out


def _image_shape(a: object, name: str) -> tuple[int, int]:
    """(H, W) of a 2-D image ``a``; ``ValueError`` naming ``name`` otherwise."""
    shape = np.shape(a)
    if len(shape) != 2:
        raise ValueError(f"{name} must be an (H, W) image, got shape {shape}")
    return shape[0], shape[1]


def _clip_box(box: tuple[int, int, int, int] | None, W: int, H: int) -> tuple[int, int, int, int]:
    """``box`` (u0, u1, v0, v1) clipped to the (W, H) image (a negative bound is the image's edge, not Python's
    index from the end); the whole image for None; ``ValueError`` for anything but four integers."""
    if box is None:
        return 0, W, 0, H
    try:
        u0, u1, v0, v1 = (operator.index(x) for x in box)
    except (TypeError, ValueError):
        raise ValueError(f"foreground_mask: box must be four integers (u0, u1, v0, v1) or None, got {box!r}") from None
    return min(max(u0, 0), W), min(max(u1, 0), W), min(max(v0, 0), H), min(max(v1, 0), H)


def _check_bg_margin(bg_margin: object, shape: tuple[int, int], win: tuple[slice, slice]) -> float | np.ndarray:
    """``bg_margin`` (its window for an (H, W) array) as given, checked: a finite number >= 0 (m) or an (H, W)
    float array of them within ``win``; ``ValueError`` naming ``bg_margin`` otherwise."""
    if type(bg_margin) in (float, int, np.float32, np.float64) and 0 <= bg_margin < math.inf:
        return bg_margin  # (the common case, O(1))
    if isinstance(bg_margin, np.ndarray) and bg_margin.ndim == 2:
        if bg_margin.shape != shape or bg_margin.dtype.kind != "f":
            raise ValueError(
                f"bg_margin must be a number >= 0 or a float (H, W) = {shape} array, got {bg_margin.dtype} "
                f"of shape {bg_margin.shape}"
            )
        m = np.ascontiguousarray(bg_margin[win])  # (what the kernel takes: reduced at full speed)
        if m.size and not (m.min() >= 0 and math.isfinite(m.sum())):  # (NaN fails the first)
            raise ValueError("bg_margin must be finite and >= 0 m in every pixel, got NaN, inf or a negative one")
        return m
    if isinstance(bg_margin, np.ndarray) and bg_margin.ndim == 0 and bg_margin.dtype.kind in "fiu":
        if 0 <= bg_margin < np.inf:
            return bg_margin
    ok = isinstance(bg_margin, int | float | np.integer | np.floating) and not isinstance(bg_margin, bool)
    if not (ok and 0 <= bg_margin < math.inf):
        raise ValueError(f"bg_margin must be a finite number of metres >= 0 or an (H, W) array, got {bg_margin!r}")
    return bg_margin


def _window_margin(margin: object, shape: tuple[int, ...]) -> tuple[np.ndarray, bool] | None:
    """``(margin, scalar)`` for :func:`_foreground_kernel`: the (h, w) float32/float64 window, or a number
    as a (1, 1) array in the type numpy computes ``background - margin`` in (float32 for a Python number);
    None for anything else (the numpy path)."""
    if type(margin) is np.ndarray:
        return (np.ascontiguousarray(margin), False) if margin.dtype in _F32_F64 and margin.shape == shape else None
    if type(margin) in (float, int) and abs(margin) < 3.0e38:
        return np.full((1, 1), margin, np.float32), True
    if type(margin) in (np.float32, np.float64):
        return np.full((1, 1), margin, margin.dtype), True
    return None


class HandObservation(NamedTuple):
    """A hand found in a depth frame: ``position`` (3,) m (centroid), ``seed`` (3,) m (nearest visible
    foreground point), ``distance`` (m, depth-space distance of the seed region to the robot surface),
    ``n_points`` (foreground points in the hand)."""

    position: np.ndarray
    seed: np.ndarray
    distance: float
    n_points: int


def _backproject(camera: Camera, depth: np.ndarray, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    z = depth[vs, us].astype(float)
    x = (us + 0.5 - camera.cx) / camera.fx * z
    y = (vs + 0.5 - camera.cy) / camera.fy * z
    return camera.camera_to_world(np.stack([x, y, z], axis=1))


def image_box(camera: Camera, centres: np.ndarray, reach: np.ndarray | float) -> tuple[int, int, int, int] | None:
    """Pixel box (u0, u1, v0, v1) covering the image of every sphere (S, 3) grown by ``reach`` (m), from the
    exact tangent bounds; the whole image if one reaches behind the camera; None if the box is empty (no
    sphere among them). Centres or reaches that are not finite (reach >= 0 m, a number or (S,)) raise
    ``ValueError`` naming them (an O(S) check)."""
    centres, reach = _check_spheres(centres, reach, "reach")
    return _image_box(camera, centres, reach) if len(centres) else None


def _image_box(camera: Camera, centres: np.ndarray, reach: np.ndarray) -> tuple[int, int, int, int] | None:
    """:func:`image_box` of checked spheres: ``centres`` (S >= 1, 3), ``reach`` (S,) m."""
    pc = camera.world_to_camera(centres)
    if pc.ndim == 2 and pc.shape[1] == 3 and len(pc):  # one compiled pass, the same box
        behind, a0, a1, b0, b1 = _box_kernel(pc, reach, camera.fx, camera.fy, camera.cx, camera.cy)
        if behind:
            return 0, camera.width, 0, camera.height
        u0, u1 = int(min(max(a0, 0), camera.width)), int(min(max(a1, 0), camera.width))
        v0, v1 = int(min(max(b0, 0), camera.height)), int(min(max(b1, 0), camera.height))
        return (u0, u1, v0, v1) if u1 > u0 and v1 > v0 else None
    z = pc[:, 2] - reach
    if np.any(z <= 1e-3):
        return 0, camera.width, 0, camera.height
    den = z * (pc[:, 2] + reach)
    spans = []
    for f, c, x in ((camera.fx, camera.cx, pc[:, 0]), (camera.fy, camera.cy, pc[:, 1])):
        root = np.sqrt(np.maximum(x * x + pc[:, 2] ** 2 - reach**2, 0.0))  # exact tangent bound (sphere_span)
        spans.append((f * (x * pc[:, 2] - reach * root) / den + c, f * (x * pc[:, 2] + reach * root) / den + c))
    (xl, xh), (yl, yh) = spans
    u0 = int(np.clip(np.floor(xl.min()) - 1, 0, camera.width))
    u1 = int(np.clip(np.ceil(xh.max()) + 2, 0, camera.width))
    v0 = int(np.clip(np.floor(yl.min()) - 1, 0, camera.height))
    v1 = int(np.clip(np.ceil(yh.max()) + 2, 0, camera.height))
    return (u0, u1, v0, v1) if u1 > u0 and v1 > v0 else None


def _check_spheres(centres: object, radii: object, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``centres`` (S, 3) and ``radii`` (a number or (S,), broadcast) as float arrays, both finite and the radii
    >= 0 m; else ``ValueError`` naming them."""
    c = np.asarray(centres, float)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"centres must be an (S, 3) array of sphere centres in metres, got shape {c.shape}")
    r = np.asarray(radii, float)
    if r.ndim > 1 or (r.ndim == 1 and r.shape != (len(c),)):
        raise ValueError(f"{name} must be a number or an ({len(c)},) array of metres, got shape {r.shape}")
    r = np.broadcast_to(r, (len(c),))
    if not math.isfinite(c.sum()):  # (a sum is finite only if every element is: one pass)
        raise ValueError("centres must be finite (S, 3) sphere centres in metres, got NaN, inf or an overflowing one")
    if len(r) and not (r.min() >= 0 and math.isfinite(r.sum())):  # (NaN fails the first)
        raise ValueError(f"{name} must be finite and >= 0 m, got {r.tolist()}")
    return c, r


def _check_locate_args(n: object, rho: object, hand_radius: object, separation: object, depth_offset: object) -> int:
    """:func:`locate_hands`' numbers checked (``ValueError`` naming the first bad one); returns ``n``."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"n (the number of hands) must be an integer >= 0, got {n!r}")
    for name, v, positive in (
        ("rho", rho, True),
        ("hand_radius", hand_radius, True),
        ("separation", separation, False),
        ("depth_offset", depth_offset, False),
    ):
        ok = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        if not (ok and math.isfinite(v) and (v > 0 if positive else v >= 0)):
            raise ValueError(f"{name} must be a finite number of metres {'> 0' if positive else '>= 0'}, got {v!r}")
    return int(n)


def _hand_at(
    camera: Camera,
    depth: np.ndarray,
    fg: np.ndarray,
    nearest: np.ndarray,
    centre: np.ndarray,
    radius: float,
    hand_radius: float,
    depth_offset: float,
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Hand centroid around the pixel of a depth-space nearest point: (position, seed, n_points)."""
    pc = camera.world_to_camera(nearest)  # camera.project of one point, in scalars (the same numbers)
    z = float(pc[2])
    inv = 1.0 / z if z > 0 else math.nan
    px, py = camera.fx * float(pc[0]) * inv + camera.cx, camera.fy * float(pc[1]) * inv + camera.cy
    if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(z)):
        return None
    u = min(max(math.floor(px), 0), camera.width - 1)
    v = min(max(math.floor(py), 0), camera.height - 1)
    # the pixel's own measured point (the nearest point may lie in the gray area behind it)
    win = np.where(
        fg[max(v - 1, 0) : v + 2, max(u - 1, 0) : u + 2], depth[max(v - 1, 0) : v + 2, max(u - 1, 0) : u + 2], np.inf
    )
    zc = float(win.min())
    if not np.isfinite(zc):
        return None
    w = int(np.ceil(1.5 * hand_radius * camera.fx / max(zc, 1e-3))) + 2
    v0, v1, u0, u1 = max(v - w, 0), min(v + w + 1, camera.height), max(u - w, 0), min(u + w + 1, camera.width)
    vs, us = np.nonzero(fg[v0:v1, u0:u1])
    if len(us) == 0:
        return None
    pts = _backproject(camera, depth, us + u0, vs + v0)
    # seed: the window's measured point nearest to the sphere that found it
    seed = pts[int(np.argmin(np.einsum("ij,ij->i", pts - centre, pts - centre)))]
    near = np.linalg.norm(pts - seed, axis=1) <= hand_radius
    c = pts[near].mean(axis=0)
    ray = c - camera.position
    return c + depth_offset * ray / np.linalg.norm(ray), seed, int(near.sum())


def _sub_camera(camera: Camera, u0: int, u1: int, v0: int, v1: int) -> Camera:
    """``camera`` cropped to the pixel box (u0, u1, v0, v1) (u1 > u0, v1 > v0, inside the image): what
    ``dataclasses.replace`` gives, without re-validating the unchanged rotation and translation."""
    if type(camera) is not Camera:
        return replace(camera, width=u1 - u0, height=v1 - v0, cx=camera.cx - u0, cy=camera.cy - v0)
    cam = object.__new__(Camera)  # the fields only (nothing derived from the full image can come along)
    cam.__dict__.update({name: getattr(camera, name) for name in _CAMERA_FIELDS})
    cam.__dict__.update(width=u1 - u0, height=v1 - v0, cx=camera.cx - u0, cy=camera.cy - v0)
    return cam


def locate_hands(
    camera: Camera,
    depth: np.ndarray,
    fg: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    n: int = 1,
    rho: float = 0.2,
    hand_radius: float = 0.06,
    separation: float = 0.15,
    depth_offset: float = 0.03,
) -> list[HandObservation]:
    """Up to ``n`` hands near the robot, nearest first (module docstring), from one depth-space query.

    Args:
        camera: the depth camera.
        depth: (H, W) depth in metres (NaN/0 = no reading).
        fg: (H, W) bool foreground mask (:func:`foreground_mask`).
        centres, radii: (S, 3), (S,) robot axis spheres in the world frame (:meth:`RobotSurface.pose`).
        n: the number of hands wanted.
        rho: search radius from the sphere surfaces, m.
        hand_radius: radius of the blob taken as the hand around its seed point, m.
        separation: two hands are further apart than this (m); nearer candidates are the same hand.
        depth_offset: points sampled per pixel on the visible half of a ball of radius ρ_h have their
            centroid (2/3) ρ_h in front of its centre: the hand position is pushed this far (m) away from
            the camera along the viewing ray (0.03 m for a 4.5 cm hand).
    Returns:
        A list of :class:`HandObservation` (possibly empty).

    Only the image box around the robot's spheres grown by ``rho`` is prepared and searched (the depth-space
    query never looks further), so the cost depends on the robot's image size, not the frame's.

    ``depth`` and ``fg`` must be the camera's (H, W) images; centres and radii finite (radii >= 0), ``n`` an
    integer >= 0, ``rho`` and ``hand_radius`` finite > 0, ``separation`` and ``depth_offset`` finite >= 0:
    anything else raises ``ValueError`` naming it (O(S) checks). No sphere (S = 0): no hand.
    """
    n = _check_locate_args(n, rho, hand_radius, separation, depth_offset)
    for name, a in (("depth", depth), ("fg", fg)):
        if np.shape(a) != camera.shape:
            raise ValueError(
                f"locate_hands: {name} must be the camera's (H, W) = {camera.shape} image, got {np.shape(a)}"
            )
    centres, radii = _check_spheres(centres, radii, "radii")
    if n == 0 or not len(centres):
        return []
    box = _image_box(camera, centres, radii + rho)
    if box is None:
        return []
    u0, u1, v0, v1 = box
    cam = _sub_camera(camera, u0, u1, v0, v1)
    d = np.asarray(depth[v0:v1, u0:u1], np.float32)
    f = np.asarray(fg[v0:v1, u0:u1], bool)
    if d.shape == f.shape:  # (contiguous windows: the kernel runs faster on them)
        dm, nf = _masked_window(np.ascontiguousarray(d), np.ascontiguousarray(f))
    else:
        dm, nf = np.where(f, d, np.float32(np.nan)), ~f
    frame = prepare_frame(cam, dm, mask=nf, invalid="ignore", fill_radius=0)
    res = query_distances(frame, centres, radii, rho=rho, mode="min")
    out: list[HandObservation] = []
    taken: list[tuple[float, float, float]] = []  # (u, v, radius) image discs of the hands found
    uvd = None  # the candidates' pixels, needed once a hand is taken
    for i in np.argsort(res.distance):
        if len(out) >= n or not np.isfinite(res.distance[i]):
            break
        if taken and uvd is None:
            uvd = cam.project(np.nan_to_num(res.nearest))
        if any(np.hypot(uvd[i, 0] - u, uvd[i, 1] - v) < w for u, v, w in taken):
            continue  # a hand already found
        found = _hand_at(cam, d, f, res.nearest[i], centres[i], radii[i], hand_radius, depth_offset)
        if found is None:
            continue
        if not any(np.linalg.norm(found[1] - h.seed) < separation for h in out):
            out.append(HandObservation(found[0], found[1], float(res.distance[i]), found[2]))
        if len(out) < n:  # (otherwise the search ends here and the disc is never looked at)
            su = cam.project(found[1])
            taken.append((su[0], su[1], separation * cam.fx / max(su[2], 1e-3)))
    return out
