"""Reachability grid of a URDF robot (SAPHARI D4.1.1 §3.2): :class:`~depthguard.octree.reach.ChainSweep` from a
:class:`~depthguard.robot.model.RobotModel` at joint positions ``q``.

Works for any serial chain of revolute and prismatic joints, so the mobile manipulator (an omnidirectional
base as prismatic x, prismatic y and revolute yaw, then the arm; ``data/omni_lwr4/omni_lwr4.urdf``) and the
fixed arm use the same code.
"""

from __future__ import annotations

import numpy as np

from depthguard.octree.grid import VoxelBox
from depthguard.octree.reach import PRISMATIC, REVOLUTE, ChainSweep, ReachabilityGrid, reachability_grid

__all__ = ["chain_sweep", "robot_reachability"]


def chain_sweep(model, q: np.ndarray, v_max: np.ndarray | None = None) -> ChainSweep:
    """The chain of ``model`` at ``q`` (n,), world frame, for :func:`~depthguard.octree.reach.reachability_grid`.

    Args:
        model: a :class:`~depthguard.robot.model.RobotModel` whose joints form one serial chain.
        q: (n,) joint positions (rad or m), within the limits.
        v_max: (n,) maximum joint speeds (default: the URDF's velocity limits).
    """
    q = model.check_q(q)
    pm = model.model
    for j in range(1, pm.njoints):
        if pm.parents[j] != j - 1 or pm.idx_vs[j] != j - 1:
            raise ValueError(f"chain_sweep: {model!r} is not one serial chain (joint {pm.names[j]!r})")
    vmax = model.v_max if v_max is None else np.asarray(v_max, dtype=float)
    if vmax.shape != (model.n_dof,) or not np.all(np.isfinite(vmax) & (vmax > 0)):
        raise ValueError(f"v_max must be ({model.n_dof},) positive speeds, got {vmax!r}")
    model.update(q)
    J = model.world_jacobian()  # (6, n): linear velocity of the world origin, angular velocity
    w, v = J[3:].T, J[:3].T  # (n, 3) angular and linear columns
    nw, nv = np.linalg.norm(w, axis=1), np.linalg.norm(v, axis=1)
    revolute = nw > 0.5
    kind = np.where(revolute, REVOLUTE, PRISMATIC).astype(np.int64)
    axis = np.where(
        revolute[:, None], w / np.where(revolute, nw, 1.0)[:, None], v / np.where(revolute, 1.0, nv)[:, None]
    )
    # a revolute joint: v_O = p x w, so w x v_O = p_perp (the axis point nearest the origin)
    point = np.where(revolute[:, None], np.cross(axis, v), 0.0)
    a, b, r = model.link_capsules(q)
    qmin = np.where(np.isfinite(model.q_min), model.q_min, -1e9)
    qmax = np.where(np.isfinite(model.q_max), model.q_max, 1e9)
    lo = np.minimum(qmin - q, 0.0)
    hi = np.maximum(qmax - q, 0.0)
    return ChainSweep(kind, axis, point, lo, hi, vmax, a, b, r, np.asarray(model._cap_joint, dtype=np.int64))


def robot_reachability(
    model,
    q: np.ndarray,
    horizon: float = 0.5,
    res: float = 0.09,
    box: VoxelBox | None = None,
    cells: int = 24,
    v_max: np.ndarray | None = None,
) -> ReachabilityGrid:
    """:func:`~depthguard.octree.reach.reachability_grid` of ``model`` at ``q`` (see there for the arguments)."""
    return reachability_grid(chain_sweep(model, q, v_max), horizon=horizon, res=res, box=box, cells=cells)
