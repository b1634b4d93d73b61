"""Test helpers for mesh robots: the ground truth of :mod:`depthguard.bench.meshtruth` (pinocchio/coal +
MuJoCo ray casting, independent of depthguard's geometry code) and per-link geometry points."""

from __future__ import annotations

import numpy as np

from depthguard.bench.meshtruth import MeshRobotTruth, distance_to_robot

__all__ = ["MeshRobotTruth", "distance_to_robot", "geometry_points"]


def geometry_points(urdf: str, q: np.ndarray, n: int = 24, faces: int = 0) -> dict[str, np.ndarray]:
    """Per link, world points of its collision geometry at ``q`` read by pinocchio/coal: every mesh vertex,
    box corners, and for cylinders, spheres and capsules points on their surfaces (``n`` around). With
    ``faces`` > 0, also a barycentric grid of ``faces`` steps on every mesh triangle (its surface)."""
    import coal
    import pinocchio as pin

    from depthguard.robot.robots import robot_data_dir

    model = pin.buildModelFromUrdf(urdf)
    geom = pin.buildGeomFromUrdf(model, urdf, pin.COLLISION, package_dirs=[str(robot_data_dir().parent)])
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(model, data, np.asarray(q, float))
    pin.updateGeometryPlacements(model, data, geom, gdata)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.c_[np.cos(ang), np.sin(ang), np.zeros(n)]
    out: dict[str, list[np.ndarray]] = {}
    for i, obj in enumerate(geom.geometryObjects):
        g = obj.geometry
        if isinstance(g, coal.Box):
            h = np.asarray(g.halfSide)
            p = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
        elif isinstance(g, coal.Cylinder):
            p = np.vstack([ring * g.radius + [0, 0, z] for z in np.linspace(-g.halfLength, g.halfLength, 9)])
        elif isinstance(g, (coal.Sphere, coal.Capsule)):
            hl = getattr(g, "halfLength", 0.0)
            u = np.random.default_rng(i).normal(size=(400, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            p = np.vstack([u * g.radius + [0, 0, z] for z in np.linspace(-hl, hl, 5)])
        else:
            p = np.asarray(g.vertices(), float) * np.asarray(obj.meshScale)
            if faces > 0:
                t = [g.tri_indices(k) for k in range(g.num_tris)]
                tri = p[np.array([[x[0], x[1], x[2]] for x in t])]  # (F, 3, 3)
                ij = np.array([(a, b) for a in range(faces + 1) for b in range(faces + 1 - a)], float) / faces
                w = np.c_[ij, 1.0 - ij.sum(axis=1)]
                p = np.vstack([p, np.einsum("gk,tkd->tgd", w, tri).reshape(-1, 3)])
        M = gdata.oMg[i]
        link = model.frames[obj.parentFrame].name
        out.setdefault(link, []).append(p @ np.asarray(M.rotation).T + M.translation)
    return {k: np.vstack(v) for k, v in out.items()}
