"""The documented guarantees of the control modules, attacked with property tests.

Each test checks a claim of a docstring (or of docs/conventions.md, docs/ssm.md) against an *independent*
computation: closed forms of the papers and docs, an event-driven integration of the time-optimal
jerk-limited stop, forward kinematics of random chains, numpy's SVD. NaN, inf, wrong shapes, empty arrays,
extreme but legal values and random sequences (of distances, bounds, time stamps) are part of the draw.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from numba import njit

from depthguard.control.admittance import AdmittanceParams, admittance_step
from depthguard.control.body import body_bounds_inplace, body_velocity_bounds
from depthguard.control.bounded import braking_step, enforce_velocity_bounds
from depthguard.control.braking import joint_stopping, point_stopping_distance, stop_one
from depthguard.control.endeffector import dls_apply, dls_damping, dls_inverse, repulsive_velocity
from depthguard.control.inputs import check_inputs
from depthguard.control.linalg import _damped_pinv, _jacobi_svd
from depthguard.control.otg import OtgState
from depthguard.control.ssm import MonitorState, SsmConfig, SsmMonitor, reaction_time
from depthguard.control.types import ControllerConfig, CycleInput, CycleStatus
from depthguard.depthspace import PointDistances
from depthguard.pivot import PivotFilter, pivot
from depthguard.repulsion import magnitude, repulsive_vectors, risk

FAST = settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**32 - 1)


def _logistic(x: float) -> float:
    """1 / (1 + exp(x)) without overflow (independent of the code under test)."""
    if x > 0:
        e = math.exp(-x)
        return e / (1.0 + e)
    return 1.0 / (1.0 + math.exp(x))


# ==================================================================================== braking (closed forms)
@njit(cache=False)
def _adv(v, a, j, h):
    return v + a * h + j * h * h / 2.0, a + j * h


@njit(cache=False)
def _abs_path(v, a, j, h):
    """Integral of |v(t)| over [0, h] under constant jerk ``j`` (sub-steps where v changes sign)."""
    v1 = v + a * h + j * h * h / 2.0
    if v * v1 >= 0.0 and not (v == 0.0 and v1 == 0.0):
        if j != 0.0:  # one sign at both ends: v may still dip through 0 at its extremum
            te = -a / j
            if 0.0 < te < h:
                ve = v + a * te + j * te * te / 2.0
                if ve * v < 0.0:
                    return _abs_path(v, a, j, te) + _abs_path(ve, 0.0, j, h - te)
        return abs(v * h + a * h * h / 2.0 + j * h**3 / 6.0)
    total, m = 0.0, 256
    tt = h / m
    for _ in range(m):
        total += abs(v * tt + a * tt * tt / 2.0 + j * tt**3 / 6.0)
        v, a = _adv(v, a, j, tt)
    return total


@njit(cache=False)
def _integrated_stop(v, a, A, J, n_steps):
    """Independent integration of the time-optimal jerk-limited stop to rest: jerk ``-J sign(s)`` with the
    switching function ``s = v + a|a|/(2J)``, ``|a| <= A``, then the final arc along ``s = 0`` at jerk
    ``-J sign(a)``. Events (``|a|`` reaching ``A``, ``s`` crossing 0) are found within a step by bisection.
    Returns (time, path length)."""
    a = min(max(a, -A), A)
    vv = abs(v) + a * a / J  # (a step of the length of the whole stop, from a crude bound of its duration)
    h0 = (vv / A + 3.0 * abs(a) / J + 2.0 * np.sqrt(vv / J) + 1e-300) / n_steps
    t, path = 0.0, 0.0
    for _ in range(100 * n_steps):
        s = v + a * abs(a) / (2.0 * J)
        if s == 0.0:
            if a == 0.0:
                return t, path
            h = abs(a) / J
            return t + h, path + _abs_path(v, a, -J if a > 0 else J, h)
        j = -J if s > 0.0 else J
        if (a <= -A and j < 0.0) or (a >= A and j > 0.0):
            j = 0.0
        h = h0
        if j != 0.0:
            th = ((-A if j < 0 else A) - a) / j
            if 0.0 <= th < h:
                h = th
        v1, a1 = _adv(v, a, j, h)
        if (v1 + a1 * abs(a1) / (2.0 * J)) * s < 0.0:  # crossing the switching curve within the step
            lo, hi = 0.0, h
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                vm, am = _adv(v, a, j, mid)
                if (vm + am * abs(am) / (2.0 * J)) * s > 0.0:
                    lo = mid
                else:
                    hi = mid
            path += _abs_path(v, a, j, hi)
            v, a = _adv(v, a, j, hi)
            t += hi
            if a == 0.0:
                return t, path
            hf = abs(a) / J
            return t + hf, path + _abs_path(v, a, -J if a > 0 else J, hf)
        path += _abs_path(v, a, j, h)
        t += h
        v, a = v1, min(max(a1, -A), A)
    return np.nan, np.nan


@settings(deadline=None, max_examples=150)
@given(
    v=st.one_of(st.floats(-10.0, 10.0), st.floats(-1e-4, 1e-4), st.just(0.0)).filter(
        lambda x: x == 0 or abs(x) > 1e-50
    ),  # (far below, the reference's own arithmetic underflows)
    a_frac=st.one_of(st.floats(-1.0, 1.0), st.just(0.0), st.sampled_from([-1.0, 1.0])).filter(
        lambda x: x == 0 or abs(x) > 1e-12
    ),
    log_a=st.floats(-2.0, 3.0),
    log_j=st.floats(0.0, 5.0),
)
@example(v=0.5, a_frac=-1.0, log_a=2.0975402094631076e-16, log_j=0.0)
def test_braking_stop_is_the_integrated_time_optimal_stop(v, a_frac, log_a, log_j):
    """braking.stop_one: 'exact for Ruckig's time-optimal velocity-mode stop', so never below the path
    length or the time of an independent integration of that stop, and equal to them, over extreme but
    legal limits (A from 0.01 to 1000, J from 1 to 1e5)."""
    A, J = 10.0**log_a, 10.0**log_j
    a = a_frac * A
    t_ref, p_ref = _integrated_stop(v, a, A, J, 2000)
    t, p = stop_one(v, a, A, J)
    # (1e-6 relative for the time too: where the speed left is just the ramp-down's A^2/(2J), both take the
    # square root of a difference that rounding leaves at 1e-16, and differ by 1e-7: v=0.5, a=-A, A=J=1)
    assert t >= t_ref * (1 - 1e-6) - 1e-15 and p >= p_ref * (1 - 1e-6) - 1e-15
    assert t == pytest.approx(t_ref, rel=1e-6, abs=1e-15)
    assert p == pytest.approx(p_ref, rel=1e-6, abs=1e-15)


@pytest.mark.parametrize("v, a", [(np.inf, 0.0), (-np.inf, 1.0), (np.nan, 0.0), (1.0, np.nan), (0.0, np.inf)])
def test_braking_of_a_non_finite_state_is_an_infinite_bound(v, a):
    """An upper bound of the stop of an unknown (non-finite) motion can only be inf, never NaN (NaN compares
    False with everything: the separation test S >= S_p would pass on it)."""
    t, p = stop_one(v, a, 10.0, 500.0)
    assert t == np.inf and p == np.inf
    js = joint_stopping(np.array([v, 0.5]), np.array([a, 0.0]), 10.0, 500.0)
    assert js.time[0] == np.inf and js.travel[0] == np.inf and np.isfinite(js.travel[1])


def _rodrigues(axis, angle):
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def _chain_fk(q, axes, links, prismatic):
    """Positions of every joint origin and of the tip of a serial chain (revolute about ``axes`` in the
    parent frame, or prismatic along them), links (n, 3) from joint i to joint i+1 (the last to the tip)."""
    R, p = np.eye(3), np.zeros(3)
    origins, world_axes = [], []
    for i in range(len(q)):
        origins.append(p.copy())
        world_axes.append(R @ axes[i])
        if prismatic[i]:
            p = p + R @ axes[i] * q[i]
        else:
            R = R @ _rodrigues(axes[i], q[i])
        p = p + R @ links[i]
    return np.array(origins), np.array(world_axes), p


@settings(deadline=None, max_examples=40)
@given(seeds, st.integers(1, 7), st.booleans())
@example(372088, 3, True)  # a revolute joint before a prismatic one (found with fresh seeds)
def test_point_stopping_distance_bounds_the_path_of_random_chains(seed, n, with_prismatic):
    """braking.point_stopping_distance: 'upper bound of the path length of every control point while the
    joints travel ``travel``', for any joint motion within those travels: random 3-D chains (random axes,
    link lengths from 0 to 1 m), the joints moving together, one after the other in random order, or back
    and forth (the travel is the unsigned path), checked by dense forward kinematics."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    links = rng.normal(size=(n, 3)) * rng.uniform(0.0, 1.0, (n, 1))
    prismatic = (rng.uniform(size=n) < 0.3) if with_prismatic else np.zeros(n, bool)
    q0 = rng.uniform(-np.pi, np.pi, n)
    travel = rng.uniform(0.0, 1.5, n) * (rng.uniform(size=n) < 0.8)
    origins, w_axes, tip = _chain_fk(q0, axes, links, prismatic)
    jac = np.where(prismatic[:, None], w_axes, np.cross(w_axes, tip - origins)).T[None]  # (1, 3, n)
    # chain length from joint j to the tip along the whole motion (triangle inequality): the links, and the
    # extension of every prismatic joint after j (its position and its travel)
    ext = (np.abs(q0) + travel) * prismatic
    lengths = np.array([[np.linalg.norm(links[j:], axis=1).sum() + ext[j + 1 :].sum() for j in range(n)]])
    bound = point_stopping_distance(jac, travel, lengths, prismatic if with_prismatic else None)[0]
    sign = rng.choice([-1.0, 1.0], n)
    for mode in ("together", "sequential", "back_and_forth"):
        s = np.linspace(0.0, 1.0, 600)
        if mode == "together":
            dq = np.outer(s, sign * travel)
        elif mode == "sequential":
            order = rng.permutation(n)
            dq = np.zeros((len(s) * n, n))
            done = np.zeros(n)
            for k, j in enumerate(order):
                dq[k * len(s) : (k + 1) * len(s)] = done
                dq[k * len(s) : (k + 1) * len(s), j] = s * sign[j] * travel[j]
                done[j] = sign[j] * travel[j]
        else:  # half the travel out and back
            tri = np.minimum(s, 1.0 - s)
            dq = np.outer(tri, sign * travel)
        tips = np.array([_chain_fk(q0 + d, axes, links, prismatic)[2] for d in dq])
        path = np.linalg.norm(np.diff(tips, axis=0), axis=1).sum()
        assert bound >= path - 1e-9, (mode, bound, path)


# ================================================================================================ SSM
def _rest_stop(v: float, A: float, J: float) -> tuple[float, float]:
    """Closed forms of docs (braking module docstring), from speed v >= 0 with zero acceleration."""
    T = v / A + A / J if v >= A * A / J else 2.0 * math.sqrt(v / J)
    return T, (v * T / 2.0 if v >= A * A / J else v * math.sqrt(v / J))


def _s_p_reference(s, jac, L, qd, qn, d, dirs, A, Jm, cfg, T_r):
    """ISO/TS 15066 eq. 1 as docs/ssm.md writes it, for zero joint accelerations, at scale ``s``. The
    direction is unknown (worst case: straight at the obstacle) where it is not a finite nonzero vector and
    where the distance is +inf (the person may be anywhere at the sensing range)."""
    N, _, n = jac.shape
    v = np.maximum(np.abs(qd), s * np.abs(qn))
    stops = [_rest_stop(v[j], A[j], Jm[j]) for j in range(n)]
    T_s = max([t for t, _ in stops], default=0.0)
    travel = np.array([d for _, d in stops])
    out = np.empty(N)
    for k in range(N):
        lever0 = np.linalg.norm(jac[k], axis=0)
        S_s = 0.0
        for j in range(n):
            S_s += min(L[k, j], lever0[j] + np.sum(L[k, j + 1 :] * travel[j + 1 :])) * travel[j]
        u = dirs[k]
        if d[k] != np.inf and np.all(np.isfinite(u)) and np.linalg.norm(u) > 0:
            u = u / np.linalg.norm(u)
            v_r = max(max(0.0, -u @ jac[k] @ qd), s * max(0.0, -u @ jac[k] @ qn))
        else:  # unknown direction: straight at the obstacle (worst case)
            v_r = max(np.linalg.norm(jac[k] @ qd), s * np.linalg.norm(jac[k] @ qn))
        rest = v_r * T_r + S_s + cfg.constant_terms
        near = cfg.v_h_near * (T_r + T_s) + rest
        out[k] = near if near <= cfg.near_limit else max(cfg.v_h_far * (T_r + T_s) + rest, cfg.near_limit)
    return out


@st.composite
def ssm_cases(draw):
    seed = draw(seeds)
    rng = np.random.default_rng(seed)
    N, n = draw(st.integers(1, 4)), draw(st.integers(1, 7))
    jac = rng.normal(size=(N, 3, n)) * rng.uniform(0.0, 0.8)
    L = np.linalg.norm(jac, axis=1) + rng.uniform(0.0, 0.5, (N, n))
    qd = rng.uniform(-2.0, 2.0, n) * draw(st.sampled_from([0.0, 0.1, 1.0]))
    qn = rng.uniform(-3.0, 3.0, n) * draw(st.sampled_from([0.0, 1.0, 5.0]))
    d = rng.uniform(-0.1, 1.5, N)
    d[rng.uniform(size=N) < 0.2] = np.inf
    d[rng.uniform(size=N) < 0.1] = np.nan
    dirs = rng.normal(size=(N, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[rng.uniform(size=N) < 0.15] = np.nan
    dirs[np.isinf(d) & (rng.uniform(size=N) < 0.5)] = 0.0  # what check_inputs hands on for +inf distances
    A, Jm = rng.uniform(1.0, 30.0, n), rng.uniform(50.0, 3000.0, n)
    rng_ = draw(st.sampled_from([np.inf, 0.4, 0.6, 2.0]))
    cfg = SsmConfig(camera_period=draw(st.sampled_from([1 / 30, 0.1, 0.3])), sensing_range=rng_)
    return jac, L, qd, qn, d, dirs, A, Jm, cfg


@settings(deadline=None, max_examples=120)
@given(ssm_cases())
def test_ssm_separation_and_scale_match_iso_ts_15066(case):
    """ssm: S_p,k is ISO/TS 15066 eq. 1 with ISO 13855 v_h (2.0 where S_p <= 0.5 m, else 1.6 and at least
    0.5 m); a +inf distance counts as ``sensing_range``, NaN as 0; the scale is the largest s in [0, 1] with
    S_k >= S_p,k(s) to the bisection's 1/4096; s = 0 is a protective stop; margin = separation - S_p.
    All checked against the formula evaluated here (closed-form stops, zero accelerations)."""
    jac, L, qd, qn, d, dirs, A, Jm, cfg = case
    out = SsmMonitor(L, A, Jm, cfg).update(jac, qd, np.zeros_like(qd), qn, d, dirs)
    T_r = reaction_time(cfg)
    d_eff = np.minimum(np.nan_to_num(d, nan=0.0, posinf=np.inf), cfg.sensing_range)
    assert 0.0 <= out.scale <= 1.0
    np.testing.assert_allclose(out.separation, d_eff, rtol=0, atol=0)
    np.testing.assert_array_equal(out.margin, out.separation - out.s_p)
    ref = _s_p_reference(out.scale, jac, L, qd, qn, d, dirs, A, Jm, cfg, T_r)
    np.testing.assert_allclose(out.s_p, ref, rtol=1e-9, atol=1e-12)
    at_rest = _s_p_reference(0.0, jac, L, qd, qn, d, dirs, A, Jm, cfg, T_r)
    if np.any(d_eff < at_rest):
        assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0
        return
    assert out.state != MonitorState.PROTECTIVE_STOP
    assert np.all(d_eff >= ref)
    assert (out.state == MonitorState.MONITOR_OK) == (out.scale == 1.0)
    if out.scale < 1.0:  # a scale 1/4096 larger would break S >= S_p somewhere
        beyond = _s_p_reference(min(1.0, out.scale + 1.0001 / 4096), jac, L, qd, qn, d, dirs, A, Jm, cfg, T_r)
        assert np.any(d_eff < beyond)
    finite = np.isfinite(out.margin)
    if finite.any():
        assert out.binding == int(np.flatnonzero(finite)[np.argmin(out.margin[finite])])


def test_ssm_a_point_with_nothing_within_sensing_range_counts_its_speed_in_any_direction():
    """docs/ssm.md: +inf is a lower bound of ``sensing_range``, not of infinity: the person may stand at
    that range in *any* direction, so the point's whole speed counts as approach (S_r = |J qdot| T_r), as
    for a non-finite direction. check_inputs hands the monitor a zero direction for +inf distances: that
    must not count as 'moving sideways'."""
    cfg = SsmConfig(sensing_range=0.6)
    jac = np.zeros((1, 3, 1))
    jac[0, 0, 0] = 0.5
    qd = np.array([1.0])  # 0.5 m/s
    worst = None
    for u in ([-1.0, 0.0, 0.0], [np.nan] * 3):  # straight at the obstacle; unknown
        out = SsmMonitor(np.array([[0.5]]), [10.0], [500.0], cfg).update(
            jac, qd, np.zeros(1), qd, np.array([np.inf]), np.array([u])
        )
        worst = out.s_p[0] if worst is None else max(worst, out.s_p[0])
    for u in ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]):
        out = SsmMonitor(np.array([[0.5]]), [10.0], [500.0], cfg).update(
            jac, qd, np.zeros(1), qd, np.array([np.inf]), np.array([u])
        )
        assert out.s_p[0] >= worst - 1e-12, u


@pytest.mark.parametrize("field", ["qdot", "qddot", "jacobians", "qdot_nominal"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_ssm_a_non_finite_motion_never_allows_motion(field, bad):
    """S_p of an unknown (non-finite) motion is unknown: the monitor must stop, never report MONITOR_OK on a
    NaN S_p (NaN >= S_p and NaN < S_p are both False)."""
    jac = np.zeros((2, 3, 2))
    jac[:, 0, :] = 0.4
    args = dict(jacobians=jac, qdot=np.zeros(2), qddot=np.zeros(2), qdot_nominal=np.full(2, 0.1))
    arr = np.array(args[field], dtype=float)
    arr.reshape(-1)[0] = bad
    args[field] = arr
    mon = SsmMonitor(np.full((2, 2), 0.8), 10.0, 500.0, SsmConfig())
    out = mon.update(**args, distances=np.array([0.8, 0.9]), directions=np.tile([1.0, 0.0, 0.0], (2, 1)))
    assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0


@st.composite
def distance_sequences(draw):
    n_steps = draw(st.integers(1, 40))
    vals = st.one_of(st.floats(-0.5, 1.0), st.just(np.inf), st.just(np.nan), st.just(-np.inf), st.floats(0.25, 0.35))
    return [np.array(draw(st.lists(vals, min_size=2, max_size=2))) for _ in range(n_steps)]


@settings(deadline=None, max_examples=80)
@given(distance_sequences(), st.floats(0.0, 0.2), st.sampled_from([np.inf, 0.3, 1.0]))
def test_ssm_protective_stop_follows_its_hysteresis(seq, hyst, sensing_range):
    """The monitor's state machine against an oracle from the docstring, on random sequences of distances
    (NaN, -inf, negative, inf, values around S_p): a stop begins when some S_k < S_p,k at rest and ends only
    on the update where every S_k >= S_p,k(rest) + hysteresis (``stop_ended`` exactly then); while stopped
    the scale is 0; otherwise the scale keeps S >= S_p (robot at rest, so S_p at rest is the ISO 13855 case)."""
    cfg = SsmConfig(hysteresis=hyst, sensing_range=sensing_range)
    jac = np.zeros((2, 3, 1))
    jac[:, 1, 0] = 0.3
    mon = SsmMonitor(np.full((2, 1), 0.3), 10.0, 500.0, cfg)
    rest = min(max(cfg.v_h_near * reaction_time(cfg) + cfg.constant_terms, 0.0), 10.0)
    assert rest <= cfg.near_limit
    dirs = np.tile([0.0, -1.0, 0.0], (2, 1))
    stopped = False
    for d in seq:
        d_eff = np.minimum(np.nan_to_num(d, nan=0.0), sensing_range)
        out = mon.update(jac, np.zeros(1), np.zeros(1), np.array([0.5]), d, dirs)
        if stopped:
            ended = bool(np.all(d_eff >= rest + hyst))
            stopped = not ended
        else:
            ended = False
            stopped = bool(np.any(d_eff < rest))
        assert out.stop_ended == ended
        assert (out.state == MonitorState.PROTECTIVE_STOP) == stopped
        if stopped:
            assert out.scale == 0.0
        else:
            assert np.all(out.margin[np.isfinite(out.margin)] >= 0.0)


@pytest.mark.parametrize(
    "field, make",
    [
        ("distances", lambda N, n: dict(distances=np.full(N - 1, 1.0))),
        ("distances", lambda N, n: dict(distances=np.zeros(0))),
        ("directions", lambda N, n: dict(directions=np.zeros((N, 2)))),
        ("jacobians", lambda N, n: dict(jacobians=np.zeros((N - 1, 3, n)))),
        ("jacobians", lambda N, n: dict(jacobians=np.zeros((N, 3, n + 1)))),
        ("qdot", lambda N, n: dict(qdot=np.zeros(n - 1))),
        ("qddot", lambda N, n: dict(qddot=np.zeros(n + 2))),
        ("qdot_nominal", lambda N, n: dict(qdot_nominal=np.zeros((n, 1)))),
        ("obstacle_speed", lambda N, n: dict(obstacle_speed=np.zeros(N + 1))),
    ],
)
def test_ssm_a_wrong_shape_gets_a_value_error_naming_the_field(field, make):
    """docs/conventions.md (safety principle 4): bad input gets a clear error naming the field; the compiled
    kernel does not check bounds, so a short array would be read past its end (garbage distances)."""
    N, n = 3, 2
    args = dict(
        jacobians=np.zeros((N, 3, n)), qdot=np.zeros(n), qddot=np.zeros(n), qdot_nominal=np.zeros(n),
        distances=np.full(N, 1.0), directions=np.zeros((N, 3)),
    )  # fmt: skip
    args.update(make(N, n))
    mon = SsmMonitor(np.full((N, n), 0.5), 10.0, 500.0)
    with pytest.raises(ValueError, match=field):
        mon.update(**args)


@settings(deadline=None, max_examples=40)
@given(
    st.one_of(st.floats(-5.0, 50.0), st.just(np.nan), st.just(np.inf), st.just(-np.inf)),
    st.one_of(st.floats(-1.0, 1.0), st.just(np.nan), st.just(np.inf), st.just(1e9)),
)
def test_ssm_measured_obstacle_speed_and_data_age(v_obs, age):
    """A measured obstacle speed replaces ISO 13855's v_h but never below ``v_h_floor`` (NaN or +inf: a stop);
    the outputs are shifted to now by (v_h + v_r) a; a NaN, +inf or huge age stops, a negative one is fresh."""
    cfg = SsmConfig()
    jac = np.zeros((1, 3, 1))
    jac[0, 0, 0] = 0.5
    out = SsmMonitor(np.array([[0.5]]), 10.0, 500.0, cfg).update(
        jac, np.zeros(1), np.zeros(1), np.zeros(1), np.array([1.0]), np.array([[1.0, 0, 0]]),
        data_age=age, obstacle_speed=np.array([v_obs]),
    )  # fmt: skip
    a = 0.0 if age < 0 else (age if math.isfinite(age) else 1e3)
    T_r = max(cfg.camera_period, a) + cfg.processing_latency + cfg.communication_latency + cfg.control_period
    if math.isnan(v_obs) or v_obs == np.inf or a > 1.0:
        assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0
        return
    if v_obs >= 0:
        v_h = max(v_obs, cfg.v_h_floor)
        sp = v_h * T_r + cfg.constant_terms
    else:  # not measured (a negative speed): ISO 13855
        sp = cfg.v_h_near * T_r + cfg.constant_terms
        if sp > cfg.near_limit:
            sp = max(cfg.v_h_far * T_r + cfg.constant_terms, cfg.near_limit)
        # the shift to now: 'where the far branch is clamped to exactly near_limit this takes the larger near
        # speed' (ssm_kernels._to_now)
        v_h = cfg.v_h_near if sp <= cfg.near_limit else cfg.v_h_far
    assert out.s_p[0] == pytest.approx(sp - v_h * a, rel=1e-12, abs=1e-12)
    assert out.separation[0] == pytest.approx(1.0 - v_h * a, rel=1e-12, abs=1e-12)
    assert (out.state == MonitorState.PROTECTIVE_STOP) == (1.0 < sp)


# =============================================================================================== body
@st.composite
def body_cases(draw):
    rng = np.random.default_rng(draw(seeds))
    N, n = draw(st.integers(0, 5)), draw(st.integers(1, 7))
    jac = rng.normal(size=(N, 3, n)) * rng.uniform(0.0, 1.0)
    jac[rng.uniform(size=(N, 3, n)) < 0.2] = 0.0
    d = rng.uniform(-0.0, 0.6, N) * rng.choice([1.0, 1e-3], N)
    d[rng.uniform(size=N) < 0.2] = np.inf
    dirs = rng.normal(size=(N, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[np.isinf(d)] = np.nan  # ignored where the distance is inf
    vmax = rng.uniform(0.1, 5.0, n)
    rho, alpha = rng.uniform(0.05, 1.0), draw(st.sampled_from([0.5, 6.0, 50.0]))
    use = rng.uniform(size=N) < 0.8
    contact = draw(st.sampled_from([0.0, 0.02, 0.1]))
    return jac, d, dirs, vmax, rho, alpha, use, contact


@settings(deadline=None, max_examples=100)
@given(body_cases())
def test_body_bounds_limit_every_motion_towards_an_obstacle(case):
    """body (ICRA'12 eqs. 12-14): for every used point within rho and every joint that moves it along n
    (|J^T n|_i > eps), the joint's velocity towards the obstacle is at most V_max (1 - f(D)) (0 at or below
    contact), f computed here; motion away keeps V_max unless another point restricts it; always
    -v_max <= qdot_min <= 0 <= qdot_max <= v_max."""
    jac, d, dirs, vmax, rho, alpha, use, contact = case
    lo, hi = body_velocity_bounds(jac, d, dirs, vmax, rho, alpha, use=use, contact_distance=contact)
    assert np.all(-vmax <= lo) and np.all(lo <= 0) and np.all(hi >= 0) and np.all(hi <= vmax)
    want_lo, want_hi = -vmax.copy(), vmax.copy()
    for k in range(len(d)):
        if not use[k] or not d[k] < rho:
            continue
        keep = 0.0 if d[k] <= contact else 1.0 - _logistic((2.0 * d[k] / rho - 1.0) * alpha)
        g = jac[k].T @ dirs[k]
        want_lo = np.where(g > 1e-6, np.maximum(want_lo, -vmax * keep), want_lo)
        want_hi = np.where(g < -1e-6, np.minimum(want_hi, vmax * keep), want_hi)
    np.testing.assert_allclose(lo, want_lo, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(hi, want_hi, rtol=1e-12, atol=1e-15)
    # any velocity within the bounds moves each restricted point towards its obstacle at most this fast
    for k in range(len(d)):
        if use[k] and d[k] < rho:
            g = jac[k].T @ dirs[k]
            worst = np.where(g > 1e-6, g * lo, np.where(g < -1e-6, g * hi, 0.0))  # most negative g_i qdot_i
            keep = 0.0 if d[k] <= contact else 1.0 - _logistic((2.0 * d[k] / rho - 1.0) * alpha)
            assert np.all(worst >= -np.abs(g) * vmax * keep - 1e-12)


@settings(deadline=None, max_examples=60)
@given(body_cases(), seeds)
def test_body_bounds_never_loosen(case, seed):
    """'The most restrictive bound over all points': nearer obstacles, more points, or prior bounds given to
    body_bounds_inplace only ever tighten the bounds."""
    jac, d, dirs, vmax, rho, alpha, use, contact = case
    rng = np.random.default_rng(seed)
    lo, hi = body_velocity_bounds(jac, d, dirs, vmax, rho, alpha, use=use, contact_distance=contact)
    nearer = np.where(np.isfinite(d), d * rng.uniform(0.0, 1.0, len(d)), d)
    lo2, hi2 = body_velocity_bounds(jac, nearer, dirs, vmax, rho, alpha, use=use, contact_distance=contact)
    assert np.all(lo2 >= lo - 1e-15) and np.all(hi2 <= hi + 1e-15)
    lo3, hi3 = body_velocity_bounds(jac, d, dirs, vmax, rho, alpha, use=np.ones(len(d), bool), contact_distance=contact)
    assert np.all(lo3 >= lo) and np.all(hi3 <= hi)
    prior_lo, prior_hi = -vmax * rng.uniform(0, 1, len(vmax)), vmax * rng.uniform(0, 1, len(vmax))
    a, b = prior_lo.copy(), prior_hi.copy()
    dist0 = np.ascontiguousarray(d)
    dirs0 = np.ascontiguousarray(np.nan_to_num(dirs))
    body_bounds_inplace(jac, dist0, dirs0, use, vmax, rho, alpha, contact, 1e-6, a, b)
    assert np.all(a >= prior_lo) and np.all(b <= prior_hi)
    np.testing.assert_array_equal(a, np.maximum(prior_lo, lo))
    np.testing.assert_array_equal(b, np.minimum(prior_hi, hi))


@pytest.mark.parametrize(
    "field, kw",
    [
        ("jacobians", dict(jacobians=np.full((2, 3, 3), np.nan))),
        ("use", dict(use=np.array([True]))),
        ("use", dict(use=np.ones((2, 1), bool))),
        ("v_max", dict(v_max=np.full(3, np.inf))),
        ("alpha", dict(alpha=np.inf)),
        ("rho", dict(rho=np.nan)),
        ("contact_distance", dict(contact_distance=np.nan)),
        ("influence_eps", dict(influence_eps=np.nan)),
        ("influence_eps", dict(influence_eps=-1.0)),
        ("distances", dict(distances=np.array([0.1, np.nan]))),
        ("directions", dict(directions=np.array([[np.nan, 0, 0], [1.0, 0, 0]]))),
        pytest.param("rho", dict(rho="0.4"), id="rho-string"),
        pytest.param("alpha", dict(alpha=True), id="alpha-bool"),
        pytest.param("contact_distance", dict(contact_distance=-0.1), id="contact-negative"),
        pytest.param("contact_distance", dict(contact_distance=np.inf), id="contact-inf"),
        pytest.param("contact_distance", dict(contact_distance="0"), id="contact-string"),
        pytest.param("influence_eps", dict(influence_eps=False), id="eps-bool"),
        pytest.param("jacobians", dict(jacobians=[[["a"] * 3] * 3] * 2), id="jacobians-strings"),
        pytest.param("distances", dict(distances=np.array([0.1, -np.inf])), id="distances-minus-inf"),
        pytest.param("distances", dict(distances=[True, False]), id="distances-bools"),
        pytest.param("v_max", dict(v_max=np.zeros(3)), id="v_max-zero"),
    ],
)
def test_body_bounds_bad_input_gets_a_value_error_naming_the_field(field, kw):
    """Before: a NaN Jacobian or influence_eps imposed nothing (motion towards a touching obstacle allowed),
    a short ``use`` was read past its end, ``v_max = inf`` gave inf bounds at contact (inf * 0 = NaN); (stop
    50) a negative contact_distance allowed motion towards a touching obstacle (V_max (1 - f(0))), a string
    rho raised TypeError, a bool read as 1, a string array raised numpy's unnamed error."""
    args = dict(
        jacobians=np.ones((2, 3, 3)), distances=np.array([0.0, 0.1]), directions=np.tile([1.0, 0, 0], (2, 1)),
        v_max=np.ones(3), rho=0.4, alpha=6.0,
    )  # fmt: skip
    args.update(kw)
    with pytest.raises(ValueError, match=field):
        body_velocity_bounds(**args)


# ============================================================================================= bounded
@st.composite
def bound_cases(draw):
    rng = np.random.default_rng(draw(seeds))
    n = draw(st.integers(1, 6))
    a_max, j_max = rng.uniform(0.5, 50.0, n), 10.0 ** rng.uniform(1.0, 5.0, n)
    dt = draw(st.sampled_from([1e-4, 1e-3, 4e-3]))
    lo = -rng.uniform(0.0, 3.0, n) * rng.choice([1.0, 0.0, 1e-6], n)
    hi = rng.uniform(0.0, 3.0, n) * rng.choice([1.0, 0.0, 1e-6], n)
    if draw(st.booleans()):  # bounds away from 0 (a bound may exclude rest)
        shift = rng.uniform(-2.0, 2.0, n)
        lo, hi = lo + shift, hi + shift
    v0 = rng.uniform(-4.0, 4.0, n)
    a0 = rng.uniform(-1.5, 1.5, n) * a_max  # beyond the limit too: clipped
    pp, vp, ap = rng.normal(size=n), v0 + rng.normal(size=n) * rng.choice([1e-3, 1.0], n), rng.normal(size=n) * 10
    return n, a_max, j_max, dt, lo, hi, rng.normal(size=n), v0, a0, pp, vp, ap


@settings(deadline=None, max_examples=200)
@given(bound_cases())
def test_bounded_command_within_bounds_and_limits_unless_reported(case):
    """bounded.enforce_velocity_bounds on arbitrary planned states (not only Ruckig's): the velocity lies
    within [lo, hi] exactly; a joint planned within its bounds is kept as planned; a corrected joint in an
    unreported cycle took the constant-jerk step (recomputed here) within the acceleration and jerk limits,
    ending with an acceleration that does not push further out; a reported cycle had a joint for which no
    such step exists (checked independently)."""
    n, a_max, j_max, dt, lo, hi, p0, v0, a0, pp, vp, ap = case
    new, limited = enforce_velocity_bounds(OtgState(p0, v0, a0), OtgState(pp, vp, ap), lo, hi, a_max, j_max, dt)
    assert np.all(new.velocity >= lo) and np.all(new.velocity <= hi)
    inside = (vp >= lo - 1e-12) & (vp <= hi + 1e-12)
    np.testing.assert_array_equal(new.position[inside], pp[inside])
    np.testing.assert_array_equal(new.acceleration[inside], ap[inside])
    np.testing.assert_allclose(new.velocity[inside], np.clip(vp, lo, hi)[inside], rtol=0, atol=0)
    a0c = np.clip(a0, -a_max, a_max)
    a_lo, a_hi = np.maximum(a0c - j_max * dt, -a_max), np.minimum(a0c + j_max * dt, a_max)
    over, under = vp > hi + 1e-12, vp < lo - 1e-12
    # does a constant-jerk step exist that lands within the bounds, not pushing further out?
    v_reach_lo, v_reach_hi = v0 + 0.5 * (a0c + a_lo) * dt, v0 + 0.5 * (a0c + a_hi) * dt
    possible_over = (
        (a_lo <= 0) & (v_reach_lo <= hi + 1e-12) & (v0 + 0.5 * (a0c + np.minimum(a_hi, 0)) * dt >= lo - 1e-12)
    )
    possible_under = (
        (a_hi >= 0) & (v_reach_hi >= lo - 1e-12) & (v0 + 0.5 * (a0c + np.maximum(a_lo, 0)) * dt <= hi + 1e-12)
    )
    feasible = np.where(over, possible_over, np.where(under, possible_under, True))
    if not limited:
        fixed = over | under
        a_new = new.acceleration[fixed]
        assert np.all(np.abs(a_new) <= a_max[fixed] * (1 + 1e-12))
        assert np.all(np.abs(a_new - a0c[fixed]) <= j_max[fixed] * dt * (1 + 1e-9) + 1e-12)
        assert np.all(a_new[over[fixed]] <= 0) and np.all(a_new[under[fixed]] >= 0)
        v_int = v0 + 0.5 * (a0c + new.acceleration) * dt
        p_int = p0 + v0 * dt + a0c * dt * dt / 2 + (new.acceleration - a0c) * dt * dt / 6
        np.testing.assert_allclose(new.velocity[fixed], np.clip(v_int, lo, hi)[fixed], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(new.position[fixed], p_int[fixed], rtol=1e-12, atol=1e-12)
        assert np.all(feasible[fixed] | (np.abs(v_int - np.clip(v_int, lo, hi)) <= 1e-12)[fixed])
    else:
        assert np.any(~feasible), (feasible, over, under)


@settings(deadline=None, max_examples=60)
@given(
    st.lists(st.one_of(st.floats(-5, 5), st.just(np.nan), st.just(np.inf)), min_size=3, max_size=3),
    st.lists(st.one_of(st.floats(-20, 20), st.just(-np.inf), st.just(np.nan)), min_size=3, max_size=3),
    st.sampled_from([1e-3, 1e-4]),
)
def test_braking_step_is_a_jerk_limited_stop(v, a, dt):
    """bounded.braking_step: finite for any state (non-finite entries as 0); each step within the
    acceleration and jerk limits; a velocity never changes sign; the joints come to rest (velocity 0)
    within the time-optimal stop's time plus a few periods, the ramp to a = 0 included."""
    A, J = np.array([10.0, 3.0, 40.0]), np.array([500.0, 100.0, 5000.0])
    s = OtgState(np.zeros(3), np.array(v), np.array(a))
    v0 = np.nan_to_num(s.velocity, nan=0.0, posinf=0.0, neginf=0.0)
    a0 = np.clip(np.nan_to_num(s.acceleration, nan=0.0, posinf=0.0, neginf=0.0), -A, A)
    t_opt = max(stop_one(v0[i], a0[i], A[i], J[i])[0] for i in range(3))
    prev_a, prev_v = a0, v0
    k = 0
    while k * dt < t_opt + 50 * dt + 2 * np.max(A / J):
        s = braking_step(s, A, J, dt)
        assert np.all(np.isfinite(s.position)) and np.all(np.isfinite(s.velocity))
        assert np.all(np.abs(s.acceleration) <= A * (1 + 1e-12))
        assert np.all(np.abs(s.acceleration - prev_a) <= J * dt * (1 + 1e-9))
        assert np.all(s.velocity * v0 >= 0)
        assert np.all(np.abs(s.velocity) <= np.abs(prev_v) + 1e-12) or np.any(a0 * v0 > 0)
        prev_a, prev_v = s.acceleration, s.velocity
        k += 1
    assert np.all(s.velocity == 0.0)


# ============================================================================================== inputs
DT = 0.001
CFG = ControllerConfig()
N_PTS, N_J, M = 3, 7, 3


def _valid(t=1.0):
    return dict(
        t=t, q=np.zeros(N_J), qdot=np.zeros(N_J), t_joints=t, xdot_d=np.zeros(M),
        distances=np.array([0.5, np.inf, 0.2]), directions=np.tile([1.0, 0.0, 0.0], (N_PTS, 1)), t_distances=t,
    )  # fmt: skip


GARBAGE = [
    None, "x", "1.0", b"1.0", bytearray(b"1"), True, np.True_, 1 + 0j, {}, [], (), object(), np.array([]),
    np.array(1.0), np.array([1.0]), np.nan, np.inf, -np.inf, 10**400,
]  # fmt: skip


def _bad_arrays(shape, inf_ok=False):
    """Arrays that are not ``shape`` finite real numbers (+inf allowed for distances: 'nothing within rho')."""
    size = int(np.prod(shape))
    out = [
        np.zeros(size + 1), np.zeros(max(size - 1, 0)), np.zeros(shape + (1,)), np.zeros(0),
        np.full(shape, np.nan), np.full(shape, -np.inf), np.full(shape, 1 + 1j), np.full(shape, 1 + 0j),
        np.full(shape, "0.1"), np.full(shape, True), np.full(shape, "a", dtype=object), np.full(shape, None),
        [[0.0]], "0" * size, [0.0] * (size + 1),
    ]  # fmt: skip
    obj = np.zeros(shape, dtype=object)
    obj.flat[0] = "0.5"
    out.append(obj)
    if not inf_ok:
        out.append(np.full(shape, np.inf))
    return out


@st.composite
def malformed_inputs(draw):
    fields = _valid()
    name = draw(
        st.sampled_from(["t", "t_joints", "t_distances", "q", "qdot", "xdot_d", "distances", "directions", "monitor"])
    )
    if name in ("t", "t_joints", "t_distances"):
        fields[name] = draw(st.sampled_from(GARBAGE))
    elif name == "monitor":
        which = draw(st.sampled_from(["alone_d", "alone_dirs", "bad_d", "bad_dirs"]))
        md, mdirs = fields["distances"].copy(), fields["directions"].copy()
        if which == "alone_d":
            return CycleInput(**fields, monitor_distances=md)
        if which == "alone_dirs":
            return CycleInput(**fields, monitor_directions=mdirs)
        if which == "bad_d":
            md = draw(st.sampled_from(_bad_arrays((N_PTS,), inf_ok=True) + [np.array([0.5, -np.inf, 0.2])]))
        else:
            mdirs = draw(st.sampled_from(_bad_arrays((N_PTS, 3))))
        return CycleInput(**fields, monitor_distances=md, monitor_directions=mdirs)
    else:
        shape = {"q": (N_J,), "qdot": (N_J,), "xdot_d": (M,), "distances": (N_PTS,), "directions": (N_PTS, 3)}[name]
        bad = draw(st.sampled_from(_bad_arrays(shape, inf_ok=name == "distances") + GARBAGE[1:]))
        if name == "distances" and draw(st.booleans()):
            bad = np.array([0.5, draw(st.sampled_from([np.nan, -np.inf])), 0.2])
        if name == "directions" and isinstance(bad, np.ndarray) and bad.dtype == float and bad.shape == (3, 3):
            bad = bad.copy()
            bad[1:] = 1.0  # the row of the +inf distance may be anything: keep the bad ones at finite distances
        fields[name] = bad
    return CycleInput(**fields)


@settings(deadline=None, max_examples=300)
@given(malformed_inputs())
def test_check_inputs_malformed_gives_an_invalid_input_stop_never_an_exception(inp):
    """inputs.check_inputs ('never raises'; 'anything malformed stops the robot'): one field of a valid input
    replaced by garbage: wrong shapes, empty arrays, NaN/inf, complex, strings, bools, objects, a time stamp
    that is a string, a bool or an array (``_time``: 'NaN for anything else (None, str, bool, inf,
    arrays...)'), one of the monitor's pair alone. No warning escapes either (a ComplexWarning would be an
    exception under ``-W error``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chk = check_inputs(inp, N_J, N_PTS, M, CFG, -np.inf)
    if inp.distances is None or inp.directions is None:  # a missing pair is a stale one (documented)
        assert chk.status in (CycleStatus.STOP_STALE_DISTANCES, CycleStatus.STOP_INVALID_INPUT)
    else:
        assert chk.status == CycleStatus.STOP_INVALID_INPUT, (chk.status, inp)


@settings(deadline=None, max_examples=200)
@given(
    st.floats(-1e6, 1e6),
    st.one_of(st.floats(-0.05, 0.05), st.sampled_from([0.0, DT, DT * 1.0000001, 0.005, 0.0050001, 0.1, 0.1000001])),
    st.one_of(st.floats(-0.3, 0.3), st.sampled_from([0.0, -DT, 0.1, 0.1000001, -0.1])),
    st.one_of(st.floats(-0.3, 0.3), st.sampled_from([0.0, -DT, -DT * 1.0000001, 0.1, 0.1000001, -0.1])),
    st.one_of(st.floats(-0.01, 0.01), st.sampled_from([0.0, np.inf])),
)
def test_check_inputs_time_stamps_against_the_oracle(t, lag_j, lag_d, lead_d, back):
    """Random time stamps (stale, future, reordered, exactly at the limits): the status is the docstring's
    rule evaluated here: invalid for t < t_prev or a stamp more than dt in the future, else stale joints for
    t - t_joints > joint_timeout, else stale distances for t - t_distances > distance_timeout."""
    t_prev = t + back if back != np.inf else -np.inf
    tj, td = t - lag_j, t - lag_d if lead_d == 0.0 else t + lead_d
    inp = CycleInput(**{**_valid(t), "t_joints": tj, "t_distances": td})
    chk = check_inputs(inp, N_J, N_PTS, M, CFG, t_prev)
    if t < t_prev or tj > t + CFG.dt or td > t + CFG.dt:
        want = CycleStatus.STOP_INVALID_INPUT
    elif t - tj > CFG.joint_timeout:
        want = CycleStatus.STOP_STALE_JOINTS
    elif t - td > CFG.distance_timeout:
        want = CycleStatus.STOP_STALE_DISTANCES
    else:
        want = CycleStatus.OK
    assert chk.status == want


@settings(deadline=None, max_examples=40)
@given(st.lists(st.tuples(st.floats(-0.02, 0.05), st.booleans()), min_size=1, max_size=30))
def test_check_inputs_reordered_sequence_never_ok_behind_the_latest_time(steps):
    """A stream of cycles with random increments (negative ones: reordered messages), the caller keeping
    t_prev as the latest valid time (as cycle.py does): every cycle behind it stops, every other is OK."""
    t_prev, t = -np.inf, 0.0
    for inc, _ in steps:
        t = t + inc
        chk = check_inputs(CycleInput(**_valid(t)), N_J, N_PTS, M, CFG, t_prev)
        assert chk.status == (CycleStatus.STOP_INVALID_INPUT if t < t_prev else CycleStatus.OK)
        t_prev = max(t_prev, chk.t) if not math.isnan(chk.t) else t_prev


def test_check_inputs_accepts_legal_forms_of_valid_input():
    """Lists, float32, integer, non-contiguous and read-only arrays of finite numbers are valid (OK), and
    the checked arrays are float64 of the right shape, directions 0 for +inf distances."""
    ro = np.zeros(N_J)
    ro.flags.writeable = False
    for q in ([0.0] * N_J, np.zeros(N_J, np.float32), np.zeros(N_J, int), np.zeros(2 * N_J)[::2], ro):
        chk = check_inputs(CycleInput(**{**_valid(), "q": q}), N_J, N_PTS, M, CFG, -np.inf)
        assert chk.status == CycleStatus.OK
        assert chk.q.dtype == np.float64 and chk.q.shape == (N_J,) and chk.q.flags.writeable
    chk = check_inputs(CycleInput(**{**_valid(), "t": np.float32(1.0), "t_joints": 1}), N_J, N_PTS, M, CFG, -np.inf)
    assert chk.status == CycleStatus.OK
    np.testing.assert_array_equal(chk.directions[1], 0.0)


# ========================================================================================== admittance
@settings(deadline=None, max_examples=200)
@given(
    st.floats(1e-3, 1e3),
    st.floats(0.0, 1e4),
    st.one_of(st.just(0.0), st.floats(1e-6, 1e5)),
    st.floats(1e-6, 10.0),
)
def test_admittance_step_is_stable_for_any_dt(mass, damping, stiffness, dt):
    """admittance_step 'stable for any dt > 0': with the displacement integrated as e+ = e + dt v+ (the
    contact point moves at the commanded velocity), the update's spectral radius (numpy) is at most 1, and
    a constant force settles to e = F / K (the spring equilibrium), v = 0."""
    p = AdmittanceParams(mass, damping, stiffness)
    cols = []
    for v, e in ((1.0, 0.0), (0.0, 1.0)):
        vn = admittance_step(p, np.array([v, 0, 0]), np.array([e, 0, 0]), np.zeros(3), dt)[0]
        cols.append([vn, e + dt * vn])
    M2 = np.array(cols).T
    assert np.max(np.abs(np.linalg.eigvals(M2))) <= 1.0 + 1e-9
    if stiffness > 0:
        F = np.array([3.0, -2.0, 1.0])
        v_fix = admittance_step(p, np.zeros(3), F / stiffness, F, dt)
        np.testing.assert_allclose(v_fix, 0.0, atol=1e-12 * (1 + np.abs(F).max()))


@pytest.mark.parametrize("kw", [dict(mass=np.inf), dict(mass=np.nan), dict(damping=np.inf), dict(stiffness=np.nan)])
def test_admittance_params_reject_non_finite_values(kw):
    """AdmittanceParams: a mass of inf was accepted and every velocity became NaN (inf * 0 / inf)."""
    args = dict(mass=1.0, damping=1.0, stiffness=0.0) | kw
    with pytest.raises(ValueError, match="admittance"):
        AdmittanceParams(**args)


@pytest.fixture(scope="module")
def lwr4():
    pytest.importorskip("pinocchio")
    from depthguard.robot.model import load_lwr4

    return load_lwr4()


@settings(deadline=None, max_examples=20, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seeds, st.sampled_from([1.0, 1e3, 1e9]))
def test_contact_admittance_command_stays_within_the_joint_limits(lwr4, seed, force_scale):
    """ContactAdmittance.step: 'the result is scaled uniformly into the joint velocity limits', for any
    finite force, any contact link; the scaling keeps the direction."""
    from depthguard.control.admittance import SOFT, ContactAdmittance

    rng = np.random.default_rng(seed)
    robot = lwr4
    q = rng.uniform(robot.q_min * 0.8, robot.q_max * 0.8)
    adm = ContactAdmittance(robot, SOFT)
    link = str(rng.choice(["lwr_link_3", "lwr_link_5", "lwr_link_6"]))
    adm.set_contacts(q, [link], [robot.frame_pose(q, link)[1] + rng.normal(size=3) * 0.03])
    qd = adm.step(q, rng.normal(size=(1, 3)) * force_scale, robot.frame_pose(q)[1] + rng.normal(size=3), 0.005)
    assert np.all(np.isfinite(qd)) and np.all(np.abs(qd) <= robot.v_max * (1 + 1e-12))


@pytest.mark.parametrize(
    "field, kw",
    [
        ("forces", dict(forces=np.array([[np.nan, 0.0, 0.0]]))),
        ("forces", dict(forces=np.array([[np.inf, 0.0, 0.0]]))),
        ("ee_target", dict(ee_target=np.array([np.nan, 0.0, 0.0]))),
        ("ee_target", dict(ee_target=np.zeros(2))),
        ("dt", dict(dt=0.0)),
        ("dt", dict(dt=np.nan)),
        ("ee_velocity", dict(ee_velocity=np.array([0.0, np.inf, 0.0]))),
    ],
)
def test_contact_admittance_bad_input_gets_a_value_error(lwr4, field, kw):
    """A NaN force made every joint velocity NaN (the uniform scaling max(|qd| / v_max) is NaN, so nothing
    was limited): bad input gets a ValueError naming the field (docs/conventions.md)."""
    from depthguard.control.admittance import SOFT, ContactAdmittance

    q = np.array([0.0, -1.1, 0.0, 1.5, 0.0, -0.9, 0.0])
    adm = ContactAdmittance(lwr4, SOFT)
    adm.set_contacts(q, ["lwr_link_5"], [lwr4.frame_pose(q, "lwr_link_5")[1]])
    args = dict(q=q, forces=np.zeros((1, 3)), ee_target=lwr4.frame_pose(q)[1], dt=0.005) | kw
    with pytest.raises(ValueError, match=field):
        adm.step(**args)


# ======================================================================================== end effector
@settings(deadline=None, max_examples=200)
@given(
    st.one_of(st.floats(-1.0, 2.0), st.just(np.inf), st.floats(1e-300, 1e-290), st.just(1e308)),
    st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3).filter(lambda u: np.linalg.norm(u) > 1e-3),
    st.one_of(st.just(0.0), st.floats(1e-6, 10.0)),
    st.floats(1e-3, 10.0),
    st.floats(1e-3, 1e3),
)
def test_repulsive_velocity_is_eq7_along_the_direction(d, u, v_max, rho, alpha):
    """endeffector.repulsive_velocity (ICRA'12 eq. 7): ``v(D) n`` with ``v = V_max / (1 + exp((2D/rho - 1)
    alpha))`` (computed here without overflow) along the normalised direction; zero for D >= rho and inf;
    never faster than V_max; no floating-point warning."""
    u = np.array(u)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = repulsive_velocity(d, u, v_max, rho, alpha)
    if not d < rho:
        np.testing.assert_array_equal(out, 0.0)
        return
    want = v_max * _logistic((2.0 * d / rho - 1.0) * alpha) * u / np.linalg.norm(u)
    np.testing.assert_allclose(out, want, rtol=1e-12, atol=1e-300)
    assert np.linalg.norm(out) <= v_max * (1 + 1e-12)


@pytest.mark.parametrize(
    "field, args",
    [
        ("distance", (np.nan, [1.0, 0, 0], 2.0, 0.4, 6.0)),
        ("direction", (0.1, [np.nan, 0, 0], 2.0, 0.4, 6.0)),
        ("direction", (0.1, [np.inf, 0, 0], 2.0, 0.4, 6.0)),
        ("alpha", (0.1, [1.0, 0, 0], 2.0, 0.4, np.nan)),
        ("rho", (0.1, [1.0, 0, 0], 2.0, np.nan, 6.0)),
        ("v_max", (0.1, [1.0, 0, 0], np.nan, 0.4, 6.0)),
    ],
)
def test_repulsive_velocity_bad_input_gets_a_value_error(field, args):
    """Before: a NaN distance or rho silently gave no repulsion at all (``not d < rho``), a NaN direction or
    alpha a NaN velocity."""
    with pytest.raises(ValueError, match=field):
        repulsive_velocity(args[0], np.array(args[1]), *args[2:])


@st.composite
def matrices(draw, m_max=6, n_max=9):
    rng = np.random.default_rng(draw(seeds))
    m, n = draw(st.integers(1, m_max)), draw(st.integers(1, n_max))
    A = rng.normal(size=(m, n))
    kind = draw(st.sampled_from(["plain", "rank", "scaled", "zero", "tiny", "huge"]))
    if kind == "rank" and min(m, n) > 1:
        r = draw(st.integers(1, min(m, n) - 1))
        A = rng.normal(size=(m, r)) @ rng.normal(size=(r, n))
    elif kind == "scaled":
        A = A * 10.0 ** rng.uniform(-4, 4, (m, 1))
    elif kind == "zero":
        A = np.zeros((m, n))
    elif kind == "tiny":
        A = A * 1e-9
    elif kind == "huge":
        A = A * 1e6
    return A


@settings(deadline=None, max_examples=150)
@given(matrices())
def test_jacobi_svd_is_an_svd(A):
    """linalg._jacobi_svd: ``A^T W = B``, W orthogonal, the columns of B mutually orthogonal with norms
    sigma, the sigmas (sorted) numpy's singular values (for m > n, m - n of them 0)."""
    B, W, sigma = _jacobi_svd(A)
    m, n = A.shape
    scale = max(np.abs(A).max(), 1e-300)
    np.testing.assert_allclose(A.T @ W, B, atol=1e-12 * scale * m)
    np.testing.assert_allclose(W.T @ W, np.eye(m), atol=1e-12)
    G = B.T @ B
    np.testing.assert_allclose(G - np.diag(np.diag(G)), 0.0, atol=1e-12 * scale**2 * n)
    np.testing.assert_allclose(np.linalg.norm(B, axis=0), sigma, rtol=1e-12)
    ref = np.zeros(m)
    ref[: min(m, n)] = np.linalg.svd(A, compute_uv=False)
    np.testing.assert_allclose(np.sort(sigma)[::-1], ref, atol=1e-11 * scale * max(m, n))


_RANK1_6x9 = np.array(  # (fresh seeds: rows of nearly one direction, cond(A A^T + d^2 I) = 2.4e7 at d = 1e-3)
    [
        [0.011281929617666255, 0.008800758079352154, 0.014107359921172648, 0.00230673185527656, -0.00026122007742265303,
         0.004215013463260278, -0.013261416665930765, 0.01617113159975602, -0.010326967145034094],
        [0.6557699772566302, 0.511550162172674, 0.8200000716342135, 0.13408038762297858, -0.015183598022291422,
         0.24500057850124682, -0.770829033695659, 0.9399582306186733, -0.6002621217583729],
        [-1.1147807946484047, -0.8696133035474491, -1.3939649010653072, -0.2279308999268447, 0.025811464470701095,
         -0.41649046016642316, 1.3103762485683703, -1.5978886188858363, 1.0204198244795002],
        [1.1617557364712483, 0.9062573097400711, 1.4527041800742189, 0.2375355153051253, -0.026899115108112725,
         0.43404065050878343, -1.3655932457915323, 1.6652208919855176, -1.0634185576115316],
        [-0.2985625122908148, -0.2329013325983324, -0.3733340804804032, -0.06104484615948927, 0.006912870866875815,
         -0.11154519231887523, 0.35094722361285147, -0.42794928178316943, 0.27329059475234285],
        [0.1435106688113246, 0.11194917188960066, 0.1794512752746951, 0.029342554202851413, -0.003322824134549561,
         0.05361666148085294, -0.16869053784321086, 0.20570327860252963, -0.13136316321772856],
    ]
)  # fmt: skip


@settings(deadline=None, max_examples=100)
@given(matrices(), st.sampled_from([0.0, 1e-3, 0.05, 1.0]))
@example(_RANK1_6x9, 1e-3)
def test_damped_pinv_and_dls_against_numpy(A, damping):
    """linalg._damped_pinv = V diag(s / (s^2 + d^2)) U^T over the singular values above rcond * s_max and
    1e-12; endeffector.dls_inverse at 0 is numpy's pinv and otherwise J^T (J J^T + d^2 I)^-1; dls_damping
    is lambda_max sqrt(1 - (s_min / eps)^2) below eps (s_min = 0 for m > n), else 0, in [0, lambda_max]."""
    m, n = A.shape
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    rcond = 1e-6
    keep = (s > rcond * max(s.max(initial=0.0), 1e-300)) & (s > 1e-12)
    near_threshold = np.any(np.abs(s - rcond * s.max(initial=0.0)) < 1e-9 * max(s.max(initial=0.0), 1e-300))
    P, rank = _damped_pinv(A, damping, rcond)
    if not near_threshold:
        want = (Vt.T[:, keep] * (s[keep] / (s[keep] ** 2 + damping**2))) @ U[:, keep].T
        assert rank == int(keep.sum())
        np.testing.assert_allclose(P, want, atol=1e-9 * max(np.abs(want).max(initial=0.0), 1.0))
    s_full = np.zeros(m)
    s_full[: len(s)] = s
    cond = (s_full.max() ** 2 + damping**2 + 1e-12) / (s_full.min() ** 2 + damping**2 + 1e-12)
    if damping == 0.0:
        np.testing.assert_allclose(dls_inverse(A, 0.0), np.linalg.pinv(A), atol=1e-9)
    elif cond < 1e8:  # (the references are themselves inaccurate beyond)
        ref = A.T @ np.linalg.solve(A @ A.T + damping**2 * np.eye(m), np.eye(m))
        np.testing.assert_allclose(dls_inverse(A, damping), ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max(initial=1))
        x = np.linspace(-1.0, 1.0, m)
        want_x = A.T @ np.linalg.solve(A @ A.T + (damping**2 + 1e-12) * np.eye(m), x)
        # a backward-stable solve's forward error is about cond * eps (relative), with a factor for the size:
        # fresh seeds found a rank-1 A at damping 1e-3 (cond 2.4e7) 2.4e-7 off numpy (and 1.0e-7 off the SVD)
        rel = max(1e-7, 64.0 * np.finfo(float).eps * cond)
        np.testing.assert_allclose(dls_apply(A, damping, x), want_x, rtol=rel, atol=rel * np.abs(want_x).max())
    eps, lam_max = 0.02, 0.05
    s_min = 0.0 if m > n else float(np.linalg.svd(A, compute_uv=False).min())
    want_l = 0.0 if s_min >= eps else lam_max * math.sqrt(1.0 - (s_min / eps) ** 2)
    lam = dls_damping(A, eps, lam_max)
    assert 0.0 <= lam <= lam_max
    if abs(s_min - eps) > 1e-9:
        assert lam == pytest.approx(want_l, rel=1e-9, abs=1e-12)


# ========================================================================================== repulsion
@settings(deadline=None, max_examples=150)
@given(
    st.lists(
        st.one_of(st.floats(-1e3, 1e3), st.just(np.inf), st.just(-np.inf), st.just(1e308)), min_size=1, max_size=8
    ),
    st.floats(1e-6, 1e3),
    st.floats(1e-3, 1e4),
    st.floats(0.0, 10.0),
)
def test_risk_and_magnitude_profile(d, rho, alpha, vmax):
    """repulsion.risk in [0, 1] (0 for +inf), equal to the logistic computed here, non-increasing in D;
    magnitude = V_max risk; no floating-point warning at extreme distances."""
    d = np.sort(np.array(d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f = risk(d, rho, alpha)
        mag = magnitude(d, vmax, rho, alpha)
    assert np.all((f >= 0) & (f <= 1))
    assert np.all(np.diff(f) <= 0)
    want = [0.0 if x == np.inf else (1.0 if x == -np.inf else _logistic((2 * float(x) / rho - 1) * alpha)) for x in d]
    np.testing.assert_allclose(f, want, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(mag, vmax * f, rtol=1e-15)


@settings(deadline=None, max_examples=60)
@given(seeds, st.integers(0, 6))
def test_repulsive_vectors_follow_direction_and_stay_within_vmax(seed, N):
    """repulsion.repulsive_vectors: v(D) times the query's direction, zero where nothing lies within rho
    (inf), never longer than V_max for unit directions; an empty query gives (0, 3)."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.0, 1.0, N)
    d[rng.uniform(size=N) < 0.3] = np.inf
    u = rng.normal(size=(N, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u[np.isinf(d)] = np.nan
    res = PointDistances(d, u, np.zeros((N, 3)), np.zeros(N, int))
    V = repulsive_vectors(res, 2.0, 0.4, 6.0)
    assert V.shape == (N, 3) and np.all(np.isfinite(V))
    for k in range(N):
        want = np.zeros(3) if np.isinf(d[k]) else 2.0 * _logistic((2 * d[k] / 0.4 - 1) * 6.0) * u[k]
        np.testing.assert_allclose(V[k], want, rtol=1e-12, atol=1e-300)
    assert np.all(np.linalg.norm(V, axis=1) <= 2.0 + 1e-12)


# ============================================================================================== pivot
@settings(deadline=None, max_examples=150)
@given(
    st.lists(st.floats(-10, 10), min_size=3, max_size=3),
    st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
    st.floats(1e-6, 1e6),
    st.floats(0.01, 50.0),
)
def test_pivot_keeps_the_magnitude_and_turns_at_most_to_a_right_angle(V, Vd, dv_max, c):
    """pivot: 'V_Rpivot with the magnitude of V', in the plane of a = dV/dt/|dV/dt| and r = V/|V| (unless
    parallel); the angle to a grows from beta to at most pi/2: gamma = beta + (pi/2 - beta) sigma, sigma in
    [0, 1] (so the angle to a lies in [beta, pi/2]); unchanged for beta >= pi/2; over extreme but legal
    dv_max (1e-6 to 1e6) and rates (up to 1e3 m/s^2)."""
    V, Vd = np.array(V), np.array(Vd)
    out = pivot(V, Vd, dv_max, c)
    nv, nd = np.linalg.norm(V), np.linalg.norm(Vd)
    assert np.all(np.isfinite(out))
    assert np.linalg.norm(out) == pytest.approx(nv, rel=1e-12, abs=1e-12)
    if nv < 1e-9 or nd < 1e-9 or V @ Vd <= 0:
        np.testing.assert_allclose(out, V, atol=1e-12)
        return
    a, r = Vd / nd, V / nv
    if np.linalg.norm(np.cross(a, r)) > 1e-2:
        beta = math.acos(np.clip(a @ r, -1, 1))
        gamma = math.acos(np.clip(a @ out / nv, -1, 1))
        assert beta - 1e-9 <= gamma <= math.pi / 2 + 1e-9
        assert abs(np.cross(a, r) @ out) <= 1e-9 * nv


def test_pivot_filter_estimates_dv_dt_on_random_time_stamps():
    """PivotFilter.step: with tau = 0, dV/dt is the finite difference over each step's dt (random dt, from
    1e-6 s to 1 s); a dt <= 0 (a reordered or repeated time stamp) is refused without changing the state."""
    rng = np.random.default_rng(5)
    f = PivotFilter(dv_max=0.5, c=5.0)
    prev, t = None, 0.0
    for _ in range(50):
        dt = float(10.0 ** rng.uniform(-6, 0))
        t += dt
        V = np.array([math.sin(t), math.cos(2 * t), 0.3])
        out = f.step(V, dt)
        assert np.linalg.norm(out) == pytest.approx(np.linalg.norm(V), rel=1e-12)
        if prev is not None:
            np.testing.assert_allclose(f.v_dot, (V - prev) / dt, rtol=1e-9, atol=1e-12)
        prev = V
        before = f.v_dot
        with pytest.raises(ValueError, match="dt"):
            f.step(V, -dt)
        np.testing.assert_array_equal(f.v_dot, before)


@pytest.mark.parametrize(
    "field, V, dt",
    [
        ("V", [np.nan, 0.0, 0.0], 0.01),
        ("V", [np.inf, 0.0, 0.0], 0.01),
        ("V", [1.0, 0.0], 0.01),
        ("dt", [1.0, 0.0, 0.0], np.inf),
        ("dt", [1.0, 0.0, 0.0], np.nan),
    ],
)
def test_pivot_filter_bad_input_is_refused_and_does_not_poison_the_state(field, V, dt):
    """One NaN vector (or dt = inf) made the filtered dV/dt NaN for ever: every later output was NaN,
    valid inputs or not. Bad input gets a ValueError naming it, and the state stays as it was."""
    f = PivotFilter(dv_max=0.5, c=5.0)
    f.step(np.array([1.0, 0.0, 0.0]), 0.01)
    f.step(np.array([1.0, 0.1, 0.0]), 0.01)
    before = f.v_dot
    with pytest.raises(ValueError, match=field):
        f.step(np.array(V), dt)
    np.testing.assert_array_equal(f.v_dot, before)
    out = f.step(np.array([1.0, 0.2, 0.0]), 0.01)
    assert np.all(np.isfinite(out)) and np.all(np.isfinite(f.v_dot))
