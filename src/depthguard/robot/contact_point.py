"""Contact point from a depth image (SAPHARI D4.1.1 §6.2, Algorithm 1).

1. The robot surface as vertices (:class:`RobotSurface`): each link capsule of the robot model is
   tessellated (rings around the axis every ``spacing`` metres and two hemispherical caps), the
   vertices are stored in their joint's frame and posed by forward kinematics.
2. The hand position ``p_h`` (:func:`locate_hand`): the depth image, after the self-filter, keeps only
   the *foreground*: pixels with a reading nearer than a background depth image by more than
   ``bg_margin`` (people and whatever they carry), robot pixels removed. The depth-space distance
   (:func:`depthguard.depthspace.query_distances`, ``mode="min"``) from spheres along the robot's capsule
   axes gives the nearest foreground obstacle point; its pixel's measured 3-D point seeds the hand, and
   the hand is the centroid of the foreground points within ``hand_radius`` of that seed.
3. The contact point: the vertex nearest to ``p_h`` (:func:`nearest_vertex`, Algorithm 1 vectorised;
   :func:`nearest_vertex_loop` is the literal per-vertex loop, kept as the benchmark's baseline), with its
   link. Run every frame, it follows a hand that slides along the link.

What the hand tracker assumes: the background (the cell without robot and people) is static and known as
one depth image; the object nearest to the robot is the touching hand; the hand is a blob about
``hand_radius`` in size. The nearest visible hand point lies ``margin`` of the self-filter (3 cm by default)
or more from the robot surface, because the self-filter removes everything closer; the centroid of the
hand's pixels is biased towards the camera by about 2/3 of the hand's radius, which ``depth_offset``
corrects. The remaining error is one to three centimetres (measured in the tests and in the experiments'
``contact_point_error_m``).
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from typing import NamedTuple

import numpy as np

from depthguard.camera import Camera
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.robot._contact_kernels import (
    _box_kernel,
    _foreground_kernel,
    _masked_window,
    _nearest_vertex_kernel,
    _pose_points,
)

_F64 = np.dtype(np.float64)
_F32_F64 = (np.dtype(np.float32), _F64)
_CAMERA_FIELDS = tuple(f.name for f in fields(Camera))

__all__ = [
    "RobotSurface",
    "HandObservation",
    "ContactPoint",
    "locate_hands",
    "nearest_vertex",
    "nearest_vertex_loop",
    "foreground_mask",
    "image_box",
]


def _capsule_vertices(a: np.ndarray, b: np.ndarray, r: float, spacing: float) -> np.ndarray:
    """(V, 3) vertices on the surface of the capsule a-b of radius r, about ``spacing`` apart."""
    w = b - a
    L = float(np.linalg.norm(w))
    z = w / L if L > 1e-12 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    n_around = max(6, int(np.ceil(2 * np.pi * r / spacing)))
    phi = np.arange(n_around) * 2 * np.pi / n_around
    ring = np.cos(phi)[:, None] * x + np.sin(phi)[:, None] * y  # (A, 3) unit
    out = []
    if L > 1e-12:
        n_along = max(2, int(np.ceil(L / spacing)) + 1)
        for s in np.linspace(0.0, L, n_along):
            out.append(a + s * z + r * ring)
    n_lat = max(2, int(np.ceil(0.5 * np.pi * r / spacing)))
    for sign, c in ((-1.0, a), (1.0, b)):
        for th in np.linspace(0.0, 0.5 * np.pi, n_lat + 1)[1:]:
            k = max(1, int(np.ceil(n_around * np.cos(th))))
            ph = np.arange(k) * 2 * np.pi / k
            rr = np.cos(ph)[:, None] * x + np.sin(ph)[:, None] * y
            out.append(c + r * (np.cos(th) * rr + sign * np.sin(th) * z))
    return np.vstack(out)


class RobotSurface:
    """The robot's surface as vertices fixed to its joints (tessellated collision capsules).

    Attributes:
        model: the :class:`depthguard.robot.model.RobotModel`.
        spacing: vertex spacing, m.
        local: (V, 3) vertices in their parent joint's frame.
        joint: (V,) pinocchio joint index of each vertex.
        link: (V,) index into :attr:`link_names` of each vertex.
        link_names: the link (BODY frame) names.
        axis_centres: (S, 3) sphere centres along the capsule axes (joint frame), ``axis_joint`` (S,),
            ``axis_radii`` (S,): the spheres the depth-space query measures from.
    """

    def __init__(self, model, spacing: float = 0.01, links: list[str] | None = None) -> None:
        if not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be a positive number of metres, got {spacing!r}")
        self.model = model
        self.spacing = float(spacing)
        caps = [(i, c) for i, c in enumerate(model.capsules) if links is None or c.link in links]
        if not caps:
            raise ValueError(f"links {links!r} select no capsule; links: {sorted({c.link for c in model.capsules})}")
        self.link_names = sorted({c.link for _, c in caps}, key=lambda s: [c.link for _, c in caps].index(s))
        loc, jnt, lnk, ac, aj, ar = [], [], [], [], [], []
        for i, c in caps:
            a, b, r = model._cap_a[i], model._cap_b[i], float(c.radius)
            v = _capsule_vertices(a, b, r, spacing)
            j = int(model._cap_joint[i])
            loc.append(v)
            jnt.append(np.full(len(v), j))
            lnk.append(np.full(len(v), self.link_names.index(c.link)))
            m = max(1, int(np.ceil(np.linalg.norm(b - a) / max(r, 1e-3) * 2)) + 1)
            ac.append(a + np.linspace(0, 1, m)[:, None] * (b - a))
            aj.append(np.full(m, j))
            ar.append(np.full(m, r))
        order = np.argsort(np.concatenate(jnt), kind="stable")  # grouped by joint: one matmul per joint
        self.local = np.vstack(loc)[order]
        self.joint = np.concatenate(jnt)[order]
        self.link = np.concatenate(lnk)[order]
        self._groups = [(j, np.flatnonzero(self.joint == j)) for j in np.unique(self.joint)]
        self._slices = [(j, slice(int(ix[0]), int(ix[-1]) + 1)) for j, ix in self._groups]
        self._group_joint = np.array([j for j, _ in self._slices], dtype=np.int64)
        self._group_start = np.array([sl.start for _, sl in self._slices] + [len(self.local)], dtype=np.int64)
        self.axis_centres = np.vstack(ac)
        self.axis_joint = np.concatenate(aj)
        self.axis_radii = np.concatenate(ar)

    @property
    def n_vertices(self) -> int:
        return len(self.local)

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World vertices (V, 3) and axis sphere centres (S, 3) at ``q`` (n,), m."""
        model = self.model
        q = model.check_q(q)
        model._pin.forwardKinematics(model.model, model.data, q)  # as joint_poses(q): the model's buffer at q
        H, _ = model.joint_kinematics(q)  # the same joint poses, compiled (no read-back from pinocchio)
        v = np.empty_like(self.local)
        s = np.empty_like(self.axis_centres)
        _pose_points(H, self._group_joint, self._group_start, self.local, v)  # vertices grouped by joint
        _pose_points(H, self.axis_joint, np.arange(len(self.axis_joint) + 1), self.axis_centres, s)
        return v, s

    def to_local(self, q: np.ndarray, index: int, point_world: np.ndarray) -> np.ndarray:
        """``point_world`` (3,) expressed in the frame of vertex ``index``'s joint at ``q``."""
        R, p = self.model.joint_poses(self.model.check_q(q))
        j = self.joint[index]
        return R[j].T @ (np.asarray(point_world, float) - p[j])


def nearest_vertex(vertices: np.ndarray, p_h: np.ndarray) -> tuple[int, float]:
    """Algorithm 1, vectorised: index of the vertex (V, 3) nearest to ``p_h`` (3,) and its distance (m).

    Float arrays take one compiled pass over the vertices (no (V, 3) temporaries), with the same result."""
    if (
        type(vertices) is np.ndarray
        and vertices.dtype is _F64
        and vertices.ndim == 2
        and vertices.shape[1] == 3
        and len(vertices)
        and type(p_h) is np.ndarray
        and p_h.dtype in _F32_F64
        and p_h.shape == (3,)
    ):  # one compiled pass, the same numbers
        i, d2 = _nearest_vertex_kernel(vertices, p_h.astype(_F64, copy=False))
        return int(i), math.sqrt(d2)
    diff = vertices - p_h
    d2 = np.einsum("ij,ij->i", diff, diff)
    i = int(np.argmin(d2))
    return i, float(np.sqrt(d2[i]))


def nearest_vertex_loop(vertices_per_link: list[np.ndarray], p_h: np.ndarray) -> tuple[np.ndarray, int, float]:
    """Algorithm 1 literally (per-link, per-vertex Python loop): ``(p_c, contact_link, distance)``.

    The benchmark's baseline; use :func:`nearest_vertex` in real code.
    """
    min_distance, contact_link, p_c = np.inf, 0, np.zeros(3)
    px, py, pz = (float(x) for x in p_h)
    for i, mesh in enumerate(vertices_per_link):
        for vx, vy, vz in mesh.tolist():
            distance = ((px - vx) ** 2 + (py - vy) ** 2 + (pz - vz) ** 2) ** 0.5
            if distance < min_distance:
                p_c, min_distance, contact_link = np.array([vx, vy, vz]), distance, i
    return p_c, contact_link, min_distance


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
    ``(u0, u1, v0, v1)`` (e.g. :func:`image_box`) only that part is computed; the rest is False.
    """
    H, W = np.shape(depth)
    u0, u1, v0, v1 = box if box is not None else (0, W, 0, H)
    win = (slice(v0, v1), slice(u0, u1))
    d = np.asarray(depth[win], np.float32)
    bg = np.asarray(background[win], np.float32)
    margin = bg_margin[win] if np.ndim(bg_margin) == 2 else bg_margin
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
    exact tangent bounds; the whole image if one reaches behind the camera; None if the box is empty."""
    pc = camera.world_to_camera(centres)
    reach = np.broadcast_to(np.asarray(reach, float), (len(pc),))
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
    """
    centres = np.asarray(centres, float)
    radii = np.asarray(radii, float)
    box = image_box(camera, centres, radii + rho)
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


class ContactPoint(NamedTuple):
    """A contact point on the robot: ``position`` (3,) world m, ``link`` (name), ``vertex`` index,
    ``local`` (3,) in the vertex's joint frame (moves with the link), ``hand_distance`` (m, hand to vertex)."""

    position: np.ndarray
    link: str
    vertex: int
    local: np.ndarray
    hand_distance: float


def contact_from_hand(surface: RobotSurface, q: np.ndarray, vertices: np.ndarray, p_h: np.ndarray) -> ContactPoint:
    """Algorithm 1 on posed ``vertices`` (V, 3) for the hand at ``p_h`` (3,): the nearest vertex and its link."""
    i, d = nearest_vertex(vertices, p_h)
    return ContactPoint(vertices[i].copy(), surface.link_names[surface.link[i]], i, surface.local[i].copy(), d)


__all__.append("contact_from_hand")
