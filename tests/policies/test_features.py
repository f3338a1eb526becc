"""Context features φ(s): values, dimensions, shapes and bad input."""

import numpy as np
import pytest

from skillkit.policies.features import FEATURES, context_features, feature_dim


def test_linear_is_identity():
    s = np.array([[1.0, -2.0], [0.5, 3.0]])
    np.testing.assert_array_equal(context_features(s, "linear"), s)


def test_quadratic_values():
    phi = context_features(np.array([1.0, 2.0, 3.0]), "quadratic")
    # s, then s_i s_j for i <= j in row-major order
    np.testing.assert_array_equal(phi, [1, 2, 3, 1, 2, 3, 4, 6, 9])


@pytest.mark.parametrize("name", FEATURES)
@pytest.mark.parametrize("n", [0, 1, 2, 5])
def test_dimensions_and_single_vs_batch(name, n):
    rng = np.random.default_rng(n)
    s = rng.normal(size=(4, n))
    phi = context_features(s, name)
    assert phi.shape == (4, feature_dim(n, name))
    for i in range(4):
        np.testing.assert_array_equal(context_features(s[i], name), phi[i])


def test_quadratic_second_moments_are_features():
    # averaging quadratic features gives the mean and the (upper) second-moment matrix
    rng = np.random.default_rng(0)
    s = rng.normal(size=(50, 3))
    phi = context_features(s, "quadratic").mean(axis=0)
    iu = np.triu_indices(3)
    np.testing.assert_allclose(phi[:3], s.mean(axis=0))
    np.testing.assert_allclose(phi[3:], (s.T @ s / 50)[iu])


def test_bad_input():
    with pytest.raises(ValueError, match="features"):
        context_features(np.zeros((2, 2)), "cubic")
    with pytest.raises(ValueError, match="contexts"):
        context_features(np.array([[np.nan, 1.0]]), "linear")
    with pytest.raises(ValueError, match="contexts"):
        context_features(np.zeros((2, 2, 2)), "linear")
    with pytest.raises(ValueError, match="context_dim"):
        feature_dim(-1, "linear")
    with pytest.raises(ValueError, match="features"):
        feature_dim(2, "cubic")
