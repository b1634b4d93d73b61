"""C(t) reused across frames while it provably stays an over-approximation (SAPHARI D4.1.1 §3.2).

The reachability grid of state ``q0`` with horizon ``T_g`` (:func:`~depthguard.octree.reach.reachability_grid`)
holds every point of the robot at every configuration of the joint box

    B(q0, T_g) = Π_j [ l_j(q0, T_g), u_j(q0, T_g) ],
    l_j(q, T) = max(q_j - v_j T, min(q_min_j, q_j)),   u_j(q, T) = min(q_j + v_j T, max(q_max_j, q_j)),

(the offsets of :class:`~depthguard.octree.reach.ChainSweep`, ``[q_min - q, q_max - q]`` widened to hold 0,
intersected with ``[-v T, v T]``). Every configuration that the robot can reach from ``q`` within ``T`` with
``|q̇| <= v`` lies in ``B(q, T)``. So if ``B(q, T) ⊆ B(q0, T_g)`` joint by joint, then
``C_q(T) ⊆ C_q0(T_g) ⊆`` the grid: the grid computed at ``q0`` stands for C(t) at ``q``, as an
over-approximation, without being recomputed. :class:`ReachReuse` computes its grids with ``T_g = T + slack``,
so a grid serves while every joint has moved less than ``slack`` seconds' worth of its maximum speed (and for
ever while the robot stands still), and checks the containment on the *measured* state each frame, not on
elapsed time. SAPHARI updated its grid at 12 Hz, slower than its sensors, without such a check.

Cost: a grid with the longer horizon (0.6 s instead of 0.5 s) holds more cells (+18 % for the mobile
manipulator at 0.09 m) and takes longer to compute; frames that reuse one take none of it. Only the boolean set
C(t) carries over: a reused grid's ``time`` is the time from ``q0``, not from the current state.
"""

from __future__ import annotations

import numpy as np

from depthguard.octree.reach import ReachabilityGrid
from depthguard.validation import check_positive

__all__ = ["joint_box", "box_within", "ReachReuse"]

_UNLIMITED = 1e9  # rad or m: what stands for a missing joint limit (as in depthguard.robot.reach.chain_sweep)


def joint_box(
    q: np.ndarray, v_max: np.ndarray, q_min: np.ndarray, q_max: np.ndarray, horizon: float
) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), each (n,): the joint box ``B(q, horizon)`` of the module docstring (rad or m)."""
    q = np.asarray(q, float)
    qmin = np.where(np.isfinite(q_min), q_min, -_UNLIMITED)
    qmax = np.where(np.isfinite(q_max), q_max, _UNLIMITED)
    return np.maximum(q - v_max * horizon, np.minimum(qmin, q)), np.minimum(q + v_max * horizon, np.maximum(qmax, q))


def box_within(inner: tuple[np.ndarray, np.ndarray], outer: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the joint box ``inner`` lies in ``outer``, every joint (exact comparison, no tolerance)."""
    return bool(np.all(inner[0] >= outer[0]) and np.all(inner[1] <= outer[1]))


class ReachReuse:
    """Keeps the last reachability grid and says whether it still stands for C(t) at a new state.

    Args:
        q_min, q_max, v_max: (n,) joint limits (rad or m; non-finite = none) and maximum speeds (> 0) of the
            model the grids are computed for (the same ``v_max`` as the grid's).
        horizon: T, s: the horizon C(t) must cover.
        slack: s (>= 0): grids are computed with ``horizon + slack`` (:attr:`grid_horizon`); 0 disables reuse
            (a grid then serves only the state it was computed at).

    Use: ``if not reuse.covers(q): reuse.store(q, grid_computed_at_q_with(reuse.grid_horizon))``, then
    ``reuse.grid`` is C(t) at ``q``. :attr:`reused` and :attr:`computed` count the frames of each kind.
    """

    def __init__(
        self, q_min: np.ndarray, q_max: np.ndarray, v_max: np.ndarray, horizon: float = 0.5, slack: float = 0.1
    ):
        self.v_max = np.asarray(v_max, float)
        n = self.v_max.shape
        if self.v_max.ndim != 1 or not np.all(np.isfinite(self.v_max) & (self.v_max > 0)):
            raise ValueError(f"v_max must be an (n,) array of positive speeds, got {v_max!r}")
        self.q_min, self.q_max = np.asarray(q_min, float), np.asarray(q_max, float)
        if self.q_min.shape != n or self.q_max.shape != n:
            raise ValueError(f"q_min and q_max must have v_max's shape {n}")
        self.horizon = check_positive(horizon, "horizon")
        if not (np.isfinite(slack) and slack >= 0):
            raise ValueError(f"slack must be a number of seconds >= 0, got {slack!r}")
        self.slack = float(slack)
        self.grid: ReachabilityGrid | None = None
        self._box: tuple[np.ndarray, np.ndarray] | None = None
        self.reused = 0
        self.computed = 0

    @classmethod
    def for_model(cls, model, horizon: float = 0.5, slack: float = 0.1, v_max: np.ndarray | None = None) -> ReachReuse:
        """For a :class:`~depthguard.robot.model.RobotModel` (its URDF limits; ``v_max`` overrides the speeds)."""
        return cls(model.q_min, model.q_max, model.v_max if v_max is None else v_max, horizon, slack)

    @property
    def grid_horizon(self) -> float:
        """The horizon (s) that new grids must be computed with: ``horizon + slack``."""
        return self.horizon + self.slack

    def _check_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, float)
        if q.shape != self.v_max.shape or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be a finite ({self.v_max.shape[0]},) array of joint positions, got {q!r}")
        return q

    def covers(self, q: np.ndarray) -> bool:
        """Whether the stored grid stands for C(t) at ``q`` (counted in :attr:`reused` when it does)."""
        q = self._check_q(q)
        if self._box is None:
            return False
        ok = box_within(joint_box(q, self.v_max, self.q_min, self.q_max, self.horizon), self._box)
        self.reused += ok
        return ok

    def store(self, q: np.ndarray, grid: ReachabilityGrid) -> ReachabilityGrid:
        """Keep ``grid``, computed at ``q`` with :attr:`grid_horizon` (checked: its ``horizon``); returns it."""
        q = self._check_q(q)
        if not abs(float(grid.horizon) - self.grid_horizon) <= 1e-12:
            raise ValueError(
                f"grid horizon {grid.horizon} s: a reused grid needs horizon + slack = {self.grid_horizon} s"
            )
        self.grid = grid
        self._box = joint_box(q, self.v_max, self.q_min, self.q_max, self.grid_horizon)
        self.computed += 1
        return grid
