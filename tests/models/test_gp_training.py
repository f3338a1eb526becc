"""Hyper-parameter training: the sparse objective's analytic gradient, the convergence test,
the guarded warm start and when a noise variance at its floor is an event."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from skillkit.models.gp import ExactGP, ForwardModel, GPNumericalWarning
from skillkit.models.reward import warm_start_hypers
from skillkit.models.sparse import FITC, _SparseNegLogML, sparse_terms
from skillkit.tasks.balancing import Balancing, collect_balancing

EPS = torch.finfo(torch.float64).eps


def _problem(E=3, M=7, N=40, d=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    X = torch.randn(N, d, generator=g, dtype=torch.float64)
    Y = torch.randn(E, N, generator=g, dtype=torch.float64)
    ls = 0.5 + torch.rand(E, d, generator=g, dtype=torch.float64)
    os = 0.5 + torch.rand(E, generator=g, dtype=torch.float64)
    noise = 0.05 + 0.1 * torch.rand(E, generator=g, dtype=torch.float64)
    Z = torch.randn(E, M, d, generator=g, dtype=torch.float64)
    return [t.requires_grad_() for t in (ls, os, noise, Z)], X, Y


@pytest.mark.parametrize("fitc", [True, False], ids=["fitc", "vfe"])
def test_sparse_objective_gradient_is_exact(fitc):
    """The analytic gradient against finite differences (gradcheck) and against autograd
    through the same forward pass, which agree to round-off: eps x N x M."""
    params, X, Y = _problem()
    f = lambda *p: _SparseNegLogML.apply(*p, X, Y, 1e-8, fitc)  # noqa: E731
    assert torch.autograd.gradcheck(f, params)
    value = f(*params)
    ours = torch.autograd.grad(value, params)
    ref_value = sparse_terms(*params, X, Y, 1e-8, fitc)[0]
    theirs = torch.autograd.grad(ref_value, params)
    assert float(value.detach()) == float(ref_value.detach())
    for a, b in zip(ours, theirs, strict=True):
        tol = EPS * X.shape[0] * params[3].shape[1] * float(b.abs().max())
        assert float((a - b).abs().max()) <= tol


def test_fixed_pseudo_inputs_get_no_gradient():
    (ls, os, noise, Z), X, Y = _problem()
    value = _SparseNegLogML.apply(ls, os, noise, Z.detach(), X, Y, 1e-8, True)
    value.backward()
    assert ls.grad is not None and Z.grad is None


def test_convergence_test_stops_early_at_the_long_runs_optimum():
    """A smooth noisy function: the fit stops "converged" well before L-BFGS runs out of
    progress, its objective (per datum) within ``tolerance`` of the long run's (the last window
    fell by less than that, and near the optimum L-BFGS's decrease shrinks from window to
    window)."""
    rng = np.random.default_rng(0)
    X = rng.uniform(-3, 3, size=(60, 2))
    Y = np.sin(X[:, 0]) + 0.1 * rng.standard_normal(60)
    tol = 1e-4
    short = ExactGP(n_steps=400, tolerance=tol).fit(X, Y, rng=1)
    long = ExactGP(n_steps=400, tolerance=0.0).fit(X, Y, rng=1)
    assert short.diagnostics["stop_reason"] == "converged"
    assert long.diagnostics["stop_reason"] == "no_progress"
    assert short.diagnostics["n_iterations"] < long.diagnostics["n_iterations"]
    gap = long.diagnostics["log_marginal_likelihood"] - short.diagnostics["log_marginal_likelihood"]
    assert 0.0 <= gap.sum() / X.shape[0] <= tol


def _balancing(n, seed):
    task = Balancing()
    data = collect_balancing(task, n, np.random.default_rng(seed))
    parts = [task.transitions(t) for t in data["trajectories"] if t.has_transitions]
    return [np.concatenate(p) for p in zip(*parts, strict=True)]


def _nlpd(model, x, u, xn):
    mean, var = model.predict(x, u)
    return (0.5 * np.log(2 * np.pi * var) + (xn - mean) ** 2 / (2 * var)).mean(1)


def test_converged_fit_predicts_held_out_transitions_as_well_as_150_iterations():
    """Balancing transitions (5 rollouts, 200 points), three additive-noise seeds: the exact GP
    run until it stops by itself (convergence test or a failed evaluation; cap 400) predicts
    held-out transitions no worse than the fixed 150-iteration fit: its mean negative log
    predictive density exceeds the fixed fit's by less than the fixed fit's seed-to-seed
    standard error."""
    train, test = _balancing(5, 0), _balancing(5, 1)
    nlpd = {400: [], 150: []}
    for seed in range(3):
        for cap, tol in ((400, 1e-4), (150, 0.0)):
            model = ForwardModel(ExactGP(n_steps=cap, tolerance=tol)).fit(*train, rng=seed)
            assert (model.gp.diagnostics["n_iterations"] < cap) == (cap == 400)
            nlpd[cap].append(_nlpd(model, *test).mean())
    fixed = np.array(nlpd[150])
    excess = np.mean(nlpd[400]) - fixed.mean()
    assert excess <= fixed.std(ddof=1) / np.sqrt(fixed.size)


def _smooth(n=40, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-3, 3, size=(n, 2))
    return X, np.sin(X[:, 0]) + 0.1 * rng.standard_normal(n)


def test_stuck_warm_start_falls_back_to_the_cold_fit():
    """A warm start far off (all noise, flat kernel) with too few steps to recover ends above
    the cold start's objective: the guarded fit is the cold fit, bit for bit."""
    X, Y = _smooth()
    cold = ExactGP(n_steps=5).fit(X, Y, rng=3)
    gp = ExactGP(n_steps=5)
    stuck = {"lengthscale": np.full(2, 1e3), "outputscale": np.array([1e-3]), "noise": [10.0]}
    warm_start_hypers(gp, stuck, X)
    gp.fit(X, Y, rng=3)
    assert gp.diagnostics["start"] == "cold" and cold.diagnostics["start"] == "cold"
    for k, v in cold.hyperparameters.items():
        np.testing.assert_array_equal(gp.hyperparameters[k], v)
    assert gp.diagnostics["log_marginal_likelihood"] == cold.diagnostics["log_marginal_likelihood"]


def test_good_warm_start_is_kept_and_reaches_the_cold_fit():
    X, Y = _smooth()
    cold = ExactGP().fit(X, Y, rng=3)
    gp = ExactGP()
    warm_start_hypers(gp, cold.hyperparameters, X)
    gp.fit(X, Y, rng=3)
    assert gp.diagnostics["start"] == "warm"
    lml, ref = (
        gp.diagnostics["log_marginal_likelihood"],
        cold.diagnostics["log_marginal_likelihood"],
    )
    assert float(lml[0]) >= float(ref[0]) - 1e-6 * abs(float(ref[0]))


def test_noise_at_floor_is_an_event_only_where_added_noise_is_fitted_as_signal():
    """Five points: the exact GP interpolates the 1 % added noise, its σ_ε² ends at the floor,
    far below the added variance: a warning and an event. Without added noise the floor is the
    nugget of noise-free data: recorded in the diagnostics only."""
    X = np.linspace(0.0, 1.0, 5)[:, None]
    Y = np.sin(2.0 * X[:, 0])
    with pytest.warns(GPNumericalWarning, match="added target noise"):
        noisy = ExactGP().fit(X, Y, rng=0)
    assert noisy.diagnostics["noise_at_floor"] == [0]
    assert noisy.diagnostics["numerical_events"]["noise_at_floor"] == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error", GPNumericalWarning)
        clean = ExactGP(additive_noise=0.0).fit(X, Y, rng=0)
    assert clean.diagnostics["noise_at_floor"] == [0]
    assert clean.diagnostics["numerical_events"]["noise_at_floor"] == 0


def test_fitc_noise_at_floor_with_added_noise_in_the_gap_is_no_event():
    """FITC on balancing transitions with added noise and a floor above that noise: σ_ε² ends at
    its floor on every output, the gap diag(K_nn − Q_nn) adds to it (effective noise, mean Λ,
    above σ_ε²); recorded in the diagnostics, no event, no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", GPNumericalWarning)
        gp = ForwardModel(FITC(n_inducing=30, noise_floor=1e-3)).fit(*_balancing(5, 0), rng=2).gp
    d = gp.diagnostics
    assert d["noise_at_floor"] == list(range(8))
    assert np.all(d["effective_noise"] > gp.predictor.noise.numpy())
    assert d["numerical_events"]["noise_at_floor"] == 0


def test_bad_tolerance():
    with pytest.raises(ValueError, match="tolerance"):
        ExactGP(tolerance=-1.0)
