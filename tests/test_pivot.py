import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from depthguard.pivot import PivotFilter, pivot
from depthguard.pivot_scenario import run_pivot_scenario

vec = st.lists(st.floats(-2, 2), min_size=3, max_size=3).map(np.array)


@settings(max_examples=200, deadline=None)
@given(vec, vec, st.floats(0.1, 2.0), st.floats(0.5, 10.0))
@example(np.array([1.0, 0.0, 0.0]), np.array([1.192092896e-07, 0.0, 0.0]), 1.0, 1.0)  # parallel, tiny: turns 1e-7
def test_pivot_properties(V, Vd, dv_max, c):
    out = pivot(V, Vd, dv_max, c)
    nv, nd = np.linalg.norm(V), np.linalg.norm(Vd)
    assert np.linalg.norm(out) == pytest.approx(nv, abs=1e-9)  # magnitude kept
    if nv < 1e-9 or nd < 1e-9 or V @ Vd <= 0:
        np.testing.assert_allclose(out, V)  # moving away (beta >= pi/2) or no variation: unchanged
    else:
        a, r = Vd / nd, V / nv
        # the result stays in the plane of a and r (unless they are parallel) and turns further from a
        if np.linalg.norm(np.cross(a, r)) > 1e-2:
            assert abs(np.cross(a, r) @ out) < 1e-6 * nv
        assert (out / nv) @ a <= r @ a + 1e-9
        # continuous at |dV/dt| = 0: it turns by (pi/2 - beta) sigma <= (pi/2) sigma, and the rescaled sigmoid
        # grows at most at (c / (2 dv_max)) / (1 - sigma(0)) per unit of |dV/dt| (its slope is at most 1/4)
        sigma0 = 1.0 / (1.0 + np.exp(c))
        turn_bound = (np.pi / 2) * min(1.0, c * nd / (2.0 * dv_max * (1.0 - sigma0)))
        assert np.linalg.norm(out - V) / nv <= turn_bound + 1e-9  # (the chord, at most the angle)


def test_gamma_limits():
    V = np.array([1.0, 1.0, 0.0])  # beta = 45 deg from a = x
    still = pivot(V, np.array([1e-6, 0, 0]), dv_max=0.5, c=5.0)
    np.testing.assert_allclose(still, V, atol=0.05)  # ~beta when the variation ~0
    fast = pivot(V, np.array([5.0, 0, 0]), dv_max=0.5, c=5.0)
    assert abs(fast @ np.array([1.0, 0, 0])) < 1e-6  # normal to dV/dt at large variation
    assert fast[1] > 0  # on r's side of a


def test_parallel_case_gets_perturbed_to_a_normal_direction():
    out = pivot(np.array([1.0, 0, 0]), np.array([3.0, 0, 0]), dv_max=0.5, c=5.0)
    assert abs(out[0]) < 0.05 and np.linalg.norm(out) == pytest.approx(1.0)


def test_filter_estimates_derivative():
    f = PivotFilter(dv_max=0.5, c=5.0)
    for k in range(5):
        f.step(np.array([0.1 * k, 0, 0]), 0.01)
    np.testing.assert_allclose(f.v_dot, [10.0, 0, 0])
    with pytest.raises(ValueError, match="dt"):
        f.step(np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="dv_max"):
        PivotFilter(dv_max=0.0)


def test_fig7_direct_collides_pivot_escapes():
    res = run_pivot_scenario()
    for key in ("direct", "pivot"):  # recompute the clearance from the traces, independently of the flag
        gap = np.linalg.norm(res[key]["trace_point"] - res[key]["trace_obstacle"], axis=1).min()
        assert gap == pytest.approx(res[key]["min_distance"], abs=0.002)
    assert res["direct"]["collided"] and res["direct"]["min_distance"] < 0.01
    assert not res["pivot"]["collided"] and res["pivot"]["min_distance"] > 0.04
    # the pivoted point left the obstacle's path sideways rather than running ahead of it
    end = res["pivot"]["trace_point"][-1]
    assert np.hypot(end[1], end[2]) > 0.1
