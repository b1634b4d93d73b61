"""The controller's reaction laws, attacked with property tests: body bounds (ICRA'12 §V-C, eqs. 12-14),
end-effector repulsion and damped least squares (§V-A, eqs. 7, 10, 11), the admittance reaction at a contact
(SAPHARI D4.1.1 §6.3) and one cycle's jerk-limited step.

References are independent of the code under test: the Cartesian velocity of a control point over every
vertex of the joint-velocity box, numpy's SVD and pseudo-inverse, the exact solution of the mass-damper-spring
ODE (scipy's matrix exponential), and the documented rules written out here.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.linalg import expm

from depthguard.control.admittance import AdmittanceParams, admittance_step, task_priority_velocity
from depthguard.control.body import body_bounds_inplace, body_velocity_bounds
from depthguard.control.endeffector import dls_apply, dls_damping, dls_inverse, repulsive_velocity
from depthguard.control.otg import JointOtg, OtgState
from depthguard.control.step import generate

seeds = st.integers(0, 2**32 - 1)
EPS = 1e-6  # influence_eps (the controller's)


def _logistic(x: float) -> float:
    """1 / (1 + exp(x)) without overflow."""
    if x > 0:
        e = math.exp(-x)
        return e / (1.0 + e)
    return 1.0 / (1.0 + math.exp(x))


def _keep(d: float, rho: float, alpha: float, contact: float) -> float:
    """1 - f(D) of eq. 14 (ICRA'12 eq. 12), 0 at or below contact (penetration included)."""
    return 0.0 if d <= contact else 1.0 - _logistic((2.0 * d / rho - 1.0) * alpha)


def _box_vertices(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(2^n, n) corners of the box [lo, hi]: a linear function takes its extremes there."""
    return np.array(list(itertools.product(*zip(lo, hi, strict=True))))


# ================================================================================================= body
@st.composite
def body_cases(draw):
    rng = np.random.default_rng(draw(seeds))
    N, n = draw(st.integers(1, 3)), draw(st.integers(1, 4))
    jac = rng.normal(size=(N, 3, n)) * 10.0 ** draw(st.sampled_from([-8.0, -3.0, 0.0, 3.0, 100.0]))
    jac[rng.uniform(size=(N, 3, n)) < 0.2] = 0.0
    d = np.array([draw(st.sampled_from([-0.05, 0.0, 0.01, 0.1, 0.3, 0.5, np.inf])) for _ in range(N)])
    d = np.where(np.isfinite(d), d * rng.uniform(0.5, 1.5, N), d)
    dirs = rng.normal(size=(N, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # unit, scaled (any length is a direction), a tiny one that hid the eps test, zero (unknown)
    scale = [draw(st.sampled_from([1.0, 1.0, 10.0, 1e-7, 1e-100, 1e100, 0.0])) for _ in range(N)]
    dirs *= np.array(scale)[:, None]
    vmax = rng.uniform(0.1, 5.0, n)
    rho, alpha = rng.uniform(0.05, 1.0), draw(st.sampled_from([0.5, 6.0, 50.0]))
    use = rng.uniform(size=N) < 0.8
    contact = draw(st.sampled_from([0.0, 0.02]))
    return jac, d, dirs, vmax, rho, alpha, use, contact


def _reference_bounds(jac, d, dirs, vmax, rho, alpha, use, contact):
    """The documented rules (module docstring of control/body.py) written out."""
    lo, hi = -vmax.copy(), vmax.copy()
    for k in range(len(d)):
        if not use[k] or not d[k] < rho:
            continue
        keep = _keep(d[k], rho, alpha, contact)
        nrm = float(np.linalg.norm(dirs[k]))
        if 1e-150 <= nrm <= 1e150:
            g = jac[k].T @ (dirs[k] / nrm)
            lower, upper = g > EPS, g < -EPS
        else:  # unknown direction: every joint that moves C, both ways
            lower = upper = np.linalg.norm(jac[k], axis=0) > EPS
        lo = np.where(lower, np.maximum(lo, -vmax * keep), lo)
        hi = np.where(upper, np.minimum(hi, vmax * keep), hi)
    return lo, hi


@settings(deadline=None, max_examples=150)
@given(body_cases())
@example(  # a direction of norm 1e-7 with the contact at 0: g = 1e-7 < eps, nothing was restricted
    (np.eye(3)[None, :, :2].copy(), np.array([0.0]), np.array([[1e-7, 0.0, 0.0]]), np.ones(2), 0.4, 6.0,
     np.array([True]), 0.0)
)  # fmt: skip
@example(  # a zero direction at contact: nothing was restricted
    (np.eye(3)[None, :, :2].copy(), np.array([0.0]), np.zeros((1, 3)), np.ones(2), 0.4, 6.0, np.array([True]), 0.0)
)
def test_body_bounds_cap_the_cartesian_approach_speed(case):
    """For every used point within rho and every joint velocity in the box [lo, hi] (all its vertices), the
    point C moves towards its obstacle (along -n) at most ``(1 - f(D))`` times the fastest approach the
    unrestricted box allows (plus eps per joint that cannot move it along n); 0 at contact and below.
    Motion away keeps its full speed (one point alone). An unknown (zero) direction caps |J_C qdot| in every
    direction. -v_max <= lo <= 0 <= hi <= v_max always; the bounds are the documented rules'."""
    jac, d, dirs, vmax, rho, alpha, use, contact = case
    lo, hi = body_velocity_bounds(jac, d, dirs, vmax, rho, alpha, use=use, contact_distance=contact)
    assert np.all(-vmax <= lo) and np.all(lo <= 0) and np.all(hi >= 0) and np.all(hi <= vmax)
    want_lo, want_hi = _reference_bounds(jac, d, dirs, vmax, rho, alpha, use, contact)
    np.testing.assert_allclose(lo, want_lo, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(hi, want_hi, rtol=1e-12, atol=1e-15)
    box, full = _box_vertices(lo, hi), _box_vertices(-vmax, vmax)
    for k in range(len(d)):
        if not use[k] or not d[k] < rho:
            continue
        keep = _keep(d[k], rho, alpha, contact)
        Jk = jac[k]
        scale = max(np.abs(Jk).max(), 1e-300) * vmax.sum()
        nrm = float(np.linalg.norm(dirs[k]))
        if nrm == 0.0:  # unknown: the speed of C in any direction
            speed = np.linalg.norm(box @ Jk.T, axis=1).max()
            cap = keep * (np.linalg.norm(Jk, axis=0) * vmax).sum() + EPS * vmax.sum()
            assert speed <= cap * (1 + 1e-12) + 1e-15 * scale
            continue
        u = dirs[k] / nrm
        towards = (-(box @ Jk.T) @ u).max()
        towards_full = (-(full @ Jk.T) @ u).max()
        assert towards <= keep * towards_full + EPS * vmax.sum() + 1e-12 * scale
        if use.sum() == 1:
            away, away_full = ((box @ Jk.T) @ u).max(), ((full @ Jk.T) @ u).max()
            assert away == pytest.approx(away_full, rel=1e-12, abs=1e-300)


def test_body_bounds_penetration_and_contact_deny_motion_towards():
    """A negative distance (penetration) is contact: no joint may move C towards the obstacle (it was refused
    as bad input); D = inf imposes nothing whatever its direction holds."""
    jac = np.zeros((1, 3, 3))
    jac[0, :, 0], jac[0, :, 1], jac[0, :, 2] = [1.0, 0, 0], [-0.5, 0.2, 0], [0, 0, 1.0]
    n = np.array([[1.0, 0.0, 0.0]])
    vmax = np.array([1.0, 2.0, 3.0])
    for d in (0.0, -0.01, -5.0):
        lo, hi = body_velocity_bounds(jac, np.array([d]), n, vmax, 0.4, 6.0)
        np.testing.assert_array_equal(lo, [0.0, -2.0, -3.0])  # joint 0: -qdot moves C towards
        np.testing.assert_array_equal(hi, [1.0, 0.0, 3.0])  # joint 1: +qdot moves C towards
    lo, hi = body_velocity_bounds(jac, np.array([np.inf]), np.array([[np.nan, np.inf, 0.0]]), vmax, 0.4, 6.0)
    np.testing.assert_array_equal(lo, -vmax)
    np.testing.assert_array_equal(hi, vmax)


@pytest.mark.parametrize(
    "d, n",
    [
        pytest.param(np.nan, [1.0, 0.0, 0.0], id="nan-distance"),
        pytest.param(0.05, [np.nan, 0.0, 0.0], id="nan-direction"),
        pytest.param(0.05, [0.0, 0.0, 0.0], id="zero-direction"),
        pytest.param(0.05, [np.inf, 0.0, 0.0], id="inf-direction"),
    ],
)
def test_body_kernel_in_doubt_restricts(d, n):
    """body_bounds_inplace (the real-time path, no validation): a NaN distance is contact (it was skipped:
    no bound at all), a NaN, zero or infinite direction is unknown (both ways capped; it imposed nothing)."""
    jac = np.zeros((1, 3, 2))
    jac[0, :, 0] = [1.0, 0.0, 0.0]  # joint 1 does not move C: never restricted
    vmax = np.array([1.0, 1.0])
    lo, hi = -vmax.copy(), vmax.copy()
    body_bounds_inplace(jac, np.array([d]), np.array([n]), np.ones(1, bool), vmax, 0.4, 6.0, 0.0, EPS, lo, hi)
    keep = 0.0 if math.isnan(d) else _keep(d, 0.4, 6.0, 0.0)
    assert lo[0] == pytest.approx(-keep, abs=1e-15) and lo[1] == -1.0 and hi[1] == 1.0
    if math.isnan(d):
        assert hi[0] == 1.0  # n is known: motion away keeps its bound
    else:
        assert hi[0] == pytest.approx(keep, abs=1e-15)


def test_body_bounds_several_points_the_tightest_wins():
    """Two points with opposite directions on the same joint: both sides capped, each by its own point."""
    jac = np.zeros((2, 3, 1))
    jac[:, 0, 0] = 1.0
    dirs = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    d = np.array([0.1, 0.3])
    lo, hi = body_velocity_bounds(jac, d, dirs, np.array([2.0]), 0.4, 6.0)
    assert lo[0] == pytest.approx(-2.0 * _keep(0.1, 0.4, 6.0, 0.0), rel=1e-14)
    assert hi[0] == pytest.approx(2.0 * _keep(0.3, 0.4, 6.0, 0.0), rel=1e-14)


# ========================================================================================= end effector
@settings(deadline=None, max_examples=100)
@given(
    st.floats(-1.0, 2.0),
    st.floats(-1.0, 2.0),
    st.floats(0.0, 10.0),
    st.floats(1e-3, 10.0),
    st.floats(1e-3, 1e3),
    st.sampled_from([1.0, 1e-200, 1e-160, 1e160, 1e200, 3e-308]),
    seeds,
)
@example(0.1, 0.2, 2.0, 0.4, 6.0, 1e-200, 0)  # a direction of norm 1e-200 gave no repulsion (its square is 0)
@example(0.1, 0.2, 2.0, 0.4, 6.0, 1e200, 0)  # ... and of norm 1e200 none either (its square is inf)
def test_repulsive_speed_is_bounded_monotone_and_along_any_length_of_direction(d1, d2, v_max, rho, alpha, s, seed):
    """eq. 7: ``|V_R| = v(D)`` in [0, V_max], non-increasing in D, 0 at inf; the direction of any finite
    non-zero length is normalised (V_R is the same as for the unit vector)."""
    u = np.random.default_rng(seed).normal(size=3)
    u /= np.linalg.norm(u)
    lo_d, hi_d = min(d1, d2), max(d1, d2)
    v_lo = repulsive_velocity(lo_d, u * s, v_max, rho, alpha)
    v_hi = repulsive_velocity(hi_d, u, v_max, rho, alpha)
    assert np.all(np.isfinite(v_lo)) and np.linalg.norm(v_lo) <= v_max * (1 + 1e-12)
    assert np.linalg.norm(v_hi) <= np.linalg.norm(v_lo) * (1 + 1e-12) + 1e-300
    want = 0.0 if not lo_d < rho else v_max * _logistic((2.0 * lo_d / rho - 1.0) * alpha)
    np.testing.assert_allclose(v_lo, want * u, rtol=1e-12, atol=1e-300)
    np.testing.assert_array_equal(repulsive_velocity(np.inf, u, v_max, rho, alpha), 0.0)


@pytest.mark.parametrize(
    "field, args",
    [
        pytest.param("distance", ("0.1", [1.0, 0, 0], 2.0, 0.4, 6.0), id="distance-string"),
        pytest.param("v_max", (0.1, [1.0, 0, 0], True, 0.4, 6.0), id="v_max-bool"),
        pytest.param("rho", (0.1, [1.0, 0, 0], 2.0, "0.4", 6.0), id="rho-string"),
        pytest.param("direction", (0.1, ["1", "0", "0"], 2.0, 0.4, 6.0), id="direction-strings"),
        pytest.param("direction", (0.1, [1.0, 0.0], 2.0, 0.4, 6.0), id="direction-short"),
    ],
)
def test_repulsive_velocity_refuses_strings_and_bools(field, args):
    """Before: "0.1" and True were read as numbers (float() takes them)."""
    with pytest.raises(ValueError, match=field):
        repulsive_velocity(*args)


def _mk_damping(A: np.ndarray, eps: float, lam_max: float) -> float:
    """Maciejewski-Klein: lambda^2 = (1 - (s_min/eps)^2) lambda_max^2 below eps (s_min = 0 for m > n)."""
    m, n = A.shape
    s_min = 0.0 if m > n else float(np.linalg.svd(A, compute_uv=False).min())
    return 0.0 if s_min >= eps else lam_max * math.sqrt(1.0 - (s_min / eps) ** 2)


@settings(deadline=None, max_examples=80)
@given(seeds, st.integers(1, 6), st.integers(1, 8), st.sampled_from(["plain", "rank1", "zero", "near"]))
def test_dls_matches_numpy_and_stays_bounded_at_singularities(seed, m, n, kind):
    """dls_damping is Maciejewski-Klein's (numpy SVD here), in [0, lambda_max]; dls_apply is numpy's
    ``J^T (J J^T + (lambda^2 + 1e-12) I)^-1 x`` and, even for a singular J, finite with
    ``|qdot| <= |x| / (2 sqrt(lambda^2 + 1e-12))`` (the damped inverse's largest gain)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(m, n))
    if kind == "rank1":
        A = np.outer(rng.normal(size=m), rng.normal(size=n))
    elif kind == "zero":
        A = np.zeros((m, n))
    elif kind == "near":  # the smallest singular value about eps / 2
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        s[-1] = 0.01
        A = (U * s) @ Vt
    lam = dls_damping(A, 0.02, 0.05)
    want_lam = _mk_damping(A, 0.02, 0.05)
    assert 0.0 <= lam <= 0.05
    assert lam == pytest.approx(want_lam, rel=1e-9, abs=1e-9)
    x = rng.normal(size=m)
    qd = dls_apply(A, lam, x)
    reg = lam * lam + 1e-12
    want = A.T @ np.linalg.solve(A @ A.T + reg * np.eye(m), x)
    assert np.all(np.isfinite(qd))
    assert np.linalg.norm(qd) <= np.linalg.norm(x) / (2.0 * math.sqrt(reg)) * (1 + 1e-6)
    cond = (np.linalg.norm(A, 2) ** 2 + reg) / reg
    np.testing.assert_allclose(qd, want, rtol=0, atol=max(1e-9, 64 * 2.2e-16 * cond) * (np.abs(want).max() + 1e-300))
    if lam > 0:
        ref = A.T @ np.linalg.inv(A @ A.T + lam**2 * np.eye(m))
        np.testing.assert_allclose(dls_inverse(A, lam), ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max(initial=1.0))


@pytest.mark.parametrize(
    "call, field",
    [
        pytest.param(lambda: dls_apply(np.ones((3, 7)), 0.0, np.zeros(2)), "x", id="apply-short-x"),
        pytest.param(lambda: dls_apply(np.ones((3, 7)), 0.0, np.zeros(4)), "x", id="apply-long-x"),
        pytest.param(lambda: dls_apply(np.ones((3, 7)), 0.0, np.array([np.nan, 0, 0])), "x", id="apply-nan-x"),
        pytest.param(lambda: dls_apply(np.full((3, 7), np.nan), 0.0, np.zeros(3)), "J", id="apply-nan-J"),
        pytest.param(lambda: dls_apply(np.ones((3, 7)), np.nan, np.zeros(3)), "damping", id="apply-nan-damping"),
        pytest.param(lambda: dls_apply(np.ones(3), 0.0, np.zeros(3)), "J", id="apply-1d-J"),
        pytest.param(lambda: dls_damping(np.ones((3, 7)), np.nan, 0.05), "eps", id="damping-nan-eps"),
        pytest.param(lambda: dls_damping(np.ones((3, 7)), 0.02, -1.0), "lambda_max", id="damping-negative-max"),
        pytest.param(lambda: dls_damping(np.full((3, 7), np.inf)), "J", id="damping-inf-J"),
        pytest.param(lambda: dls_inverse(np.ones((3, 7)), np.nan), "damping", id="inverse-nan-damping"),
        pytest.param(lambda: dls_inverse(np.ones((3, 7)), True), "damping", id="inverse-bool-damping"),
    ],
)
def test_dls_bad_input_is_named(call, field):
    """Before: a short x was read past its end (garbage joint velocities), a NaN J, x or damping gave NaN
    commands, a NaN eps a NaN damping and a negative lambda_max a negative one."""
    with pytest.raises(ValueError, match=field):
        call()


# ========================================================================================== admittance
def _exact(M: float, D: float, K: float, F: float, dt: float, steps: int) -> np.ndarray:
    """(steps,) exact e(k dt), k = 1..steps, of ``M v' + D v + K e = F``, ``e' = v``, from rest at e = 0: the
    state transition ``expm(A dt)`` (scipy) applied to the error from the equilibrium F/K."""
    phi = expm(np.array([[0.0, 1.0], [-K / M, -D / M]]) * dt)
    x, out = np.array([-F / K, 0.0]), np.empty(steps)
    for k in range(steps):
        x = phi @ x
        out[k] = x[0] + F / K
    return out


@settings(deadline=None, max_examples=60)
@given(
    st.floats(1e-2, 1e2),
    st.floats(1e-2, 1e4),
    st.floats(1e-2, 1e5),
    st.floats(-100.0, 100.0),
    st.floats(1e-6, 1e3),
    st.floats(-1.0, 1.0),
)
def test_admittance_energy_never_grows_for_a_constant_force(mass, damping, stiffness, force, dt, e0):
    """'Stable for any dt > 0': with e+ = e + dt v+, the energy ``M v^2/2 + K (e - F/K)^2/2`` of the error
    from the exact equilibrium F/K never grows, whatever dt; the equilibrium is a fixed point."""
    p = AdmittanceParams(mass, damping, stiffness)
    F = np.array([force, 0.0, 0.0])
    e, v = np.array([e0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])

    def energy(e, v):
        return 0.5 * mass * v[0] ** 2 + 0.5 * stiffness * (e[0] - force / stiffness) ** 2

    E = energy(e, v)
    for _ in range(50):
        v = admittance_step(p, v, e, F, dt)
        e = e + dt * v
        E_new = energy(e, v)
        assert E_new <= E * (1 + 1e-9) + 1e-12 * (1 + force**2 / stiffness)
        E = E_new
    v_eq = admittance_step(p, np.zeros(3), F / stiffness, F, dt)
    np.testing.assert_allclose(v_eq, 0.0, atol=1e-12 * (1 + abs(force)))


@pytest.mark.parametrize("params", [(1.5, 60.0, 120.0), (3.0, 450.0, 3000.0), (1.0, 0.5, 50.0)], ids=str)
def test_admittance_converges_to_the_exact_ode_solution(params):
    """The implicit step follows the exact solution of the mass-damper-spring ODE to first order in dt (error
    halves with dt) and is within 2 % of the step response at dt = 0.1 ms (SOFT, STIFF, an underdamped set)."""
    M, D, K = params
    p = AdmittanceParams(M, D, K)
    F, T = 20.0, 0.4
    errs = []
    for dt in (2e-4, 1e-4):
        steps = int(round(T / dt))
        ref = _exact(M, D, K, F, dt, steps)
        e, v, got = np.zeros(3), np.zeros(3), []
        for _ in range(steps):
            v = admittance_step(p, v, e, np.array([F, 0.0, 0.0]), dt)
            e = e + dt * v
            got.append(e[0])
        errs.append(np.abs(np.array(got) - ref).max())
    assert errs[1] <= 0.02 * F / K
    assert 1.6 <= errs[0] / errs[1] <= 2.4  # first order


@pytest.mark.parametrize(
    "field, kw",
    [
        pytest.param("force", dict(force=np.array([np.nan, 0.0, 0.0])), id="force-nan"),
        pytest.param("force", dict(force=np.zeros(2)), id="force-short"),
        pytest.param("dt", dict(dt=0.0), id="dt-zero"),
        pytest.param("dt", dict(dt=-0.5), id="dt-negative"),
        pytest.param("dt", dict(dt=np.nan), id="dt-nan"),
        pytest.param("dt", dict(dt="0.005"), id="dt-string"),
        pytest.param("v", dict(v=np.array([np.inf, 0.0, 0.0])), id="v-inf"),
        pytest.param("e", dict(e=np.zeros(4)), id="e-long"),
        pytest.param("overflow", dict(p=AdmittanceParams(1e300, 1e300, 1e300), dt=1e10), id="overflow"),
    ],
)
def test_admittance_step_bad_input_is_named(field, kw):
    """Before: a NaN force gave a NaN velocity, dt <= 0 was integrated (backwards), overflow gave NaN."""
    args = dict(p=AdmittanceParams(1.0, 1.0, 1.0), v=np.ones(3), e=np.ones(3), force=np.ones(3), dt=0.005) | kw
    with pytest.raises(ValueError, match=field):
        admittance_step(**args)


@pytest.mark.parametrize(
    "kw, field",
    [
        pytest.param(dict(mass="1.0"), "mass", id="mass-string"),
        pytest.param(dict(damping=True), "damping", id="damping-bool"),
        pytest.param(dict(stiffness=-1.0), "stiffness", id="stiffness-negative"),
        pytest.param(dict(mass=0.0), "mass", id="mass-zero"),
    ],
)
def test_admittance_params_name_the_bad_field(kw, field):
    with pytest.raises(ValueError, match=field):
        AdmittanceParams(**(dict(mass=1.0, damping=1.0, stiffness=0.0) | kw))


@settings(deadline=None, max_examples=80)
@given(seeds, st.integers(1, 4), st.integers(1, 3), st.integers(0, 4))
def test_task_priority_primary_first_secondary_in_its_null_space(seed, k, m2, extra):
    """Siciliano-Slotine with tiny damping against numpy's pinv: ``q = J1+ v1 + (J2 P)+ (v2 - J2 J1+ v1)``,
    ``P = I - J1+ J1``: the contact tasks are met exactly where feasible (J1 of full row rank), the second
    task's part lies in the null space of J1, and J2 q = v2 too when J2 P has full row rank."""
    rng = np.random.default_rng(seed)
    n = k + extra + 1
    J1, J2 = rng.normal(size=(k, n)), rng.normal(size=(m2, n))
    v1, v2 = rng.normal(size=k), rng.normal(size=m2)
    qd = task_priority_velocity(J1, v1, J2, v2, lam=1e-9)
    J1p = np.linalg.pinv(J1)
    P = np.eye(n) - J1p @ J1
    want = J1p @ v1 + np.linalg.pinv(J2 @ P, rcond=1e-10) @ (v2 - J2 @ J1p @ v1)
    s1 = np.linalg.svd(J1, compute_uv=False)
    s2 = np.linalg.svd(J2 @ P, compute_uv=False)
    if s1.min() < 1e-3 or (s2.size and 1e-12 < s2.min() < 1e-3):  # (ill-conditioned: the damping shows)
        return
    np.testing.assert_allclose(J1 @ qd, v1, atol=1e-7 * (1 + np.abs(v1).max()))
    np.testing.assert_allclose(J1 @ (qd - J1p @ v1), 0.0, atol=1e-7 * (1 + np.abs(qd).max()))
    np.testing.assert_allclose(qd, want, atol=1e-6 * (1 + np.abs(want).max()))
    if n - k >= m2:
        np.testing.assert_allclose(J2 @ qd, v2, atol=1e-6 * (1 + np.abs(v2).max()))


def test_task_priority_without_damping_on_a_singular_task_is_the_pseudo_inverse():
    """lam = 0 with a rank-deficient contact Jacobian (two contacts on one point) raised numpy's LinAlgError;
    it is now numpy's pseudo-inverse solution (the limit lam -> 0)."""
    rng = np.random.default_rng(3)
    row = rng.normal(size=(3, 7))
    J1 = np.vstack([row, row])
    v1 = rng.normal(size=3)
    qd = task_priority_velocity(J1, np.concatenate([v1, v1]), lam=0.0)
    np.testing.assert_allclose(qd, np.linalg.pinv(J1) @ np.concatenate([v1, v1]), atol=1e-10)
    np.testing.assert_allclose(row @ qd, v1, atol=1e-10)


@pytest.mark.parametrize(
    "kw, field",
    [
        pytest.param(dict(v1=np.array([np.nan, 0.0, 0.0])), "v1", id="v1-nan"),
        pytest.param(dict(lam=np.nan), "lam", id="lam-nan"),
        pytest.param(dict(lam=-1.0), "lam", id="lam-negative"),
        pytest.param(dict(J2=np.ones((3, 6)), v2=np.zeros(3)), "J2", id="J2-columns"),
        pytest.param(dict(J2=np.ones((3, 7))), "v2", id="J2-without-v2"),
        pytest.param(dict(v1=np.zeros(2)), "v1", id="v1-short"),
    ],
)
def test_task_priority_bad_input_is_named(kw, field):
    """Before: a NaN velocity or damping gave NaN joint velocities (and ContactAdmittance's scaling into the
    joint limits let NaN through: NaN > 1 is False)."""
    args = dict(J1=np.eye(3, 7), v1=np.zeros(3), J2=None, v2=None, lam=0.01) | kw
    with pytest.raises(ValueError, match=field):
        task_priority_velocity(**args)


@pytest.mark.parametrize(
    "kw, field",
    [
        pytest.param(dict(lam=np.nan), "lam", id="lam-nan"),
        pytest.param(dict(ee_gain=np.inf), "ee_gain", id="gain-inf"),
        pytest.param(dict(ee_gain="5"), "ee_gain", id="gain-string"),
        pytest.param(dict(params=(1.0, 1.0, 1.0)), "params", id="params-tuple"),
    ],
)
def test_contact_admittance_parameters_are_checked(kw, field):
    """ContactAdmittance took lam = NaN and ee_gain = inf and sent NaN joint velocities at the first step."""
    from depthguard.control.admittance import SOFT, ContactAdmittance

    args = dict(model=None, params=SOFT) | kw
    with pytest.raises(ValueError, match=field):
        ContactAdmittance(**args)


def test_contact_admittance_limit_stops_on_a_non_finite_command():
    """The uniform scaling into the joint limits: a non-finite command is a stop (NaN > 1 is False)."""
    from depthguard.control.admittance import SOFT, ContactAdmittance

    class _Model:
        v_max = np.full(3, 2.0)

    adm = ContactAdmittance(_Model(), SOFT)
    np.testing.assert_array_equal(adm._limit(np.array([np.nan, 0.1, 0.2])), 0.0)
    np.testing.assert_array_equal(adm._limit(np.array([np.inf, 0.1, 0.2])), 0.0)
    np.testing.assert_allclose(adm._limit(np.array([4.0, 1.0, -1.0])), [2.0, 0.5, -0.5])


# ================================================================================================ step
@st.composite
def step_cases(draw):
    rng = np.random.default_rng(draw(seeds))
    n = draw(st.integers(1, 4))
    dt = draw(st.sampled_from([1e-3, 4e-3]))
    a_max, j_max = rng.uniform(0.5, 30.0, n), 10.0 ** rng.uniform(1.0, 4.0, n)
    p = rng.uniform(-2.0, 2.0, n)
    v = rng.uniform(-3.0, 3.0, n)
    a = rng.uniform(-1.5, 1.5, n) * a_max
    lo, hi = -rng.uniform(0.0, 3.0, n), rng.uniform(0.0, 3.0, n)
    target = rng.uniform(-4.0, 4.0, n)
    bad = draw(st.sampled_from(["none", "nan-v", "nan-a", "nan-p", "nan-target", "nan-bound", "crossed"]))
    i = int(rng.integers(n))
    if bad == "nan-v":
        v[i] = np.nan
    elif bad == "nan-a":
        a[i] = np.inf
    elif bad == "nan-p":
        p[i] = np.nan
    elif bad == "nan-target":
        target[i] = np.nan
    elif bad == "nan-bound":
        lo[i] = np.nan
    elif bad == "crossed":
        lo[i], hi[i] = 0.5, -0.2
    away = draw(st.sampled_from([None, "random", "nan"]))
    away_v = None if away is None else (rng.normal(size=n) if away == "random" else np.full(n, np.nan))
    return JointOtg(n, dt, a_max, j_max), OtgState(p, v, a), target, lo, hi, away_v, bad


@settings(deadline=None, max_examples=120, suppress_health_check=[HealthCheck.too_slow])
@given(step_cases())
def test_generate_stays_within_the_cycle_bounds_and_the_limits(case):
    """step.generate: the new velocity is finite and within [lo, hi] (as read: a NaN bound is 0, crossed
    bounds the value between them nearest 0); without ``limited`` the acceleration is within a_max and
    changed at most j_max dt from the (clipped) state's; bad input is reported (limited or Ruckig failed);
    the step taken with ``away`` approaches the obstacle no more than the time-optimal one."""
    j, state, target, lo, hi, away, bad = case
    new, ok, limited = generate(j, state, target, lo, hi, away)
    lo_r, hi_r = np.nan_to_num(lo, nan=0.0), np.nan_to_num(hi, nan=0.0)
    crossed = lo_r > hi_r
    mid = np.clip(0.0, hi_r, lo_r)
    lo_r, hi_r = np.where(crossed, mid, lo_r), np.where(crossed, mid, hi_r)
    assert np.all(np.isfinite(new.velocity)) and np.all(np.isfinite(new.acceleration))
    assert np.all(lo_r <= new.velocity) and np.all(new.velocity <= hi_r)
    if bad not in ("none", "nan-target"):
        assert limited
    if bad == "nan-target":
        assert not ok
    if not limited:
        a0 = np.clip(np.nan_to_num(state.acceleration, nan=0.0, posinf=0.0, neginf=0.0), -j.a_max, j.a_max)
        assert np.all(np.abs(new.acceleration) <= j.a_max * (1 + 1e-9))
        assert np.all(np.abs(new.acceleration - a0) <= j.j_max * j.dt * (1 + 1e-9) + 1e-12)
    if away is not None and bad == "none":
        plain, _, _ = generate(j, state, target, lo, hi, None)
        assert away @ (new.position - state.position) >= away @ (plain.position - state.position) - 1e-15 or (
            np.isnan(away).any()
        )
