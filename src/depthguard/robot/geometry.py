"""The robot's collision geometry packed for the self-filter and the control points (built once per model).

:class:`RobotGeometry` holds every collision shape of a :class:`depthguard.robot.model.RobotModel` (the
URDF's and the user's attachments, :class:`depthguard.robot.shapes.Shape`), split in two:

* analytic capsules (spheres, capsules, URDF cylinders with a sphere at each end): segment ends in the
  parent *joint* frame, radii;
* triangle meshes (meshes, boxes, plain cylinders): vertices in the parent joint frame, per-vertex inflation
  offsets (:func:`depthguard.robot.inflation.inflation_directions`; boxes and convex meshes: their rounded
  offset, :func:`depthguard.robot.inflation.rounded_convex_mesh`), faces; optionally decimated at load time
  (``max_triangles`` per mesh), in which case the self-filter inflates it by ``margin - excess`` (so that
  it still removes nothing farther than ``margin`` from the original surface), at least by ``slack`` (so
  that the original surface stays inside).

Conventions: SI units; world frame = robot base frame (see ``docs/conventions.md``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from depthguard.robot.inflation import inflation_directions, is_closed, rounded_convex_mesh
from depthguard.robot.shapes import (
    Shape,
    ShapeGeometry,
    capsule_idiom,
    rpy_to_matrix,
    shape_geometry,
    surface_points,
)

__all__ = ["RobotGeometry"]


def _point_distances(v: np.ndarray, f: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) distance (m) from each point to the surface of the mesh ``v``, ``f`` (coal BVH)."""
    import coal

    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(f), len(v))
    bvh.addVertices(np.ascontiguousarray(v, dtype=float))
    bvh.addTriangles(np.ascontiguousarray(f, dtype=np.int64))
    bvh.endModel()
    dot, eye, req, res = coal.Sphere(1e-12), coal.Transform3s(), coal.DistanceRequest(), coal.DistanceResult()
    out = np.empty(len(points))
    for k, p in enumerate(points):
        res.clear()
        out[k] = coal.distance(bvh, eye, dot, coal.Transform3s(np.eye(3), p), req, res)
    return out


def _decimate(v: np.ndarray, f: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Decimate to about ``target`` faces (fast-simplification). Returns the mesh, ``slack`` (m): the
    largest distance from the original surface to the decimated one, and ``excess`` (m): the largest
    distance from the decimated surface to the original; both over the vertices and points on the faces
    every 5 mm (:func:`depthguard.robot.shapes.surface_points`)."""
    try:
        import coal  # noqa: F401
        import fast_simplification
        import trimesh
    except ImportError as e:  # pragma: no cover
        raise ValueError(f"max_triangles needs fast-simplification (pip install 'depthguard[robot]'): {e}") from e

    ratio = 1.0 - target / len(f)
    v2, f2 = fast_simplification.simplify(v.astype(np.float32), f.astype(np.int32), target_reduction=ratio)
    m2 = trimesh.Trimesh(np.asarray(v2, float), np.asarray(f2, np.int64), process=True)
    trimesh.repair.fix_normals(m2)
    v2, f2 = np.asarray(m2.vertices, float), np.asarray(m2.faces, np.int64)
    slack = float(_point_distances(v2, f2, surface_points(v, f, 0.005)).max(initial=0.0))
    excess = float(_point_distances(v, f, surface_points(v2, f2, 0.005)).max(initial=0.0))
    return v2, f2, slack, excess


HULL_TOLERANCE = 0.002  # m: a closed mesh whose convex hull lies within this of it is drawn as its hull


def _hull_excess(v: np.ndarray, f: np.ndarray) -> float | None:
    """How far (m) the convex hull of the closed mesh ``v``, ``f`` lies outside it, when at most
    :data:`HULL_TOLERANCE` (a convex or nearly convex mesh, e.g. a collision hull saved with rounding);
    None otherwise (open, clearly concave, or farther). Measured like decimation's ``excess``: the hull's
    triangles that are not faces of the mesh are sampled every 5 mm (:func:`surface_points`) and their
    distance to the mesh taken with coal; the hull's other triangles lie on the mesh."""
    from scipy.spatial import ConvexHull

    if not is_closed(f):
        return None
    try:
        hull = ConvexHull(v)
    except Exception:  # noqa: BLE001 - flat or degenerate: not a solid
        return None
    tri = v[f]
    volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0
    if volume < 0.98 * hull.volume:  # clearly concave: no need to measure
        return None
    faces = {tuple(sorted(t)) for t in f.tolist()}
    extra = np.array([t for t in hull.simplices if tuple(sorted(t)) not in faces], dtype=np.int64).reshape(-1, 3)
    if not len(extra):
        return 0.0
    excess = float(_point_distances(v, f, surface_points(v, extra, 0.005)).max(initial=0.0))
    return excess if excess <= HULL_TOLERANCE else None


def _filter_mesh(g: ShapeGeometry, max_triangles: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """What the self-filter draws for the mesh shape ``g`` (link frame): vertices, inflation offsets, faces
    and whether its winding number counts (a closed, non-convex mesh).

    A box, or a (nearly) convex mesh at most ``max_triangles`` big, is drawn as its rounded offset (convex:
    the depth interval alone is exact; a mesh's hull excess is taken off the margin through ``g.excess``);
    any other mesh is decimated above ``max_triangles`` (``g.slack``, ``g.excess`` set) and inflated by
    per-vertex offsets. Updates ``g`` accordingly."""
    v, f = g.vertices, g.faces
    decimate = max_triangles is not None and len(f) > max_triangles
    if g.shape.kind == "mesh":
        hull_excess = None if decimate else _hull_excess(v, f)
        if hull_excess is not None:  # (nearly) convex: its hull's rounded offset, less the hull's excess
            g.filter_mesh, g.excess = rounded_convex_mesh(v), hull_excess
    if g.filter_mesh is not None:
        return *g.filter_mesh, False
    if decimate:
        v, f, g.slack, g.excess = _decimate(v, f, max_triangles)
        g.vertices, g.faces = v, f
    return v, inflation_directions(v, f), f, is_closed(f)


def _inscribed_capsules(shape: Shape) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules inside a box or a cylinder shape, link frame: ends ``a``, ``b`` (3,) m and radius (m).

    Cylinder (radius r, length L, axis z): radius r and the segment shortened by r at each end; when
    L < 2r (a disc), balls of radius L/2: one on the axis and a ring of them ``r - L/2`` from it, 30° apart.
    Box (half extents h): along its longest axis, radius the smaller of the other two half extents, the
    segment shortened by that radius at each end. None for other kinds.
    """
    Rs, ps = rpy_to_matrix(shape.rpy), np.asarray(shape.xyz, float)
    if shape.kind == "cylinder":
        r, half = float(shape.size[0]), 0.5 * float(shape.size[1])
        if half >= r:
            ends = [(np.array([0.0, 0.0, half - r]), np.array([0.0, 0.0, r - half]))]
            radius = r
        else:
            ring = [(r - half) * np.array([np.cos(t), np.sin(t), 0.0]) for t in np.radians(np.arange(0, 360, 30))]
            ends = [(c, c) for c in [np.zeros(3), *ring]]
            radius = half
    elif shape.kind == "box":
        h = 0.5 * np.asarray(shape.size, float)
        k = int(np.argmax(h))
        radius = float(min(h[i] for i in range(3) if i != k))
        reach = max(float(h[k]) - radius, 0.0)
        ends = [(-reach * np.eye(3)[k], reach * np.eye(3)[k])]
    else:
        return []
    return [(Rs @ a + ps, Rs @ b + ps, radius) for a, b in ends]


def _inscribed_mesh_capsule(v: np.ndarray, f: np.ndarray, step: float = 0.002) -> tuple | None:
    """A capsule inside the closed mesh ``v`` (V, 3), ``f`` (F, 3) (link frame, m): ends ``a``, ``b`` (3,) and
    radius (m), or None (an open mesh, or no capsule of radius >= 5 mm found).

    Its axis is the principal axis of the mesh's surface points, centred on their extent along it; of the
    segments 0-90 % of that extent long, the one whose capsule has the largest volume is kept. The axis is
    sampled at most ``step`` apart; a segment counts only if its samples all lie inside the mesh (trimesh's
    ray test), and its radius is their smallest distance to the surface (coal) less half the sample spacing
    (the distance to the surface is 1-Lipschitz along the segment) and 1 mm, so it does not reach the surface.
    """
    if not is_closed(f):
        return None
    import trimesh

    pts = surface_points(v, f, 0.01)
    c = pts.mean(axis=0)
    axis = np.linalg.svd(pts - c, full_matrices=False)[2][0]
    along = (pts - c) @ axis
    mid, half = c + axis * 0.5 * (along.max() + along.min()), 0.5 * float(along.max() - along.min())
    n = 2 * int(np.ceil(0.9 * half / step)) + 1  # odd: a sample at the middle
    t = np.linspace(-0.9 * half, 0.9 * half, n)
    spacing = t[1] - t[0] if n > 1 else 0.0
    samples = mid + t[:, None] * axis
    inside = trimesh.Trimesh(vertices=v, faces=f, process=False).contains(samples)
    dist = _point_distances(v, f, samples)
    best, best_volume = None, 0.0
    for frac in np.linspace(0.0, 0.9, 10):
        sub = np.abs(t) <= frac * half + 1e-12
        if not inside[sub].all():
            break  # (the segments are nested: a longer one is not inside either)
        r = float(dist[sub].min()) - 0.5 * spacing - 0.001
        length = float(t[sub].max() - t[sub].min())
        volume = np.pi * r * r * length + 4.0 / 3.0 * np.pi * r**3
        if r >= 0.005 and volume > best_volume:
            best, best_volume = (mid + t[sub].min() * axis, mid + t[sub].max() * axis, r), volume
    return best


def _face_planes(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F, 4) outward unit normal (right-handed winding) and offset of each face; zeros for a degenerate one."""
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1)
    n = np.where(ln[:, None] > 1e-15, n / np.maximum(ln, 1e-300)[:, None], 0.0)
    return np.ascontiguousarray(np.c_[n, np.einsum("ij,ij->i", n, tri[:, 0])])


class RobotGeometry:
    """Collision geometry of a robot, rigidly attached to its pinocchio joints.

    Attributes:
        shapes: the :class:`Shape` list it was built from.
        geoms: per-shape :class:`ShapeGeometry` (link frame), analytic capsules first.
        cap_joint (C,), cap_a, cap_b (C, 3), cap_r (C,): analytic capsules in their parent joint frame.
        mesh_joint (S,), V, O (Vt, 3), F (Ft, 3), vr, fr (S, 2): meshes in their joint frame.
        slack, excess (S,): how far (m) a decimated mesh's original surface lies outside it, and how far it
            lies outside its original surface (0 when not decimated).
        n_triangles: total triangle count of the meshes used by the filter.
        face_planes (Ft, 4): outward unit normal and offset ``h`` (``n . x = h``) of each face, joint frame.
        closed (S,) bool: the mesh is closed (every edge shared by two faces in opposite directions), so
            that the self-filter may count its crossings (winding number); False for a convex shape (a box or
            a hull's rounded offset), whose depth interval is exact without them.
        watertight (S,) bool: the mesh drawn is closed (convex shapes included), so that its cross-section
            with the camera's near plane is a closed polygon.
    """

    def __init__(self, model, shapes: Sequence[Shape], max_triangles: int | None = None) -> None:
        self.shapes = tuple(shapes)
        caps, rest = capsule_idiom(list(self.shapes))
        self.geoms: list[ShapeGeometry] = caps + [shape_geometry(s) for s in rest]
        cj, ca, cb, cr = [], [], [], []
        mj, Vs, Os, Fs, vr, fr, slack, excess, closed, shut = [], [], [], [], [], [], [], [], [], []
        nv = nf = 0
        for g in self.geoms:
            fid = model.frame_id(g.shape.link)
            frame = model.model.frames[fid]
            M = frame.placement
            Rl, pl = np.array(M.rotation), np.array(M.translation)
            if not g.is_mesh:
                cj.append(int(frame.parentJoint))
                ca.append(Rl @ g.a + pl)
                cb.append(Rl @ g.b + pl)
                cr.append(g.radius)
                continue
            g.inscribed = _inscribed_mesh_capsule(g.vertices, g.faces) if g.shape.kind == "mesh" else None
            v, o, f, is_shut = _filter_mesh(g, max_triangles)
            closed.append(is_shut)
            shut.append(is_shut or is_closed(f))  # (a convex shape's winding is not needed, but it is watertight)
            mj.append(int(frame.parentJoint))
            Vs.append(v @ Rl.T + pl)
            Os.append(o @ Rl.T)
            Fs.append(f + nv)
            vr.append((nv, nv + len(v)))
            fr.append((nf, nf + len(f)))
            slack.append(g.slack)
            excess.append(g.excess)
            nv += len(v)
            nf += len(f)
        self.cap_joint = np.array(cj, dtype=np.int64)
        self.cap_a = np.array(ca, float).reshape(-1, 3)
        self.cap_b = np.array(cb, float).reshape(-1, 3)
        self.cap_r = np.array(cr, float)
        self.mesh_joint = np.array(mj, dtype=np.int64)
        self.V = np.ascontiguousarray(np.vstack(Vs) if Vs else np.zeros((0, 3)))
        self.O = np.ascontiguousarray(np.vstack(Os) if Os else np.zeros((0, 3)))
        self.F = np.ascontiguousarray(np.vstack(Fs) if Fs else np.zeros((0, 3), np.int64))
        self.vr = np.array(vr, dtype=np.int64).reshape(-1, 2)
        self.fr = np.array(fr, dtype=np.int64).reshape(-1, 2)
        self.slack = np.array(slack, float)
        self.excess = np.array(excess, float)
        self.n_triangles = int(len(self.F))
        self.face_planes = _face_planes(self.V, self.F)
        self.closed = np.array(closed, dtype=np.bool_)
        self.watertight = np.array(shut, dtype=np.bool_)
        ij, ia, ib, ir = [], [], [], []
        for g in self.geoms:  # capsules inscribed in the mesh-rendered boxes, cylinders and meshes
            frame = model.model.frames[model.frame_id(g.shape.link)]
            Rl, pl = np.array(frame.placement.rotation), np.array(frame.placement.translation)
            # (a mesh's was computed on the original, undecimated mesh)
            inner = [g.inscribed] if g.inscribed is not None else _inscribed_capsules(g.shape) if g.is_mesh else []
            for a, b, r in inner:
                ij.append(int(frame.parentJoint))
                ia.append(Rl @ a + pl)
                ib.append(Rl @ b + pl)
                ir.append(r)
        self.inscribed_joint = np.array(ij, dtype=np.int64)
        self.inscribed_a = np.array(ia, float).reshape(-1, 3)
        self.inscribed_b = np.array(ib, float).reshape(-1, 3)
        self.inscribed_r = np.array(ir, float)

    def inner_capsules(self, R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capsules that lie inside the collision geometry, world frame, from joint poses ``R`` (J+1, 3, 3),
        ``p`` (J+1, 3): the analytic capsules themselves and one capsule inscribed in every box, cylinder
        (:func:`_inscribed_capsules`) and closed mesh (:func:`_inscribed_mesh_capsule`). ``a``, ``b`` (C, 3)
        m, ``radius`` (C,) m."""
        a, b, r = self.world_capsules(R, p)
        Rj, pj = R[self.inscribed_joint], p[self.inscribed_joint]
        ai = np.matmul(Rj, self.inscribed_a[:, :, None])[:, :, 0] + pj
        bi = np.matmul(Rj, self.inscribed_b[:, :, None])[:, :, 0] + pj
        return np.vstack([a, ai]), np.vstack([b, bi]), np.concatenate([r, self.inscribed_r])

    def world_capsules(self, R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytic capsules in the world frame from joint poses ``R`` (J+1, 3, 3), ``p`` (J+1, 3):
        ``a``, ``b`` (C, 3) m, ``radius`` (C,) m."""
        Rj, pj = R[self.cap_joint], p[self.cap_joint]
        a = np.matmul(Rj, self.cap_a[:, :, None])[:, :, 0] + pj
        b = np.matmul(Rj, self.cap_b[:, :, None])[:, :, 0] + pj
        return a, b, self.cap_r.copy()

    def world_triangles(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(Ft, 3, 3) the self-filter's mesh triangles (:attr:`F`, shape ``s`` at rows ``fr[s]``) in the world
        frame, from joint poses ``R`` (J+1, 3, 3), ``p`` (J+1, 3), m."""
        V = np.empty_like(self.V)
        for s, j in enumerate(self.mesh_joint):
            a, b = self.vr[s]
            V[a:b] = self.V[a:b] @ R[j].T + p[j]
        return V[self.F]

    def mesh_transforms(self, R: np.ndarray, p: np.ndarray, Rc: np.ndarray, tc: np.ndarray) -> np.ndarray:
        """(S, 3, 4) camera-from-joint transforms of the meshes; camera pose ``P_C = Rc P_W + tc``."""
        Rj, pj = R[self.mesh_joint], p[self.mesh_joint]
        T = np.empty((len(self.mesh_joint), 3, 4))
        T[:, :, :3] = np.matmul(Rc, Rj)
        T[:, :, 3] = pj @ Rc.T + tc
        return T

    def link_points(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per link, what its ``auto`` spheres must cover, in the link frame: ball centres (P, 3) and radii
        (P,) m (mesh vertices before decimation and face samples with radius 0; balls along capsules)."""
        out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        for g in self.geoms:
            r = np.zeros(len(g.source_vertices)) if g.source_radii is None else g.source_radii
            out.setdefault(g.shape.link, []).append((g.source_vertices, r))
        return {k: (np.vstack([p for p, _ in v]), np.concatenate([r for _, r in v])) for k, v in out.items()}

    def link_triangles(self) -> dict[str, np.ndarray]:
        """Per link, the triangles (F, 3, 3) of its mesh, box and cylinder shapes before any decimation, in
        the link frame, m (a cylinder as the prism that circumscribes it; spheres and capsules have none:
        :meth:`link_points` holds them exactly as balls)."""
        out: dict[str, list[np.ndarray]] = {}
        for g in self.geoms:
            if g.shape.kind in ("mesh", "box", "cylinder"):
                full = shape_geometry(g.shape)  # the geometry before decimation
                out.setdefault(g.shape.link, []).append(full.vertices[full.faces])
        return {k: np.concatenate(v) for k, v in out.items()}
