"""Ground truth per control point: the clearance of each control sphere to the nearest non-robot geom.

Used only for metrics (how close the evaluated distances stay to the truth), never by the pipeline.
The clearance of a control point is measured from its sphere's surface to the nearest geom that is not
part of the robot (people, boxes, the table, the walls, the floor), with coal (FCL), independently of
both the pipeline and MuJoCo's own distance code. Penetration counts as 0.

The obstacle geoms are posed from a *snapshot* (:meth:`PointClearance.snapshot`), so the truth can be
taken for the instant a depth frame was captured while the spheres are where the distance stage put
them: the synchronous truth, free of the camera's frame latency (see :mod:`depthguard.sim.accuracy`).

coal's GJK stops within a tolerance *above* the true distance (by default 1e-6 relative: up to 6 µm over
on an ellipsoid); here it runs to 1e-9, so the truth is never above the exact clearance by more than
about 1e-8 m (``tests/test_sim_truth_guarantees.py`` checks it against the analytic distances).
"""

from __future__ import annotations

import numpy as np

from depthguard.sim.cell import GROUP_ROBOT, Cell
from depthguard.validation import check_finite_array

__all__ = ["PointClearance"]


class PointClearance:
    """Clearance of control spheres to every non-robot geom of a cell (coal).

    Args:
        cell: the cell; every geom outside the robot's group is an obstacle.
        distmax: clearances are exact up to this value (m, > 0; inf: no clipping); larger ones are reported
            as ``distmax``.
        exclude_groups: geom groups that are not obstacles either: the background that a
            :class:`depthguard.sim.background.BackgroundFilter` removes from the images on purpose (the
            evaluated distances then claim nothing about it, so neither does the truth they are held to).
    """

    def __init__(self, cell: Cell, distmax: float = 1.0, exclude_groups: tuple[int, ...] = ()) -> None:
        import coal
        import mujoco

        m = cell.model
        try:
            self.distmax = float(distmax)
        except (TypeError, ValueError):
            self.distmax = float("nan")
        if not self.distmax > 0:  # (NaN too)
            raise ValueError(f"PointClearance: distmax must be a positive number of metres, got {distmax!r}")
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
        self._req.gjk_tolerance = 1e-9  # the default (1e-6) over-reports by up to 6 µm (module docstring)
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

    def _sphere(self, r: float) -> tuple[object, float]:
        """A cached coal sphere of radius ``r`` rounded to 1e-9 m, and the rounding (cached radius - r): the
        distance from the rounded sphere plus it is the distance from the sphere of radius ``r``."""
        key = round(float(r), 9)
        if key not in self._spheres:
            self._spheres[key] = self._coal.Sphere(key)
        return self._spheres[key], key - float(r)

    def _check(self, centres: np.ndarray, radii: np.ndarray, snap) -> tuple[np.ndarray, np.ndarray, tuple]:
        """``evaluate``'s arguments as float arrays, or ``ValueError`` naming the bad one."""
        c = check_finite_array(np.atleast_2d(np.asarray(centres, float)), (-1, 3), "PointClearance: centres")
        rr = np.asarray(radii, float)
        if rr.ndim > 1 or (rr.ndim == 1 and rr.shape[0] != len(c)):
            raise ValueError(f"PointClearance: radii must be one number or ({len(c)},), got shape {rr.shape}")
        if not np.all(np.isfinite(rr) & (rr >= 0)):
            raise ValueError("PointClearance: radii must be finite and >= 0 (metres)")
        r = np.broadcast_to(rr, (len(c),))
        shapes = ((len(self.geoms), 3), (len(self.geoms), 3, 3), (len(self.planes), 3), (len(self.planes), 3, 3))
        if not isinstance(snap, tuple | list) or len(snap) != 4:
            raise ValueError("PointClearance: snap must be the 4-tuple of snapshot(), got " + type(snap).__name__)
        arrs = tuple(np.asarray(a, float) for a in snap)
        if any(a.shape != s for a, s in zip(arrs, shapes, strict=True)) or not all(np.isfinite(a).all() for a in arrs):
            raise ValueError("PointClearance: snap must be a finite snapshot() of this object's obstacles")
        return c, r, arrs

    def evaluate(self, centres: np.ndarray, radii: np.ndarray, snap) -> tuple[np.ndarray, list[str]]:
        """Clearance (N,) m of each sphere (centre (N, 3) or (3,), radius (N,) or one number, m, finite,
        >= 0) to the obstacles posed as in ``snap`` (:meth:`snapshot`), and the nearest obstacle's name per
        sphere ("" when none is within ``distmax``). Penetration gives 0. Bad input: ``ValueError``."""
        coal = self._coal
        c, r, (pos, mat, ppos, pmat) = self._check(centres, radii, snap)
        out = np.full(len(c), self.distmax)
        who = [""] * len(c)
        for i in range(len(c)):
            for q in range(len(ppos)):  # planes: signed distance along the normal (the plane's z axis)
                d = float((c[i] - ppos[q]) @ pmat[q][:, 2]) - r[i]
                if d < out[i]:
                    out[i], who[i] = d, "plane"
            lower = np.linalg.norm(pos - c[i], axis=1) - self.rbound - r[i]
            sph, rounding = self._sphere(r[i])
            tf_p = coal.Transform3s(np.eye(3), c[i])
            for j in np.argsort(lower):
                if lower[j] >= out[i]:
                    break
                self._res.clear()
                d = coal.distance(sph, tf_p, self.shapes[j], coal.Transform3s(mat[j], pos[j]), self._req, self._res)
                d += rounding
                if d < out[i]:
                    out[i], who[i] = float(d), self.names[j]
        return np.maximum(out, 0.0), who
