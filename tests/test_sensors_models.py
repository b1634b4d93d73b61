"""Taxel and Sharp IR ranger models: monotonicity, range, saturation, the safe handling of the ambiguity
below the minimum range, the 38 ms update sampled at 300 Hz."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK, AmbiguityTracker, IRRanger
from depthguard.sensors.taxel import SKIN_REFLECTIVITY, ContactTaxel, ProximityTaxel


def test_proximity_taxel_inverse_square_range_and_saturation():
    p = ProximityTaxel(noise_counts=0.0)
    d = np.array([0.02, 0.04])
    v = p.voltage(d) - p.v_dark
    assert v[0] / v[1] == pytest.approx(((0.04 + p.d0) / (0.02 + p.d0)) ** 2)
    assert 15 <= p.counts_at(0.05) <= 30  # about 5 cm range on skin: a few times the noise
    assert p.counts(np.array([0.0]))[0] == p.counts(np.array([0.001]))[0]  # saturated
    assert p.counts(np.array([np.inf]))[0] == p.counts(np.array([1.0]))[0]  # nothing in range
    darker = p.counts(np.array([0.03]), reflectivity=0.3)[0]
    assert darker < p.counts(np.array([0.03]))[0]


@settings(max_examples=80, deadline=None)
@given(d=st.floats(0.0, 0.12), rho=st.floats(0.3, 1.0))
def test_proximity_lower_bound_never_over_reports(d, rho):
    p = ProximityTaxel(noise_counts=0.0)
    est = p.distance_lower_bound(p.counts(np.array([d]), reflectivity=rho), min_reflectivity=0.3)[0]
    assert est <= d + 1e-12


def test_contact_taxel_monotone_and_threshold():
    c = ContactTaxel(noise_counts=0.0)
    f = np.linspace(0, 50, 200)
    assert np.all(np.diff(c.voltage(f)) > 0)
    assert np.all(c.deformation(f) < c.thickness)
    np.testing.assert_allclose(c.force(c.deformation(f)), f, rtol=1e-9, atol=1e-9)
    assert not c.in_contact(c.counts(np.array([0.0])))[0]
    assert c.in_contact(c.counts(np.array([2 * c.contact_force])))[0]


@pytest.mark.parametrize("model", [GP2Y0A21YK, GP2D120XJ00F])
def test_sharp_curves_and_ranges(model):
    d = np.linspace(model.d_min, model.d_max, 50)
    v = model.voltage(d)
    assert np.all(np.diff(v) < 0)  # far branch: decreasing
    np.testing.assert_allclose(model.distance_far(v), d, atol=1e-9)
    assert model.voltage(np.array([np.inf]))[0] == model.v_floor
    assert np.isinf(model.distance_far(np.array([model.v_floor]))[0])
    # ambiguity: a voltage on the near branch is also produced by a farther object
    near = model.voltage(np.array([0.5 * model.d_peak]))[0]
    assert model.distance_far(np.array([near]))[0] > model.d_peak


@pytest.mark.parametrize("model", [GP2Y0A21YK, GP2D120XJ00F])
def test_tracker_is_safe_through_an_approach_below_min_range(model):
    """An object comes from far to 0 and back at 0.25 m/s, read every 38 ms: the reported distance is
    never more than the true distance once the object is inside the rated range."""
    tr = AmbiguityTracker(model)
    t = np.arange(0, 2 * model.d_max / 0.25, 0.038)
    true = np.abs(model.d_max - 0.25 * t)
    for d in true:
        rep = tr.update(float(model.voltage(np.array([d]))[0]))
        if d <= model.d_max - 1e-3:
            assert rep <= d + 0.01
    # a far-branch-only tracker (the naive inversion) over-reports near contact
    d = 0.3 * model.d_peak
    assert model.distance_far(model.voltage(np.array([d])))[0] > d


def test_ranger_timing_38ms_sampled_at_300hz():
    r = IRRanger(GP2Y0A21YK, rng=np.random.default_rng(4))
    dt = 1 / 300
    updates, last = [], None
    for k in range(3000):
        t = k * dt
        due = r.due(t)
        v, _ = r.sample(t, 0.3 if due else None)
        if due:
            updates.append(t)
        last = v
    gaps = np.diff(updates)
    assert 0.030 < np.mean(gaps) < 0.048 and gaps.min() >= 0.038 - 0.0096 - 1e-9
    assert last == pytest.approx(0.92, abs=0.05)
    assert SKIN_REFLECTIVITY > 0


@settings(max_examples=80, deadline=None)
@given(
    model=st.sampled_from([GP2Y0A21YK, GP2D120XJ00F]),
    speeds=st.lists(st.floats(-0.25, 0.25), min_size=5, max_size=80),
    start=st.floats(0.0, 1.0),
)
def test_tracker_never_over_reports_at_hand_speed(model, speeds, start):
    """Any trajectory at up to 0.25 m/s (the hand's speed), read every 38.3 + 9.6 ms from a start beyond the
    minimum range: once in the rated range or closer, the reported distance never exceeds the true one."""
    tr = AmbiguityTracker(model)
    d = model.d_min + start * (model.d_max - model.d_min)
    for v in speeds:
        d = min(max(d + v * 0.0479, 0.0), 1.2 * model.d_max)
        rep = tr.update(float(model.voltage(np.array([d]))[0]))
        if d <= model.d_max:
            assert rep <= d + 1e-9
