"""Property tests of the documented guarantees of the SAPHARI close-range modules (skin sensors, protective
buffer and NSB control, momentum residual, contact point and force), attacked with NaN, inf, wrong shapes,
empty arrays, extreme but legal parameters and random input sequences. Every number is checked against an
independent computation (finite differences, closed forms, analytic geometry, numpy's SVD), never against
another output of the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from depthguard.control.nsb import LAMBDA_KINDS, NSBConfig, NSBController, weight
from depthguard.robot.contact_force import estimate_contact_forces, observable_error, point_jacobian
from depthguard.robot.contact_point import RobotSurface, _capsule_vertices, nearest_vertex
from depthguard.robot.model import load_lwr4
from depthguard.robot.residual import ContactDetector, MomentumObserver, RigidBodyDynamics, discrete_time_constant
from depthguard.robot.youbot import YOUBOT_Q0, YOUBOT_SENSORS, load_youbot
from depthguard.sensors.buffer import energy_gradient, spring_energy, total_energy
from depthguard.sensors.graycode import (
    binary_decode,
    binary_encode,
    count_glitches,
    gray_decode,
    gray_encode,
    multibit_windows_sampled,
    simulate_lines,
)
from depthguard.sensors.levels import LevelMap, LevelStepper, extra_stop_delay, hold_time
from depthguard.sensors.mount import SensorMount
from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK, AmbiguityTracker
from depthguard.sensors.skin import SkinLayout
from depthguard.sensors.taxel import ContactTaxel, ProximityTaxel

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
READING = st.one_of(st.floats(-1.0, 2.0), st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -0.0]))
SETTINGS = settings(deadline=None, max_examples=40)


@pytest.fixture(scope="module")
def youbot():
    return load_youbot()


@pytest.fixture(scope="module")
def lwr():
    return load_lwr4()


# --------------------------------------------------------------------------------------------------------
# protective buffer (eqs. 5.1-5.2, 5.6-5.7)


@SETTINGS
@given(d=st.lists(READING, min_size=0, max_size=12), rest=st.floats(1e-3, 1.0))
def test_spring_energy_is_eq_5_1_non_negative_and_nan_is_an_obstacle_at_the_sensor(d, rest):
    """eq. 5.1 per spring, computed here in plain floats: NaN and negatives count as 0 m, inf as nothing."""
    e = spring_energy(np.array(d, float), rest)
    assert e.shape == (len(d),)
    for dk, ek in zip(d, e, strict=True):
        x = 0.0 if math.isnan(dk) else max(dk, 0.0)
        assert ek == pytest.approx(0.5 * (x - rest) ** 2 if x <= rest else 0.0, abs=1e-15)
        assert ek >= 0.0 and math.isfinite(ek)
    assert total_energy(np.array(d, float), rest) == pytest.approx(math.fsum(e), abs=1e-15)


@SETTINGS
@given(
    n_sensors=st.integers(0, 6),
    n_dof=st.integers(1, 5),
    seed=st.integers(0, 2**31 - 1),
    rest=st.floats(0.05, 0.5),
)
def test_energy_gradient_matches_finite_differences_of_a_linear_sensor_motion(n_sensors, n_dof, seed, rest):
    """Sensor points ``p_sk(q) = b_k + A_k q``, obstacle points fixed on the sensors' axes (some beyond the
    rest length): eqs. 5.6-5.7 equal central differences of sigma(q). No sensor: a zero gradient."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n_sensors, 3, n_dof))
    b = rng.normal(size=(n_sensors, 3))
    q = rng.normal(size=n_dof)
    axes = rng.normal(size=(n_sensors, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    obst = b + A @ q + axes * rng.uniform(0.02, 2 * rest, (n_sensors, 1))

    def dist(qq):
        return np.linalg.norm(obst - (b + A @ qq), axis=1)

    d = dist(q)
    g = energy_gradient(d, rest, axes, A)
    assert g.shape == (n_dof,)
    h = 1e-6
    for i in range(n_dof):
        e = np.zeros(n_dof)
        e[i] = h
        fd = (total_energy(dist(q + e), rest) - total_energy(dist(q - e), rest)) / (2 * h)
        assert g[i] == pytest.approx(fd, abs=1e-6)


# --------------------------------------------------------------------------------------------------------
# NSB weighting and controller (eqs. 5.4-5.12)


@SETTINGS
@given(
    ds=st.lists(READING, min_size=2, max_size=8),
    kind=st.sampled_from(LAMBDA_KINDS),
    f=st.floats(0.01, 1.0),
    K=st.floats(0.1, 1e4),
    delta=st.floats(1e-3, 0.5),
)
def test_weight_is_in_unit_interval_non_increasing_and_minus_inf_is_the_closest(ds, kind, f, K, delta):
    """lambda(d) in [0, 1], non-increasing in d (NaN counting as 0 m), 0 at +inf (nothing seen) and, for a
    reading of -inf (nearer than anything), the same as for any negative distance: full avoidance."""
    lam = [weight(x, kind, f, K, delta) for x in ds]
    assert all(0.0 <= v <= 1.0 for v in lam)
    key = [0.0 if math.isnan(x) else x for x in ds]
    for i in range(len(ds)):
        for j in range(len(ds)):
            if key[i] <= key[j]:
                assert lam[i] >= lam[j] - 1e-12, (ds[i], ds[j], lam[i], lam[j])
    assert weight(np.inf, kind, f, K, delta) == 0.0
    assert weight(-np.inf, kind, f, K, delta) == pytest.approx(1.0)
    assert weight(-np.inf, kind, f, K, delta) >= weight(-1e300, kind, f, K, delta)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("weights", (np.nan,) * 8),
        ("weights", (np.inf,) * 8),
        ("qdot_max", (0.0,) * 8),
        ("qdot_max", (-1.0,) * 8),
        ("qdot_max", (np.nan,) * 8),
        ("damping", -1e-3),
        ("damping", np.nan),
    ],
)
def test_nsb_config_rejects_bad_fields_naming_them(field, value):
    with pytest.raises(ValueError, match=f"NSBConfig.{field}"):
        NSBConfig(**{field: value})


@settings(deadline=None, max_examples=30)
@given(
    seed=st.integers(0, 2**31 - 1),
    readings=st.lists(READING, min_size=10, max_size=10),
    bad=st.sampled_from(["x_d", "xdot_d"]),
    how=st.sampled_from(["nan", "inf", "short", "long"]),
)
def test_nsb_step_command_is_finite_within_limits_and_bad_targets_name_the_field(youbot, seed, readings, bad, how):
    """Any readings (NaN, +-inf, negative): a finite command within the joint limits and lambda = lambda(d_min)
    with NaN as 0 m. A non-finite or mis-shaped target raises ValueError naming it (never a NaN command)."""
    rng = np.random.default_rng(seed)
    ctrl = NSBController(youbot, YOUBOT_SENSORS, NSBConfig(lambda_kind=LAMBDA_KINDS[seed % 3]))
    q = YOUBOT_Q0 + rng.uniform(-1.0, 1.0, 8)
    d = np.array(readings, float)
    x_d, xdot_d = rng.normal(size=3), rng.normal(size=3)
    for out in (ctrl.step(q, x_d, xdot_d, d), ctrl.step_reference(q, x_d, xdot_d, d)):
        assert np.all(np.isfinite(out.qdot)) and np.all(np.isfinite(out.q_next))
        assert np.all(np.abs(out.qdot) <= np.asarray(ctrl.cfg.qdot_max) * (1 + 1e-12))
        d_min = min(0.0 if math.isnan(x) else x for x in readings)
        assert out.lam == weight(d_min, ctrl.cfg.lambda_kind, ctrl.cfg.f, ctrl.cfg.K, ctrl.cfg.delta)
        assert out.sigma >= 0.0
    target = {"nan": np.array([np.nan, 0, 0]), "inf": np.array([0, -np.inf, 0]), "short": np.zeros(2)}.get(how)
    if target is None:
        target = np.zeros(4)
    args = {"x_d": x_d, "xdot_d": xdot_d, bad: target}
    for fn in (ctrl.step, ctrl.step_reference):
        with pytest.raises(ValueError, match=bad):
            fn(q, args["x_d"], args["xdot_d"], d)


@settings(deadline=None, max_examples=25)
@given(seed=st.integers(0, 2**31 - 1), n_close=st.integers(1, 4))
def test_nsb_full_avoidance_drains_the_energy_at_the_commanded_rate(youbot, seed, n_close):
    """With lambda = 1 (switch, an obstacle within f) the energy task is met exactly: along the command, the
    energy of fixed obstacle points on the sensors' axes falls at ``-gamma_o sigma`` times the velocity scale
    (central differences of sigma(q + s qdot) measured here, with the distances recomputed)."""
    rng = np.random.default_rng(seed)
    cfg = NSBConfig(lambda_kind="switch", rest=0.3, f=0.25)
    ctrl = NSBController(youbot, YOUBOT_SENSORS, cfg)
    q = YOUBOT_Q0 + rng.uniform(-0.3, 0.3, 8)
    st0 = ctrl.sensors.evaluate(q)
    d = np.full(10, np.inf)
    idx = rng.choice(10, n_close, replace=False)
    d[idx] = rng.uniform(0.05, 0.25, n_close)
    obst = st0.positions[idx] + st0.axes[idx] * d[idx, None]
    out = ctrl.step(q, st0.ee_position + rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05, d)
    assert out.lam == 1.0

    def sigma(qq):
        p = ctrl.sensors.evaluate(qq).positions[idx]
        dd = np.linalg.norm(obst - p, axis=1)
        return float(np.sum(np.where(dd <= 0.3, 0.5 * (dd - 0.3) ** 2, 0.0)))

    assert sigma(q) == pytest.approx(out.sigma, rel=1e-12)
    s = 1e-6
    rate = (sigma(q + s * out.qdot) - sigma(q - s * out.qdot)) / (2 * s)
    assert rate == pytest.approx(-cfg.gamma_o * out.sigma * out.scale, rel=1e-4, abs=1e-9)


# --------------------------------------------------------------------------------------------------------
# safety levels, stepping, Gray code, skewed lines


@settings(deadline=None, max_examples=80)
@given(
    base=st.floats(0.0, 100.0),
    gaps=st.lists(st.floats(0.5, 30.0), min_size=5, max_size=5),
    hysteresis=st.floats(0.0, 40.0),
    near=st.lists(st.tuples(st.integers(0, 5), st.floats(-1.0, 1.0)) | st.none(), min_size=2, max_size=40),
)
def test_level_map_never_rises_on_a_falling_signal_whatever_the_threshold_spacing(base, gaps, hysteresis, near):
    """Level l is reached only with the signal >= thresholds[l - 1]; going down (a lower raw level) never
    raises the level, even with thresholds closer together than the hysteresis. Signals are drawn around
    the thresholds (within the hysteresis and a gap), None = NaN."""
    th = np.concatenate([[base], base + np.cumsum(gaps)])
    assume(np.all(np.diff(th) > 0))
    m = LevelMap(thresholds=tuple(th), hysteresis=hysteresis)
    signals = [math.nan if x is None else th[x[0]] + x[1] * (hysteresis + 30.0) for x in near]
    prev = 0
    for s in signals:
        lv = m.update(s, False)
        assert 0 <= lv <= 6
        if math.isnan(s):
            assert lv == 6
        elif lv > prev:
            assert s >= th[lv - 1], (prev, lv, s)
        elif lv < prev:
            assert s + hysteresis < th[prev - 1]
        prev = lv


@SETTINGS
@given(
    hold=st.floats(0.0, 0.02),
    steps=st.lists(st.tuples(st.floats(0.0, 0.01), st.integers(0, 7)), min_size=1, max_size=60),
)
def test_level_stepper_moves_one_level_towards_the_target_and_holds(hold, steps):
    """At most one level per update, towards the target, writes at least ``hold`` apart (to 1e-12 s)."""
    s = LevelStepper(hold=hold)
    t, t_write, level = 0.0, -np.inf, 0
    for dt, target in steps:
        t += dt
        new, wrote = s.update(t, target)
        assert wrote == (new != level)
        if wrote:
            assert abs(new - level) == 1 and abs(target - new) < abs(target - level)
            assert t - t_write >= hold - 1e-12
            t_write = t
        level = new
    # a constant target is reached after |target - level| holds
    target = steps[-1][1]
    for k in range(1, 9):
        s.update(t + k * (hold + 1e-9), target)
    assert s.level == target


@SETTINGS
@given(
    skew=st.floats(0.0, 0.01),
    period=st.floats(1e-4, 0.01),
    a=st.integers(0, 7),
    b=st.integers(0, 7),
)
def test_extra_stop_delay_is_the_stepping_delay(skew, period, a, b):
    """Stepping from a to b with updates every 1 us: the last level is written ``extra_stop_delay`` after the
    first (a direct jump would write it at once), to one update."""
    hold = hold_time(skew, period)
    s = LevelStepper(hold=hold, level=a)
    writes, t = [], 0.0
    for k in range(int(8 * hold / 1e-6) + 10):
        t = k * 1e-6
        if s.update(t, b)[1]:
            writes.append(t)
        if s.level == b:
            break
    assert s.level == b and len(writes) == abs(b - a)
    span = writes[-1] - writes[0] if writes else 0.0
    assert span == pytest.approx(extra_stop_delay(skew, period, a, b), abs=abs(b - a) * 1e-6 + 1e-12)


@SETTINGS
@given(
    levels=arrays(
        st.sampled_from([np.int64, np.int8, np.uint8, np.uint16]),
        st.tuples(st.integers(0, 3), st.integers(0, 3)),
        elements=st.integers(0, 7),
    ),
    bad=st.one_of(
        st.integers(-(2**40), -1), st.integers(8, 2**40), st.floats(allow_nan=True), st.booleans(), st.text(max_size=2)
    ),
)
def test_codes_round_trip_on_any_integer_array_and_reject_anything_else(levels, bad):
    g = gray_encode(levels)
    assert g.shape == levels.shape
    np.testing.assert_array_equal(gray_decode(g), levels)
    np.testing.assert_array_equal(binary_decode(binary_encode(levels)), levels)
    # Gray: adjacent levels differ on one line exactly
    flat = levels.ravel().astype(int)
    for x in flat:
        if x < 7:
            assert bin(int(gray_encode(x)) ^ int(gray_encode(x + 1))).count("1") == 1
    for fn in (gray_encode, binary_encode):
        with pytest.raises(ValueError, match="level"):
            fn(bad)
    for fn in (gray_decode, binary_decode):
        with pytest.raises(ValueError, match="code"):
            fn(bad)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"t_end": np.inf}, "t_end"),
        ({"t_end": np.nan}, "t_end"),
        ({"t_end": 1.0, "sample_phase": np.nan}, "sample_phase"),
        ({"t_end": 1.0, "sample_phase": -np.inf}, "sample_phase"),
    ],
)
def test_simulate_lines_rejects_non_finite_times_naming_them(kw, field):
    for fn in (simulate_lines, multibit_windows_sampled):
        with pytest.raises(ValueError, match=field):
            fn(np.array([0.0, 0.1]), np.array([0, 3]), **kw)


@settings(deadline=None, max_examples=80)
@given(
    seq=st.lists(st.tuples(st.floats(0.011, 0.03), st.integers(0, 7)), min_size=1, max_size=10),
    d1=st.floats(0.0, 0.005),
    d2=st.floats(0.0, 0.005),
    period=st.floats(2e-4, 4e-3),
    phase=st.floats(0.0, 4e-3),
    t_end_frac=st.floats(0.0, 1.0),
)
def test_binary_skew_windows_against_brute_force(seq, d1, d2, period, phase, t_end_frac):
    """With writes farther apart than the skew: a natural-binary transition is reported as sampled inside its
    skew window exactly when a sample ``phase + k period <= t_end`` lies in [first switch, last switch), and
    every such sample is a glitch."""
    delays = (0.0, d1, d2)
    tc, lv, t = [0.0], [0], 0.0
    for dt, level in seq:
        t += dt
        tc.append(t)
        lv.append(level)
    tc, lv = np.array(tc), np.array(lv)
    t_end = t_end_frac * (t + 0.02)
    ts = phase + period * np.arange(int(np.ceil((t_end + 1.0) / period)) + 1)
    ts = ts[(ts <= t_end) & (ts >= 0.0)]
    want: dict[str, list[int]] = {}
    n_inside = 0
    for m in range(1, lv.size):
        a, b = int(lv[m - 1]), int(lv[m])
        bits = [i for i in range(3) if (a ^ b) >> i & 1]
        if len(bits) < 2:
            continue
        lo, hi = tc[m] + min(delays[i] for i in bits), tc[m] + max(delays[i] for i in bits)
        k = int(np.count_nonzero((ts >= lo) & (ts < hi)))
        rec = want.setdefault(f"{a}->{b}", [0, 0])
        rec[0] += 1
        rec[1] += int(k > 0)
        n_inside += k
    assert multibit_windows_sampled(tc, lv, t_end, delays, period, phase) == want
    trace = simulate_lines(tc, lv, t_end, delays, period, phase, "binary")
    np.testing.assert_allclose(trace.t_sample, ts, rtol=0, atol=0)
    assert count_glitches(trace) == n_inside


# --------------------------------------------------------------------------------------------------------
# sensors: Sharp rangers, taxels, mounts, skin layout


@SETTINGS
@given(model=st.sampled_from([GP2Y0A21YK, GP2D120XJ00F]), d=st.lists(ANY_FLOAT | st.floats(-0.1, 2.0), max_size=20))
def test_sharp_scalar_voltage_equals_the_vectorised_one(model, d):
    """``voltage_scalar`` is ``voltage`` for one distance, whatever the distance (NaN, +-inf, negative)."""
    with np.errstate(over="ignore"):  # huge distances: the near-branch term, discarded, overflows
        v = model.voltage(np.array(d, float))
    for x, vx in zip(d, v, strict=True):
        assert model.voltage_scalar(x) == vx
        assert math.isfinite(vx) and vx >= min(model.v_floor, model.v_contact) - 1e-12


@SETTINGS
@given(model=st.sampled_from([GP2Y0A21YK, GP2D120XJ00F]), vs=st.lists(ANY_FLOAT | st.floats(-1, 5), max_size=40))
def test_tracker_never_reports_more_than_the_far_candidate_nor_nan(model, vs):
    """For any voltage sequence the report is >= 0, never NaN, never more than the far-branch distance of the
    table (interpolated here), and on the near branch never more than the peak distance; NaN/inf -> 0."""
    tr = AmbiguityTracker(model)
    dt, vt = np.array(model.d_table), np.array(model.v_table)
    v_dmax = np.interp(model.d_max, dt, vt)
    for v in vs:
        rep = tr.update(v)
        assert not math.isnan(rep) and rep >= 0.0
        if not math.isfinite(v):
            assert rep == 0.0
            continue
        far = math.inf if v < v_dmax else float(np.interp(-v, -vt, dt))
        assert rep <= far
        if tr.near:
            assert rep <= model.d_peak


@settings(deadline=None, max_examples=150)
@given(
    d=st.floats(0.0, 0.15),
    rho=st.floats(0.0, 1.0),
    min_rho=st.floats(0.05, 1.0),
    vref=st.floats(1.0, 5.0),
    v_sat=st.floats(1.0, 6.0),
    r_pd=st.floats(1e3, 1e5),
)
def test_proximity_lower_bound_never_over_reports_for_any_adc_and_saturation(d, rho, min_rho, vref, v_sat, r_pd):
    """The bound holds for any surface at least as bright as ``min_rho``, inside the range, also where the
    ADC clips at its reference before the amplifier saturates (``v_sat > vref``). inf only at the dark level
    (nothing seen: documented; a weak element reads dark within its ``max_range``)."""
    assume(rho >= min_rho)
    p = ProximityTaxel(noise_counts=0.0, vref=vref, v_sat=v_sat, r_pd=r_pd)
    c = p.counts(np.array([d]), reflectivity=rho)
    assert 0 <= c[0] <= 2**p.bits - 1
    est = p.distance_lower_bound(c, min_reflectivity=min_rho)[0]
    if np.isinf(est):
        assert c[0] <= round(p.v_dark / p.vref * (2**p.bits - 1))
    else:
        assert est <= d + 1e-12, (c, est)


def test_proximity_lower_bound_of_a_nan_signal_is_zero():
    """A NaN (filtered) signal is no evidence of free space: the bound is 0, not NaN."""
    p = ProximityTaxel(noise_counts=0.0)
    out = p.distance_lower_bound(np.array([np.nan, 0.0, 2000.0]))
    assert out[0] == 0.0 and np.isinf(out[1]) and out[2] == 0.0


@SETTINGS
@given(d=st.lists(READING, min_size=1, max_size=20), rho=st.floats(0.0, 1.0))
def test_proximity_voltage_is_monotone_bounded_and_nothing_beyond_range(d, rho):
    p = ProximityTaxel(noise_counts=0.0)
    v = p.voltage(np.array(d, float), rho)
    assert np.all((v >= p.v_dark) & (v <= p.v_sat))
    for x, vx in zip(d, v, strict=True):
        if not (math.isfinite(x) and x <= p.max_range):
            assert vx == p.v_dark
    key = np.array([x if math.isfinite(x) and x <= p.max_range else np.inf for x in d])
    o = np.argsort(np.maximum(key, 0.0), kind="stable")
    assert np.all(np.diff(v[o]) <= 1e-15)


@SETTINGS
@given(forces=st.lists(st.floats(-1e308, 1e308) | st.sampled_from([np.inf, -np.inf, np.nan]), min_size=1, max_size=20))
def test_contact_taxel_counts_are_valid_monotone_and_nan_or_inf_force_is_contact(forces):
    """Counts stay within the 10-bit range and never fall with a larger force; deformation in [0, h]; an
    infinite or NaN force (a blown-up simulation) reads as contact, never as no contact."""
    c = ContactTaxel(noise_counts=0.0)
    f = np.array(forces, float)
    with np.errstate(over="ignore"):
        dl = c.deformation(f)
        k = c.counts(f)
    assert np.all((k >= 0) & (k <= 2**c.bits - 1))
    assert np.all((dl >= 0) & (dl <= c.thickness))
    key = np.where(np.isnan(f), np.inf, f)
    o = np.argsort(key, kind="stable")
    assert np.all(np.diff(k[o]) >= 0)
    bad = ~np.isfinite(f) & ~(f < 0)
    assert np.all(c.in_contact(k[bad]))


@SETTINGS
@given(
    radius=st.floats(0.01, 0.2),
    z0=st.floats(-0.5, 0.5),
    pitch=st.floats(1e-3, 0.1),
    n_modules=st.integers(1, 9),
    pattern=st.text(alphabet="PC", min_size=1, max_size=9),
    angle0=st.floats(-10, 10),
)
def test_skin_mounts_lie_on_the_cylinder_with_outward_unit_axes(radius, z0, pitch, n_modules, pattern, angle0):
    L = SkinLayout("link", radius, z0, pitch, n_modules, len(pattern), pattern, 0.15, angle0)
    ms = L.mounts()
    assert len(ms) == L.n_elements == n_modules * len(pattern) and len({m.name for m in ms}) == len(ms)
    kinds = L.kinds()
    for k, m in enumerate(ms):
        mod, e = divmod(k, len(pattern))
        p, a = np.array(m.position), np.array(m.axis)
        assert np.hypot(p[0], p[1]) == pytest.approx(radius, rel=1e-12)
        assert p[2] == pytest.approx(z0 + e * pitch, abs=1e-12)
        np.testing.assert_allclose(a, np.r_[p[:2] / radius, 0.0], atol=1e-12)  # outward normal
        phi = angle0 + 2 * np.pi * mod / n_modules
        np.testing.assert_allclose(a[:2], [np.cos(phi), np.sin(phi)], atol=1e-12)
        assert m.kind == ("proximity" if kinds[k] == "P" else "contact") and m.link == "link"


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"pattern": "PCX"}, "pattern"),
        ({"pattern": "PC"}, "pattern"),
        ({"radius": np.nan}, "radius"),
        ({"radius": -0.1}, "radius"),
        ({"pitch": 0.0}, "pitch"),
        ({"n_modules": 0}, "n_modules"),
    ],
)
def test_skin_layout_rejects_bad_fields_naming_them(kw, match):
    base = {"link": "l", "per_module": 3, "pattern": "PCP"}
    with pytest.raises(ValueError, match=match):
        SkinLayout(**{**base, **kw})


@SETTINGS
@given(
    pos=st.lists(ANY_FLOAT, min_size=0, max_size=4),
    axis=st.lists(ANY_FLOAT, min_size=0, max_size=4),
    max_range=ANY_FLOAT,
)
def test_sensor_mount_accepts_only_what_it_documents(pos, axis, max_range):
    p, a = np.array(pos, float), np.array(axis, float)
    ok_p = p.shape == (3,) and np.all(np.isfinite(p))
    with np.errstate(over="ignore"):
        ok_a = a.shape == (3,) and np.all(np.isfinite(a)) and abs(np.linalg.norm(a) - 1.0) <= 1e-3
    ok_r = math.isfinite(max_range) and max_range > 0
    with np.errstate(over="ignore"):
        _check_mount(pos, axis, max_range, ok_p, ok_a, ok_r)


def _check_mount(pos, axis, max_range, ok_p, ok_a, ok_r):
    if ok_p and ok_a and ok_r:
        SensorMount("s", "l", tuple(pos), tuple(axis), max_range)
    else:
        field = "position" if not ok_p else "axis" if not ok_a else "max_range"
        with pytest.raises(ValueError, match=f"sensor 's': {field}"):
            SensorMount("s", "l", tuple(pos), tuple(axis), max_range)


# --------------------------------------------------------------------------------------------------------
# momentum residual and contact detection (§6.1)


def _static_response(lwr, gain, dt, tau_mode, terms, tau_ext, q, steps):
    """The observer on a robot held still at q (q̇ = 0) with τ = g(q) - τ_ext: then τ_ext = g - τ exactly."""
    import pinocchio as pin

    g = np.array(pin.computeGeneralizedGravity(lwr.model, lwr.model.createData(), q))
    obs = MomentumObserver(RigidBodyDynamics(lwr), gain=gain, dt=dt, tau_mode=tau_mode, terms=terms)
    out = [obs.update(q, np.zeros(7), g - tau_ext) for _ in range(steps + 1)]
    return np.array(out)


@settings(deadline=None, max_examples=20)
@given(
    seed=st.integers(0, 2**31 - 1),
    gain_dt=st.floats(0.01, 6.0),
    dt=st.floats(1e-4, 0.02),
    tau_mode=st.sampled_from(["sample", "average"]),
    terms=st.sampled_from(["pinocchio", "compiled"]),
)
def test_residual_is_the_discrete_first_order_filter_and_its_time_constant(lwr, seed, gain_dt, dt, tau_mode, terms):
    """Held still under a constant external torque, every residual component follows
    ``r_k = τ_ext (1 - a^k)``, ``a = (1 - K dt/2) / (1 + K dt/2)`` (closed form of the Tustin update), for any
    ``K dt > 0``; and the error envelope decays with :func:`discrete_time_constant`: ``|a|^k = exp(-k dt/T)``,
    a finite T >= 0 (0: dead-beat at ``K dt = 2``)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0, 2.0, 7)
    tau_ext = rng.uniform(-30, 30, 7)
    gain = gain_dt / dt
    r = _static_response(lwr, gain, dt, tau_mode, terms, tau_ext, q, 12)
    a = (1 - gain * dt / 2) / (1 + gain * dt / 2)
    k = np.arange(13)[:, None]
    np.testing.assert_allclose(r, tau_ext * (1 - a**k), rtol=0, atol=1e-8 * (1 + 30 * 13))
    T = discrete_time_constant(gain, dt)
    assert np.isfinite(T) and T >= 0
    np.testing.assert_allclose(
        np.exp(-np.arange(13) * dt / T) if T > 0 else (np.arange(13) == 0),
        np.abs(a) ** np.arange(13),
        rtol=1e-9,
        atol=1e-300,
    )


@settings(deadline=None, max_examples=30)
@given(
    field=st.sampled_from(["q", "qd", "tau"]),
    index=st.integers(0, 6),
    value=st.sampled_from([np.nan, np.inf, -np.inf]),
    terms=st.sampled_from(["pinocchio", "compiled"]),
    kind=st.sampled_from(["array", "list", "int_ok"]),
    seed=st.integers(0, 2**31 - 1),
)
def test_observer_rejects_non_finite_input_naming_it_and_keeps_its_state(lwr, field, index, value, terms, kind, seed):
    """A NaN/inf in q, q̇ or τ (float64 array or list) raises ValueError naming the field, and the observer
    goes on exactly as a twin that never saw it; a list or integer input gives the float64 array's residual."""
    rng = np.random.default_rng(seed)
    dyn = RigidBodyDynamics(lwr)
    a, b = (MomentumObserver(dyn, gain=50.0, dt=0.005, terms=terms) for _ in range(2))
    ins = [(rng.uniform(-1, 1, 7), rng.uniform(-1, 1, 7), rng.uniform(-5, 5, 7)) for _ in range(4)]
    for x in ins[:2]:
        np.testing.assert_array_equal(a.update(*x), b.update(*x))
    bad = [v.copy() for v in ins[2]]
    bad[("q", "qd", "tau").index(field)][index] = value
    if kind == "list":
        bad = [v.tolist() for v in bad]
    with pytest.raises(ValueError, match=rf"\b{field} must be finite"):
        a.update(*bad)
    np.testing.assert_array_equal(a.r, b.r)
    for x in ins[2:]:
        y = [np.round(v).astype(int) for v in x] if kind == "int_ok" else [v.tolist() for v in x]
        np.testing.assert_array_equal(a.update(*y), b.update(*(np.asarray(v, float) for v in y)))


@settings(deadline=None, max_examples=80)
@given(
    seq=st.lists(
        st.lists(st.floats(-5, 5) | st.sampled_from([np.nan, np.inf, -np.inf, 1e308]), min_size=3, max_size=3),
        min_size=1,
        max_size=40,
    ),
    r_th=st.floats(0.1, 5.0),
    joint_th=st.none() | st.floats(0.1, 5.0),
    ratio=st.floats(0.05, 1.0),
    cycles=st.integers(-1, 5),
)
def test_contact_detector_hysteresis_invariants(seq, r_th, joint_th, ratio, cycles):
    """Any residual over a threshold, or non-finite, is a contact in that cycle; a release comes only after
    ``release_cycles`` consecutive finite cycles below ``release_ratio`` times every threshold; onset and
    release flags mark the changes; the label is set exactly while in contact. ``release_cycles < 1`` (which
    would release a contact still over its threshold) is refused, naming the field."""
    rj = None if joint_th is None else np.full(3, joint_th)
    if cycles < 1:
        with pytest.raises(ValueError, match="release_cycles"):
            ContactDetector(r_th=r_th, r_th_joint=rj, release_ratio=ratio, release_cycles=cycles)
        cycles = 1 - cycles  # and check the property with a valid count
    det = ContactDetector(r_th=r_th, r_th_joint=rj, release_ratio=ratio, release_cycles=cycles)
    was, below = False, 0
    for r in seq:
        r = np.array(r)
        s = det.step(r, 0.005)
        finite = bool(np.all(np.isfinite(r)))
        norm = float(np.sqrt(np.sum((r / 1e300) ** 2)) * 1e300) if finite else math.inf

        def over(k, r=r, norm=norm):
            return norm > k * r_th or (rj is not None and bool(np.any(np.abs(r) > k * rj)))

        if not finite or over(1.0):
            assert s.active
        assert s.onset == (s.active and not was) and s.release == (was and not s.active)
        assert (s.label != "") == s.active
        below = below + 1 if (was and finite and not over(ratio)) else 0
        if s.release:
            assert below >= cycles
        was = s.active
    for bad_dt in (0.0, -0.005, np.nan):
        with pytest.raises(ValueError, match="dt"):
            det.step(np.zeros(3), bad_dt)


# --------------------------------------------------------------------------------------------------------
# contact force (§6.1) and contact point (§6.2)


def _svd_estimate(At, r, eps, lambda_max):
    """The module docstring's formula from numpy's SVD of A = Atᵀ."""
    U, s, Vt = np.linalg.svd(At.T, full_matrices=False)  # A (n, m) = U S Vt
    lam2 = np.where(s < eps, lambda_max**2 * (1 - (s / eps) ** 2), 0.0)
    den = s**2 + lam2
    coef = np.divide(s, den, out=np.zeros_like(s), where=den > 1e-300)
    return Vt.T @ (coef * (U.T @ r)), s, lam2


@settings(deadline=None, max_examples=60)
@given(
    seed=st.integers(0, 2**31 - 1),
    k=st.integers(1, 2),
    n=st.integers(3, 9),
    rank_drop=st.integers(0, 3),
    scale=st.sampled_from([1e-4, 1e-2, 1.0]),
    eps=st.floats(1e-4, 0.05),
    lambda_max=st.floats(1e-3, 0.1),
)
def test_force_estimate_equals_the_damped_svd_formula(seed, k, n, rank_drop, scale, eps, lambda_max):
    """F̂ = Σ σ_i/(σ_i² + λ_i²) v_i u_iᵀ r against numpy's SVD, the singular values, an orthonormal
    unobservable basis in the null space of A, the projector I - U Uᵀ, and exactness on observable forces."""
    rng = np.random.default_rng(seed)
    m = 3 * k
    At = rng.normal(size=(m, n)) * scale
    drop = min(rank_drop, m - 1)
    if drop:  # make A rank deficient: some rows combinations of the others
        At[m - drop :] = rng.normal(size=(drop, m - drop)) @ At[: m - drop]
    r = rng.normal(size=n) * 20
    est = estimate_contact_forces(list(At.reshape(k, 3, n)), r, eps=eps, lambda_max=lambda_max)
    F, s, lam2 = _svd_estimate(At, r, eps, lambda_max)
    s = np.r_[s, np.zeros(m - s.size)]  # A (n, 3k) with n < 3k: the other singular values are 0
    lam2 = np.r_[lam2, np.full(m - lam2.size, lambda_max**2)]
    smax = s[0]
    np.testing.assert_allclose(est.singular_values**2, s**2, rtol=0, atol=1e-11 * smax**2)
    np.testing.assert_allclose(est.stacked, F, rtol=1e-6, atol=1e-6 * np.linalg.norm(r) / max(smax, 1e-12))
    assert est.forces.shape == (k, 3) and est.damping >= 0
    assert est.damping == pytest.approx(lam2.max(), rel=1e-5, abs=1e-12 * lambda_max**2)
    Un = est.unobservable
    assert Un.shape[1] == np.count_nonzero(s < 1e-3 * smax)
    np.testing.assert_allclose(Un.T @ Un, np.eye(Un.shape[1]), atol=1e-9)
    # (reported where sigma < tol * sigma_max: ||A u|| is that small, not 0)
    assert np.all(np.linalg.norm(At.T @ Un, axis=0) <= 1e-3 * smax * (1 + 1e-6))
    P = est.projector
    np.testing.assert_allclose(P, P.T, atol=1e-12)
    np.testing.assert_allclose(P @ P, P, atol=1e-9)
    if s[-1] >= eps and s[-1] >= 1e-3 * smax:  # well conditioned: exact on any force
        Fa = rng.normal(size=m) * 10
        est2 = estimate_contact_forces(list(At.reshape(k, 3, n)), At.T @ Fa, eps=eps, lambda_max=lambda_max)
        err, frac = observable_error(est2, Fa)
        assert np.linalg.norm(err) <= 1e-6 * np.linalg.norm(Fa) and frac == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("jac", "r", "match"),
    [
        ([], np.zeros(7), "jacobians"),
        (np.zeros(3), np.zeros(7), "jacobians"),
        (np.zeros((2, 7)), np.zeros(7), "jacobians"),
        ([np.zeros((3, 7)), np.zeros((3, 7, 1))], np.zeros(7), "jacobians"),
        (np.zeros((3, 7)), np.zeros((7, 1)), "r must"),
        (np.zeros((3, 7)), np.array([np.nan] + [0.0] * 6), "finite"),
        (np.full((3, 7), -np.inf), np.zeros(7), "finite"),
    ],
)
def test_force_estimate_bad_input_names_the_field(jac, r, match):
    with pytest.raises(ValueError, match=match):
        estimate_contact_forces(jac, r)


@settings(deadline=None, max_examples=15)
@given(
    seed=st.integers(0, 2**31 - 1),
    link=st.sampled_from([f"lwr_link_{i}" for i in range(1, 8)]),
)
def test_point_jacobian_matches_finite_differences_anywhere(lwr, seed, link):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, 7)
    local = rng.uniform(-0.1, 0.1, 3)
    R, o = lwr.frame_pose(q, link)
    J = point_jacobian(lwr, q, link, R @ local + o)
    h = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        Rp, op = lwr.frame_pose(q + dq, link)
        Rm, om = lwr.frame_pose(q - dq, link)
        np.testing.assert_allclose(J[:, i], ((Rp @ local + op) - (Rm @ local + om)) / (2 * h), atol=1e-7)


@SETTINGS
@given(
    V=arrays(
        np.float64,
        st.tuples(st.integers(1, 30), st.just(3)),
        elements=st.floats(-10, 10) | st.sampled_from([np.nan, np.inf, -np.inf]),
    ),
    p=arrays(np.float64, 3, elements=st.floats(-10, 10) | st.sampled_from([np.nan, np.inf])),
)
@example(V=np.array([[1e-05, 3.0, 3.0], [3.0, 1e-05, 3.0]]), p=np.zeros(3))  # a tie that einsum's order broke
def test_nearest_vertex_compiled_pass_is_the_first_minimum_like_numpy(V, p):
    """The compiled pass (float64 arrays) gives numpy's argmin: the first minimum, or the first NaN distance."""
    i, d = nearest_vertex(V, p)
    with np.errstate(invalid="ignore"):
        j, e = nearest_vertex(V, p.tolist())  # the numpy path
        dist = np.sqrt(np.sum((V - p) ** 2, axis=1))
    ref = int(np.argmin(dist))
    assert i == j == ref
    assert (math.isnan(d) and math.isnan(e) and math.isnan(dist[ref])) or d == pytest.approx(dist[ref], rel=1e-12)


@SETTINGS
@given(
    a=arrays(np.float64, 3, elements=st.floats(-1, 1)),
    w=arrays(np.float64, 3, elements=st.floats(-0.5, 0.5)),
    r=st.floats(0.005, 0.15),
    spacing=st.floats(0.01, 0.05),
    degenerate=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
@example(a=np.zeros(3), w=np.zeros(3), r=0.1015625, spacing=0.041015625, degenerate=True, seed=0)  # a sphere
def test_capsule_vertices_lie_on_the_capsule_and_cover_it(a, w, r, spacing, degenerate, seed):
    """Every vertex is at distance r from the axis segment; every surface point (sampled here: cylinder and
    both caps) has a vertex within ``spacing`` (a sphere when the segment is degenerate)."""
    b = a if degenerate else a + w
    V = _capsule_vertices(a, b, r, spacing)
    ab = b - a
    L2 = float(ab @ ab)
    t = np.clip(((V - a) @ ab) / L2, 0, 1) if L2 > 1e-24 else np.zeros(len(V))
    np.testing.assert_allclose(np.linalg.norm(V - (a + t[:, None] * ab), axis=1), r, atol=1e-12)
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    s = rng.uniform(0, 1, 200)
    pts = []
    for sk, uk in zip(s, u, strict=True):
        if L2 > 1e-24:
            z = ab / np.sqrt(L2)
            perp = uk - (uk @ z) * z
            if np.linalg.norm(perp) < 1e-6:
                continue
            pts.append(a + sk * ab + r * perp / np.linalg.norm(perp))  # on the cylinder
            pts.append((a if uk @ z < 0 else b) + r * uk)  # on a cap
        else:
            pts.append(a + r * uk)
    D = np.linalg.norm(np.array(pts)[:, None] - V[None], axis=2).min(axis=1)
    assert D.max() <= spacing


@pytest.mark.parametrize("spacing", [0.0, -0.01, np.nan, np.inf, -np.inf])
def test_robot_surface_rejects_bad_spacing(lwr, spacing):
    with pytest.raises(ValueError, match="spacing"):
        RobotSurface(lwr, spacing=spacing)
