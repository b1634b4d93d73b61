"""The depth grid (RA-L'16 §III, eq. 4): a discretisation of space in the principal camera's depth space.

A cell ``(g_x, g_y, g_d)`` is the part of the frustum of principal pixel ``(g_x, g_y)`` with depth
``z_C`` in ``[d_min + g_d Δd, d_min + (g_d + 1) Δd)``: ``g_d = r(d) = floor((d - d_min) / Δd)`` (eq. 4).

``d_min`` and the number of depth cells follow from a workspace box as in RA-L'16 §VIII: they are the
smallest and largest depth ``z_C`` of the part of the box that lies inside the principal camera's field
of view (an exact linear programme, the box and the viewing pyramid both being convex polyhedra).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.camera import Camera
from depthguard.validation import check_positive

__all__ = ["DepthGrid", "workspace_depth_range", "check_workspace"]


def check_workspace(workspace: object) -> tuple[float, float, float, float, float, float]:
    """Return ``(xmin, xmax, ymin, ymax, zmin, zmax)`` as floats, or raise ``ValueError``."""
    try:
        w = tuple(float(x) for x in workspace)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"workspace must be xmin,xmax,ymin,ymax,zmin,zmax, got {workspace!r}") from None
    if len(w) != 6 or not all(math.isfinite(x) for x in w):
        raise ValueError(f"workspace must be 6 finite numbers (xmin..zmax), got {workspace!r}")
    if not (w[0] < w[1] and w[2] < w[3] and w[4] < w[5]):
        raise ValueError(f"workspace must have xmin < xmax, ymin < ymax, zmin < zmax, got {w}")
    return w  # type: ignore[return-value]


def workspace_depth_range(camera: Camera, workspace: object) -> tuple[float, float]:
    """Smallest and largest depth ``z_C`` of the workspace box inside the camera's field of view (metres).

    Solves two linear programmes over the world point ``P``: the box bounds, and the viewing pyramid
    ``0 <= fx x_C + cx z_C <= W z_C``, ``0 <= fy y_C + cy z_C <= H z_C``, ``z_C >= 0`` with
    ``P_C = R P + t`` (eq. 2).

    Raises:
        ValueError: when no part of the box is in view.
    """
    from scipy.optimize import linprog

    w = check_workspace(workspace)
    R, t = camera.R, camera.t
    rows, rhs = [], []
    # each constraint a.P_C + c >= 0 with P_C = R P + t  ->  -(a R) P <= a.t + c
    for a, c in (
        (np.array([camera.fx, 0.0, camera.cx]), 0.0),
        (np.array([-camera.fx, 0.0, camera.width - camera.cx]), 0.0),
        (np.array([0.0, camera.fy, camera.cy]), 0.0),
        (np.array([0.0, -camera.fy, camera.height - camera.cy]), 0.0),
        (np.array([0.0, 0.0, 1.0]), 0.0),
    ):
        rows.append(-(a @ R))
        rhs.append(a @ t + c)
    bounds = [(w[0], w[1]), (w[2], w[3]), (w[4], w[5])]
    out = []
    for sign in (1.0, -1.0):
        res = linprog(sign * R[2], A_ub=np.array(rows), b_ub=np.array(rhs), bounds=bounds, method="highs")
        if res.status != 0:
            raise ValueError(f"the workspace box {w} is not in the principal camera's field of view")
        out.append(float(R[2] @ res.x + t[2]))
    return out[0], out[1]


@dataclass(frozen=True)
class DepthGrid:
    """The depth grid of the principal camera (RA-L'16 §III).

    Attributes:
        camera: the principal camera; the grid has ``camera.width x camera.height x n_cells`` cells.
        dd: depth quantisation Δd in metres (eq. 4).
        d_min: depth of the near face of the first cell, metres.
        n_cells: number of depth cells per pixel.
    """

    camera: Camera
    dd: float
    d_min: float
    n_cells: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "dd", check_positive(self.dd, "grid dd"))
        object.__setattr__(self, "d_min", check_positive(self.d_min, "grid d_min"))
        if isinstance(self.n_cells, bool) or int(self.n_cells) != self.n_cells or self.n_cells < 1:
            raise ValueError(f"grid n_cells must be a positive integer, got {self.n_cells!r}")
        object.__setattr__(self, "n_cells", int(self.n_cells))

    @classmethod
    def from_workspace(cls, camera: Camera, dd: float = 0.01, workspace: object | None = None) -> DepthGrid:
        """The grid covering ``workspace`` (RA-L'16 §VIII); without one, ``[min_depth, max_depth]``."""
        dd = check_positive(dd, "grid dd")
        if workspace is None:
            lo, hi = camera.min_depth, camera.max_depth
        else:
            lo, hi = workspace_depth_range(camera, workspace)
            lo = max(lo, 1e-3)
        n = max(1, math.ceil((hi - lo) / dd - 1e-9))
        return cls(camera, dd, lo, n)

    @property
    def d_max(self) -> float:
        """Depth of the far face of the last cell, metres."""
        return self.d_min + self.n_cells * self.dd

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(height, width, n_cells)``."""
        return (self.camera.height, self.camera.width, self.n_cells)

    @property
    def size(self) -> int:
        """Number of cells."""
        return self.camera.height * self.camera.width * self.n_cells

    def r(self, d: np.ndarray | float) -> np.ndarray:
        """Eq. 4: the depth-cell index ``floor((d - d_min) / Δd)`` (may fall outside ``[0, n_cells)``)."""
        return np.floor((np.asarray(d, dtype=float) - self.d_min) / self.dd).astype(np.int64)

    def cell_depths(self, g: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """Near and far depths ``d_1, d_2`` of depth cell(s) ``g`` (RA-L'16 §IV)."""
        g = np.asarray(g, dtype=float)
        return self.d_min + g * self.dd, self.d_min + (g + 1.0) * self.dd
