"""Ground truth per control point: the clearance of each control sphere to the nearest non-robot geom.

Used only for metrics (how close the evaluated distances stay to the truth), never by the pipeline.
The clearance of a control point is measured from its sphere's surface to the nearest geom that is not
part of the robot (people, boxes, the table, the walls, the floor), with coal (FCL), independently of
both the pipeline and MuJoCo's own distance code. Penetration counts as 0.

The obstacle geoms are posed from a *snapshot* (:meth:`PointClearance.snapshot`), so the truth can be
taken for the instant a depth frame was captured while the spheres are where the distance stage put
them: the synchronous truth, free of the camera's frame latency (see :mod:`depthguard.sim.accuracy`).
"""

from __future__ import annotations

import numpy as np

from depthguard.sim.cell import GROUP_ROBOT, Cell

__all__ = ["PointClearance"]


class PointClearance:
    """Clearance of control spheres to every non-robot geom of a cell (coal).

    Args:
        cell: the cell; every geom outside the robot's group is an obstacle.
        distmax: clearances are exact up to this value (m); larger ones are reported as ``distmax``.
        exclude_groups: geom groups that are not obstacles either: the background that a
            :class:`depthguard.sim.background.BackgroundFilter` removes from the images on purpose (the
            evaluated distances then claim nothing about it, so neither does the truth they are held to).
    """

    def __init__(self, cell: Cell, distmax: float = 1.0, exclude_groups: tuple[int, ...] = ()) -> None:
        import coal
        import mujoco

        m = cell.model
        self.distmax = float(distmax)
        self.excluded_groups = tuple(sorted(int(g) for g in exclude_groups))
        ids, shapes, names, planes = [], [], [], []
        for g in range(m.ngeom):
            if m.geom_group[g] == GROUP_ROBOT or int(m.geom_group[g]) in exclude_groups:
                continue
            typ, size = int(m.geom_type[g]), m.geom_size[g]
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
            if typ == mujoco.mjtGeom.mjGEOM_PLANE:
                planes.append(g)  # a half-space below its plane: distance along its normal
                continue
            if typ == mujoco.mjtGeom.mjGEOM_BOX:
                shape = coal.Box(*(2.0 * size[:3]))
            elif typ == mujoco.mjtGeom.mjGEOM_CAPSULE:
                shape = coal.Capsule(float(size[0]), 2.0 * float(size[1]))
            elif typ == mujoco.mjtGeom.mjGEOM_SPHERE:
                shape = coal.Sphere(float(size[0]))
            elif typ == mujoco.mjtGeom.mjGEOM_CYLINDER:
                shape = coal.Cylinder(float(size[0]), 2.0 * float(size[1]))
            elif typ == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
                shape = coal.Ellipsoid(*size[:3])
            else:
                raise ValueError(f"PointClearance: geom {name!r} has a type ({typ}) without a coal shape here")
            ids.append(g)
            shapes.append(shape)
            names.append(name)
        self.geoms = np.asarray(ids, dtype=int)
        self.planes = np.asarray(planes, dtype=int)
        self.shapes = shapes
        self.names = names
        self.rbound = np.asarray(m.geom_rbound[self.geoms], float)
        self._coal = coal
        self._req = coal.DistanceRequest()
        self._res = coal.DistanceResult()
        self._spheres: dict[float, object] = {}

    def snapshot(self, data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Poses of the obstacle geoms now: ``(pos (G, 3), mat (G, 3, 3), plane_pos (Q, 3), plane_mat (Q, 3, 3))``."""
        return (
            np.array(data.geom_xpos[self.geoms], float),
            np.array(data.geom_xmat[self.geoms], float).reshape(-1, 3, 3),
            np.array(data.geom_xpos[self.planes], float),
            np.array(data.geom_xmat[self.planes], float).reshape(-1, 3, 3),
        )

    def _sphere(self, r: float):
        key = round(float(r), 9)
        if key not in self._spheres:
            self._spheres[key] = self._coal.Sphere(key)
        return self._spheres[key]

    def evaluate(self, centres: np.ndarray, radii: np.ndarray, snap) -> tuple[np.ndarray, list[str]]:
        """Clearance (N,) m of each sphere (centre (N, 3), radius (N,)) to the posed obstacles, and the
        nearest obstacle's name per sphere ("" when none is within ``distmax``). Penetration gives 0."""
        coal = self._coal
        pos, mat, ppos, pmat = snap
        c = np.atleast_2d(np.asarray(centres, float))
        r = np.broadcast_to(np.asarray(radii, float), (len(c),))
        out = np.full(len(c), self.distmax)
        who = [""] * len(c)
        for i in range(len(c)):
            for q in range(len(ppos)):  # planes: signed distance along the normal (the plane's z axis)
                d = float((c[i] - ppos[q]) @ pmat[q][:, 2]) - r[i]
                if d < out[i]:
                    out[i], who[i] = d, "plane"
            lower = np.linalg.norm(pos - c[i], axis=1) - self.rbound - r[i]
            sph = self._sphere(r[i])
            tf_p = coal.Transform3s(np.eye(3), c[i])
            for j in np.argsort(lower):
                if lower[j] >= out[i]:
                    break
                self._res.clear()
                d = coal.distance(sph, tf_p, self.shapes[j], coal.Transform3s(mat[j], pos[j]), self._req, self._res)
                if d < out[i]:
                    out[i], who[i] = float(d), self.names[j]
        return np.maximum(out, 0.0), who
