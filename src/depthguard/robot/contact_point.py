"""Contact point from a depth image (SAPHARI D4.1.1 §6.2, Algorithm 1).

1. The robot surface as vertices (:class:`RobotSurface`): each link capsule of the robot model is
   tessellated (rings around the axis every ``spacing`` metres and two hemispherical caps), the
   vertices are stored in their joint's frame and posed by forward kinematics.
2. The hand position ``p_h`` (:mod:`depthguard.robot.hand_locate`): the depth image, after the
   self-filter, keeps only the *foreground*: pixels with a reading nearer than a background depth image
   by more than ``bg_margin`` (people and whatever they carry), robot pixels removed. The depth-space
   distance (:func:`depthguard.depthspace.query_distances`, ``mode="min"``) from spheres along the robot's
   capsule axes gives the nearest foreground obstacle point; its pixel's measured 3-D point seeds the
   hand, and the hand is the centroid of the foreground points within ``hand_radius`` of that seed.
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
from typing import NamedTuple

import numpy as np

from depthguard.robot._contact_kernels import (
    _nearest_vertex_kernel,
    _pose_points,
)
from depthguard.robot.hand_locate import HandObservation, foreground_mask, image_box, locate_hands

_F64 = np.dtype(np.float64)
_F32_F64 = (np.dtype(np.float32), _F64)

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
    else:  # a sphere: its equator (the caps' rings start above it)
        out.append(a + r * ring)
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
        if isinstance(spacing, bool | np.bool_ | str | bytes) or not (np.isfinite(spacing) and spacing > 0):
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

    Float arrays take one compiled pass over the vertices (no (V, 3) temporaries), with the same result.
    As ``np.argmin``: the first minimum, or the first NaN distance where a NaN is involved (never a finite
    distance then; :func:`contact_from_hand` refuses it). ``vertices`` not a non-empty (V, 3) numeric array,
    or ``p_h`` not a (3,) one: ``ValueError`` naming it. Where every squared distance overflows (a point
    beyond ~1e154 m) the differences are compared scaled: a finite distance, correct to rounding."""
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
        if d2 != math.inf:  # (inf: an infinite input, or every squared distance overflowed: below)
            return int(i), math.sqrt(d2)
    V, p = _checked_vertices(vertices, p_h)
    with np.errstate(over="ignore", invalid="ignore"):
        diff = V - p
        # (the kernel's order of operations, so that near ties go the same way; einsum's order differed)
        d2 = (diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1]) + diff[..., 2] * diff[..., 2]
    i = int(np.argmin(d2))
    if d2[i] == math.inf and np.all(np.isfinite(V)) and np.all(np.isfinite(p)):  # overflow: scaled
        s = float(np.abs(diff).max())
        diff = diff / s
        d2 = (diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1]) + diff[..., 2] * diff[..., 2]
        i = int(np.argmin(d2))
        return i, s * float(np.sqrt(d2[i]))
    return i, float(np.sqrt(d2[i]))


def _checked_vertices(vertices: object, p_h: object) -> tuple[np.ndarray, np.ndarray]:
    """``vertices`` (V >= 1, 3) and ``p_h`` (3,) as float arrays, or ``ValueError`` naming the bad one."""
    out = []
    for x, name, shape in ((vertices, "vertices", "(V, 3), V >= 1"), (p_h, "p_h", "(3,)")):
        a = np.asarray(x) if not isinstance(x, str | bytes) else np.empty(0, object)
        ok = a.dtype.kind in "iuf" and (
            a.shape == (3,) if name == "p_h" else a.ndim == 2 and a.shape[1] == 3 and len(a)
        )
        if not ok:
            raise ValueError(f"{name} must be a numeric array of shape {shape}, got {x!r}")
        out.append(a.astype(_F64))
    return out[0], out[1]


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


class ContactPoint(NamedTuple):
    """A contact point on the robot: ``position`` (3,) world m, ``link`` (name), ``vertex`` index,
    ``local`` (3,) in the vertex's joint frame (moves with the link), ``hand_distance`` (m, hand to vertex)."""

    position: np.ndarray
    link: str
    vertex: int
    local: np.ndarray
    hand_distance: float


def contact_from_hand(surface: RobotSurface, q: np.ndarray, vertices: np.ndarray, p_h: np.ndarray) -> ContactPoint:
    """Algorithm 1 on posed ``vertices`` (V, 3) for the hand at ``p_h`` (3,): the nearest vertex and its link.

    ``ValueError`` naming ``p_h`` or ``vertices`` where one is not finite (a NaN hand has no contact point)."""
    i, d = nearest_vertex(vertices, p_h)
    if not math.isfinite(d):
        bad = "p_h" if not np.all(np.isfinite(np.asarray(p_h, float))) else "vertices"
        raise ValueError(f"{bad} must be finite (no NaN or inf) to give a contact point")
    return ContactPoint(vertices[i].copy(), surface.link_names[surface.link[i]], i, surface.local[i].copy(), d)


__all__.append("contact_from_hand")
