"""Property tests of the contact guarantees (SAPHARI D4.1.1 §6; De Luca et al., IROS 2006): the momentum residual
(robot.residual), the contact force estimate (robot.contact_force) and the contact point (robot.contact_point),
against references written here: an independent simulation of ``M q̈ + C q̇ + g = τ + τ_ext`` (pinocchio's
``crba`` and ``nonLinearEffects``, RK4) and the analytic filter response ``τ_ext (1 - exp(-K_I t))``; ``J_cᵀ F``
from pinocchio's ``rnea`` with an external force; the minimum-norm solution by ``numpy.linalg.lstsq``; a
reference model of the documented detection rules; ``math.dist`` for the nearest vertex.

Faults these tests found (each failed on the old code):

* ``MomentumObserver``: a bool or a numeric string was accepted as ``gain`` or ``dt`` (``gain=True``: a 1 s time
  constant), a wrong-length gain got numpy's broadcast message naming no field; ``update`` took string or bool
  arrays for ``q``, ``qd``, ``tau`` and a bool ``dt``. ``discrete_time_constant`` gave NaN for ``dt = 0`` or a
  NaN gain; ``scaled_inertia_model`` made negative masses.
* ``ContactDetector``: ``step`` accepted ``dt = inf`` (rise rate 0: every impact labelled "intentional"), an
  empty residual (read as "no contact"), a negative ``hand_distance`` (labelled "intentional"); strings and
  wrong shapes gave TypeErrors or numpy messages; bools were accepted for ``r_th``, ``release_ratio``,
  ``release_cycles``; a string ``release_ratio`` passed the constructor and failed later.
* ``estimate_contact_forces``: without damping (``lambda_max = 0``, allowed) a rank-deficient ``J_c`` gave tens
  of newtons along an unobservable direction (the rounding-noise singular value was inverted) instead of the
  pseudo-inverse's minimum-norm force; huge finite Jacobians gave a NaN estimate without an error; bools,
  strings and complex numbers were accepted or refused without naming the field.
* ``nearest_vertex``: a far hand (> 1e154 m) gave vertex 0 at distance inf (squared distances overflowed), a hand
  of shape (1,) was broadcast to a wrong answer, an empty vertex array got numpy's argmin message;
  ``contact_from_hand`` turned a NaN or infinite hand (or a NaN vertex) into a contact point at some vertex with
  a NaN or infinite hand distance. (``nearest_vertex`` keeps numpy's argmin semantics for NaN: the first NaN
  distance, as tests/test_saphari_properties.py pins.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

pin = pytest.importorskip("pinocchio")

from depthguard.robot.contact_force import estimate_contact_forces, point_jacobian  # noqa: E402
from depthguard.robot.contact_point import RobotSurface, contact_from_hand, nearest_vertex  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402
from depthguard.robot.residual import (  # noqa: E402
    ContactDetector,
    MomentumObserver,
    RigidBodyDynamics,
    discrete_time_constant,
    scaled_inertia_model,
)

NAN, INF = math.nan, math.inf
ARM = np.full(7, 0.1)  # rotor inertias of the simulated drives, kg m²
LINKS = [f"lwr_link_{i}" for i in range(1, 8)]
_CACHE: dict = {}


def _lwr():
    if "lwr" not in _CACHE:
        _CACHE["lwr"] = load_lwr4()
    return _CACHE["lwr"]


def _surface() -> RobotSurface:
    if "surf" not in _CACHE:
        _CACHE["surf"] = RobotSurface(_lwr(), spacing=0.02)
    return _CACHE["surf"]


# ------------------------------------------------------------------------------- independent simulation
def _simulate(seed: int, tau_ext: np.ndarray, gain: float, dt: float, steps: int, terms: str, sub: int = 4):
    """The LWR under a PD + gravity law (τ held over each period) and a constant ``tau_ext`` from t = 0:
    ``(M + diag(ARM)) q̈ = τ + τ_ext - D q̇ - nle(q, q̇)`` by RK4 with ``sub`` steps a period, pinocchio's
    ``crba`` and ``nonLinearEffects`` (RNEA: not the observer's Coriolis matrix). Returns the residuals (steps, 7)
    of a ``tau_mode="average"`` observer (τ is the period's mean, exactly), the first at t = dt."""
    robot = _lwr()
    model = robot.model
    data = model.createData()
    D = np.asarray(model.damping, float)

    def acc(q, qd, tau):
        M = np.array(pin.crba(model, data, q))
        M = np.triu(M) + np.triu(M, 1).T + np.diag(ARM)
        return np.linalg.solve(M, tau - D * qd - pin.nonLinearEffects(model, data, q, qd))

    rng = np.random.default_rng(seed)
    q, qd = rng.uniform(-1.5, 1.5, 7), rng.uniform(-1.0, 1.0, 7)
    amp, w, ph = rng.uniform(0.2, 0.6, 7), rng.uniform(1.0, 4.0, 7), rng.uniform(0.0, 6.0, 7)
    q0 = q.copy()
    obs = MomentumObserver(RigidBodyDynamics(robot, ARM, D), gain=gain, dt=dt, tau_mode="average", terms=terms)
    obs.update(q, qd, np.zeros(7))
    out, h = [], dt / sub
    for k in range(steps):
        q_des = q0 + amp * (np.sin(w * k * dt + ph) - np.sin(ph))
        tau = np.array(pin.computeGeneralizedGravity(model, data, q)) + 200.0 * (q_des - q) - 20.0 * qd
        for _ in range(sub):
            k1q, k1v = qd, acc(q, qd, tau + tau_ext)
            k2q, k2v = qd + h / 2 * k1v, acc(q + h / 2 * k1q, qd + h / 2 * k1v, tau + tau_ext)
            k3q, k3v = qd + h / 2 * k2v, acc(q + h / 2 * k2q, qd + h / 2 * k2v, tau + tau_ext)
            k4q, k4v = qd + h * k3v, acc(q + h * k3q, qd + h * k3v, tau + tau_ext)
            q = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            qd = qd + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        out.append(obs.update(q, qd, tau))
    return np.array(out)


@pytest.mark.parametrize("terms", ["pinocchio", "compiled"])
def test_residual_is_a_first_order_filter_of_a_step_external_torque_on_a_moving_robot(terms):
    """r(t) -> τ_ext (1 - exp(-K_I t)) along a fast motion: time constant 1/K_I, unity gain. The tolerance is
    the Tustin discretisation's own deviation from the exponential, max_k |a^k - exp(-K k dt)| |τ_ext|
    (a = (1 - K dt/2)/(1 + K dt/2)), plus 1e-4 N m of integration error (the free-motion residual is ~1e-5)."""
    gain, dt, steps = 50.0, 0.001, 200  # 10 time constants
    tau_ext = np.random.default_rng(3).uniform(-10.0, 10.0, 7)
    r = _simulate(0, tau_ext, gain, dt, steps, terms)
    k = np.arange(1, steps + 1)[:, None]
    a = (1 - gain * dt / 2) / (1 + gain * dt / 2)
    disc = float(np.abs(a**k - np.exp(-gain * dt * k)).max())
    np.testing.assert_allclose(r, tau_ext * (1 - np.exp(-gain * dt * k)), rtol=0, atol=disc * 10.0 + 1e-4)
    i = int(round(1 / (gain * dt))) - 1  # t = 1/K_I: 63.2 %
    np.testing.assert_allclose(r[i] / tau_ext, 1 - math.exp(-1), atol=1e-3)


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_free_motion_gives_no_false_alarm(seed):
    """No contact (τ_ext = 0), a random fast motion: |r| stays below 1e-3 N m (the exact model), so a detector
    at 1e-2 N m never fires."""
    r = _simulate(seed, np.zeros(7), 100.0, 0.002, 100, "pinocchio")
    assert np.abs(r).max() < 1e-3
    det = ContactDetector(r_th=1e-2)
    assert not any(det.step(x, 0.002).active for x in r)


# ------------------------------------------------------------------------------------ observer: bad input
@pytest.mark.parametrize(
    "gain",
    [True, "100", "abc", NAN, INF, 0.0, -1.0, np.ones(3), [50.0] * 6 + [True], None, np.full((7, 1), 50.0)],
    ids=["bool", "numstr", "str", "nan", "inf", "zero", "neg", "len3", "boolin", "none", "2d"],
)
def test_observer_refuses_a_bad_gain_naming_it(gain):
    with pytest.raises(ValueError, match="gain"):
        MomentumObserver(RigidBodyDynamics(_lwr()), gain=gain)


@pytest.mark.parametrize("dt", [True, "0.005", NAN, INF, 0.0, -0.005, None], ids=str)
def test_observer_refuses_a_bad_dt_naming_it(dt):
    with pytest.raises(ValueError, match="dt"):
        MomentumObserver(RigidBodyDynamics(_lwr()), dt=dt)
    obs = MomentumObserver(RigidBodyDynamics(_lwr()), dt=0.005)
    if dt is not None:  # (None: the default period)
        with pytest.raises(ValueError, match="dt"):
            obs.update(np.zeros(7), np.zeros(7), np.zeros(7), dt=dt)


@settings(max_examples=30, deadline=None)
@given(
    field=st.sampled_from(["q", "qd", "tau"]),
    bad=st.sampled_from(["str", "bool", "short", "2d", "nan", "ninf", "obj"]),
    terms=st.sampled_from(["pinocchio", "compiled"]),
    seed=st.integers(0, 2**31 - 1),
)
@example(field="q", bad="str", terms="pinocchio", seed=0)  # old code: a string array was taken as numbers
def test_observer_refuses_bad_joint_vectors_by_name_and_keeps_its_state(field, bad, terms, seed):
    """A string, bool, wrong-shape or non-finite q, q̇ or τ: ValueError naming it; the observer goes on exactly
    as a twin that never saw it (the caller stops; the residual is not corrupted)."""
    rng = np.random.default_rng(seed)
    dyn = RigidBodyDynamics(_lwr())
    a, b = (MomentumObserver(dyn, gain=50.0, dt=0.005, terms=terms) for _ in range(2))
    ins = [tuple(rng.uniform(-1, 1, 7) for _ in range(3)) for _ in range(3)]
    np.testing.assert_array_equal(a.update(*ins[0]), b.update(*ins[0]))
    args = list(ins[1])
    i = ("q", "qd", "tau").index(field)
    x = args[i]
    args[i] = {
        "str": x.astype(str),
        "bool": x > 0,
        "short": x[:6],
        "2d": x[None, :],
        "nan": np.r_[x[:3], NAN, x[4:]],
        "ninf": np.r_[x[:6], -INF].tolist(),
        "obj": x.astype(object),
    }[bad]
    with pytest.raises(ValueError, match=rf"\b{field} must"):
        a.update(*args)
    np.testing.assert_array_equal(a.r, b.r)
    for x in ins[1:]:
        np.testing.assert_array_equal(a.update(*x), b.update(*x))


@pytest.mark.parametrize(
    ("gain", "dt", "field"),
    [(NAN, 0.005, "gain"), (-1.0, 0.005, "gain"), (True, 0.005, "gain"), ("5", 0.005, "gain"), (50.0, 0.0, "dt")]
    + [(50.0, NAN, "dt"), (50.0, -1.0, "dt"), (50.0, INF, "dt")],
    ids=["gain-nan", "gain-neg", "gain-bool", "gain-str", "dt-0", "dt-nan", "dt-neg", "dt-inf"],
)
def test_discrete_time_constant_refuses_bad_arguments(gain, dt, field):
    with pytest.raises(ValueError, match=field):
        discrete_time_constant(gain, dt)


@pytest.mark.parametrize("scale", [-1.0, 0.0, NAN, INF, True, "1", np.ones(3)], ids=str)
def test_scaled_inertia_model_refuses_a_scale_that_is_not_positive(scale):
    with pytest.raises(ValueError, match="scale"):
        scaled_inertia_model(_lwr(), scale)
    m = scaled_inertia_model(_lwr(), 1.1)  # (a valid one: masses scaled)
    assert m.inertias[3].mass == pytest.approx(1.1 * _lwr().model.inertias[3].mass)


# ----------------------------------------------------------------------------------------------- detector
def _ref_detector(seq, r_th, rj, ratio, cycles, dts, hands):
    """The documented rules: contact when ‖r‖ > r_th or some |r_i| > r_th,i, or r not finite (then the rate is
    inf); released after ``cycles`` consecutive finite cycles with ‖r‖ and every |r_i| <= ratio × threshold;
    the onset's label from the default classifier (a hand within 0.10 m: intentional; else the rise rate of
    ‖r‖ over the last cycle (from the last finite ‖r‖, 0 at start) > 400 N m/s: collision; NaN hand: none)."""
    active, below, prev, label, out = False, 0, 0.0, "", []
    for r, dt, hd in zip(seq, dts, hands, strict=True):
        finite = all(math.isfinite(x) for x in r)
        norm = math.hypot(*r) if finite else INF
        finite = finite and math.isfinite(norm)
        rate = (norm - prev) / dt if finite else INF
        prev = norm if finite else prev

        def over(k, r=r, norm=norm):
            return norm > k * r_th or (rj is not None and any(abs(x) > k * t for x, t in zip(r, rj, strict=True)))

        onset = release = False
        if not active:
            if not finite or over(1.0):
                active, onset, below = True, True, 0
                near = hd is not None and not math.isnan(hd) and hd <= 0.10
                label = "intentional" if near or rate <= 400.0 else "collision"
        else:
            below = below + 1 if finite and not over(ratio) else 0
            if below >= cycles:
                active, release, label = False, True, ""
        out.append((active, onset, release, label))
    return out


_R = st.floats(-5, 5) | st.sampled_from([NAN, INF, -INF, 1e308, 2.0, -2.0, 1.0])


@settings(max_examples=80, deadline=None)
@given(
    seq=st.lists(st.lists(_R, min_size=3, max_size=3), min_size=1, max_size=30),
    r_th=st.sampled_from([1.0, 2.0, 2.5]),
    joint_th=st.none() | st.sampled_from([0.5, 1.0, 4.0]),
    ratio=st.sampled_from([0.2, 0.5, 1.0]),
    cycles=st.integers(1, 4),
    dt=st.sampled_from([1e-3, 0.005, 0.1]),
    hand=st.none() | st.sampled_from([0.0, 0.05, 0.1, 0.3, NAN, INF]),
)
@example(seq=[[0.0, 0.0, 0.0], [2.5, 0.0, 0.0]], r_th=2.0, joint_th=None, ratio=0.5, cycles=1, dt=0.005, hand=None)
def test_detector_equals_the_reference_model_of_its_documented_rules(seq, r_th, joint_th, ratio, cycles, dt, hand):
    rj = None if joint_th is None else [joint_th] * 3
    det = ContactDetector(
        r_th=r_th, r_th_joint=None if rj is None else np.array(rj), release_ratio=ratio, release_cycles=cycles
    )
    got = [tuple(det.step(np.array(r), dt, hand)) for r in seq]
    assert got == _ref_detector(seq, r_th, rj, ratio, cycles, [dt] * len(seq), [hand] * len(seq))


@pytest.mark.parametrize(
    ("kw", "field"),
    [({"r_th": True}, "r_th"), ({"r_th": "2"}, "r_th"), ({"r_th": NAN}, "r_th"), ({"r_th": INF}, "r_th")]
    + [({"r_th": 0.0}, "r_th"), ({"release_ratio": True}, "release_ratio"), ({"release_ratio": "0.5"}, "release_ratio")]
    + [({"release_ratio": NAN}, "release_ratio"), ({"release_ratio": 1.5}, "release_ratio")]
    + [({"release_cycles": True}, "release_cycles"), ({"release_cycles": 0}, "release_cycles")]
    + [({"release_cycles": 2.0}, "release_cycles"), ({"release_cycles": "4"}, "release_cycles")]
    + [({"r_th_joint": np.ones(7, bool)}, "r_th_joint"), ({"r_th_joint": ["1"] * 7}, "r_th_joint")]
    + [({"r_th_joint": []}, "r_th_joint"), ({"r_th_joint": np.r_[np.ones(6), NAN]}, "r_th_joint")]
    + [({"r_th_joint": -np.ones(7)}, "r_th_joint"), ({"r_th_joint": np.ones((7, 1))}, "r_th_joint")],
    ids=lambda v: v if isinstance(v, str) else "-".join(f"{k}={v[k]!r}"[:24] for k in v),
)
def test_detector_refuses_a_bad_configuration_naming_the_field(kw, field):
    with pytest.raises(ValueError, match=field):
        ContactDetector(**kw)


@pytest.mark.parametrize(
    ("r", "dt", "hand", "field"),
    [
        pytest.param(np.zeros(7), INF, None, "dt", id="dt-inf"),  # (rate 0: an impact labelled intentional)
        pytest.param(np.zeros(7), NAN, None, "dt", id="dt-nan"),
        pytest.param(np.zeros(7), 0.0, None, "dt", id="dt-0"),
        pytest.param(np.zeros(7), True, None, "dt", id="dt-bool"),
        pytest.param(np.zeros(7), "0.005", None, "dt", id="dt-str"),
        pytest.param(np.zeros(0), 0.005, None, "r", id="r-empty"),  # (read as "no contact")
        pytest.param(np.zeros((7, 1)), 0.005, None, "r", id="r-2d"),
        pytest.param(np.float64(5.0), 0.005, None, "r", id="r-scalar"),
        pytest.param("abc", 0.005, None, "r", id="r-str"),
        pytest.param(np.ones(7, bool), 0.005, None, "r", id="r-bool"),
        pytest.param(np.zeros(6), 0.005, None, "r", id="r-len-vs-r_th_joint"),
        pytest.param(np.full(7, 5.0), 0.005, -1.0, "hand_distance", id="hand-negative"),  # (read as intentional)
        pytest.param(np.full(7, 5.0), 0.005, "x", "hand_distance", id="hand-str"),
        pytest.param(np.full(7, 5.0), 0.005, True, "hand_distance", id="hand-bool"),
    ],
)
def test_detector_step_refuses_bad_input_naming_it(r, dt, hand, field):
    det = ContactDetector(r_th=2.0, r_th_joint=np.ones(7))
    with pytest.raises(ValueError, match=rf"\b{field} must"):
        det.step(r, dt, hand)


def test_detector_reads_a_nan_hand_distance_as_no_hand_and_a_nan_residual_as_a_collision():
    det = ContactDetector(r_th=2.0)
    s = det.step(np.r_[np.zeros(6), NAN], 0.005, NAN)
    assert s.active and s.onset and s.label == "collision"
    for _ in range(10):  # a NaN residual never counts towards the release
        assert det.step(np.full(7, NAN), 0.005).active


# ------------------------------------------------------------------------------------------ contact force
def _pin_point(q, link, local):
    """The world point rigidly attached to ``link``'s joint at ``local`` (joint frame), its positional Jacobian
    from pinocchio's joint Jacobian (LOCAL_WORLD_ALIGNED: v_p = v_o + ω × (p - o)), and a force applied there as
    pinocchio's external-force list for rnea."""
    robot = _lwr()
    model = robot.model
    data = model.createData()
    jid = int(model.frames[model.getFrameId(link)].parentJoint)
    pin.forwardKinematics(model, data, q)
    pin.computeJointJacobians(model, data, q)
    M = data.oMi[jid]
    p = M.rotation @ local + M.translation
    Jj = pin.getJointJacobian(model, data, jid, pin.LOCAL_WORLD_ALIGNED)
    d = p - M.translation
    skew = np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    Jp = Jj[:3] - skew @ Jj[3:]

    def tau_of(F):  # J_cᵀ F = rnea(q, 0, 0) - rnea(q, 0, 0, f_ext) (rnea subtracts Jᵀ f_ext)
        fl = M.rotation.T @ F
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        fext[jid] = pin.Force(fl, np.cross(local, fl))
        z = np.zeros(model.nv)
        return pin.rnea(model, data, q, z, z) - pin.rnea(model, data, q, z, z, fext)

    return p, Jp, tau_of


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    link=st.sampled_from(LINKS),
    lambda_max=st.sampled_from([0.0, 0.02]),
)
@example(seed=0, link="lwr_link_1", lambda_max=0.0)  # old code: (20, -84, 0) N instead of (47, -20, 0) N
@example(seed=528140, link="lwr_link_2", lambda_max=0.02)  # σ = (0.096, 0.0032, 0): damped, not compared
@example(seed=10000000, link="lwr_link_4", lambda_max=0.0)  # a σ below tol σ_max but not 0: unobservable
def test_force_at_a_random_point_is_the_minimum_norm_solution_of_jt_f(seed, link, lambda_max):
    """A force F at a random point of a link: τ_ext = J_cᵀ F from pinocchio's rnea; the estimate from
    point_jacobian equals the minimum-norm least-squares force (numpy lstsq on pinocchio's Jacobian), hence F
    itself on its observable part; the unobservable directions give no torque. Links 1 and 2 (rank 1 and 2)
    attack the rank-deficient case; without damping the old code put tens of newtons there."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0, 2.0, 7)
    q[3] = rng.choice([-1, 1]) * rng.uniform(0.6, 2.0)  # elbow bent: away from the arm's own singularity
    local, F = rng.uniform(-0.1, 0.1, 3), rng.uniform(-50, 50, 3)
    p, Jp, tau_of = _pin_point(q, link, local)
    tau = tau_of(F)
    np.testing.assert_allclose(Jp.T @ F, tau, atol=1e-9)  # (the two pinocchio routes agree)
    J = point_jacobian(_lwr(), q, link, p)
    np.testing.assert_allclose(J, Jp, atol=1e-10)
    est = estimate_contact_forces(J, tau, lambda_max=lambda_max)
    s = np.linalg.svd(Jp, compute_uv=False)
    ref = np.linalg.lstsq(Jp.T, tau, rcond=1e-3)[0]  # (rcond: the estimate's tol)
    if lambda_max == 0.0 or np.all((s >= 0.005) | (s < 1e-9 * s[0])):  # undamped: no σ in (0, eps)
        np.testing.assert_allclose(est.stacked, ref, atol=1e-6 * (1 + np.abs(F).max()))
    # (unobservable: σ < tol σ_max, tol = 1e-3: their torque is below that)
    assert np.all(np.linalg.norm(Jp.T @ est.unobservable, axis=0) <= 1e-3 * s[0] + 1e-12)
    if est.unobservable.shape[1]:
        np.testing.assert_allclose(est.unobservable.T @ est.stacked, 0.0, atol=1e-6 * np.abs(F).max())


def test_undamped_estimate_puts_no_force_in_the_null_space_of_a_rank_deficient_jacobian():
    """Pinned: a rank-2 J_c (two rows dependent), λ_max = 0: the pseudo-inverse's minimum-norm force, not a
    force along the unobservable direction (old code: 30 N and more)."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        J = rng.normal(size=(3, 7))
        J[2] = 0.3 * J[0] + 0.7 * J[1]
        F = rng.normal(size=3) * 20
        est = estimate_contact_forces(J, J.T @ F, lambda_max=0.0)
        assert est.unobservable.shape == (3, 1)
        np.testing.assert_allclose(est.stacked, np.linalg.pinv(J.T, rcond=1e-10) @ (J.T @ F), atol=1e-9)


@pytest.mark.parametrize(
    ("J", "r"),
    [(np.zeros((3, 7)), np.ones(7)), (np.eye(3, 7), np.zeros(7)), (np.zeros((3, 7)), np.zeros(7))],
    ids=["zero-J", "zero-r", "both-zero"],
)
@pytest.mark.parametrize("lambda_max", [0.0, 0.02])
def test_degenerate_inputs_give_zero_force(J, r, lambda_max):
    est = estimate_contact_forces(J, r, lambda_max=lambda_max)
    np.testing.assert_array_equal(est.stacked, 0.0)


@pytest.mark.parametrize(
    ("J", "r", "kw", "field"),
    [
        pytest.param(np.eye(3, 7) * 1e200, np.ones(7), {}, "overflow", id="huge-J"),  # (old: NaN estimate)
        pytest.param(np.eye(3, 7), np.ones(7), {"eps": True}, "eps", id="eps-bool"),
        pytest.param(np.eye(3, 7), np.ones(7), {"eps": "0.01"}, "eps", id="eps-str"),
        pytest.param(np.eye(3, 7), np.ones(7), {"lambda_max": True}, "lambda_max", id="lambda-bool"),
        pytest.param(np.eye(3, 7), np.ones(7), {"tol": None}, "tol", id="tol-none"),
        pytest.param(np.eye(3, 7), np.ones(7), {"tol": NAN}, "tol", id="tol-nan"),
        pytest.param(np.ones((3, 7), bool), np.ones(7), {}, "jacobians", id="J-bool"),
        pytest.param(np.eye(3, 7).astype(str), np.ones(7), {}, "jacobians", id="J-str"),
        pytest.param(np.eye(3, 7) + 0j, np.ones(7), {}, "jacobians", id="J-complex"),
        pytest.param([np.eye(3, 7).tolist(), [["a"] * 7] * 3], np.ones(7), {}, "jacobians", id="J-list-str"),
        pytest.param(np.eye(3, 7), np.ones(7, bool), {}, "r", id="r-bool"),
        pytest.param(np.eye(3, 7), "abc", {}, "r", id="r-str"),
        pytest.param(np.eye(3, 7), np.r_[np.ones(6), NAN], {}, "finite", id="r-nan"),
    ],
)
def test_force_estimate_refuses_bad_input_naming_it(J, r, kw, field):
    with pytest.raises(ValueError, match=field):
        estimate_contact_forces(J, r, **kw)


# ------------------------------------------------------------------------------------------ contact point
def _ref_nearest(V, p):
    d = [math.dist(v, p) for v in V.tolist()]  # (math.dist scales: no overflow)
    return min(d)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    far=st.sampled_from([1.0, 1e3, 1e160, 1e200, 1e300]),
    f32=st.booleans(),
)
@example(seed=0, far=1e200, f32=False)  # old code: vertex 0 at distance inf
def test_nearest_vertex_is_the_nearest_also_for_far_points(seed, far, f32):
    """The distance returned is the smallest distance (math.dist) and belongs to the returned vertex, also where
    squared distances overflow (old code: vertex 0 at distance inf)."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(50, 3)) * far / 10
    p = rng.normal(size=3) * far
    p = p.astype(np.float32) if f32 and far < 1e30 else p
    i, d = nearest_vertex(V, p)
    ref = _ref_nearest(V, p.astype(float))
    assert math.isfinite(d)
    assert d == pytest.approx(ref, rel=1e-12)
    assert math.dist(V[i], p.astype(float)) == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize(
    ("V", "p", "field"),
    [
        pytest.param(np.ones((4, 3)), np.zeros(1), "p_h", id="p-shape1"),
        pytest.param(np.ones((4, 3)), np.zeros((3, 1)), "p_h", id="p-shape31"),
        pytest.param(np.ones((4, 3)), "abc", "p_h", id="p-str"),
        pytest.param(np.ones((4, 3)), np.ones(3, bool), "p_h", id="p-bool"),
        pytest.param(np.zeros((0, 3)), np.zeros(3), "vertices", id="V-empty"),
        pytest.param(np.ones((4, 2)), np.zeros(3), "vertices", id="V-shape"),
    ],
)
def test_nearest_vertex_refuses_bad_input_naming_it(V, p, field):
    with pytest.raises(ValueError, match=field):
        nearest_vertex(V, p)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), dist=st.floats(0.0, 0.3))
def test_contact_point_is_on_the_robot_surface_nearest_the_hand(seed, dist):
    """A hand near a random surface point: the contact is on a capsule surface of its link (distance to the
    axis segment = radius), no vertex is nearer to the hand (math.dist), ``hand_distance`` is its distance, and
    ``local`` is the position in its joint's frame (pinocchio's placement)."""
    robot, surf = _lwr(), _surface()
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0, 2.0, 7)
    V, _ = surf.pose(q)
    p_h = V[rng.integers(len(V))] + dist * rng.normal(size=3) / math.sqrt(3)
    cp = contact_from_hand(surf, q, V, p_h)
    assert cp.hand_distance == pytest.approx(_ref_nearest(V, p_h), rel=1e-12, abs=1e-15)
    assert cp.hand_distance == pytest.approx(math.dist(cp.position, p_h), rel=1e-12, abs=1e-15)
    a, b, rad = robot.link_capsules(q)
    on = []
    for k, c in enumerate(robot.capsules):
        if c.link == cp.link:
            ab = b[k] - a[k]
            t = np.clip((cp.position - a[k]) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
            on.append(abs(np.linalg.norm(cp.position - (a[k] + t * ab)) - rad[k]))
    assert on and min(on) < 1e-9
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    M = data.oMi[int(surf.joint[cp.vertex])]
    np.testing.assert_allclose(M.rotation @ cp.local + M.translation, cp.position, atol=1e-12)


@pytest.mark.parametrize("where", ["p_h", "vertices"])
@pytest.mark.parametrize("value", [NAN, INF, -INF], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("kind", ["array", "list"])
def test_a_non_finite_hand_or_vertex_gives_no_finite_distance_and_no_contact_point(where, value, kind):
    """nearest_vertex (numpy's argmin semantics): a NaN gives a NaN distance, an infinite hand an infinite one,
    never a finite distance; contact_from_hand refuses both, naming the argument (old code: a contact point at
    vertex 0 with a NaN or infinite hand distance)."""
    surf, q = _surface(), np.zeros(7)
    V, _ = surf.pose(q)
    V, p = V.copy(), V[5] + 0.01
    if where == "p_h":
        p[1] = value
    else:
        V[17, 2] = value
    V, p = (V.tolist(), p.tolist()) if kind == "list" else (V, p)
    i, d = nearest_vertex(V, p)
    if where == "p_h" or math.isnan(value):
        assert not math.isfinite(d)
        with pytest.raises(ValueError, match=rf"{where} must be finite"):
            contact_from_hand(surf, q, np.asarray(V, float), p)
    else:  # an infinite vertex is merely far: the nearest finite one is found
        Va = np.asarray(V, float)
        assert d == pytest.approx(_ref_nearest(np.delete(Va, 17, axis=0), np.asarray(p)), rel=1e-12)
        assert math.dist(Va[i], p) == pytest.approx(d, rel=1e-12)


def test_robot_surface_refuses_a_bool_spacing():
    with pytest.raises(ValueError, match="spacing"):
        RobotSurface(_lwr(), spacing=True)
