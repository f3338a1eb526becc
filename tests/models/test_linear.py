"""The linear-Gaussian forward model and the GP forward model's linear prior mean: exact
recovery of linear dynamics, the exact Gaussian step against Monte Carlo, bad input."""

import warnings

import numpy as np
import pytest
import torch

from skillkit.models.gp import ExactGP, ForwardModel
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.moment_matching import moment_match, propagate, with_linear_mean
from skillkit.models.sparse import FITC
from skillkit.search.pilco import model_moment_step


def _linear_data(n=200, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    A = np.array([[1.0, 0.1], [-0.2, 0.9]])
    B = np.array([[0.0], [0.5]])
    c = np.array([0.05, -0.1])
    x = rng.standard_normal((n, 2))
    u = rng.standard_normal((n, 1))
    xn = x @ A.T + u @ B.T + c + noise * rng.standard_normal((n, 2))
    return A, B, c, x, u, xn


@pytest.mark.parametrize("target", ["delta", "next"])
def test_linear_gaussian_model_recovers_noiseless_dynamics(target):
    A, B, c, x, u, xn = _linear_data()
    m = LinearGaussianModel(target=target).fit(x, u, xn)
    np.testing.assert_allclose(m.A, A, atol=1e-8)
    np.testing.assert_allclose(m.B, B, atol=1e-8)
    np.testing.assert_allclose(m.c, c, atol=1e-8)
    mom = m.next_state_moments(torch.as_tensor(x[:5]), torch.as_tensor(u[:5]))
    np.testing.assert_allclose(mom.mean.numpy(), xn[:5], atol=1e-8)


def test_linear_gaussian_step_matches_monte_carlo():
    """The exact step ([A B] m + c, [A B] S [A B]ᵀ + Σ_w) against 200k samples."""
    _, _, _, x, u, xn = _linear_data(noise=0.1, seed=1)
    m = LinearGaussianModel().fit(x, u, xn)
    mz = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)
    L = torch.tensor([[0.3, 0, 0], [0.1, 0.2, 0], [0.05, -0.1, 0.4]], dtype=torch.float64)
    mean, cov = model_moment_step(m)(mz, L @ L.T)
    rng = np.random.default_rng(2)
    z = mz.numpy() + rng.standard_normal((200_000, 3)) @ L.numpy().T
    w = rng.multivariate_normal(np.zeros(2), m.noise_cov, size=200_000)
    y = z[:, :2] @ m.A.T + z[:, 2:] @ m.B.T + m.c + w
    np.testing.assert_allclose(mean.numpy(), y.mean(0), atol=5e-3)
    np.testing.assert_allclose(cov.numpy(), np.cov(y.T), atol=5e-3)


def test_forward_model_linear_mean_predicts_linear_dynamics_exactly():
    """With a linear prior mean the GP models only the residual: on noiseless linear data
    its predictions equal the truth, also on inputs far outside the data."""
    A, B, c, x, u, xn = _linear_data(n=60)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lin = ForwardModel(ExactGP(n_steps=20), mean="linear").fit(x, u, xn, rng=0)
    xq, uq = np.array([[6.0, -5.0]]), np.array([[4.0]])
    truth = xq @ A.T + uq @ B.T + c
    np.testing.assert_allclose(lin.predict(xq, uq)[0], truth, atol=1e-4)
    assert "mean='linear'" in repr(lin)
    with pytest.raises(ValueError, match="mean"):
        ForwardModel(ExactGP(), mean="quadratic")


def test_moment_matching_with_a_linear_mean_matches_monte_carlo():
    """y = Wᵀz + b + f(z) + ε at z ~ N(m, S): the moments of with_linear_mean(moment_match)
    against Monte Carlo over z and the GP's predictive distribution at each z."""
    rng = np.random.default_rng(3)
    x = rng.standard_normal((80, 2))
    u = rng.standard_normal((80, 1))
    xn = x @ np.array([[1.0, 0.2], [0.0, 0.8]]).T + 0.3 * np.sin(2 * x) + 0.4 * u
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = ForwardModel(FITC(n_inducing=20, n_steps=15), target="next", mean="linear")
        model.fit(x, u, xn + 0.01 * rng.standard_normal(xn.shape), rng=0)
    m = torch.tensor([0.2, -0.3, 0.1], dtype=torch.float64)
    S = torch.diag(torch.tensor([0.1, 0.05, 0.2], dtype=torch.float64))
    g = with_linear_mean(model, moment_match(model.predictor, m, S), m, S)
    z = m.numpy() + rng.standard_normal((100_000, 3)) * np.sqrt(np.diag(S.numpy()))
    mean, var = model.predict(z[:, :2], z[:, 2:])
    y = mean + np.sqrt(var) * rng.standard_normal(mean.shape)
    np.testing.assert_allclose(g.mean.numpy(), y.mean(0), atol=1e-2)
    np.testing.assert_allclose(g.cov.numpy(), np.cov(y.T), atol=1e-2)
    zc = z - z.mean(0)
    np.testing.assert_allclose(
        g.input_output_cov.numpy(), zc.T @ (y - y.mean(0)) / len(z), atol=1e-2
    )
    # propagate() adds the linear part the same way.
    means, _ = propagate(model, m[:2].numpy(), S[:2, :2].numpy(), 1, np.zeros((1, 2)),
                         np.array([0.1]))  # fmt: skip
    S0 = S.clone()
    S0[2, 2] = 0.0
    g0 = with_linear_mean(model, moment_match(model.predictor, m, S0), m, S0)
    np.testing.assert_allclose(means[1].numpy(), g0.mean.numpy(), atol=1e-10)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="target"):
        LinearGaussianModel(target="x")
    with pytest.raises(ValueError, match="ridge"):
        LinearGaussianModel(ridge=-1.0)
    with pytest.raises(ValueError, match="states"):
        LinearGaussianModel().fit(np.zeros((3, 2)), np.zeros((3, 1)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="next_states"):
        LinearGaussianModel().fit(np.zeros((9, 2)), np.zeros((9, 1)), np.zeros((9, 3)))
    with pytest.raises(RuntimeError, match="fit"):
        LinearGaussianModel().next_state_moments(torch.zeros(1, 2), torch.zeros(1, 1))
    assert "unfitted" in repr(LinearGaussianModel())
