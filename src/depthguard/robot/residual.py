"""Generalized-momentum residual and contact detection (SAPHARI D4.1.1 §6.1; De Luca et al., IROS 2006).

With the generalized momentum ``p = M(q) q̇`` the residual is (D4.1.1 §6.1, eq. of r(t))::

    r(t) = K_I ( p(t) - p(0) - ∫_0^t (τ + Cᵀ(q, q̇) q̇ - g(q) + r) ds )

and, for the robot dynamics ``M q̈ + C q̇ + g = τ + τ_ext`` (which implies ``ṗ = τ + Cᵀ q̇ - g + τ_ext``
because ``Ṁ = C + Cᵀ``), every component is a unity-gain first-order filter of the external torque::

    ṙ = K_I (τ_ext - r),       time constant 1 / K_I,i  per joint.

Dynamics (:class:`RigidBodyDynamics`): ``M`` from pinocchio ``crba`` (which fills one triangle only: we
symmetrise it) plus the drives' ``armature`` (rotor inertia, on the diagonal), ``C`` from
``computeCoriolisMatrix`` (the factorisation that satisfies ``Ṁ = C + Cᵀ``, the property the residual
needs), ``g`` from ``computeGeneralizedGravity``. Viscous joint damping ``D`` known to the model is
moved to the torque side: the observer uses ``τ - D q̇`` as the joint torque.

The observer needs only ``p = M q̇`` and ``Cᵀ q̇ - g``, and ``Cᵀ q̇ = Ṁ q̇ - C q̇ = ∂T/∂q`` (T the kinetic
energy) whatever the factorisation. With ``MomentumObserver(..., terms="compiled")`` it computes both
without forming M and C, in one compiled O(n) pass from the model's joint placements and inertias, read
once (:func:`_momentum_terms`): equal to pinocchio's ``crba``, ``computeCoriolisMatrix`` and
``computeGeneralizedGravity`` to rounding (``tests/test_residual.py``), about 5 µs less per cycle than the
three calls. The default is pinocchio's terms (the reference implementation); models with other joints
than one-coordinate revolute or prismatic ones, and a :class:`RigidBodyDynamics` whose ``raw_terms`` is
overridden, always go through ``raw_terms``.

Discrete time (:class:`MomentumObserver`), at the control period ``dt``: the integrand
``β = Cᵀ q̇ - g - D q̇`` is integrated with the trapezoidal rule between samples; the motor torque either
the same way (``tau_mode="sample"``: τ sampled at each cycle) or exactly (``tau_mode="average"``: τ is the
mean motor torque over the period that just ended, as a drive reporting its averaged current gives);
the feedback term ``∫ r`` is trapezoidal too (Tustin), which makes the update implicit in ``r_k`` and is
solved in closed form::

    I_k = I_{k-1} + ∫τ + dt/2 (β_k + β_{k-1}) + dt/2 (r_k + r_{k-1})
    r_k = K_I (p_k - p_0 - I_k)  =>  r_k = K_I (p_k - p_0 - I'_k) / (1 + K_I dt / 2)

The discrete filter pole is ``(1 - K_I dt/2) / (1 + K_I dt/2)``: stable for every ``K_I dt > 0``, with
the time constant ``-dt / ln(pole)`` ≈ ``1/K_I (1 - (K_I dt)²/12)`` (0.5 % short of ``1/K_I`` at ``K_I dt = 0.25``)
(:func:`discrete_time_constant`).

Detection (:class:`ContactDetector`, in :mod:`depthguard.robot.contact_detector`): a contact is detected
when ``‖r‖ > r_th`` or any ``|r_i| > r_th,i``, and released when ``‖r‖`` and every ``|r_i|`` have stayed
below ``release_ratio`` times their thresholds for ``release_cycles`` cycles (hysteresis). At every onset a
classifier hook labels the contact ``"intentional"`` or ``"collision"``; the default, :func:`default_classifier`, is
documented there.

No simulator is imported here; pinocchio is imported when a :class:`RigidBodyDynamics` is built.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from depthguard.robot.contact_detector import (  # noqa: F401 - their old import path
    ContactDetector,
    ContactEvidence,
    DetectionState,
    default_classifier,
)
from depthguard.robot.fk import ChainKinematics, _pack_chain
from depthguard.robot.observer_kernels import (  # noqa: F401 - _momentum_terms, _observer_step: for tests
    _body_array,
    _chain_observer_step,
    _checked_observer_step,
    _momentum_terms,
    _observer_step,
)
from depthguard.validation import (
    check_finite_array,
    is_numeric_nest,
    numeric_vector,
    positive_number,
    positive_numbers,
)

__all__ = [
    "RigidBodyDynamics",
    "MomentumObserver",
    "ContactDetector",
    "DetectionState",
    "ContactEvidence",
    "default_classifier",
    "discrete_time_constant",
    "scaled_inertia_model",
]


class RigidBodyDynamics:
    """``M(q)``, ``C(q, q̇)``, ``g(q)`` of a pinocchio model, with armature and viscous damping.

    Args:
        model: a :class:`depthguard.robot.model.RobotModel` or a ``pinocchio.Model``.
        armature: (n,) rotor inertias added to the diagonal of ``M`` (kg m², default zeros).
        damping: (n,) viscous joint damping D, N m s/rad (default: the model's URDF ``damping``).
    Not thread-safe (one pinocchio ``Data`` buffer).
    """

    def __init__(self, model, armature: np.ndarray | None = None, damping: np.ndarray | None = None) -> None:
        import pinocchio as pin

        self._pin = pin
        self.model = getattr(model, "model", model)
        self.data = self.model.createData()
        n = int(self.model.nv)
        self.n_dof = n
        self.armature = np.zeros(n) if armature is None else check_finite_array(armature, (n,), "armature")
        if damping is None:
            damping = np.asarray(getattr(self.model, "damping", np.zeros(n)), float)
        self.damping = check_finite_array(damping, (n,), "damping")
        if np.any(self.armature < 0) or np.any(self.damping < 0):
            raise ValueError("armature and damping must be >= 0")
        self._arm = np.diag(self.armature)
        # pinocchio's crba fills the upper triangle (older versions) or both (pinocchio >= 3 in Python):
        # find out once, then mirror only when needed
        probe = np.array(pin.crba(self.model, self.data, np.linspace(0.1, 0.7, n)))
        self._mirror = not np.allclose(probe, probe.T, atol=1e-12)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """(n, n) symmetric inertia matrix ``M(q)`` including the armature, kg m²."""
        M = self._pin.crba(self.model, self.data, q)
        if self._mirror:
            M = np.triu(M) + np.triu(M, 1).T
        return M + self._arm

    def raw_terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """pinocchio's ``M`` (without the armature; its upper triangle is always filled, the lower one only
        by some versions), ``C`` and ``g`` at ``(q, q̇)``, as pinocchio returns them (no copies): the
        control-rate path of :class:`MomentumObserver`."""
        pin, m, d = self._pin, self.model, self.data
        return pin.crba(m, d, q), pin.computeCoriolisMatrix(m, d, q, qd), pin.computeGeneralizedGravity(m, d, q)

    def terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``M`` (n, n), ``C`` (n, n) with ``Ṁ = C + Cᵀ``, and ``g`` (n,) N m at ``(q, q̇)``."""
        M = self.mass_matrix(q)
        C = np.array(self._pin.computeCoriolisMatrix(self.model, self.data, q, qd))
        g = np.array(self._pin.computeGeneralizedGravity(self.model, self.data, q))
        return M, C, g


def scaled_inertia_model(model, scale: np.ndarray | float):
    """A copy of a pinocchio model (or ``RobotModel``) with every link's mass and inertia scaled.

    ``scale`` is one factor or (n,) factors, one per joint body (for model-error studies, e.g. 0.9-1.1), each
    finite and > 0 (else ``ValueError``: a negative mass has no meaning).
    """
    base = getattr(model, "model", model)
    m = copy.deepcopy(base)
    s = positive_numbers(scale, m.njoints - 1, "scale")
    for j in range(1, m.njoints):
        inert = m.inertias[j]
        inert.mass = float(inert.mass * s[j - 1])
        inert.inertia = np.array(inert.inertia) * s[j - 1]
        m.inertias[j] = inert
    return m


def discrete_time_constant(gain: float | np.ndarray, dt: float) -> np.ndarray:
    """Time constant (s) of the discrete residual filter of :class:`MomentumObserver` per joint: that of the
    decay ``|pole|^k = exp(-k dt / T)`` (for ``K_I dt > 2`` the pole is negative and the error alternates
    in sign within that envelope; ``K_I dt = 2``: dead-beat, 0). ``gain`` and ``dt`` must be finite and > 0."""
    g = np.asarray(gain, float) if is_numeric_nest(gain) else None
    if g is None or not (np.all(np.isfinite(g)) and np.all(g > 0)):
        raise ValueError(f"gain must be finite numbers > 0, got {gain!r}")
    dt = positive_number(dt, "dt")
    a = g * dt / 2.0
    with np.errstate(divide="ignore"):
        return -dt / np.log(np.abs((1.0 - a) / (1.0 + a)))


def _chain_dynamics(dynamics: RigidBodyDynamics, par: np.ndarray, average: bool) -> tuple | None:
    """The buffers :func:`_chain_observer_step` takes for ``dynamics`` (read once), or None where it does
    not apply: ``raw_terms`` overridden, a joint that is not a one-coordinate revolute or prismatic joint,
    pinocchio's own ``armature`` set, or a gravity with an angular part."""
    if type(dynamics).raw_terms is not RigidBodyDynamics.raw_terms:
        return None
    model = dynamics.model
    chain = ChainKinematics.from_model(model)
    if chain is None or chain.n_dof != dynamics.n_dof:
        return None
    if np.any(np.asarray(getattr(model, "armature", np.zeros(dynamics.n_dof))) != 0):
        return None
    if np.any(np.asarray(model.gravity.angular) != 0):
        return None
    return _pack_chain(chain, ints=[int(average)], floats=np.concatenate([_body_array(model).ravel(), par.ravel()]))


_F64 = np.dtype(np.float64)
_tuple_new = tuple.__new__


def _is_vector(x: object, n: int) -> bool:
    return type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (n,)


class MomentumObserver:
    """Discrete-time generalized-momentum residual (module docstring for the equations).

    Args:
        dynamics: a :class:`RigidBodyDynamics`.
        gain: K_I, one value or (n,) per joint, 1/s (default 100: time constant 10 ms).
        dt: control period, s.
        tau_mode: ``"sample"`` (τ sampled at each cycle, trapezoidal) or ``"average"`` (τ is the mean
            over the period that just ended, integrated exactly).
        terms: where ``M``, ``C`` and ``g`` come from: ``"pinocchio"`` (the default: ``crba``,
            ``computeCoriolisMatrix``, ``computeGeneralizedGravity``) or ``"compiled"`` (``p = M q̇`` and
            ``Cᵀ q̇ - g`` in one compiled pass, :func:`_momentum_terms`, equal to pinocchio's to rounding and
            about 5 µs faster per cycle; robots of one-coordinate revolute/prismatic joints only, otherwise
            pinocchio's are used).
    Call :meth:`update` once per cycle; the first call initialises ``p(0)`` and returns zeros.
    """

    def __init__(
        self,
        dynamics: RigidBodyDynamics,
        gain: float | np.ndarray = 100.0,
        dt: float = 0.005,
        tau_mode: str = "sample",
        terms: str = "pinocchio",
    ) -> None:
        n = dynamics.n_dof
        self.dyn = dynamics
        self.dt = positive_number(dt, "dt")
        self.gain = positive_numbers(gain, n, "gain")
        if tau_mode not in ("sample", "average"):
            raise ValueError(f"tau_mode must be 'sample' or 'average', got {tau_mode!r}")
        self.tau_mode = tau_mode
        self._average = tau_mode == "average"
        self._par = np.array([dynamics.armature, dynamics.damping, self.gain])
        self._shape = (n,)
        if terms not in ("pinocchio", "compiled"):
            raise ValueError(f"terms must be 'pinocchio' or 'compiled', got {terms!r}")
        self.terms = terms
        # None: pinocchio's M, C, g
        self._chain = _chain_dynamics(dynamics, self._par, self._average) if terms == "compiled" else None
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next :meth:`update` re-initialises ``p(0)``."""
        self._state = np.zeros((5, self.dyn.n_dof))  # I, p(0), β_prev, τ_prev, r
        self._started = False

    @property
    def r(self) -> np.ndarray:
        """(n,) the latest residual, N m."""
        return self._state[4].copy()

    def update(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float | None = None) -> np.ndarray:
        """One cycle: joint positions ``q`` (n,) rad, velocities ``qd`` (n,) rad/s, motor torques ``tau``
        (n,) N m. Returns the residual ``r`` (n,) N m (an estimate of τ_ext). Non-finite input, wrong shapes,
        non-numbers (strings, bools) and a ``dt`` that is not a finite number > 0 raise ``ValueError`` naming
        the field, with the state untouched (the caller should then treat the robot as in contact, i.e. stop)."""
        n = self.dyn.n_dof
        sh = self._shape
        if dt is None:
            h = self.dt
        else:  # a valid dt takes the fast path too; anything else is checked (and rejected) below
            h = dt if type(dt) is float and 0.0 < dt < math.inf else 0.0
        if (  # the control-rate path: float64 (n,) arrays, finiteness checked in the compiled step
            h > 0.0
            and type(q) is np.ndarray
            and type(qd) is np.ndarray
            and type(tau) is np.ndarray
            and q.dtype is _F64
            and qd.dtype is _F64
            and tau.dtype is _F64
            and q.shape == sh
            and qd.shape == sh
            and tau.shape == sh
        ):
            r, chain = np.empty(n), self._chain
            if chain is not None:  # (the common case of _step, inline)
                if _chain_observer_step(q, qd, tau, chain[0], chain[1], h, not self._started, self._state, r):
                    self._started = True
                    return r
            elif self._step(q, qd, tau, h, r):
                return r
            # not finite: the checks below raise the error naming the input
        if not (_is_vector(q, n) and _is_vector(qd, n) and _is_vector(tau, n)) or not math.isfinite(
            q.sum() + qd.sum() + tau.sum()
        ):
            q, qd, tau = (numeric_vector(x, n, name) for x, name in ((q, "q"), (qd, "qd"), (tau, "tau")))
        h = self.dt if dt is None else positive_number(dt, "dt")
        r = np.empty(n)
        self._step(q, qd, tau, h, r)
        return r

    def _step(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, h: float, r: np.ndarray) -> bool:
        """The update into ``r``; False (nothing changed) when ``q``, ``qd`` or ``tau`` is not finite."""
        first, chain = not self._started, self._chain
        if chain is not None:  # M q̇ and Cᵀ q̇ - g compiled (_momentum_terms), in the same call
            ok = _chain_observer_step(q, qd, tau, chain[0], chain[1], h, first, self._state, r)
        else:
            M, C, g = self.dyn.raw_terms(q, qd)  # (M: upper triangle at least; the kernel mirrors it)
            ok = _checked_observer_step(M, C, g, q, qd, tau, self._par, h, self._average, first, self._state, r)
        if ok:
            self._started = True
        return ok
