"""Gray code, skewed lines and glitches, safety-level mapping with hysteresis, one-level stepping."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.sensors.graycode import (
    binary_encode,
    count_glitches,
    gray_decode,
    gray_encode,
    multibit_windows_sampled,
    simulate_lines,
)
from depthguard.sensors.levels import TABLE1_SPEEDS, LevelMap, LevelStepper, extra_stop_delay, hold_time

DELAYS = (0.0, 2.2e-3, 4.4e-3)
TS = 2.0e-3


def test_gray_table1_and_adjacency():
    # Table 1, written line 2 first
    table = ["000", "001", "011", "010", "110", "111", "101", "100"]
    assert [format(int(gray_encode(k)), "03b") for k in range(8)] == table
    assert np.array_equal(gray_decode(gray_encode(np.arange(8))), np.arange(8))
    for k in range(7):
        assert bin(int(gray_encode(k)) ^ int(gray_encode(k + 1))).count("1") == 1
    # binary has multi-line transitions
    multi = [k for k in range(7) if bin(int(binary_encode(k)) ^ int(binary_encode(k + 1))).count("1") > 1]
    assert multi == [1, 3, 5]
    assert TABLE1_SPEEDS == (0.4, 0.32, 0.26, 0.2, 0.14, 0.08, 0.01, 0.0)


@pytest.mark.parametrize("bad", [-1, 8, 3.5])
def test_encode_rejects_bad_levels(bad):
    with pytest.raises(ValueError, match="level"):
        gray_encode(np.array(bad))


def _stepped_sequence(targets, hold, t0=0.0, dt=1e-3):
    """Host writes while stepping one level per update through ``targets`` (each reached in turn)."""
    st_ = LevelStepper(hold=hold)
    t, tc, lv = t0, [t0], [0]
    for target in targets:
        while st_.level != target:
            t += dt
            level, wrote = st_.update(t, target)
            if wrote:
                tc.append(t)
                lv.append(level)
    return np.array(tc), np.array(lv), t + 0.05


def test_binary_glitches_gray_never_on_same_skewed_lines():
    hold = hold_time(max(DELAYS) - min(DELAYS), TS)
    tc, lv, t_end = _stepped_sequence([7, 0, 7, 3, 0], hold)
    g = simulate_lines(tc, lv, t_end, DELAYS, TS, 0.0003, code="gray")
    b = simulate_lines(tc, lv, t_end, DELAYS, TS, 0.0003, code="binary")
    assert count_glitches(g) == 0
    assert count_glitches(b) > 0
    cover = multibit_windows_sampled(tc, lv, t_end, DELAYS, TS, 0.0003)
    assert set(cover) >= {"1->2", "3->4", "5->6", "2->1", "4->3", "6->5"}
    assert all(v[1] >= 1 for v in cover.values())  # every multi-bit transition sampled inside its window
    # the glitching binary samples are exactly the ones inside multi-bit windows: e.g. 3->4 read as 0..2 or 5..7
    bad = b.decoded[(b.decoded != b.sent) & (b.decoded != b.previous)]
    assert bad.size > 0


def test_gray_glitches_if_hold_shorter_than_skew():
    # jumping without holding (two adjacent changes closer than the skew) breaks even Gray code
    tc = np.array([0.0, 0.010, 0.0105, 0.0110])
    lv = np.array([0, 1, 2, 3])
    g = simulate_lines(tc, lv, 0.05, DELAYS, 0.0002, 0.0, code="gray")
    assert count_glitches(g) > 0


@settings(max_examples=60, deadline=None)
@given(
    targets=st.lists(st.integers(0, 7), min_size=1, max_size=8),
    skew=st.floats(0.0, 6e-3),
    period=st.floats(0.5e-3, 5e-3),
    phase=st.floats(0.0, 5e-3),
)
def test_gray_never_glitches_property(targets, skew, period, phase):
    delays = (0.0, skew * 0.37, skew)
    hold = hold_time(skew, period)
    tc, lv, t_end = _stepped_sequence(targets, hold)
    assert count_glitches(simulate_lines(tc, lv, t_end, delays, period, phase, "gray")) == 0


def test_stepper_steps_one_level_and_holds():
    s = LevelStepper(hold=0.006)
    out = [s.update(k * 0.001, 7) for k in range(60)]
    levels = [lv for lv, _ in out]
    assert max(np.abs(np.diff(levels))) == 1
    writes = [k * 0.001 for k, (_, w) in enumerate(out) if w]
    assert np.all(np.diff(writes) >= 0.006 - 1e-9)
    assert levels[-1] == 7
    assert extra_stop_delay(0.0044, 0.002) == pytest.approx(6 * 0.0064)
    with pytest.raises(ValueError, match="target"):
        s.update(1.0, 8)


def test_level_map_ranges_contact_and_hysteresis():
    th = (20, 30, 45, 70, 110, 180)
    m = LevelMap(thresholds=th, hysteresis=5)
    assert [m.raw_level(s) for s in (0, 19.9, 20, 44, 45, 179, 180, 900)] == [0, 0, 1, 2, 3, 5, 6, 6]
    assert m.raw_level(float("nan")) == 6  # no reading: the safe side
    assert m.update(50, False) == 3
    assert m.update(44, False) == 3  # within the hysteresis band: no drop
    assert m.update(39, False) == 2
    # noisy signal around a threshold does not chatter
    m.reset()
    rng = np.random.default_rng(1)
    lv = [m.update(45 + rng.normal(0, 1.5), False) for _ in range(500)]
    assert np.count_nonzero(np.diff(lv)) <= 1
    # contact -> 7, held while near, resumes only below the resume threshold minus hysteresis
    assert m.update(300, True) == 7
    assert m.update(300, False) == 7
    assert m.update(18, False) == 7  # 18 > 20 - 5
    assert m.update(14, False) == 0
    with pytest.raises(ValueError, match="thresholds"):
        LevelMap(thresholds=(1, 2, 3))


@settings(max_examples=40, deadline=None)
@given(
    writes=st.lists(st.tuples(st.floats(0.0005, 0.02), st.integers(0, 7)), min_size=1, max_size=12),
    code=st.sampled_from(["gray", "binary"]),
)
def test_online_lines_match_offline_simulation(writes, code):
    from depthguard.sensors.graycode import SkewedLines

    lines = SkewedLines(DELAYS, code)
    t, tc, lv = 0.0, [0.0], [0]
    lines.write(0.0, 0)
    for dt, level in writes:
        t += dt
        lines.write(t, level)
        tc.append(t)
        lv.append(level)
    trace = simulate_lines(np.array(tc), np.array(lv), t + 0.01, DELAYS, TS, 0.0007, code)
    online = [lines.read(ts) for ts in trace.t_sample]
    assert online == trace.decoded.tolist()


@settings(max_examples=60, deadline=None)
@given(
    signals=st.lists(st.floats(0, 400) | st.just(float("nan")), min_size=2, max_size=60),
    contacts=st.lists(st.booleans(), min_size=60, max_size=60),
)
def test_level_map_moves_only_across_thresholds(signals, contacts):
    th = np.array([20.0, 30, 45, 70, 110, 180])
    h = 5.0
    m = LevelMap(thresholds=tuple(th), hysteresis=h)
    prev = 0
    for s, c in zip(signals, contacts, strict=False):
        lv = m.update(s, c)
        assert 0 <= lv <= 7
        if c:
            assert lv == 7
        elif np.isnan(s):
            assert lv >= 6  # no reading: at least the slowest moving level
        elif prev == 7 and lv < 7:
            assert s < th[0] - h  # resumed only below the minimum safety distance
        elif lv > prev:
            assert s >= th[lv - 1]
        elif lv < prev:
            assert s < th[prev - 1] - h  # dropped only beyond the hysteresis
        prev = lv
