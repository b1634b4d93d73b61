"""Property tests of the guarantees of the proximity sensing of SAPHARI D4.1.1 §4.3 and §5 (sensors.sharp,
sensors.graycode, sensors.levels, sensors.taxel): a distance derived from a reading is never larger than the
true one (the ambiguous near branch of the Sharp sensors resolved on the safe side), and a bad reading gives
the safe answer (0 m, obstacle present) or a ValueError naming the field. References written here: the
data-sheet curve points and the near-branch line, inverted by bisection; the common fit
``V = 20.99 / d[cm] + 0.19`` quoted in the module docstring; ``g = b ^ (b >> 1)`` and the prefix-XOR decoding
of Gray codes; a line-by-line model of skewed digital lines.

Faults these tests found (each failed on the old code):

* ``AmbiguityTracker`` / ``IRRanger``: with the ranger's own noise (0.01 V) an object at contact reads
  ``v_contact`` minus a little, the tracker left the near branch and reported ``d_far`` (16.6 cm on the
  GP2Y0A21, 8 cm on the GP2D120) for a touching object, until it moved out again; the 10-bit ADC's rounding
  alone over-reported (up to inf at ``d_max``) and a saturated ADC count was read as a real voltage; a
  negative voltage gave inf (nothing in range), a voltage above the peak ``d_peak``; a string raised
  numpy's TypeError and a bool was taken for volts; NaN/inf times and non-numbers were accepted by
  ``IRRanger.sample`` (an inf time froze the sensor for good).
* ``SharpModel.distance_far``/``distance_near``: NaN gave NaN, a negative voltage inf.
* ``multibit_windows_sampled``: no validation (IndexError, or silent nonsense on NaN times);
  ``SkewedLines.write`` took a one-element array level, a bool or a numeric string time; string
  ``t_change`` got numpy's message naming no field.
* ``speed_for_level`` truncated a fractional level (6.9 -> 6: 10 mm/s instead of a stop);
  ``extra_stop_delay`` too; ``LevelMap.update`` raised TypeError on a string signal.
* ``ProximityTaxel.distance_lower_bound``: a negative count (no ADC gives one) gave inf (nothing seen).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from depthguard.sensors.graycode import SkewedLines, gray_decode, gray_encode, multibit_windows_sampled, simulate_lines
from depthguard.sensors.levels import LevelMap, extra_stop_delay, speed_for_level
from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK, AmbiguityTracker, IRRanger, SharpModel
from depthguard.sensors.taxel import ProximityTaxel

NAN, INF = math.nan, math.inf
MODELS = [pytest.param(GP2Y0A21YK, id="GP2Y0A21YK"), pytest.param(GP2D120XJ00F, id="GP2D120XJ00F")]
ANY_MODEL = st.sampled_from([GP2Y0A21YK, GP2D120XJ00F])
HAND = 0.25  # m/s, the speed the module's docstring property-tests
T_MEAS = 38.3e-3 + 9.6e-3  # s, the longest measurement period
BAD_NUMBERS = [True, False, np.bool_(True), "1.5", "a", None, [1.0], np.array([1.0]), b"1", 1 + 0j]

# ------------------------------------------------------------------------------------------- references
# Data-sheet readings (distance m, typical output V of a white reflector), near branch: linear from
# v_contact at 0 m to the peak; beyond the last point: v_last d_last / d, floored at v_floor; 1.5 d_max on:
# nothing (v_floor). Written here from the data sheets' figures, not read from the module.
REF = {
    "GP2Y0A21YK": (
        [0.06, 0.07, 0.08, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.50, 0.60, 0.70, 0.80],
        [3.15, 3.00, 2.75, 2.30, 1.65, 1.30, 1.08, 0.92, 0.80, 0.73, 0.60, 0.50, 0.45, 0.40],
        1.5,
        0.25,
    ),
    "GP2D120XJ00F": (
        [0.03, 0.04, 0.05, 0.06, 0.08, 0.10, 0.12, 0.14, 0.16, 0.18, 0.20, 0.25, 0.30],
        [3.00, 2.75, 2.30, 1.95, 1.53, 1.25, 1.08, 0.93, 0.83, 0.74, 0.67, 0.53, 0.45],
        1.5,
        0.25,
    ),
}


def ref_voltage(model: SharpModel, d: float) -> float:
    dt, vt, v_contact, v_floor = REF[model.name]
    if not (math.isfinite(d) and d <= 1.5 * model.d_max):
        return v_floor
    if d < dt[0]:
        return v_contact + (vt[0] - v_contact) * max(d, 0.0) / dt[0]
    if d > dt[-1]:
        return max(vt[-1] * dt[-1] / d, v_floor)
    i = max(k for k in range(len(dt)) if dt[k] <= d)
    if i == len(dt) - 1:
        return vt[-1]
    return vt[i] + (vt[i + 1] - vt[i]) * (d - dt[i]) / (dt[i + 1] - dt[i])


def _bisect(f, lo: float, hi: float) -> float:
    """The root of the monotone ``f`` on [lo, hi] (f(lo), f(hi) of opposite signs or zero)."""
    flo = f(lo)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if (f(mid) > 0) == (flo > 0):
            lo, flo = mid, f(mid)
        else:
            hi = mid
    return 0.5 * (lo + hi)


def ref_far(model: SharpModel, v: float) -> float:
    """Far-branch distance of ``v`` by bisection on the reference curve over [d_peak, d_max]; inf below the
    voltage at d_max, d_peak above the peak."""
    dt, vt, _, _ = REF[model.name]
    if v < ref_voltage(model, model.d_max):
        return INF
    if v >= vt[0]:
        return dt[0]
    return _bisect(lambda d: ref_voltage(model, d) - v, dt[0], model.d_max)


def ref_near(model: SharpModel, v: float) -> float:
    dt, vt, v_contact, _ = REF[model.name]
    if v <= v_contact:
        return 0.0
    if v >= vt[0]:
        return dt[0]
    return _bisect(lambda d: ref_voltage(model, d) - v, 0.0, dt[0])


class ClippedNormal:
    """A random generator whose ``normal`` noise is clipped to ``+-k`` standard deviations: noise within the
    tolerance the ranger allows for (4 standard deviations)."""

    def __init__(self, seed: int, k: float = 4.0) -> None:
        self.g, self.k = np.random.default_rng(seed), k

    def normal(self, loc: float, scale: float) -> float:
        return loc + float(np.clip(self.g.normal(0.0, scale), -self.k * scale, self.k * scale))

    def uniform(self, lo: float, hi: float) -> float:
        return float(self.g.uniform(lo, hi))


def _walk(model: SharpModel, start: float, steps: list[float], dt: float) -> list[float]:
    """Distances of an object moving by ``steps`` (m/s) every ``dt`` s, clipped to [0, 1.2 d_max]."""
    d, out = model.d_min + start * (model.d_max - model.d_min), []
    for v in steps:
        d = min(max(d + v * dt, 0.0), 1.2 * model.d_max)
        out.append(d)
    return out


# ------------------------------------------------------------------------------------------- the curves
@pytest.mark.parametrize("model", MODELS)
def test_curve_is_the_data_sheet_curve_with_monotone_branches(model):
    d = np.concatenate([np.linspace(-0.05, 1.6 * model.d_max, 997), [NAN, INF, -INF, 1e300]])
    with np.errstate(over="ignore"):
        v = model.voltage(d)
    np.testing.assert_allclose(v, [ref_voltage(model, x) for x in d], rtol=0, atol=1e-12)
    near = d[(d >= 0) & (d < model.d_peak)]
    far = d[(d >= model.d_peak) & (d <= 1.5 * model.d_max)]
    assert np.all(np.diff(model.voltage(near)) > 0) and np.all(np.diff(model.voltage(far)) <= 0)
    assert np.all(np.diff(model.voltage(far[far <= model.d_max])) < 0)
    if model is GP2Y0A21YK:  # the docstring's claim about the common fit over 10-80 cm
        pts = np.array([x for x in REF[model.name][0] if x >= 0.10])
        assert np.max(np.abs(model.voltage(pts) - (20.99 / (100 * pts) + 0.19))) <= 0.061
        dd = np.linspace(0.10, 0.80, 2000)
        err = model.voltage(dd) - (20.99 / (100 * dd) + 0.19)
        assert -0.061 <= err.min() and err.max() <= 0.11
        assert 0.25 <= float(model.voltage(np.array([0.8]))[0]) <= 0.55  # the data sheet's range at 80 cm


@settings(max_examples=60, deadline=None)
@given(model=ANY_MODEL, u=st.floats(0.0, 1.0))
def test_branch_inverses_against_bisection_and_nan_or_negative_is_zero(model, u):
    v_far = ref_voltage(model, model.d_max) + u * (model.v_peak - ref_voltage(model, model.d_max))
    assert float(model.distance_far(np.array([v_far]))[0]) == pytest.approx(ref_far(model, v_far), abs=1e-9)
    v_near = model.v_contact + u * (model.v_peak - model.v_contact)
    assert float(model.distance_near(np.array([v_near]))[0]) == pytest.approx(ref_near(model, v_near), abs=1e-9)
    out = model.distance_far(np.array([NAN, -1e-9, -INF, INF]))
    assert out.tolist() == [0.0, 0.0, 0.0, model.d_peak]
    assert model.distance_near(np.array([NAN, -INF, INF])).tolist() == [0.0, 0.0, model.d_peak]


# ------------------------------------------------------------------------------------------- the tracker
@settings(max_examples=80, deadline=None)
@given(
    model=ANY_MODEL,
    steps=st.lists(st.floats(-HAND, HAND), min_size=1, max_size=80),
    start=st.floats(0.0, 1.0),
    tol=st.floats(0.0, 0.06),
    noise=st.lists(st.floats(-1.0, 1.0), min_size=80, max_size=80),
)
@example(model=GP2Y0A21YK, steps=[-HAND] * 80, start=0.0, tol=0.01, noise=[-1.0] * 80)  # sits at contact
@example(model=GP2D120XJ00F, steps=[-HAND] * 30, start=0.0, tol=0.01, noise=[-1.0] * 80)
def test_tracker_never_over_reports_with_readings_within_its_tolerance(model, steps, start, tol, noise):
    """Any path at the hand's speed from inside the rated range, read every 47.9 ms with any error within
    ``+-v_tol``: inside the range the report never exceeds the true distance, and on the far branch it is the
    bisection inverse of ``v + v_tol`` (the nearest distance the reading allows)."""
    tr = AmbiguityTracker(model, v_tol=tol)
    for d, e in zip(_walk(model, start, steps, T_MEAS), noise, strict=False):
        v = ref_voltage(model, d) + e * tol
        near_before = tr.near
        rep = tr.update(v)
        if d <= model.d_max:
            assert rep <= d + 1e-12, (d, v, rep, tr.near)
        if not near_before and not tr.near:
            assert rep == pytest.approx(ref_far(model, v + tol), abs=1e-9)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("v", [NAN, INF, -INF, -1e-9, -1.0, 0.0, 0.2, 3.2, 4.99, 5.0, 1e300], ids=repr)
def test_tracker_reading_no_distance_gives_is_obstacle_present(model, v):
    """A voltage outside [v_floor, v_peak] (tolerance 0) is a fault: 0 m, near branch, also from far."""
    if model.v_floor <= v <= model.v_peak:
        pytest.skip("a real reading for this model")
    tr = AmbiguityTracker(model)
    assert tr.update(model.v_floor) == INF
    assert tr.update(v) == 0.0 and tr.near
    assert tr.update(np.float64(v)) == 0.0


@pytest.mark.parametrize("bad", BAD_NUMBERS, ids=repr)
def test_tracker_refuses_non_numbers_by_name(bad):
    tr = AmbiguityTracker(GP2Y0A21YK)
    with pytest.raises(ValueError, match="v must be a real number"):
        tr.update(bad)
    for tol in (-0.01, NAN, INF, True, "0.1"):
        with pytest.raises(ValueError, match="v_tol"):
            AmbiguityTracker(GP2Y0A21YK, v_tol=tol)


# ------------------------------------------------------------------------------------------- the ranger
def _ranger_run(r: IRRanger, model: SharpModel, dists: list[float]) -> None:
    """Sample at 300 Hz while the object follows ``dists`` (one per sample): every report is at most the
    true distance at the last measurement, inside the rated range."""
    d_meas = INF
    for k, d in enumerate(dists):
        t = k / 300.0
        if r.due(t):
            d_meas = d
        _, rep = r.sample(t, d)
        if d_meas <= model.d_max:
            assert rep <= d_meas + 1e-12, (t, d_meas, rep)


@settings(max_examples=40, deadline=None)
@given(
    model=ANY_MODEL,
    steps=st.lists(st.floats(-HAND, HAND), min_size=1, max_size=400),
    start=st.floats(0.0, 1.0),
    vref=st.sampled_from([5.0, 3.3, 2.5]),
    bits=st.sampled_from([8, 10, 12]),
)
@example(model=GP2D120XJ00F, steps=[0.0], start=1.0, vref=5.0, bits=10)  # at d_max: the ADC rounded to inf
@example(model=GP2Y0A21YK, steps=[-HAND] * 400, start=0.0, vref=2.5, bits=10)  # a saturated ADC count
def test_noise_free_ranger_never_over_reports_through_its_adc(model, steps, start, vref, bits):
    r = IRRanger(model, noise_v=0.0, vref=vref, bits=bits)
    _ranger_run(r, model, _walk(model, start, steps, 1 / 300))


@settings(max_examples=30, deadline=None)
@given(
    model=ANY_MODEL,
    steps=st.lists(st.floats(-HAND, HAND), min_size=1, max_size=400),
    start=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31),
)
@example(model=GP2Y0A21YK, steps=[-HAND] * 400, start=0.0, seed=1)  # at contact: flipped to 16.6 cm
@example(model=GP2D120XJ00F, steps=[-HAND] * 400, start=0.0, seed=1)
def test_noisy_ranger_never_over_reports_with_noise_within_4_sigma(model, steps, start, seed):
    """The default ranger (0.01 V noise, here clipped at 4 standard deviations, and a 10-bit ADC)."""
    r = IRRanger(model, rng=ClippedNormal(seed))
    dists = _walk(model, start, steps, 1 / 300)
    _ranger_run(r, model, dists + dists[-1:] * 100)  # and stays there


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"noise_v": -0.01}, "noise_v"),
        ({"noise_v": NAN}, "noise_v"),
        ({"noise_v": INF}, "noise_v"),
        ({"vref": 0.0}, "vref"),
        ({"vref": NAN}, "vref"),
        ({"vref": "5"}, "vref"),
        ({"bits": True}, "bits"),
        ({"bits": 0}, "bits"),
        ({"bits": 10.0}, "bits"),
        ({"period": INF}, "period"),
        ({"period": NAN}, "period"),
        ({"v_tol": -1.0}, "v_tol"),
        ({"v_tol": NAN}, "v_tol"),
    ],
    ids=lambda x: repr(x) if not isinstance(x, dict) else ",".join(f"{k}={v!r}" for k, v in x.items()),
)
def test_ranger_refuses_bad_parameters_by_name(kw, field):
    with pytest.raises(ValueError, match=field):
        IRRanger(GP2Y0A21YK, **kw)


@pytest.mark.parametrize("t", [NAN, INF, -INF, "0.1", True, None], ids=repr)
def test_ranger_refuses_a_bad_time_and_keeps_measuring(t):
    r = IRRanger(GP2Y0A21YK, noise_v=0.0)
    with pytest.raises(ValueError, match="t"):
        r.sample(t, 0.3)
    v, rep = r.sample(0.0, 0.3)  # a new measurement still comes (an inf time used to freeze it)
    assert rep <= 0.3 and v == pytest.approx(0.92, abs=0.003)
    for bad in ("0.3", True, [0.3]):
        with pytest.raises(ValueError, match="true_distance"):
            r.sample(1.0, bad)


def test_sharp_model_refuses_inconsistent_tables():
    base = {"name": "x", "d_min": 0.1, "d_max": 0.3, "v_contact": 1.0}
    for kw, msg in [
        ({"d_table": (0.05, 0.3), "v_table": (3.0,)}, "same length"),
        ({"d_table": (0.05, 0.3), "v_table": (3.0, NAN)}, "finite"),
        ({"d_table": (0.3, 0.05), "v_table": (3.0, 0.5)}, "increasing"),
        ({"d_table": (0.05, 0.3), "v_table": (0.5, 3.0)}, "decreasing"),
        ({"d_table": (0.05, 0.2), "v_table": (3.0, 0.5)}, "d_max"),
        ({"d_table": (0.05, 0.3), "v_table": (3.0, 0.5), "v_contact": 2.9}, "v_contact"),
    ]:
        with pytest.raises(ValueError, match=msg):
            SharpModel(**{**base, **kw})


# ------------------------------------------------------------------------------------------- Gray code
def _ref_gray(b: int) -> int:
    return b ^ (b >> 1)


def _ref_gray_inverse(g: int) -> int:
    b, shift = g, 1
    while g >> shift:
        b ^= g >> shift
        shift += 1
    return b


@settings(max_examples=40, deadline=None)
@given(
    levels=arrays(
        st.sampled_from([np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64]),
        st.tuples(st.integers(0, 4), st.integers(0, 3)),
        elements=st.integers(0, 7),
    )
)
def test_gray_round_trip_against_xor_reference(levels):
    g = gray_encode(levels)
    assert g.shape == levels.shape
    assert g.tolist() == [[_ref_gray(int(b)) for b in row] for row in levels]
    assert gray_decode(g).tolist() == levels.tolist()
    assert gray_decode(levels).tolist() == [[_ref_gray_inverse(int(c)) for c in row] for row in levels]
    for b in range(8):  # Table 1, line 2 first
        assert format(int(gray_encode(b)), "03b") == format(_ref_gray(b), "03b")


@pytest.mark.parametrize(
    "bad",
    [-1, 8, 2**70, -(2**70), 3.0, NAN, True, np.bool_(False), "3", None, [1, 8], np.array([0.5]), [[1], [2, 3]]],
    ids=repr,
)
def test_gray_refuses_invalid_levels_and_codes(bad):
    with pytest.raises(ValueError, match="level"):
        gray_encode(bad)
    with pytest.raises(ValueError, match="code"):
        gray_decode(bad)


def _ref_lines(writes: list[tuple[float, int]], delays: tuple[float, float, float], t: float) -> int:
    """Line-by-line model: line i holds bit i of the Gray code of the last write with t_w + delay_i <= t (level
    0 before any), decoded by prefix XOR."""
    code = 0
    for i in range(3):
        last = 0
        for tw, lv in writes:
            if tw + delays[i] <= t:
                last = lv
        code |= ((_ref_gray(last) >> i) & 1) << i
    return _ref_gray_inverse(code)


@settings(max_examples=40, deadline=None)
@given(
    writes=st.lists(st.tuples(st.floats(0.0, 0.01), st.integers(0, 7)), max_size=10),
    delays=st.tuples(st.floats(0.0, 0.005), st.floats(0.0, 0.005), st.floats(0.0, 0.005)),
    reads=st.lists(st.floats(-0.01, 0.12), min_size=1, max_size=20),
)
def test_skewed_lines_read_what_the_line_model_says(writes, delays, reads):
    lines, t, seq = SkewedLines(delays, "gray"), 0.0, []
    for dt, lv in writes:
        t += dt
        lines.write(t, lv)
        seq.append((t, lv))
    for tr in reads:
        assert lines.read(tr) == _ref_lines(seq, delays, tr)


def test_skewed_lines_refuse_bad_writes_and_reads_by_name():
    lines = SkewedLines()
    for level in (np.array([3]), np.array([1, 2]), True, 3.0, "3", 8):
        with pytest.raises(ValueError, match="level"):
            lines.write(0.1, level)
    for t in ("0.1", True, None, NAN, INF):
        with pytest.raises(ValueError, match="time t"):
            lines.write(t, 1)
    for t in ("0.1", True, None, NAN):
        with pytest.raises(ValueError, match="time t"):
            lines.read(t)
    assert lines.t_writes == [-INF] and lines.read(1.0) == 0  # nothing was written


@pytest.mark.parametrize(
    ("tc", "lv", "delays", "field"),
    [
        ([0.0, 0.1], [0, 3, 4], (0.0, 0.001, 0.002), "same non-zero length"),
        ([0.0, 0.1, 0.2], [0, 3], (0.0, 0.001, 0.002), "same non-zero length"),
        ([], [], (0.0, 0.001, 0.002), "levels"),
        ([0.0, NAN], [0, 3], (0.0, 0.001, 0.002), "t_change"),
        ([0.1, 0.0], [0, 3], (0.0, 0.001, 0.002), "t_change"),
        (["a", "b"], [0, 3], (0.0, 0.001, 0.002), "t_change"),
        ([0.0, 0.1], [0, 3], (0.0, 0.001), "line_delays"),
        ([0.0, 0.1], [0, 3], (0.0, NAN, 0.002), "line_delays"),
        ([0.0, 0.1], [0, 3], (0.0, -0.001, 0.002), "line_delays"),
        ([0.0, 0.1], [0, 3.5], (0.0, 0.001, 0.002), "levels"),
    ],
    ids=["short-t", "short-levels", "empty", "nan-t", "decreasing-t", "string-t", "2-delays", "nan-delay",
         "negative-delay", "fractional-level"],
)  # fmt: skip
def test_line_simulations_refuse_bad_sequences_by_name(tc, lv, delays, field):
    for fn in (simulate_lines, multibit_windows_sampled):
        with pytest.raises(ValueError, match=field):
            fn(np.array(tc) if tc else [], np.array(lv) if lv else [], 0.3, delays)


# ------------------------------------------------------------------------------------------- levels, taxels
@pytest.mark.parametrize("bad", [6.9, 0.5, 7.0, True, "3", None, -1, 8], ids=repr)
def test_level_functions_refuse_non_integer_levels(bad):
    with pytest.raises(ValueError, match="level"):
        speed_for_level(bad)
    with pytest.raises(ValueError, match="level"):
        extra_stop_delay(0.0044, 0.002, 0, bad)


def test_speed_for_level_is_table1_and_refuses_bad_speed_tables():
    assert [speed_for_level(k) for k in range(8)] == [0.4, 0.32, 0.26, 0.2, 0.14, 0.08, 0.01, 0.0]
    assert speed_for_level(np.int8(7)) == 0.0
    for speeds in ((0.1,) * 7, (NAN,) * 8, (-0.1,) * 8):
        with pytest.raises(ValueError, match="speeds"):
            speed_for_level(3, speeds)


@pytest.mark.parametrize("bad", ["50", True, None, [50.0]], ids=repr)
def test_level_map_refuses_a_non_number_signal(bad):
    m = LevelMap(thresholds=(20, 30, 45, 70, 110, 180))
    with pytest.raises(ValueError, match="signal"):
        m.update(bad, False)
    assert m.update(NAN, False) == 6 and m.update(-INF, False) == 6  # no reading: the safe side


@settings(max_examples=30, deadline=None)
@given(c=st.lists(st.floats(-1e9, -1e-9) | st.just(-INF), min_size=1, max_size=5))
def test_taxel_negative_counts_are_a_fault_not_free_space(c):
    p = ProximityTaxel(noise_counts=0.0)
    assert np.all(p.distance_lower_bound(np.array(c)) == 0.0)
