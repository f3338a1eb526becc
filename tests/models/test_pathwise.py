"""Pathwise GP sampling: marginals and joint covariance of the exact GP, consistency, seeding."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from skillkit.models.gp import ExactGP, ForwardModel, GPNumericalWarning, Moments
from skillkit.models.pathwise import PathwiseBasis, pathwise_flops_per_step
from skillkit.models.sampling import sample_trajectories
from skillkit.models.sparse import FITC

# Bound on |z| for the Monte Carlo comparisons below (P(|z| > 4.5) = 6.8e-6 per score).
Z_MAX = 4.5


def _data(n: int, seed: int):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, size=(n, 2))
    u = rng.uniform(-1, 1, size=(n, 1))
    step = 0.3 * np.stack([np.sin(3 * x[:, 1]), -np.sin(3 * x[:, 0]) + u[:, 0]], axis=1)
    return x, u, x + step + 0.05 * rng.standard_normal((n, 2))


@pytest.fixture(scope="module", params=["exact", "fitc"])
def model(request):
    gp = ExactGP(n_steps=25) if request.param == "exact" else FITC(30, n_steps=25)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        return ForwardModel(gp, target="delta").fit(*_data(120, 0), rng=0)


# Queries: on the data, between, and far from it (the prior).
QUERIES = torch.tensor([[0.3, -0.2, 0.1], [0.9, 0.9, -1.0], [2.5, -2.0, 1.5]], dtype=torch.float64)


def _latent_standardised(p, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    m = p.moments(q, include_noise=False)
    return ((m.mean - p.y_mean) / p.y_scale).T, (m.var / p.y_scale**2).T  # (E, n)


def _values(functions, q: torch.Tensor) -> torch.Tensor:
    """g_i(q_j) for every function i and query j: Tensor (n_functions, n_queries, E)."""
    n = functions.amplitudes.shape[0]
    return torch.stack([functions.latent(qj.expand(n, -1)) for qj in q], dim=1)


def draw_functions(predictor, n: int, n_features: int, rng: int):
    """``n`` posterior functions, one seed each from ``rng``."""
    seeds = np.random.default_rng(rng).integers(2**63 - 1, size=n)
    return PathwiseBasis(predictor, n_features).draw(seeds)


def test_one_step_marginals_equal_the_gp_posterior(model):
    """Mean and variance of g(x) over 6000 functions vs kᵀβ and σ_f² − kᵀ iK k (z-scores).

    Fresh features per function make the covariance exact in expectation, so only Monte Carlo
    error remains (the variance's standard error uses the sample fourth moment: an F-feature
    draw is a Gaussian scale mixture, slightly heavier-tailed than Gaussian).
    """
    p = model.predictor
    n = 6000
    g = _values(draw_functions(p, n, n_features=64, rng=1), QUERIES)  # (n, 3, E)
    mu, var = _latent_standardised(p, QUERIES)
    mean, s2 = g.mean(0), g.var(0)
    m4 = ((g - mean) ** 4).mean(0)
    z_mean = (mean - mu.T) / (s2 / n).sqrt()
    z_var = (s2 - var.T) / ((m4 - s2**2) / n).sqrt()
    assert z_mean.abs().max() < Z_MAX and z_var.abs().max() < Z_MAX
    assert var.T[0].max() < 0.1 * var.T[2].min()  # the queries do span data and prior


def test_joint_covariance_equals_the_posterior_covariance(model):
    """Cov(g(x), g(x′)) = k(x, x′) − k(x)ᵀ iK k(x′) (the predictor's latent_covariance)."""
    p = model.predictor
    n = 6000
    g = _values(draw_functions(p, n, n_features=64, rng=2), QUERIES[:2])  # (n, 2, E)
    C = (p.latent_covariance(QUERIES[:2]) / p.y_scale[:, None, None] ** 2)[:, 0, 1]
    c = g - g.mean(0)
    emp = (c[:, 0] * c[:, 1]).mean(0)
    s = c.square().mean(0)  # (2, E)
    se = ((s[0] * s[1] + emp**2) / n).sqrt()
    assert ((emp - C) / se).abs().max() < Z_MAX


def test_sampler_one_step_matches_predictive_distribution(model):
    x0 = np.array([[0.3, -0.2], [2.5, -2.0]])
    L = 5000
    res = sample_trajectories(
        model, x0, lambda t, x, p: 0.1 - 0.2 * x[:, :1], 1, L, rng=3, method="pathwise"
    )
    u0 = 0.1 - 0.2 * x0[:, :1]
    mean, var = model.predict(x0, u0)
    x1 = res.states[:, :, 1].numpy()
    assert np.all(np.abs(x1.mean(1) - mean) < Z_MAX * np.sqrt(var / L))
    c = x1 - x1.mean(1, keepdims=True)
    se_var = np.sqrt(((c**4).mean(1) - x1.var(1) ** 2) / L)
    assert np.all(np.abs(x1.var(1, ddof=1) - var) < Z_MAX * se_var)


def test_a_function_is_fixed_along_the_trajectory(model):
    """A drawn function evaluated twice at one input gives one value (a function, not draws)."""
    f = draw_functions(model.predictor, 4, n_features=32, rng=5)
    x = QUERIES[:1].expand(4, -1)
    a, b = f.latent(x), f.latent(x)
    assert torch.equal(a, b)
    assert (a[1:] - a[0]).abs().min() > 0  # different functions differ
    m = f.moments(x)
    assert isinstance(m, Moments)
    torch.testing.assert_close(
        m.var, (model.predictor.y_scale**2 * model.predictor.noise).expand(4, -1)
    )
    torch.testing.assert_close(f.moments(x, include_noise=False).var, torch.zeros_like(m.var))


def test_same_seed_same_result_and_chunk_invariance(model):
    x0 = np.array([[0.3, -0.2], [0.0, 0.5]])
    pol = lambda t, x, p: -0.5 * x[:, :1]  # noqa: E731
    a = sample_trajectories(model, x0, pol, 6, 40, rng=3, method="pathwise", n_features=32)
    b = sample_trajectories(model, x0, pol, 6, 40, rng=3, method="pathwise", n_features=32)
    c = sample_trajectories(model, x0, pol, 6, 40, rng=4, method="pathwise", n_features=32)
    d = sample_trajectories(
        model, x0, pol, 6, 40, rng=3, method="pathwise", n_features=32, max_chunk_bytes=20000
    )
    assert torch.equal(a.states, b.states)
    assert not torch.allclose(a.states, c.states)
    torch.testing.assert_close(a.states, d.states, rtol=0, atol=1e-9)
    # the per-step sampler with the same seed uses the same observation noise stream but a
    # different model draw: the two methods differ
    e = sample_trajectories(model, x0, pol, 6, 40, rng=3)
    assert not torch.allclose(a.states[:, :, 1:], e.states[:, :, 1:])


def test_float32_functions_follow_float64_functions(model):
    p = model.predictor
    seeds = [11, 12, 13]
    f64 = PathwiseBasis(p, 64).draw(seeds)
    f32 = PathwiseBasis(p, 64, torch.float32).draw(seeds)
    x = torch.tensor([[0.3, -0.2, 0.1]] * 3, dtype=torch.float64)
    g64, g32 = f64.latent(x), f32.latent(x.float())
    _, var = _latent_standardised(p, x[:1])
    std = (var.T + p.noise).sqrt()  # predictive std of a transition, standardised
    err = ((g32.double() - g64).abs() / std).max()
    # measured 5.9e-3 (exact GP: v = β − iK f̃(X) − ξ has entries ~1/σ_ε², cancelling in kᵀv)
    # and 2.6e-5 (FITC); the per-step float32 mean errors on such models are alike
    assert err < 2e-2


def test_shared_basis_marginals_within_rff_error(model):
    """One basis for all functions: the variance is off by O(σ_f²/√F), not by Monte Carlo error.

    Far from the data g's variance is the features' φ(x)ᵀφ(x) = σ_f² (1 + Σ_j cos(2ωⱼᵀx + 2bⱼ)/F),
    whose spread over bases is σ_f²/√(2F): 4 such spreads bound it here (plus Monte Carlo).
    """
    p = model.predictor
    F, n = 32, 4000
    basis = PathwiseBasis(p, F, shared_seed=7)
    f = basis.draw(range(n))
    assert f.frequencies.shape[0] == 1
    g = _values(f, QUERIES[2:])[:, 0]  # far query, (n, E)
    sf2 = p.outputscale
    s2 = g.var(0)
    mc = s2 * math.sqrt(2.0 / n)
    assert ((s2 - sf2).abs() < 4 * sf2 / math.sqrt(2 * F) + Z_MAX * mc).all()


def test_bad_input(model):
    x0 = np.zeros((1, 2))
    pol = lambda t, x, p: x[:, :1]  # noqa: E731
    with pytest.raises(ValueError, match="method"):
        sample_trajectories(model, x0, pol, 2, 2, method="functions")
    with pytest.raises(ValueError, match="n_features"):
        sample_trajectories(model, x0, pol, 2, 2, method="pathwise", n_features=0)
    with pytest.raises(ValueError, match="n_features"):
        PathwiseBasis(model.predictor, 2.5)
    with pytest.raises(ValueError, match="predictor"):
        PathwiseBasis(model, 8)

    class NotAGP:
        state_dim, control_dim = 2, 1

        def to(self, device=None, dtype=None):
            return self

    with pytest.raises(ValueError, match="model"):
        sample_trajectories(NotAGP(), x0, pol, 2, 2, method="pathwise")


def test_flop_count():
    # E = 1, M = 2, d = 1, F = 1: 2·2·1 + 3·2 + 2 + 2·2 + 2·1·1 + 4·1 = 22
    assert pathwise_flops_per_step(1, 2, 1, 1) == 22
    assert pathwise_flops_per_step(8, 300, 12, 256) == 8 * pathwise_flops_per_step(1, 300, 12, 256)
