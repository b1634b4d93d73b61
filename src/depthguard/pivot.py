"""The pivot algorithm: bend the repulsive vector away from the obstacle's motion (ICRA'12 §IV-A).

``dV/dt`` of the repulsive vector stands in for the obstacle velocity. With ``a = dV/dt/|dV/dt|``,
``r = V/|V|`` and ``β = acos(aᵀr)``: if ``β < π/2`` (the obstacle approaches) the vector is turned in the
plane of ``a`` and ``r`` to the angle ``γ = β + (π/2 - β) σ`` from ``a``, with
``σ = 1 / (1 + exp(-(|dV/dt| 2/dVmax - 1) c))`` (``docs/conventions.md``), shifted and rescaled so that it is exactly 0
at ``|dV/dt| = 0`` (the raw sigmoid is ``1/(1+e^c)`` there: 0.7 % for c = 5, 27 % for c = 1): ``γ = β`` for
a still obstacle and
``γ -> π/2`` (escape at right angles to the approach) as ``|dV/dt| -> dVmax``. When ``a`` and ``r`` are
nearly parallel the plane is undefined and a small deterministic perturbation picks one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from depthguard.validation import check_finite_array, check_positive

__all__ = ["pivot", "PivotFilter"]

_EPS = 1e-9


def _any_perpendicular(a: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to unit ``a``, chosen deterministically (the perturbation)."""
    axis = np.eye(3)[int(np.argmin(np.abs(a)))]
    p = np.cross(a, axis)
    return p / np.linalg.norm(p)


def pivot(
    V: np.ndarray,
    V_dot: np.ndarray,
    dv_max: float,
    c: float,
    parallel_tol: float = 1e-3,
) -> np.ndarray:
    """Apply the pivot algorithm to one repulsive vector.

    Args:
        V: (3,) repulsive vector ``V_R(P)`` (m/s).
        V_dot: (3,) its time derivative ``dV_R/dt`` (m/s²).
        dv_max: ``dV_Rmax``, the variation at which the escape becomes perpendicular (m/s²).
        c: positive shape factor of the sigmoid.
        parallel_tol: below this ``|r - a (aᵀr)|``, ``a`` is perturbed by a small deterministic rotation.
    Returns:
        (3,) ``V_Rpivot`` with the magnitude of ``V``.
    Raises:
        ValueError: ``V`` or ``V_dot`` not 3 finite numbers, ``dv_max`` or ``c`` not a finite number > 0,
            ``parallel_tol`` not in (0, 0.1].
    """
    V = check_finite_array(V, (3,), "V")
    V_dot = check_finite_array(V_dot, (3,), "V_dot")
    dv_max = check_positive(dv_max, "dv_max")
    c = check_positive(c, "c")
    if not (isinstance(parallel_tol, int | float) and 0.0 < parallel_tol <= 0.1):
        raise ValueError(f"parallel_tol must be a number in (0, 0.1], got {parallel_tol!r}")
    nv = float(np.linalg.norm(V))
    nd = float(np.linalg.norm(V_dot))
    if nv < _EPS or nd < _EPS:
        return V.copy()
    a = V_dot / nd
    r = V / nv
    if float(np.linalg.norm(r - a * (a @ r))) <= parallel_tol and a @ r > 0:
        a = a + 10 * parallel_tol * _any_perpendicular(a)  # the perturbation of dV/dt's orientation
        a /= np.linalg.norm(a)
    cos_b = float(np.clip(a @ r, -1.0, 1.0))
    beta = float(np.arccos(cos_b))
    if beta >= np.pi / 2:
        return V.copy()  # the obstacle moves away: no change
    perp = r - a * cos_b  # = (n × a) with n = a × r, up to its norm
    v = perp / np.linalg.norm(perp)
    sigma0 = 1.0 / (1.0 + np.exp(c))  # the sigmoid at |dV/dt| = 0, subtracted so that gamma = beta exactly
    sigma = 1.0 / (1.0 + np.exp(-(nd * 2.0 / dv_max - 1.0) * c))
    sigma = max(0.0, (sigma - sigma0) / (1.0 - sigma0))
    gamma = beta + (np.pi / 2 - beta) * sigma
    return nv * (np.cos(gamma) * a + np.sin(gamma) * v)


@dataclass
class PivotFilter:
    """Stateful pivot for one control point: estimates ``dV/dt`` by finite differences + a low-pass filter.

    Args:
        dv_max: ``dV_Rmax`` (m/s²); ICRA'12 Exp. 1 uses 0.5.
        c: sigmoid shape factor; Exp. 1 uses 5.
        tau: time constant (s) of the first-order low-pass filter on ``dV/dt``, for noisy depth data.
            The rule is sensitive to lag in ``dV/dt`` (at 1 kHz, tau = 2 ms already halves the clearance of
            the Fig. 7 scenario), so keep it to a few camera frames at most; 0 = raw finite differences.
    """

    dv_max: float = 0.5
    c: float = 5.0
    tau: float = 0.0
    _prev: np.ndarray | None = field(default=None, init=False, repr=False)
    _vdot: np.ndarray = field(default_factory=lambda: np.zeros(3), init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("dv_max", "c"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"PivotFilter.{name} must be positive, got {getattr(self, name)!r}")
        if not (np.isfinite(self.tau) and self.tau >= 0):
            raise ValueError(f"PivotFilter.tau must be >= 0 seconds, got {self.tau!r}")

    def reset(self) -> None:
        self._prev = None
        self._vdot = np.zeros(3)

    @property
    def v_dot(self) -> np.ndarray:
        """The current filtered estimate of ``dV/dt`` (3,)."""
        return self._vdot.copy()

    def step(self, V: np.ndarray, dt: float) -> np.ndarray:
        """Feed the latest repulsive vector ``V`` (3,) after ``dt`` seconds; return the pivoted vector.

        A ``V`` that is not 3 finite numbers or a ``dt`` that is not a finite number > 0 raises ValueError and
        leaves the filter as it was (one NaN would otherwise make every later estimate NaN)."""
        V = np.asarray(V, dtype=float)
        if not (dt > 0 and np.isfinite(dt)):
            raise ValueError(f"dt must be positive seconds, got {dt!r}")
        if V.shape != (3,) or not np.all(np.isfinite(V)):
            raise ValueError(f"V must be 3 finite numbers (m/s), got {V!r}")
        if self._prev is not None:
            raw = (V - self._prev) / dt
            k = dt / (self.tau + dt)
            self._vdot = self._vdot + k * (raw - self._vdot)
        self._prev = V.copy()
        return pivot(V, self._vdot, self.dv_max, self.c)
