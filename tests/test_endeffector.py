"""End-effector helpers: the damped least-squares map and the repulsive velocity's far tail."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from depthguard.control.endeffector import dls_apply, repulsive_velocity


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("damping", [0.0, 0.01, 0.05])
def test_dls_apply_matches_the_formula(seed, damping):
    rng = np.random.default_rng(seed)
    J, x = rng.normal(size=(3, 7)), rng.normal(size=3)
    want = J.T @ np.linalg.inv(J @ J.T + (damping**2 + 1e-12) * np.eye(3)) @ x
    np.testing.assert_allclose(dls_apply(J, damping, x), want, rtol=1e-9, atol=1e-12)


def test_dls_apply_rank_deficient_at_zero_damping_stays_finite():
    J = np.zeros((3, 7))
    J[0, 0] = 1.0
    assert np.isfinite(dls_apply(J, 0.0, np.array([0.1, 0.2, 0.3]))).all()


def test_repulsive_velocity_far_tail_is_zero_without_overflow():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        v = repulsive_velocity(1e6, np.array([0.0, 0.0, 1.0]), 2.0, 0.4, 6.0)
    assert np.array_equal(v, np.zeros(3))
    near = repulsive_velocity(0.0, np.array([0.0, 0.0, 2.0]), 2.0, 0.4, 6.0)
    np.testing.assert_allclose(near, [0.0, 0.0, 2.0 / (1.0 + np.exp(-6.0))])  # ICRA'12 eq. 7 at D = 0
