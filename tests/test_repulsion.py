import numpy as np
import pytest

from depthguard.depthspace import PointDistances
from depthguard.repulsion import magnitude, repulsive_vectors, risk


def test_profile_matches_fig4_reading():
    # Fig. 4: Vmax = 3, rho = 0.4, alpha = 6: ~Vmax at 0, Vmax/2 at rho/2, ~0 at rho
    assert magnitude(0.0, 3.0, 0.4, 6.0) == pytest.approx(3.0 / (1 + np.exp(-6)))
    assert magnitude(0.2, 3.0, 0.4, 6.0) == pytest.approx(1.5)
    assert magnitude(0.4, 3.0, 0.4, 6.0) < 0.01
    d = np.linspace(0, 0.6, 61)
    assert np.all(np.diff(magnitude(d, 3.0, 0.4, 6.0)) < 0)
    assert magnitude(np.inf, 3.0, 0.4, 6.0) == 0.0
    assert risk(0.0, 0.4, 6.0) == pytest.approx(1 / (1 + np.exp(-6)))


def test_bad_profile_parameters():
    with pytest.raises(ValueError, match="rho"):
        magnitude(0.1, 1.0, 0.0, 6.0)
    with pytest.raises(ValueError, match="alpha"):
        magnitude(0.1, 1.0, 0.4, -1.0)
    with pytest.raises(ValueError, match="vmax"):
        magnitude(0.1, -1.0, 0.4, 6.0)


def test_repulsive_vectors_follow_direction_and_vanish_without_obstacles():
    res = PointDistances(
        np.array([0.1, np.inf]),
        np.array([[0.0, 0.0, 1.0], [np.nan] * 3]),
        np.array([[0.0, 0.0, 0.0], [np.nan] * 3]),
        np.array([10, 0]),
    )
    V = repulsive_vectors(res, 2.0, 0.4, 6.0)
    np.testing.assert_allclose(V[0], [0, 0, magnitude(0.1, 2.0, 0.4, 6.0)])
    np.testing.assert_array_equal(V[1], 0.0)
