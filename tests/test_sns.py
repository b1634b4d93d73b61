"""SNS (saturation in the null space): bounds, task preservation, optimal scaling (checked with linprog)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from depthguard.control import sns_velocity
from depthguard.control.endeffector import dls_damping
from depthguard.control.sns import sns_velocity_raw, sns_velocity_unchecked


def _max_feasible_scale(J: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Independent reference: max s in [0, 1] s.t. J q = s x, lo <= q <= hi (a linear program)."""
    m, n = J.shape
    res = linprog(
        np.r_[np.zeros(n), -1.0],
        A_eq=np.hstack([J, -x[:, None]]),
        b_eq=np.zeros(m),
        bounds=[(a, b) for a, b in zip(lo, hi, strict=True)] + [(0.0, 1.0)],
        method="highs",
    )
    assert res.status == 0
    return float(res.x[-1])


@st.composite
def problems(draw, max_m: int = 3, max_n: int = 7):
    m = draw(st.integers(1, max_m))
    n = draw(st.integers(m, max_n))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(m, n))
    x = rng.normal(size=m) * draw(st.floats(0.05, 10.0))
    lo = -rng.uniform(0.0, 2.0, n)
    hi = rng.uniform(0.0, 2.0, n)
    if draw(st.booleans()):  # some joints may only move one way (as body constraints produce)
        k = rng.integers(n)
        if rng.uniform() < 0.5:
            lo[k] = 0.0
        else:
            hi[k] = 0.0
    return J, x, lo, hi


def _near_singular(J: np.ndarray, sigma_min: float) -> np.ndarray:
    """J with its smallest singular value set to ``sigma_min`` (the controller's damped path)."""
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    sv[-1] = sigma_min
    return np.ascontiguousarray(U @ np.diag(sv) @ Vt)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems(max_m=6, max_n=9), st.sampled_from(["none", "random", "near_singular"]), st.floats(0.0001, 0.05))
def test_bounds_respected_by_the_solver_itself_before_any_clip(p, damping_case: str, x) -> None:
    """The raw solver's output (no final guard, no clip) is within the bounds to 1e-9, also with damping,
    and the guarded result is that output clipped (the guard never had to replace it by zero)."""
    J, xd, lo, hi = p
    lam = 0.0
    if damping_case == "random":
        lam = x
    elif damping_case == "near_singular":  # as in the controller: lambda from dls_damping near a singularity
        J = _near_singular(J, x * 0.2)
        lam = dls_damping(J)
        assert lam > 0.0
    J = np.ascontiguousarray(J)
    q, s = sns_velocity_raw(J, xd, lo, hi, lam)
    assert q.shape == (J.shape[1],) and np.all(np.isfinite(q))
    assert 0.0 <= s <= 1.0
    assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)
    qg, sg = sns_velocity_unchecked(J, xd, lo, hi, lam)
    np.testing.assert_array_equal(qg, np.clip(q, lo, hi))
    assert sg == s


@settings(max_examples=300, deadline=None)
@given(problems())
def test_task_direction_and_scale_preserved(p) -> None:
    J, x, lo, hi = p
    if np.linalg.cond(J) > 1e3:
        return
    q, s = sns_velocity(J, x, lo, hi)
    np.testing.assert_allclose(J @ q, s * x, atol=1e-6 * np.linalg.norm(x))


@settings(max_examples=300, deadline=None)
@given(problems())
def test_matches_pseudo_inverse_when_nothing_saturates(p) -> None:
    J, x, lo, hi = p
    q_pinv = np.linalg.pinv(J) @ x
    q, s = sns_velocity(J, x, lo, hi)
    if np.all(q_pinv >= lo) and np.all(q_pinv <= hi):
        assert s == 1.0
        np.testing.assert_allclose(q, q_pinv, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(problems(max_m=6, max_n=9))
def test_no_larger_feasible_scale_exists(p) -> None:
    J, x, lo, hi = p
    if np.linalg.matrix_rank(J) < J.shape[0]:
        return
    _, s = sns_velocity(J, x, lo, hi)
    s_lp = _max_feasible_scale(J, x, lo, hi)
    assert s >= s_lp - 1e-6  # scaling only as much as the task is infeasible
    assert s <= s_lp + 1e-6


@settings(max_examples=100, deadline=None)
@given(problems(max_m=6, max_n=9), st.floats(0.0001, 0.0199))  # (σ within rounding of eps = 0.02: maybe none)
def test_damped_path_never_scales_more_than_the_lp_optimum(p, sigma_min: float) -> None:
    """The controller's real path near a singularity (damping from dls_damping > 0): the task is never
    scaled down more than the exact optimum requires (linprog on the undamped task), and the bounds hold
    before the clip."""
    J, x, lo, hi = p
    J = _near_singular(J, sigma_min)
    lam = dls_damping(J)
    assert lam > 0.0
    q, s = sns_velocity_raw(J, x, lo, hi, lam)
    assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)
    s_lp = _max_feasible_scale(J, x, lo, hi)
    assert s >= s_lp - 1e-6


def test_null_space_compensates_a_saturated_joint() -> None:
    # x = q1 + q2 = 1.2, q1 <= 0.4: the pseudo-inverse gives (0.6, 0.6); SNS saturates q1 at 0.4
    # and the null space gives q2 = 0.8, so the task is kept without scaling.
    q, s = sns_velocity(np.array([[1.0, 1.0]]), np.array([1.2]), np.array([-1.0, -1.0]), np.array([0.4, 1.0]))
    assert s == 1.0
    np.testing.assert_allclose(q, [0.4, 0.8], atol=1e-12)
    # x = 2 needs 0.4 + 1.0 = 1.4 at most: scale 0.7
    q, s = sns_velocity(np.array([[1.0, 1.0]]), np.array([2.0]), np.array([-1.0, -1.0]), np.array([0.4, 1.0]))
    assert s == pytest.approx(0.7)
    np.testing.assert_allclose(q, [0.4, 1.0], atol=1e-12)


def test_zero_task_and_zero_bounds() -> None:
    J = np.random.default_rng(0).normal(size=(3, 7))
    q, s = sns_velocity(J, np.zeros(3), -np.ones(7), np.ones(7))
    assert s == 1.0 and np.all(q == 0)
    q, s = sns_velocity(J, np.ones(3), np.zeros(7), np.zeros(7))
    assert s == 0.0 and np.all(q == 0)


def test_infinite_bounds_are_allowed() -> None:
    J = np.random.default_rng(1).normal(size=(3, 7))
    q, s = sns_velocity(J, np.ones(3), np.full(7, -np.inf), np.full(7, np.inf))
    assert s == 1.0
    np.testing.assert_allclose(J @ q, np.ones(3))


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((np.ones(3), np.ones(1), -np.ones(3), np.ones(3)), "J must be a 2-D"),
        ((np.ones((2, 3)), np.ones(3), -np.ones(3), np.ones(3)), "xdot must have shape"),
        ((np.ones((2, 3)), np.ones(2), -np.ones(4), np.ones(3)), "qdot_min must have shape"),
        ((np.ones((2, 3)), np.ones(2), np.ones(3), -np.ones(3)), "qdot_min must be <= qdot_max"),
        ((np.ones((2, 3)), np.ones(2), np.array([0.1, -1, -1]), np.ones(3)), "contain zero"),
        ((np.full((2, 3), np.nan), np.ones(2), -np.ones(3), np.ones(3)), "J must be finite"),
        ((np.ones((2, 3)), np.array([1.0, np.nan]), -np.ones(3), np.ones(3)), "xdot must be finite"),
        ((np.ones((2, 3)), np.ones(2), np.array([np.nan, -1, -1]), np.ones(3)), "NaN"),
    ],
)
def test_bad_inputs_raise_clear_errors(args, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        sns_velocity(*args)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 6), st.integers(1, 9), st.integers(0, 2**32 - 1), st.floats(-3.0, 2.0),
    st.sampled_from(["full", "zero_columns", "dependent_rows"]), st.sampled_from([0.0, 1e-3, 0.05]),
)  # fmt: skip
def test_damped_pinv_equals_numpys_svd_formula(m, n, seed, log_scale, kind, damping) -> None:
    """The Jacobi SVD behind SNS's pseudo-inverse against numpy's LAPACK SVD: the same numerical rank and
    ``V diag(s / (s^2 + d^2)) U^T`` to 1e-10 relative, for full-rank, zero-column (saturated joints) and
    rank-deficient matrices over five decades of scale."""
    from depthguard.control.linalg import _damped_pinv

    rng = np.random.default_rng(seed)
    A = rng.normal(size=(m, n)) * 10.0**log_scale
    if kind == "zero_columns":
        A[:, rng.random(n) < 0.5] = 0.0
    elif kind == "dependent_rows" and m > 1:
        A[-1] = A[0] * rng.normal()
    P, rank = _damped_pinv(np.ascontiguousarray(A), damping, 1e-10)
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    keep = (s > 1e-10 * max(s.max(), 1e-300)) & (s > 1e-12)
    want = (Vt[keep].T * (s[keep] / (s[keep] ** 2 + damping**2))) @ U[:, keep].T
    assert rank == int(keep.sum())
    assert np.abs(P - want).max() <= 1e-10 * max(np.abs(want).max(), 1e-300)
