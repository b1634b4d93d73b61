"""Ground truth: the true clearance between every robot geom and every obstacle geom (``mj_geomDistance``).

Used only for metrics and tests, never by the pipeline. Pairs whose bounding spheres are farther apart
than ``distmax`` are skipped (their clearance is reported as ``distmax``; a plane obstacle, unbounded, is
never skipped so, whatever its ``geom_rbound`` of 0 says); the robot base link and the links fixed to it are left out
(it is bolted to the table), and so is the pair (first moving link, table).

MuJoCo's capsule-box distance is wrong where the capsule's axis passes through the box with both ends
outside it (it returns +radius for a capsule that crosses a panel): there the signed distance is taken
from the box's signed distance function along the axis instead (:func:`_capsule_box_crossing`).
"""

from __future__ import annotations

import numpy as np

from depthguard.sim.cell import Cell

__all__ = ["TrueClearance"]

_PLANE, _CAPSULE, _BOX = 0, 3, 6  # mujoco.mjtGeom


def _capsule_box_crossing(m, d, gc: int, gb: int) -> float | None:
    """Signed distance (m) of capsule geom ``gc`` to box geom ``gb`` when the capsule's axis meets the box,
    else None: the minimum over the axis of the box's signed distance function (convex along a segment,
    golden-section search to ~1e-12 m) less the capsule's radius (negative: a penetration depth)."""
    R, h = d.geom_xmat[gb].reshape(3, 3), m.geom_size[gb]
    axis = d.geom_xmat[gc].reshape(3, 3)[:, 2] * m.geom_size[gc][1]
    a = R.T @ (d.geom_xpos[gc] - axis - d.geom_xpos[gb])
    ab = R.T @ (2.0 * axis)
    lo, hi = 0.0, 1.0
    for k in range(3):  # slab test of the segment a + s ab, s in [0, 1]
        if ab[k] == 0.0:
            if abs(a[k]) > h[k]:
                return None
            continue
        with np.errstate(over="ignore"):  # (a nearly parallel axis: inf, as it should)
            t1, t2 = sorted(((-h[k] - a[k]) / ab[k], (h[k] - a[k]) / ab[k]))
        lo, hi = max(lo, t1), min(hi, t2)
        if lo > hi:
            return None

    def sd(s: float) -> float:
        q = np.abs(a + s * ab) - h
        return float(np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0))

    lo, hi, g = 0.0, 1.0, (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        lo, hi = (lo, m2) if sd(m1) < sd(m2) else (m1, hi)
    return min(sd(0.5 * (lo + hi)), sd(0.0), sd(1.0)) - float(m.geom_size[gc][0])


def _welded_to_root(desc) -> set[str]:
    """The root link and every link fixed to it (a mounting plate, a Kinova's ``link_base``): bolted to the
    table with it, so their contact with the table is not a collision."""
    welded = {desc.root}
    for j in getattr(desc, "joints", ()):  # (from the base outwards)
        if j.type == "fixed" and j.parent in welded:
            welded.add(j.child)
    return welded


class TrueClearance:
    """Clearance per robot link (body) to the nearest obstacle geom.

    Args:
        cell: the cell.
        distmax: distances are exact up to this value (m); larger ones are clipped to it.
    """

    def __init__(self, cell: Cell, distmax: float = 0.5) -> None:
        m = cell.model
        self.cell = cell
        self.distmax = float(distmax)
        keep = [i for i, b in enumerate(cell.robot_geom_body) if b not in _welded_to_root(cell.desc)]
        self.robot = np.asarray(cell.robot_geoms, dtype=int)[keep]
        self.links = sorted({cell.robot_geom_body[i] for i in keep}, key=lambda s: s)
        self.link_of = np.array([self.links.index(cell.robot_geom_body[i]) for i in keep])
        self.obst = np.asarray(cell.obstacle_geoms, dtype=int)
        self.rb_r = m.geom_rbound[self.robot]
        # a plane's rbound is 0 but it is unbounded: inf keeps its pairs from the bounding-sphere skip
        self.rb_o = np.where(m.geom_type[self.obst] == _PLANE, np.inf, m.geom_rbound[self.obst])
        self.obst_names = [cell.geom_names[g] for g in self.obst]
        self.is_static = np.array([n == "table" for n in self.obst_names], bool)
        self.last_dynamic = self.distmax  # clearance to people and boxes (not the table), last evaluate()
        self._fromto = np.zeros(6)
        # the first moving link sits on the table by construction: not a collision
        first = cell.desc.actuated[0].child if cell.desc.actuated else ""
        self.skip = np.array(
            [[self.links[li] == first and nm == "table" for nm in self.obst_names] for li in self.link_of], bool
        ).reshape(len(self.robot), len(self.obst))

    def evaluate(self) -> tuple[np.ndarray, float, str, np.ndarray]:
        """Per-link clearance (L,) m, overall minimum, the nearest obstacle's name, nearest segment (6,).

        Negative values are penetration depths (collision).
        """
        import mujoco

        m, d = self.cell.model, self.cell.data
        pr = d.geom_xpos[self.robot]
        po = d.geom_xpos[self.obst]
        centre = np.linalg.norm(pr[:, None, :] - po[None, :, :], axis=2)
        lower = centre - self.rb_r[:, None] - self.rb_o[None, :]
        lower[self.skip] = np.inf
        per_link = np.full(len(self.links), self.distmax)
        best, best_name, best_seg = self.distmax, "", np.full(6, np.nan)
        dyn = self.distmax
        ii, jj = np.nonzero(lower < self.distmax)
        for i, j in zip(ii, jj, strict=True):
            gr, go = int(self.robot[i]), int(self.obst[j])
            dist = mujoco.mj_geomDistance(m, d, gr, go, self.distmax, self._fromto)
            types = (int(m.geom_type[gr]), int(m.geom_type[go]))
            if types in ((_CAPSULE, _BOX), (_BOX, _CAPSULE)):  # (module docstring)
                cross = _capsule_box_crossing(m, d, *((gr, go) if types[0] == _CAPSULE else (go, gr)))
                if cross is not None and cross < dist:
                    dist = cross
                    self._fromto[:] = np.nan  # (no witness segment for this case)
            li = self.link_of[i]
            if dist < per_link[li]:
                per_link[li] = dist
            if dist < best:
                best, best_name, best_seg = dist, self.obst_names[j], self._fromto.copy()
            if not self.is_static[j] and dist < dyn:
                dyn = dist
        self.last_dynamic = float(dyn)
        return per_link, float(best), best_name, best_seg
