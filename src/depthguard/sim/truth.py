"""Ground truth: the true clearance between every robot geom and every obstacle geom (``mj_geomDistance``).

Used only for metrics and tests, never by the pipeline. Pairs whose bounding spheres are farther apart
than ``distmax`` are skipped (their clearance is reported as ``distmax``); the robot base link is left out
(it is bolted to the table), and so is the pair (first moving link, table).
"""

from __future__ import annotations

import numpy as np

from depthguard.sim.cell import Cell

__all__ = ["TrueClearance"]


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
        keep = [i for i, b in enumerate(cell.robot_geom_body) if b != cell.desc.root]
        self.robot = np.asarray(cell.robot_geoms)[keep]
        self.links = sorted({cell.robot_geom_body[i] for i in keep}, key=lambda s: s)
        self.link_of = np.array([self.links.index(cell.robot_geom_body[i]) for i in keep])
        self.obst = np.asarray(cell.obstacle_geoms)
        self.rb_r = m.geom_rbound[self.robot]
        self.rb_o = m.geom_rbound[self.obst]
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
            dist = mujoco.mj_geomDistance(m, d, int(self.robot[i]), int(self.obst[j]), self.distmax, self._fromto)
            li = self.link_of[i]
            if dist < per_link[li]:
                per_link[li] = dist
            if dist < best:
                best, best_name, best_seg = dist, self.obst_names[j], self._fromto.copy()
            if not self.is_static[j] and dist < dyn:
                dyn = dist
        self.last_dynamic = float(dyn)
        return per_link, float(best), best_name, best_seg
