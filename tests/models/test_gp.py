"""Exact GP (Eqs 2.24–2.28), its numerical safeguards, and the transition forward model."""

from __future__ import annotations

import dataclasses
import math
import warnings

import gpytorch
import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.gp import (
    ExactGP,
    ForwardModel,
    GPNumericalError,
    GPNumericalWarning,
    GPPredictor,
    HyperCurb,
    neg_log_marginal_likelihood,
    optimize,
    record_numerical_events,
    robust_cholesky,
)
from skillkit.models.sparse import FITC


def _data(n=40, seed=0, noise=0.1):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-3, 3, size=(n, 2))
    Y = np.stack([np.sin(X[:, 0]) + X[:, 1] ** 2 / 5, np.cos(X[:, 1]) * X[:, 0]], axis=1)
    return X, Y + noise * rng.standard_normal(Y.shape)


def _numpy_gp(X, y, Xs, ls, sf2, sn2):
    """Direct evaluation of Eqs (2.26), (2.27), (2.28) for one output (raw units)."""

    def k(a, b):
        return sf2 * np.exp(-0.5 * (((a[:, None, :] - b[None, :, :]) / ls) ** 2).sum(-1))

    Ky = k(X, X) + sn2 * np.eye(len(X))
    ks = k(X, Xs)
    mean = ks.T @ np.linalg.solve(Ky, y)
    var = sn2 + sf2 - np.einsum("ij,ij->j", ks, np.linalg.solve(Ky, ks))
    sign, logdet = np.linalg.slogdet(Ky)
    lml = -0.5 * y @ np.linalg.solve(Ky, y) - 0.5 * logdet - 0.5 * len(y) * np.log(2 * np.pi)
    return mean, var, lml


def _gp_tols(X, Xs, y, ls, sf2, sn2, y_scale=1.0):
    """Round-off of one evaluation of the mean and variance (Eqs 2.26–2.27) at ``Xs`` and of
    the log marginal likelihood (2.28) of one output, absolute (max over queries), to first
    order. Kernel entries are relatively off by (d + 2) S ε: the library's exponent is a
    (d + 2)-term product of terms up to S = 2 max‖x/w‖² + |log σ_f²| (standardised σ_f²).
    The Cholesky (or LU) factorisation is backward stable, |ΔK| ≤ N ε |L||Lᵀ|, which also
    bounds |K|. With v = K⁻¹k and α = K⁻¹y, ΔK moves kᵀK⁻¹y by |v|ᵀ|ΔK||α|, kᵀK⁻¹k by
    |v|ᵀ|ΔK||v|, yᵀK⁻¹y by |α|ᵀ|ΔK||α| and log|K| by Σ|K⁻¹|∘|ΔK|; the explicit L⁻¹ = R of
    the variance adds 2|Rk|ᵀ|R||L||R||k|, the N-term sums their terms' absolute values."""
    N, d = X.shape

    def k(a, b):
        return sf2 * np.exp(-0.5 * (((a[:, None, :] - b[None, :, :]) / ls) ** 2).sum(-1))

    K, ks = k(X, X) + sn2 * np.eye(N), k(X, Xs)
    L = np.linalg.cholesky(K)
    R = np.linalg.inv(L)
    iK = R.T @ R
    alpha, v, LL = iK @ y, iK @ ks, np.abs(L) @ np.abs(L).T
    S = 2 * max(((X / ls) ** 2).sum(1).max(), ((Xs / ls) ** 2).sum(1).max())
    S += abs(np.log(sf2 / y_scale**2))
    n_ops = N + (d + 2) * S
    mean = np.abs(ks).T @ np.abs(alpha) + np.abs(v).T @ LL @ np.abs(alpha)
    var = sf2 + sn2 + 2 * np.abs(ks * v).sum(0) + np.einsum("ij,ik,kj->j", np.abs(v), LL, np.abs(v))
    var += 2 * (np.abs(R @ ks) * (np.abs(R) @ np.abs(L) @ np.abs(R) @ np.abs(ks))).sum(0)
    lml = 0.5 * np.abs(alpha) @ LL @ np.abs(alpha) + (np.abs(iK) * LL).sum()
    lml += np.abs(y) @ np.abs(alpha) + np.abs(np.log(np.diag(L))).sum()
    lml += N * (np.log(2 * np.pi) + abs(np.log(y_scale)))
    return fp_tol(n_ops, scale=mean.max()), fp_tol(n_ops, scale=var.max()), fp_tol(n_ops, lml)


@pytest.mark.parametrize("standardize", [False, True])
def test_prediction_equals_numpy_eqs_2_26_2_27_2_28(standardize):
    X, Y = _data()
    gp = ExactGP(additive_noise=0.0, n_steps=15, standardize=standardize).fit(X, Y, rng=0)
    Xs = np.random.default_rng(1).uniform(-4, 4, size=(25, 2))
    mean, var = gp.predict(Xs)
    fmean, fvar = gp.predict(Xs, include_noise=False)
    h = gp.hyperparameters
    for a in range(2):
        m = Y[:, a].mean() if standardize else 0.0  # the constant prior mean of standardisation
        theta = (h["lengthscale"][a], h["outputscale"][a], h["noise"][a])
        ref_mean, ref_var, ref_lml = _numpy_gp(X, Y[:, a] - m, Xs, *theta)
        # Standardised Cholesky and augmented-product kernel vs raw LU and direct kernel: two
        # evaluations, each within the first-order bound of _gp_tols (≈ 1e-8 on means and
        # variances of size 1–10, 1e-7 on the likelihood: looser than the former rtol=1e-10
        # there, which was what this CPU printed), plus the rounding of + m
        mean_tol, var_tol, lml_tol = _gp_tols(X, Xs, Y[:, a] - m, *theta, gp.y_scale[a])
        mean_tol = 2 * mean_tol + fp_tol(2, scale=abs(m))
        np.testing.assert_allclose(mean[:, a], ref_mean + m, rtol=0, atol=mean_tol)
        np.testing.assert_allclose(var[:, a], ref_var, rtol=0, atol=2 * var_tol)
        fvar_ref = ref_var - h["noise"][a]
        np.testing.assert_allclose(fvar[:, a], fvar_ref, rtol=0, atol=2 * var_tol)
        np.testing.assert_allclose(fmean[:, a], mean[:, a])
        np.testing.assert_allclose(
            gp.diagnostics["log_marginal_likelihood"][a], ref_lml, rtol=0, atol=2 * lml_tol
        )


def test_objective_matches_gpytorch_mll_and_has_exact_gradient():
    X, Y = _data(30)
    gp = ExactGP(additive_noise=0.0, n_steps=0).fit(X, Y)
    with torch.no_grad():
        ours = float(gp._loss())
    gp.model.train()
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(gp.likelihood, gp.model)
    with gpytorch.settings.max_cholesky_size(10**6):
        theirs = -float((mll(gp.model(*gp.model.train_inputs), gp.Y) * gp.Y.shape[1]).sum())
    # both Cholesky-based, on the standardised targets and hyper-parameters: two evaluations
    # of the summed likelihoods, each within _gp_tols' bound per output
    X0, Ys = gp.X.numpy(), gp.Y.numpy()
    theta = [t.detach().numpy() for t in gp._hypers()]
    tol = sum(_gp_tols(X0, X0[:1], Ys[a], *(t[a] for t in theta))[2] for a in range(len(Ys)))
    assert ours == pytest.approx(theirs, rel=0, abs=2 * tol)
    rng = np.random.default_rng(2)
    Xt = torch.as_tensor(rng.normal(size=(12, 3)))
    Yt = torch.as_tensor(rng.normal(size=(2, 12)))
    ls = torch.as_tensor(rng.uniform(0.5, 2.0, (2, 3))).requires_grad_()
    os = torch.tensor([1.3, 0.6], dtype=torch.float64, requires_grad=True)
    sn = torch.tensor([0.1, 0.3], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda a, b, c: neg_log_marginal_likelihood(Xt, Yt, a, b, c), (ls, os, sn)
    )


def test_training_raises_likelihood_and_recovers_noise_level():
    X, Y = _data(150, seed=3, noise=0.1)
    gp = ExactGP(additive_noise=0.0).fit(X, Y, rng=0)
    trace = gp.diagnostics["objective_trace"]
    assert min(trace) < trace[0] - 0.1
    # The true noise variance is 0.01 in both outputs.
    assert np.all((gp.hyperparameters["noise"] > 0.005) & (gp.hyperparameters["noise"] < 0.02))
    Xs = np.random.default_rng(4).uniform(-2.5, 2.5, size=(200, 2))
    truth = np.stack([np.sin(Xs[:, 0]) + Xs[:, 1] ** 2 / 5, np.cos(Xs[:, 1]) * Xs[:, 0]], axis=1)
    mean, var = gp.predict(Xs)
    assert np.sqrt(np.mean((mean - truth) ** 2)) < 0.1


def test_additive_noise_is_alpha_percent_of_std_and_seeded():
    X, Y = _data(50, noise=0.0)
    gp = ExactGP(additive_noise=2.0, n_steps=0).fit(X, Y, rng=5)
    np.testing.assert_allclose(gp.diagnostics["additive_noise_std"], 2.0 * 1e-2 * Y.std(axis=0))
    added = gp.Y.numpy().T * gp.y_scale + gp.y_mean - Y
    # A sample standard deviation of n Gaussian draws has relative standard error
    # 1/sqrt(2(n − 1)) (0.1 at n = 50): five of them (was atol=0.35, 3.5 of them).
    np.testing.assert_allclose(
        added.std(axis=0) / (2e-2 * Y.std(axis=0)), 1.0, atol=5 / np.sqrt(2 * (len(Y) - 1))
    )
    same = ExactGP(additive_noise=2.0, n_steps=0).fit(X, Y, rng=5)
    other = ExactGP(additive_noise=2.0, n_steps=0).fit(X, Y, rng=6)
    assert torch.equal(gp.Y, same.Y) and not torch.equal(gp.Y, other.Y)
    clean = ExactGP(additive_noise=0.0, n_steps=0, standardize=False).fit(X, Y, rng=5)
    np.testing.assert_array_equal(clean.Y.numpy().T, Y)


def test_same_seed_same_fit():
    X, Y = _data(40)
    a = ExactGP(n_steps=10).fit(X, Y, rng=11)
    b = ExactGP(n_steps=10).fit(X, Y, rng=11)
    for k in a.hyperparameters:
        np.testing.assert_array_equal(a.hyperparameters[k], b.hyperparameters[k])


def test_ill_conditioned_duplicates_and_constant_targets():
    rng = np.random.default_rng(7)
    base = rng.uniform(-1, 1, size=(40, 2))
    X = np.repeat(base, 10, axis=0)  # every input 10 times
    Y = np.stack([np.sin(3 * X[:, 0]), np.full(len(X), 2.5)], axis=1)  # second output constant
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp = ExactGP(additive_noise=0.0, n_steps=30).fit(X, Y, rng=0)
    assert gp.diagnostics["constant_outputs"] == [1]
    assert 1 in gp.diagnostics["noise_at_floor"]
    # no target noise was added: the floor is the nugget, neither an event nor a warning
    assert not any("floor" in str(w.message) for w in caught)
    assert gp.diagnostics["numerical_events"]["noise_at_floor"] == 0
    Xs = np.vstack([base, rng.uniform(-3, 3, size=(50, 2))])
    mean, var = gp.predict(Xs)
    fmean, fvar = gp.predict(Xs, include_noise=False)
    assert np.all(np.isfinite(mean)) and np.all(var > 0) and np.all(fvar >= 0)
    np.testing.assert_allclose(mean[:, 1], 2.5, atol=1e-6)
    np.testing.assert_allclose(mean[:40, 0], np.sin(3 * base[:, 0]), atol=1e-3)


@pytest.mark.slow  # one N = 10,000 Cholesky + inverse per evaluation: minutes on a loaded machine
def test_ten_thousand_points_train_without_crash():
    rng = np.random.default_rng(8)
    X = np.repeat(rng.uniform(-2, 2, size=(2000, 3)), 5, axis=0)  # 10,000 points, duplicates
    y = np.sin(X).sum(1)
    gp = ExactGP(additive_noise=1.0, n_steps=1).fit(X, y, rng=0)
    mean, var = gp.predict(rng.uniform(-3, 3, size=(100, 3)))
    assert np.all(np.isfinite(mean)) and np.all(var >= 0)


def test_latent_covariance_diagonal_matches_variance():
    X, Y = _data(30)
    gp = ExactGP(n_steps=5).fit(X, Y, rng=0)
    Xs = torch.as_tensor(np.random.default_rng(2).uniform(-3, 3, size=(10, 2)))
    cov = gp.predictor.latent_covariance(Xs)
    _, fvar = gp.predict(Xs.numpy(), include_noise=False)
    # The same kernel vectors k and factor R on both sides; Rk through matrix products of
    # other shapes (N-term sums, off by N ε |R||k|, so ‖Rk‖² by 2 N ε |Rk|ᵀ|R||k|), k(x, x)
    # = σ_f² up to the (d + 2)-term exponent's rounding (terms ≤ 2‖x/w‖² + |log σ_f²|, as in
    # _gp_tols); standardised units, scaled to raw ones
    pred = gp.predictor
    k = pred.kernel_vectors(Xs).numpy()  # (E, n, N)
    R = pred.var_factor.numpy()
    Rk = np.abs(np.einsum("eij,enj->eni", R, k))
    quad = 2 * np.einsum("eni,eij,enj->en", Rk, np.abs(R), np.abs(k)).max(1)
    sf2 = pred.outputscale.numpy()
    S = 2 * ((Xs[None] / pred.lengthscale[:, None]) ** 2).sum(-1).amax(1).numpy()
    n_ops = k.shape[-1] + (Xs.shape[1] + 2) * (S + np.abs(np.log(sf2))).max()
    tol = 2 * fp_tol(n_ops, scale=((quad + sf2) * pred.y_scale.numpy() ** 2).max())
    np.testing.assert_allclose(cov.diagonal(dim1=-2, dim2=-1).numpy().T, fvar, rtol=0, atol=tol)
    assert np.linalg.eigvalsh(cov.numpy()).min() > -1e-9


def test_robust_cholesky_jitter_policy():
    A = torch.ones(3, 3, dtype=torch.float64)  # rank one
    with pytest.warns(GPNumericalWarning, match="jitter"):
        L, j = robust_cholesky(A, "A")
    assert j > 0
    torch.testing.assert_close(L @ L.T, A + j * torch.eye(3, dtype=torch.float64))
    with warnings.catch_warnings(), record_numerical_events() as events:
        warnings.simplefilter("error", GPNumericalWarning)  # counted instead of warned about
        assert robust_cholesky(A, "A")[1] == j
        L, j = robust_cholesky(torch.eye(2, dtype=torch.float64))
    assert events.counts["jitter_increased"] == 1 and events.max_jitter == 1e-12
    assert j == 0.0
    with pytest.raises(GPNumericalError, match="non-finite"):
        robust_cholesky(torch.tensor([[float("nan")]], dtype=torch.float64))
    with pytest.raises(GPNumericalError, match="not positive definite"):
        robust_cholesky(-torch.eye(2, dtype=torch.float64))


def test_optimizer_stops_on_failure_and_restores_best():
    p = torch.nn.Parameter(torch.tensor([3.0], dtype=torch.float64))
    calls = {"n": 0}

    def loss():
        calls["n"] += 1
        if calls["n"] > 4:
            raise GPNumericalError("boom")
        return (p - 1.0).pow(4).sum()

    with pytest.warns(GPNumericalWarning, match="stopped early"):
        res = optimize([p], loss, 20)
    assert res["stopped_early"] == "boom"
    calls["n"], p.data[:] = 0, 3.0
    with warnings.catch_warnings(), record_numerical_events() as events:
        warnings.simplefilter("error", GPNumericalWarning)  # counted instead of warned about
        assert optimize([p], loss, 20)["stopped_early"] == "boom"
    assert events.counts["restored_iterate"] == 1 and events.total == 1
    assert res["best"] == min(res["trace"])
    assert float((p.detach() - 1.0) ** 4) == pytest.approx(res["best"])


def test_lbfgs_never_returns_a_rejected_line_search_point():
    """f(p) = −p + 0.8 p⁴ from p = 0. L-BFGS's first trial p = 1 has f = −0.2 < f(0)
    (Armijo holds) but f'(1) = 2.2 breaks the strong-Wolfe curvature condition, so the line
    search rejects it and evaluates again; that evaluation fails. The last completed iterate is
    p = 0, not the best value *seen* (the rejected p = 1)."""
    p = torch.nn.Parameter(torch.tensor([0.0], dtype=torch.float64))
    calls = {"n": 0}

    def loss():
        calls["n"] += 1
        if calls["n"] == 3:
            return p.sum() * float("nan")
        return -p.sum() + 0.8 * p.pow(4).sum()

    with pytest.warns(GPNumericalWarning, match="stopped early"):
        res = optimize([p], loss, 20)
    assert res["trace"][:2] == [0.0, pytest.approx(-0.2)]  # the rejected trial was evaluated
    assert float(p.detach()) == 0.0
    assert res["best"] == 0.0
    assert res["n_iterations"] == 0


def test_lbfgs_ends_on_a_completed_iterate_with_its_value():
    """Without failures the result is L-BFGS's last accepted iterate: its objective is the
    reported ``best``, no larger than the start, and the minimiser of a convex quadratic."""
    A = torch.tensor([[3.0, 1.0], [1.0, 2.0]], dtype=torch.float64)
    b = torch.tensor([1.0, -1.0], dtype=torch.float64)
    p = torch.nn.Parameter(torch.tensor([2.0, 2.0], dtype=torch.float64))

    def loss():
        return 0.5 * p @ A @ p - b @ p

    res = optimize([p], loss, 50)
    torch.testing.assert_close(p.detach(), torch.linalg.solve(A, b))
    # ``best`` is the cached objective of the parameters' exact bytes: the same computation
    assert res["best"] == float(loss().detach())
    assert res["best"] <= res["trace"][0]
    assert 1 <= res["n_iterations"] <= 50 and res["stopped_early"] is None


def test_hyper_curb_penalty_closed_form_and_gradient():
    curb = HyperCurb(lengthscale_ratio=100.0, snr=500.0, power=30)
    ls = torch.tensor([[100.0, 0.5]], dtype=torch.float64)  # first at the limit 100·std
    os = torch.tensor([4.0], dtype=torch.float64)
    nz = torch.tensor([4.0 / 500.0**2], dtype=torch.float64)  # σ_f/σ_ε = 500: at the limit
    std = torch.tensor([1.0, 0.5], dtype=torch.float64)
    # (log 100 / log 100)^30 + (0)^30 + (log 500 / log 500)^30 = 2
    # each ratio (two logs, a difference, a product, a quotient; log σ_f² > 0 > log σ_ε², so
    # no cancellation) is relatively off by ≲ 5 ε, then raised to the 30th power (cond 30)
    assert float(curb.penalty(ls, os, nz, std)) == pytest.approx(2.0, rel=fp_tol(6, cond=30))
    inside = curb.penalty(ls / 10, os, nz * 500, std)  # w/std = 10, 0.1, SNR √500: √ limits
    assert float(inside) == pytest.approx(3 * 0.5**30, rel=1e-9)
    log_args = [  # in log space, where the optimiser works; beyond and within the limits
        torch.log(torch.tensor(v, dtype=torch.float64)).requires_grad_()
        for v in ([[300.0, 0.05]], [2.0], [2e-6])
    ]
    assert torch.autograd.gradcheck(
        lambda a, b, c: curb.penalty(a.exp(), b.exp(), c.exp(), std), log_args
    )
    for bad in (dict(lengthscale_ratio=1.0), dict(snr=0.5), dict(power=3), dict(power=0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            HyperCurb(**bad)
    with pytest.raises(ValueError, match="curb: expected a HyperCurb"):
        ExactGP(curb=100.0)


@pytest.mark.filterwarnings("ignore:noise variance:skillkit.models.gp.GPNumericalWarning")
@pytest.mark.parametrize("make", [ExactGP, lambda **kw: FITC(n_inducing=20, **kw)])
def test_hyper_curb_stops_the_linear_limit(make):
    """Nearly noise-free linear data: maximum likelihood takes the SE kernel toward its linear
    limit (length-scales far beyond the inputs' spread, σ_f/σ_ε in the thousands); the curb
    keeps both near its limits (100 std(x), 500), and the diagnostics report them."""
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, size=(200, 3))
    Y = X @ np.array([1.0, -2.0, 0.5]) + 1e-3 * rng.standard_normal(200)
    free = make(n_steps=100).fit(X, Y, rng=0).diagnostics
    held = make(n_steps=100, curb=HyperCurb()).fit(X, Y, rng=0).diagnostics
    assert free["curb_penalty"] is None and free["max_signal_to_noise"] > 5000
    assert held["max_lengthscale_ratio"] < 100 * 1.2 and held["max_signal_to_noise"] < 500 * 1.2
    assert 0 < held["curb_penalty"] < 10


@pytest.mark.filterwarnings("ignore:noise variance:skillkit.models.gp.GPNumericalWarning")
def test_forward_model_delta_and_next_targets():
    rng = np.random.default_rng(9)
    A = np.array([[1.0, 0.1], [-0.1, 0.95]])
    B = np.array([[0.0], [0.1]])
    x = rng.uniform(-1, 1, size=(120, 2))
    u = rng.uniform(-1, 1, size=(120, 1))
    xn = x @ A.T + u @ B.T
    xs, us = rng.uniform(-0.8, 0.8, size=(20, 2)), rng.uniform(-0.8, 0.8, size=(20, 1))
    for target in ("delta", "next"):
        fm = ForwardModel(ExactGP(additive_noise=0.0, n_steps=40), target=target).fit(
            x, u, xn, rng=0
        )
        mean, var = fm.predict(xs, us)
        np.testing.assert_allclose(mean, xs @ A.T + us @ B.T, atol=5e-3)
        assert var.shape == (20, 2) and np.all(var > 0)
    assert fm.state_dim == 2 and fm.control_dim == 1


def test_bad_input():
    X, Y = _data(10)
    with pytest.raises(ValueError, match="X"):
        ExactGP().fit(X[:, 0], Y)
    with pytest.raises(ValueError, match="Y"):
        ExactGP().fit(X, Y[:5])
    Xn = X.copy()
    Xn[0, 0] = np.nan
    with pytest.raises(ValueError, match="X"):
        ExactGP().fit(Xn, Y)
    with pytest.raises(ValueError, match="Y"):
        ExactGP().fit(X, np.full_like(Y, np.inf))
    gp = ExactGP(n_steps=0).fit(X, Y)
    with pytest.raises(ValueError, match="X"):
        gp.predict(np.zeros((3, 5)))
    with pytest.raises(RuntimeError, match="fit"):
        ExactGP().predict(X)
    with pytest.raises(ValueError, match="n_steps"):
        ExactGP(n_steps=-1)
    with pytest.raises(ValueError, match="noise_floor"):
        ExactGP(noise_floor=0.0)
    with pytest.raises(ValueError, match="additive_noise"):
        ExactGP(additive_noise=-1.0)
    with pytest.raises(ValueError, match="lengthscale"):
        ExactGP(lengthscale=[1.0, 2.0, 3.0], n_steps=0).fit(X, Y)
    fm = ForwardModel(ExactGP(n_steps=0))
    with pytest.raises(ValueError, match="next_states"):
        fm.fit(X, X[:, :1], X[:5])
    with pytest.raises(ValueError, match="controls"):
        fm.fit(X, X[:5, :1], X)
    with pytest.raises(ValueError, match="target"):
        ForwardModel(ExactGP(), target="state")
    with pytest.raises(ValueError, match="gp"):
        ForwardModel(object())
    assert math.isfinite(ExactGP(n_steps=0).fit(X, Y).diagnostics["log_marginal_likelihood"].sum())


# ---------------------------------------------------------------------------- device
PREDICTOR_FIELDS = tuple(f.name for f in dataclasses.fields(GPPredictor) if f.init)


def _fit_outputs(gp, X_test):
    """Everything a fit returns, as numpy arrays: predictor tensors, θ, log ML, predictions."""
    out = {f: getattr(gp.predictor, f).cpu().numpy() for f in PREDICTOR_FIELDS}
    out.update({f"h_{k}": v for k, v in gp.hyperparameters.items()})
    out["lml"] = np.asarray(gp.diagnostics["log_marginal_likelihood"])
    out["mean"], out["var"] = gp.predict(X_test)
    return out


@pytest.mark.parametrize("device", ["cpu", torch.device("cpu")])
def test_explicit_cpu_device_is_bit_identical_to_default(device):
    X, Y = _data(30)
    default = _fit_outputs(ExactGP(n_steps=20).fit(X, Y, rng=1), X[:7] + 0.1)
    gp = ExactGP(n_steps=20, device=device)
    assert gp.device == torch.device("cpu")
    explicit = _fit_outputs(gp.fit(X, Y, rng=1), X[:7] + 0.1)
    for key, value in default.items():
        np.testing.assert_array_equal(explicit[key], value, err_msg=key)


def test_training_tensors_live_on_the_device():
    X, Y = _data(20)
    gp = ExactGP(n_steps=3, device="cpu").fit(X, Y, rng=0)
    tensors = [getattr(gp.predictor, f) for f in PREDICTOR_FIELDS]
    tensors += [gp.X, gp.Y, gp.cholesky, *gp.model.parameters(), *gp.model.buffers()]
    assert gp.predictor.device == torch.device("cpu")
    assert all(t.device == gp.device and t.dtype == torch.float64 for t in tensors)


@pytest.mark.parametrize("device", ["nonsense", "mps", "meta", 1.5, "cuda:99"])
def test_bad_device_raises(device):
    with pytest.raises(ValueError, match="device"):
        ExactGP(device=device)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without CUDA")
def test_cuda_device_without_cuda_raises():
    with pytest.raises(ValueError, match="device: .*CUDA is not available"):
        ExactGP(device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_fit_matches_cpu():
    X, Y = _data(30)
    outs = {}
    for device in ("cpu", "cuda"):
        gp = ExactGP(n_steps=10, device=device).fit(X, Y, rng=1)
        assert gp.predictor.device.type == device
        outs[device] = _fit_outputs(gp, X[:7] + 0.1)
        fm = ForwardModel(ExactGP(n_steps=10, device=device)).fit(X, Y[:, :1], X, rng=2)
        assert fm.predictor.device.type == device
        outs[device]["fm_mean"], outs[device]["fm_var"] = fm.predict(X[:5], Y[:5, :1])
    for key, value in outs["cpu"].items():
        np.testing.assert_allclose(
            outs["cuda"][key], value, rtol=1e-8, atol=1e-8 * np.abs(value).max(), err_msg=key
        )


def test_predictive_draws_have_the_predicted_moments():
    """``sample``: independent draws whose mean and variance are ``predict``'s (Eqs 2.26–2.27),
    1-D targets give (n, L), same generator state ⇒ same draws, L must be a count."""
    rng = np.random.default_rng(0)
    X = rng.uniform(-2, 2, size=(30, 2))
    Y = np.column_stack([np.sin(X[:, 0]), X[:, 1] ** 2]) + 0.1 * rng.standard_normal((30, 2))
    gp = ExactGP(n_steps=20).fit(X, Y, rng=0)
    Xq = rng.uniform(-2, 2, size=(4, 2))
    mean, var = gp.predict(Xq)
    draws = gp.sample(Xq, 20000, np.random.default_rng(1))
    assert draws.shape == (4, 20000, 2)
    np.testing.assert_allclose(draws.mean(axis=1), mean, atol=5 * np.sqrt(var.max() / 20000))
    np.testing.assert_allclose(draws.var(axis=1), var, rtol=0.05)
    np.testing.assert_array_equal(
        gp.sample(Xq, 3, np.random.default_rng(7)), gp.sample(Xq, 3, np.random.default_rng(7))
    )
    one = ExactGP(n_steps=20).fit(X, Y[:, 0], rng=0)
    assert one.sample(Xq, 5, 0).shape == (4, 5)
    latent = one.sample(Xq, 20000, 1, include_noise=False).var(axis=1)
    np.testing.assert_allclose(latent, one.predict(Xq, include_noise=False)[1], rtol=0.05)
    with pytest.raises(ValueError, match="n_samples"):
        gp.sample(Xq, 0, 0)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.int64])
def test_predictor_to_an_unsupported_dtype_names_it(dtype):
    """float64 and float32 only (the kernel floor is defined for those); before, float16 failed
    later with a KeyError inside ``kernel_vectors`` and int64 with a torch.finfo TypeError."""
    X, Y = _data(15)
    pred = ExactGP(n_steps=0).fit(X, Y, rng=0).predictor
    with pytest.raises(ValueError, match="dtype: expected torch.float64 or torch.float32"):
        pred.to(dtype=dtype)
    assert pred.to(dtype=torch.float64) is pred
