"""Simulated 2-D laser scanner in the MuJoCo cell: one ``mj_multiRay`` per scan (REP 117 ranges)."""

from __future__ import annotations

import math

import numpy as np

from depthguard.octree.scanner import LaserScanner

__all__ = ["LaserSim"]


class LaserSim:
    """Ranges of a :class:`~depthguard.octree.scanner.LaserScanner` in a MuJoCo model (the robot included).

    Args:
        model: the ``mujoco.MjModel``.
        scanner: the scanner (world pose).
        sigma: range noise (m, 1 sigma, finite, >= 0); ``seed`` for it.
        dropout: fraction of rays without a reading (NaN), in [0, 1].
    """

    def __init__(self, model, scanner: LaserScanner, sigma: float = 0.005, dropout: float = 0.0, seed: int = 0) -> None:
        if not isinstance(scanner, LaserScanner):
            raise ValueError(f"LaserSim: scanner must be a LaserScanner, got {type(scanner).__name__}")
        for name, value, hi in (("sigma", sigma, math.inf), ("dropout", dropout, 1.0)):
            ok = not isinstance(value, bool) and isinstance(value, int | float | np.number)
            if not (ok and math.isfinite(value) and 0.0 <= value <= hi):
                raise ValueError(f"LaserSim: {name} must be a finite number in [0, {hi}], got {value!r}")
        self.model = model
        self.scanner = scanner
        self.dirs = np.ascontiguousarray(scanner.directions().ravel())
        self.sigma = float(sigma)
        self.dropout = float(dropout)
        self.rng = np.random.default_rng(seed)
        self._geom = np.empty(scanner.n_rays, np.int32)
        self._dist = np.empty(scanner.n_rays, np.float64)

    def capture(self, data) -> np.ndarray:
        """(n_rays,) ranges in metres: +inf where nothing lies within ``range_max``, NaN for dropouts.

        A hit within ``range_max`` stays a reading within it under the noise (clipped to ``range_max``: a
        value above it would read as "nothing within range_max", REP 117), and a noisy reading at or below
        0 (a hit nearer than a few sigma) reads ``-inf``, REP 117's "nearer than range_min".
        """
        import mujoco

        sc = self.scanner
        mujoco.mj_multiRay(
            self.model, data, np.asarray(sc.position, float), self.dirs, None, True, -1,
            self._geom, self._dist, None, sc.n_rays, sc.range_max,
        )  # fmt: skip
        r = self._dist.copy()
        r[(self._geom < 0) | (r > sc.range_max)] = np.inf
        hit = np.isfinite(r)
        if self.sigma > 0:
            noisy = np.minimum(r[hit] + self.rng.normal(0.0, self.sigma, hit.sum()), sc.range_max)
            noisy[noisy <= 0.0] = -np.inf
            r[hit] = noisy
        if self.dropout > 0:
            r[self.rng.random(sc.n_rays) < self.dropout] = np.nan
        return r
