"""SNS (:mod:`depthguard.control.sns`) and NSB (:mod:`depthguard.control.nsb`) attacked with property tests.

SNS (Flacco, De Luca, Khatib ICRA 2012):

* the real-time entry :func:`sns_velocity_unchecked` on *any* input (J of any magnitude, rank deficient,
  m > n, NaN/inf in J, xdot, bounds or damping; empty, zero-width and zero-excluding boxes): a finite result
  within every box that has one, and, when in doubt (non-finite input, an empty box), the velocity nearest to
  zero within the bounds with scale 0 (reference: ``np.clip(0, lo, hi)`` written here);
* with full row rank, ``J qdot = s xdot`` and ``s`` the largest feasible scale (``scipy.optimize.linprog``) at
  every magnitude of ``J`` from 1e-300 to 1e300; with a rank-deficient ``J`` (or m > n) the part of the task
  that ``J`` can realise, ``J qdot = s J J^+ xdot`` (numpy's pinv); ``s = 1`` and the pseudo-inverse solution
  when that is within the bounds; deterministic, inputs left alone;
* :func:`sns_velocity` refuses bools, strings, complex numbers and ragged nests naming the argument.

NSB (SAPHARI D4.1.1 §5.2, eqs. 5.4-5.12):

* :func:`nsb_velocity` against an independent weighted pseudo-inverse (``W^1/2 pinv(J W^1/2)``) and the null
  space projector ``I - pinv(J_o) J_o`` of numpy: the energy task (priority) is met exactly with lambda = 1,
  undisturbed by the end-effector task; zero energy gradient: the end-effector task alone;
* :class:`NSBController.step` against the same projection, with ``J_o`` written here from eqs. 5.6-5.7 (the
  compressed springs along the sensor axes); the command is a uniform scaling of it into ``qdot_max``;
* an overflowing target is a stop (never a NaN command); bad arguments are refused naming the field;
  lambda(d) is Lipschitz with the slope the paper's eqs. 5.11/5.12 give, and refuses bools and bad parameters.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.control.nsb import NSBConfig, NSBController, nsb_velocity, weight
from depthguard.control.sns import sns_velocity, sns_velocity_raw, sns_velocity_unchecked
from depthguard.robot.youbot import YOUBOT_Q0, YOUBOT_SENSORS, load_youbot
from test_sns import _max_feasible_scale as _lp_scale  # (independent reference: a linear program)

NAN, INF = math.nan, math.inf
_CACHE: dict = {}


def _youbot():
    if "yb" not in _CACHE:
        _CACHE["yb"] = load_youbot()
    return _CACHE["yb"]


def _nearest_to_zero(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The documented safe result: per joint the velocity nearest to zero in [lo, hi], 0 where that is empty."""
    ok = (lo <= hi) & (lo < INF) & (hi > -INF)
    return np.where(ok, np.clip(0.0, np.where(ok, lo, 0.0), np.where(ok, hi, 0.0)), 0.0)


# ----------------------------------------------------------------------------------------------- SNS


@st.composite
def any_sns_problem(draw):
    """Anything the real-time path could be handed: every magnitude, rank and shape, special values."""
    m, n = draw(st.integers(1, 4)), draw(st.integers(1, 7))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    J = rng.normal(size=(m, n)) * 10.0 ** draw(st.sampled_from([-300, -14, -7, 0, 0, 7, 14, 150, 300]))
    rank = draw(st.sampled_from(["full", "zero_columns", "dependent_rows", "zero"]))
    if rank == "zero_columns":
        J[:, rng.random(n) < 0.5] = 0.0
    elif rank == "dependent_rows" and m > 1:
        J[-1] = J[0] * rng.normal()
    elif rank == "zero":
        J[:] = 0.0
    x = rng.normal(size=m) * 10.0 ** draw(st.sampled_from([-300, -3, 0, 0, 3, 300]))
    if draw(st.booleans()):
        x[:] = 0.0
    lo, hi = -rng.uniform(0.0, 2.0, n), rng.uniform(0.0, 2.0, n)
    for j in range(n):
        kind = draw(st.sampled_from(["plain"] * 4 + ["zero_width", "locked", "above0", "below0", "empty", "inf"]))
        if kind == "zero_width":
            lo[j] = hi[j] = rng.uniform(-1, 1)
        elif kind == "locked":
            lo[j], hi[j] = -0.0, 0.0
        elif kind == "above0":
            lo[j] = rng.uniform(0.01, 0.5)
            hi[j] = lo[j] + rng.uniform(0.0, 1.0)
        elif kind == "below0":
            hi[j] = -rng.uniform(0.01, 0.5)
            lo[j] = hi[j] - rng.uniform(0.0, 1.0)
        elif kind == "empty":
            lo[j], hi[j] = hi[j] + rng.uniform(1e-12, 1.0), lo[j]
        else:
            lo[j], hi[j] = (-INF, INF) if kind == "inf" else (lo[j], hi[j])
    poison = draw(st.sampled_from(["none"] * 6 + ["J", "x", "lo", "hi"]))
    if poison != "none":
        arr = {"J": J, "x": x, "lo": lo, "hi": hi}[poison]
        arr.flat[rng.integers(arr.size)] = draw(st.sampled_from([NAN, INF, -INF]))
    damping = draw(st.sampled_from([0.0, 0.0, 1e-3, NAN, INF]))
    return np.ascontiguousarray(J), x, lo, hi, damping


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# found by make test-random: an unbounded joint took the overflowing solution xdot / J = -1e600 (-inf)
@example((np.array([[1.25730221e-301]]), np.array([-1.32104863e299]), np.array([-INF]), np.array([INF]), 0.0))
@given(any_sns_problem())
def test_unchecked_result_is_finite_and_within_every_box_whatever_the_input(p) -> None:
    """Never NaN, never outside a box that exists; non-finite input or an empty box: the velocity nearest to
    zero within the bounds (0 where no finite velocity is) with scale 0 - the documented safe result."""
    J, x, lo, hi, damping = p
    q, s = sns_velocity_unchecked(J, x, lo, hi, damping)
    assert q.shape == (J.shape[1],) and np.all(np.isfinite(q)) and math.isfinite(s) and 0.0 <= s <= 1.0
    ok = (lo <= hi) & (lo < INF) & (hi > -INF)  # a box with a finite velocity in it (False for NaN)
    assert np.all(q[ok] >= lo[ok]) and np.all(q[ok] <= hi[ok])
    assert np.all(q[~ok] == 0.0)
    finite = np.all(np.isfinite(J)) and np.all(np.isfinite(x)) and math.isfinite(damping)
    if not finite or not np.all(ok):
        assert s == 0.0
        np.testing.assert_array_equal(q, _nearest_to_zero(lo, hi))


@pytest.mark.parametrize(
    ("J", "x", "lo", "hi", "want"),
    [
        pytest.param([[1.0, 1.0]], [1.0], [0.1, 0.2], [1.0, 1.0], None, id="zero-below-both-boxes"),
        pytest.param([[1.0, 0.0]], [1.0], [0.5, -1.0], [0.4, 1.0], [0.0, 0.0], id="first-box-empty"),
        pytest.param([[NAN, 1.0]], [1.0], [-1.0, -1.0], [1.0, 1.0], [0.0, 0.0], id="nan-in-J"),
        pytest.param([[1.0, 1.0]], [INF], [-1.0, 0.3], [1.0, 1.0], [0.0, 0.3], id="inf-task"),
        pytest.param([[1.0, 1.0]], [1.0], [NAN, -1.0], [1.0, -0.5], [0.0, -0.5], id="nan-bound"),
    ],
)
def test_unchecked_safe_result_examples(J, x, lo, hi, want) -> None:
    """Worked cases of the safe result (old code: zero outside the box, or scale 1 for a NaN Jacobian)."""
    lo, hi = np.array(lo, float), np.array(hi, float)
    q, s = sns_velocity_unchecked(np.array(J, float), np.array(x, float), lo, hi, 0.0)
    assert np.all(q >= lo) and np.all(q <= hi) if np.all(lo <= hi) else True
    if want is not None:
        assert s == 0.0
        np.testing.assert_array_equal(q, want)
    else:  # the pseudo-inverse (0.5, 0.5) is within the box: the task is kept
        assert s == 1.0 and q @ [1.0, 1.0] == pytest.approx(1.0)


@st.composite
def well_conditioned(draw, max_m: int = 4, max_n: int = 7, square: bool = False):
    m = draw(st.integers(1, max_m))
    n = m if square else draw(st.integers(m, max_n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    J = rng.normal(size=(m, n))
    while np.linalg.cond(J) > 1e3:
        J = rng.normal(size=(m, n))
    x = rng.normal(size=m) * draw(st.floats(0.05, 10.0))
    lo, hi = -rng.uniform(0.0, 2.0, n), rng.uniform(0.0, 2.0, n)
    locked = rng.random(n) < draw(st.sampled_from([0.0, 0.3]))  # zero-width boxes at 0 (a stopped joint)
    lo[locked] = hi[locked] = 0.0
    return J, x, lo, hi


@settings(max_examples=150, deadline=None)
@given(well_conditioned(), st.floats(-300.0, 300.0))
@example((np.array([[0.3, -1.2, 0.8]]), np.array([2.0]), -np.ones(3), np.ones(3)), -13.0)  # SVD's 1e-12 floor
@example((np.array([[0.3, -1.2, 0.8], [1.0, 0.4, -0.2]]), np.array([0.5, 0.2]), -np.ones(3), np.ones(3)), 150.0)
def test_full_rank_task_and_optimal_scale_at_any_magnitude_of_J(p, log_c: float) -> None:
    """``c J`` and ``c xdot`` is the same task: J qdot = s xdot, and s is the largest feasible scale
    (linprog on the unscaled problem), whatever c (old code: s = 1 with the task not realised at all for
    |J| ~ 1e-13 or 1e150, the SVD's absolute threshold and overflow)."""
    J, x, lo, hi = p
    c = 10.0**log_c
    q, s = sns_velocity(J * c, x * c, lo, hi)
    assert np.all(q >= lo) and np.all(q <= hi)
    np.testing.assert_allclose(J @ q, s * x, atol=1e-7 * (1.0 + np.linalg.norm(x)))
    s_lp = _lp_scale(J, x, lo, hi)
    if np.linalg.matrix_rank(J[:, hi > lo]) == J.shape[0]:  # (locked joints may take the rank away)
        assert s == pytest.approx(s_lp, abs=1e-6)
    else:
        assert s <= s_lp + 1e-6


@settings(max_examples=120, deadline=None)
@given(well_conditioned(square=True), st.floats(0.5, 4.0))
def test_scale_is_continuous_and_homogeneous_in_the_task(p, k: float) -> None:
    """m = n: the zonotope {J qdot} is a fixed set, so the scale of k xdot is min(1, t / k) with t the exit of
    the ray along xdot: s(k x) k = min(k, s*(x)) whenever s*(x) < 1 (linprog for s*)."""
    J, x, lo, hi = p
    if np.linalg.matrix_rank(J[:, hi > lo]) < J.shape[0]:
        return
    s_star = _lp_scale(J, x, lo, hi)
    _, s = sns_velocity(J, k * x, lo, hi)
    assert s == pytest.approx(_lp_scale(J, k * x, lo, hi), abs=1e-6)
    if s_star < 1.0 - 1e-9:
        assert s * k == pytest.approx(min(k, s_star), abs=1e-6)


@st.composite
def rank_deficient(draw):
    """rank(J) = r < m (a product of Gaussians), or m > n; J of any magnitude."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if draw(st.booleans()):
        m = draw(st.integers(2, 4))
        n, r = draw(st.integers(m, 7)), draw(st.integers(0, m - 1))
        J = rng.normal(size=(m, r)) @ rng.normal(size=(r, n)) if r else np.zeros((m, n))
    else:
        n = draw(st.integers(1, 3))
        m = draw(st.integers(n + 1, 5))
        J = rng.normal(size=(m, n))
    c = 10.0 ** draw(st.sampled_from([-20, 0, 0, 20]))
    x = rng.normal(size=m) * draw(st.floats(0.05, 10.0))
    lo, hi = -rng.uniform(0.0, 2.0, n), rng.uniform(0.0, 2.0, n)
    return J * c, x * c, lo, hi


@settings(max_examples=200, deadline=None)
@given(rank_deficient())
def test_rank_deficient_realises_the_projection_of_the_task(p) -> None:
    """J qdot = s J J^+ xdot: the part of the task J can realise, scaled (numpy's pinv for J^+)."""
    J, x, lo, hi = p
    q, s = sns_velocity(J, x, lo, hi)
    assert np.all(q >= lo) and np.all(q <= hi) and 0.0 <= s <= 1.0
    scale = float(np.abs(J).max()) or 1.0
    proj = J @ (np.linalg.pinv(J / scale, rcond=1e-10) @ (x / scale))
    np.testing.assert_allclose((J / scale) @ q, s * proj / scale, atol=1e-7 * (1.0 + np.linalg.norm(x / scale)))
    q_pinv = np.linalg.pinv(J / scale, rcond=1e-10) @ (x / scale)
    if np.all(q_pinv >= lo + 1e-9) and np.all(q_pinv <= hi - 1e-9):  # the docstring: that solution, s = 1
        assert s == 1.0
        np.testing.assert_allclose(q, q_pinv, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(any_sns_problem())
def test_deterministic_and_inputs_left_alone(p) -> None:
    J, x, lo, hi, damping = p
    copies = [a.copy() for a in (J, x, lo, hi)]
    a = sns_velocity_unchecked(J, x, lo, hi, damping)
    b = sns_velocity_unchecked(J, x, lo, hi, damping)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1] or (math.isnan(a[1]) and math.isnan(b[1]))
    for before, after in zip(copies, (J, x, lo, hi), strict=True):
        np.testing.assert_array_equal(before, after)
    if np.all(np.isfinite(J)) and np.all(np.isfinite(x)) and np.all(lo <= hi) and math.isfinite(damping):
        r = sns_velocity_raw(J, x, lo, hi, damping)
        assert r[1] == a[1] or a[1] == 0.0  # the guard only ever replaces the solver's result by the safe one


_J, _X, _LO, _HI = np.ones((2, 3)), np.ones(2), -np.ones(3), np.ones(3)


@pytest.mark.parametrize(
    ("args", "name"),
    [
        pytest.param((_J > 0, _X, _LO, _HI), "J", id="J-bools"),
        pytest.param((_J + 1j, _X, _LO, _HI), "J", id="J-complex"),
        pytest.param(("abc", _X, _LO, _HI), "J", id="J-string"),
        pytest.param(([[1.0, True, 0.0], [0.0, 1.0, 0.0]], _X, _LO, _HI), "J", id="J-bool-in-list"),
        pytest.param((_J, None, _LO, _HI), "xdot", id="xdot-None"),
        pytest.param((_J, [1.0, [2.0, 3.0]], _LO, _HI), "xdot", id="xdot-ragged"),
        pytest.param((_J, ["1", "2"], _LO, _HI), "xdot", id="xdot-strings"),
        pytest.param((_J, _X, np.array([-1, -1, -1], dtype=object), _HI), "qdot_min", id="qdot_min-object"),
        pytest.param((_J, _X, _LO, _HI > 0), "qdot_max", id="qdot_max-bools"),
        pytest.param((_J, _X, _LO, "1"), "qdot_max", id="qdot_max-string"),
    ],
)
def test_sns_velocity_refuses_non_real_inputs_by_name(args, name: str) -> None:
    with pytest.raises(ValueError, match=f"^{name} must"):
        sns_velocity(*args)


# ----------------------------------------------------------------------------------------------- NSB


def _wpinv(J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Footnote 1 without damping, independently: ``W^1/2 (J W^1/2)^+`` = ``W J^T (J W J^T)^-1``."""
    h = np.sqrt(w)
    return h[:, None] * np.linalg.pinv(J * h)


def _nsb_reference(J, err, xd, sigma, Jo, lam, w, gg, go) -> np.ndarray:
    """eq. 5.8 from numpy's pseudo-inverses: the energy task first, the end-effector task in its null space."""
    qg = _wpinv(J, w) @ (xd + gg * err)
    Jo_p = np.linalg.pinv(Jo[None, :], rcond=1e-12)  # (n, 1); zero for a zero gradient
    qo = Jo_p[:, 0] * (go * (0.0 - sigma))
    N = np.eye(len(Jo)) - Jo_p @ Jo[None, :]
    return (1.0 - lam) * qg + lam * (qo + N @ qg)


@settings(max_examples=120, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 1.0, 0.5, 0.123]), st.sampled_from(["random", "zero", "tiny"]))
def test_nsb_velocity_priority_against_independent_projection(seed, lam, grad) -> None:
    rng = np.random.default_rng(seed)
    n, r = 8, 3
    J = rng.normal(size=(r, n))
    while np.linalg.cond(J) > 1e3:
        J = rng.normal(size=(r, n))
    Jo = {"random": rng.normal(size=n), "zero": np.zeros(n), "tiny": rng.normal(size=n) * 1e-8}[grad]
    err, xd, w = rng.normal(size=r) * 0.1, rng.normal(size=r) * 0.1, rng.uniform(0.1, 2.0, n)
    sigma, gg, go = rng.uniform(0.0, 0.05), rng.uniform(0.5, 10), rng.uniform(0.5, 10)
    t = nsb_velocity(J, err, xd, sigma, Jo, lam, w, gg, go, 0.0)
    want = _nsb_reference(J, err, xd, sigma, Jo, lam, w, gg, go)
    if grad == "tiny":  # ||J_o||^2 = 1e-16 is below the code's 1e-12 floor: a zero gradient there
        want = _nsb_reference(J, err, xd, sigma, np.zeros(n), lam, w, gg, go)
    np.testing.assert_allclose(t.qdot, want, atol=1e-10 * (1.0 + np.abs(want).max()))
    qg = _wpinv(J, w) @ (xd + gg * err)
    np.testing.assert_allclose(J @ t.qdot_g, xd + gg * err, atol=1e-9)  # the end-effector task alone
    if grad == "random":  # priority: the energy rate is lambda's mix, the end-effector task cannot disturb it
        assert Jo @ t.qdot == pytest.approx((1 - lam) * (Jo @ qg) + lam * (-go * sigma), abs=1e-10)
    else:  # no gradient: the end-effector task alone, whatever lambda
        np.testing.assert_allclose(J @ t.qdot, xd + gg * err, atol=1e-9)


def _jo_eq_5_7(d, rest, axes, jac) -> np.ndarray:
    """eqs. 5.6-5.7 written here: sum over compressed springs of (r_k - d_k) a_k^T J_k (NaN as 0 m)."""
    d = np.where(np.isnan(d), 0.0, np.maximum(d, 0.0))
    g = np.zeros(jac.shape[2])
    for k in np.flatnonzero(d <= rest):
        g += (rest - d[k]) * (axes[k] @ jac[k])
    return g


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["switch", "arctan", "linear"]), st.integers(0, 4))
def test_step_is_a_uniform_scaling_of_the_independent_nsb_solution(seed, kind, n_close) -> None:
    """The controller's command against eq. 5.8 from numpy's pseudo-inverses and J_o from eq. 5.7 written
    here: ``qdot = scale * reference`` with ``scale = min(1, 1 / max |ref| / qdot_max)``; with an obstacle
    within f (switch: lambda = 1) the energy falls at exactly ``-gamma_o sigma`` times the scale: the
    end-effector task does not disturb it, and the sensors that see something back off."""
    rng = np.random.default_rng(seed)
    cfg = NSBConfig(lambda_kind=kind, damping=0.0, rest=0.3)
    ctrl = NSBController(_youbot(), YOUBOT_SENSORS, cfg)
    q = YOUBOT_Q0 + rng.uniform(-0.3, 0.3, 8)
    st0 = ctrl.sensors.evaluate(q)
    d = np.full(10, INF)
    idx = rng.choice(10, n_close, replace=False)
    d[idx] = rng.uniform(0.0, 0.25, n_close)
    if n_close and rng.random() < 0.3:
        d[idx[0]] = NAN  # counts as 0 m
    x_d, v_d = st0.ee_position + rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
    out = ctrl.step(q, x_d, v_d, d)
    Jo = _jo_eq_5_7(d, 0.3, st0.axes, st0.jacobians)
    sigma = float(np.sum(0.5 * (np.minimum(np.where(np.isnan(d), 0.0, d), 0.3) - 0.3) ** 2))
    lam = weight(0.0 if n_close and np.isnan(d).any() else float(np.min(np.where(np.isnan(d), 0.0, d))), kind)
    assert out.lam == lam and out.sigma == pytest.approx(sigma, abs=1e-15)
    np.testing.assert_allclose(out.J_o, Jo, atol=1e-12)
    ref = _nsb_reference(st0.ee_jacobian, x_d - st0.ee_position, v_d, sigma, Jo, lam, ctrl.w, 5.0, 10.0)
    want_scale = min(1.0, 1.0 / np.max(np.abs(ref) / ctrl.qdot_max))
    assert out.scale == pytest.approx(want_scale, rel=1e-9)
    np.testing.assert_allclose(out.qdot, want_scale * ref, atol=1e-9)
    assert np.all(np.abs(out.qdot) <= ctrl.qdot_max * (1 + 1e-12))
    if lam == 1.0 and sigma > 0:
        assert Jo @ out.qdot == pytest.approx(-10.0 * sigma * out.scale, rel=1e-9, abs=1e-14)
        assert Jo @ out.qdot < 0.0  # repulsive: the compressed springs relax


@pytest.mark.parametrize(
    "target",
    [
        pytest.param(("x_d", [1e308, 0.0, 0.0]), id="x_d-near-max-float"),
        pytest.param(("x_d", [-1.7e308, 1.7e308, 0.0]), id="x_d-opposite-huge"),
        pytest.param(("xdot_d", [1.7e308, 1.7e308, -1.7e308]), id="xdot_d-huge"),
    ],
)
def test_overflowing_target_is_a_stop_not_a_nan_command(target) -> None:
    """Finite but huge targets: the unscaled command overflows; the controller stops (old code: NaN)."""
    ctrl = NSBController(_youbot(), YOUBOT_SENSORS)
    ee = ctrl.sensors.evaluate(YOUBOT_Q0).ee_position
    args = {"x_d": ee, "xdot_d": np.zeros(3)}
    args[target[0]] = np.array(target[1])
    d = np.full(10, INF)
    for fn in (ctrl.step, ctrl.step_reference):
        with np.errstate(over="ignore", invalid="ignore"):
            out = fn(YOUBOT_Q0, args["x_d"], args["xdot_d"], d)
        assert np.all(np.isfinite(out.qdot)) and np.all(np.abs(out.qdot) <= ctrl.qdot_max)
        with np.errstate(over="ignore", invalid="ignore"):
            overflows = not np.all(np.isfinite(5.0 * (args["x_d"] - ee) + args["xdot_d"]))
        if overflows:
            assert out.scale == 0.0 and np.all(out.qdot == 0.0)


_Q, _D = YOUBOT_Q0, np.full(10, INF)


@pytest.mark.parametrize(
    ("field", "args"),
    [
        pytest.param("distances", (_Q, None, None, np.ones(10, bool)), id="distances-bools"),
        pytest.param("distances", (_Q, None, None, ["0.1"] * 10), id="distances-strings"),
        pytest.param("distances", (_Q, None, None, np.ones(10) + 0j), id="distances-complex"),
        pytest.param("distances", (_Q, None, None, np.ones(9)), id="distances-short"),
        pytest.param("distances", (_Q, None, None, [0.1] * 9 + [True]), id="distances-bool-in-list"),
        pytest.param("x_d", (_Q, [True, False, True], None, _D), id="x_d-bools"),
        pytest.param("x_d", (_Q, "abc", None, _D), id="x_d-string"),
        pytest.param("xdot_d", (_Q, None, [0, 0, 0j], _D), id="xdot_d-complex"),
        pytest.param("q", (np.ones(8, bool), None, None, _D), id="q-bools"),
        pytest.param("q", (["0"] * 8, None, None, _D), id="q-strings"),
        pytest.param("q", (np.full(8, NAN), None, None, _D), id="q-nan"),
    ],
)
@pytest.mark.parametrize("method", ["step", "step_reference"])
def test_step_refuses_bad_inputs_naming_the_field(field, args, method) -> None:
    ctrl = NSBController(_youbot(), YOUBOT_SENSORS)
    ee = ctrl.sensors.evaluate(YOUBOT_Q0).ee_position
    q, x_d, v_d, d = args
    with pytest.raises(ValueError, match=field):
        getattr(ctrl, method)(q, ee if x_d is None else x_d, np.zeros(3) if v_d is None else v_d, d)


_JG, _E, _JO, _W = np.eye(3, 8), np.zeros(3), np.ones(8), np.ones(8)
_GOOD = {"J_g": _JG, "task_error": _E, "xdot_d": _E, "sigma": 0.0, "J_o": _JO, "lam": 0.5, "w": _W}


@pytest.mark.parametrize(
    ("field", "value"),
    [
        pytest.param("J_g", np.ones(8), id="J_g-1d"),
        pytest.param("J_g", np.eye(3, 8) > 0, id="J_g-bools"),
        pytest.param("task_error", np.zeros(1), id="task_error-broadcastable"),
        pytest.param("xdot_d", [0, NAN, 0], id="xdot_d-nan"),
        pytest.param("J_o", np.ones((1, 8)), id="J_o-2d"),
        pytest.param("w", 1.0, id="w-scalar"),
        pytest.param("w", np.zeros(8), id="w-zero"),
        pytest.param("sigma", NAN, id="sigma-nan"),
        pytest.param("sigma", -0.1, id="sigma-negative"),
        pytest.param("lam", 2.0, id="lam-above-1"),
        pytest.param("lam", True, id="lam-bool"),
        pytest.param("gamma_g", INF, id="gamma_g-inf"),
        pytest.param("damping", -1e-3, id="damping-negative"),
    ],
)
def test_nsb_velocity_refuses_bad_arguments_by_name(field, value) -> None:
    kw = dict(_GOOD, gamma_g=5.0, gamma_o=10.0, damping=1e-6)
    kw[field] = value
    with pytest.raises(ValueError, match=f"^{field} must"):
        nsb_velocity(**kw)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        pytest.param((True,), "d", id="d-bool"),
        pytest.param(("0.1",), "d", id="d-string"),
        pytest.param((np.array([0.1, 0.2]),), "d", id="d-array"),
        pytest.param((0.1, "arctan", NAN), "f", id="f-nan"),
        pytest.param((0.1, "arctan", 0.25, -1.0), "K", id="K-negative"),
        pytest.param((0.1, "linear", 0.25, 40.0, 0.0), "delta", id="delta-zero"),
        pytest.param((0.1, "linear", 0.25, 40.0, INF), "delta", id="delta-inf"),
    ],
)
def test_weight_refuses_non_numbers_and_bad_parameters(args, field) -> None:
    with pytest.raises(ValueError, match=field):
        weight(*args)


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from(["arctan", "linear"]), st.floats(-1.0, 2.0), st.floats(-1.0, 2.0),
    st.floats(0.05, 1.0), st.floats(1.0, 100.0), st.floats(0.01, 0.5),
)  # fmt: skip
def test_weight_is_lipschitz_with_the_papers_slope(kind, d1, d2, f, K, delta) -> None:
    """eq. 5.11: |d lambda / d d| <= K / pi; eq. 5.12: <= 1 / delta. Continuous, in [0, 1], non-increasing."""
    l1, l2 = weight(d1, kind, f, K, delta), weight(d2, kind, f, K, delta)
    slope = K / math.pi if kind == "arctan" else 1.0 / delta
    assert 0.0 <= l1 <= 1.0 and 0.0 <= l2 <= 1.0
    assert abs(l1 - l2) <= slope * abs(d1 - d2) * (1 + 1e-9) + 1e-12
    if d1 <= d2:
        assert l1 >= l2 - 1e-12
