"""The batched, blocked moment matching equals a straightforward reference implementation.

``_reference_moment_match`` below is the unbatched ``moment_match_step`` (one Python
loop over outputs a, one (M × M) log-domain product per pair a ≤ b, no exponent floor): an
independent computation of the same formulas. Means, covariances and input–output covariances
must agree to 1e-10 relative (‖new − old‖_max ≤ 1e-10 ‖old‖_max for each), for exact and FITC
models, one step and multi-step :func:`propagate` with linear-feedback gains and offsets, every
block shape of the blocked loop, with exponents far below the floor, and in their gradients.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.gp import DTYPE, ExactGP, ForwardModel, GPNumericalWarning, GPPredictor
from skillkit.models.moment_matching import (
    LOG_FLOOR,
    GaussianPrediction,
    _second_moments,
    moment_match,
    moment_match_step,
    propagate,
    with_linear_mean,
)
from skillkit.models.sparse import FITC

# Round-off estimate: each entry sums ≤ 2M terms (M ≤ 370 here) whose log-domain exponents
# have parts of size ≲ 50 (products of D ≤ 12 terms): worst case ε (2M + 50 (D + 2)) ≈ 3e-13
# of the terms' magnitude, so 1e-10 leaves ≥ 300x. Against max|old| only where the terms do
# not cancel; where they do (small variances), against _term_scale.
RTOL = 1e-10


def _reference_moment_match(
    pred: GPPredictor, m: torch.Tensor, S: torch.Tensor, include_noise: bool = True
) -> GaussianPrediction:
    """The unbatched implementation (its latent-variance clamp without the warning)."""
    E, M, D = pred.support.shape
    iL = 1.0 / pred.lengthscale  # (E, D)
    sf2 = pred.outputscale
    eye = torch.eye(D, dtype=DTYPE)
    nu = pred.support - m  # (E, M, D)
    nut = nu * iL[:, None, :]  # Λ^{-1/2} ν
    Sa = iL[:, :, None] * S * iL[:, None, :] + eye
    Lsa = torch.linalg.cholesky(Sa)
    sol = torch.cholesky_solve(nut.transpose(-1, -2), Lsa)  # (E, D, M)
    quad = (nut * sol.transpose(-1, -2)).sum(-1)
    logdet_sa = 2.0 * torch.log(Lsa.diagonal(dim1=-2, dim2=-1)).sum(-1)
    q = sf2[:, None] * torch.exp(-0.5 * quad - 0.5 * logdet_sa[:, None])
    bq = pred.beta * q
    mu = bq.sum(-1)  # (E,)
    io = S @ (iL * (sol @ bq[..., None]).squeeze(-1)).T  # (D, E)
    logk = torch.log(sf2)[:, None] - 0.5 * (nut * nut).sum(-1)  # (E, M)
    zeta = nut * iL[:, None, :]  # Λ^{-1} ν, (E, M, D)
    second = torch.empty((E, E), dtype=DTYPE)
    latent_var = torch.empty(E, dtype=DTYPE)
    for a in range(E):
        b = torch.arange(a, E)
        dab = iL[a] ** 2 + iL[b] ** 2  # (nb, D): Λ_a^{-1} + Λ_b^{-1}
        sd = dab.sqrt()
        P = sd[:, :, None] * S * sd[:, None, :]
        LR = torch.linalg.cholesky(P + eye)  # R is similar to P + I
        T = torch.cholesky_solve(P, LR) / (sd[:, :, None] * sd[:, None, :])  # R^{-1} S
        T = 0.5 * (T + T.transpose(-1, -2))
        logdet_r = 2.0 * torch.log(LR.diagonal(dim1=-2, dim2=-1)).sum(-1)
        za = zeta[a].expand(len(b), M, D)
        Ta = za @ T  # (nb, M, D)
        qa = 0.5 * (Ta * za).sum(-1)
        qb = 0.5 * ((zeta[b] @ T) * zeta[b]).sum(-1)
        logQ = torch.baddbmm(
            (logk[a] + qa)[:, :, None] + (logk[b] + qb)[:, None, :] - 0.5 * logdet_r[:, None, None],
            Ta,
            zeta[b].transpose(-1, -2),
        )
        Q = torch.exp(logQ)  # (nb, M, M)
        vals = ((Q @ pred.beta[b].unsqueeze(-1)).squeeze(-1) * pred.beta[a]).sum(-1)
        second[a, a:] = vals
        second[a:, a] = vals
        latent_var[a] = sf2[a] - (pred.iK[a] * Q[0]).sum()
    V = second - mu[:, None] * mu[None, :]
    V = V + torch.diag(latent_var.clamp_min(0.0) + (pred.noise if include_noise else 0.0))
    V = 0.5 * (V + V.T)
    s = pred.y_scale
    return GaussianPrediction(pred.y_mean + s * mu, s[:, None] * V * s[None, :], io * s[None, :])


def _reference_propagate(model: ForwardModel, m, S, T: int, K, k):
    """The moment-matching branch of :func:`propagate`, step by step with the reference."""
    pred = model.predictor.to("cpu", DTYPE)
    m, S = torch.as_tensor(m, dtype=DTYPE), torch.as_tensor(S, dtype=DTYPE)
    K, k = torch.as_tensor(K, dtype=DTYPE), torch.as_tensor(k, dtype=DTYPE)
    n_x = model.state_dim
    means, covs = [m], [S]
    for _ in range(T):
        A = torch.cat([torch.eye(n_x, dtype=DTYPE), K], dim=0)
        mz = A @ m + torch.cat([torch.zeros(n_x, dtype=DTYPE), k])
        Sz = A @ S @ A.T
        g = _reference_moment_match(pred, mz, 0.5 * (Sz + Sz.T))
        g = with_linear_mean(model, g, mz, Sz)
        if model.delta:
            cx = g.input_output_cov[:n_x]
            m, S = m + g.mean, S + g.cov + cx + cx.T
        else:
            m, S = g.mean, g.cov
        S = 0.5 * (S + S.T)
        means.append(m)
        covs.append(S)
    return torch.stack(means), torch.stack(covs)


def _assert_same(new, old, rtol=RTOL, what=""):
    new, old = torch.as_tensor(new), torch.as_tensor(old)
    scale = float(old.abs().max())
    err = float((new - old).abs().max())
    assert err <= rtol * scale, f"{what}: max error {err:.3e} vs scale {scale:.3e}"


def _term_scale(pred: GPPredictor, m: torch.Tensor, S: torch.Tensor) -> torch.Tensor:
    """(E, E): the magnitude of the terms whose sum cov(y_a, y_b) is,

    s_a s_b (Σ_ij |β_ai| Q^{ab}_ij |β_bj| + |μ_a μ_b| + δ_ab (σ_{f,a}² + Σ_ij |iK_a,ij| Q^{aa}_ij
    + σ_ε,a²)),

    from the reference run with |β| and −|iK| (all its terms then add up). Float64 round-off in
    any implementation of the sum is a small multiple of 1e-16 times this, which can exceed
    1e-10 |cov| where the variance is small by cancellation (an input narrower than the data
    spacing of an exact GP with large β)."""
    ref = _reference_moment_match(pred, m, S)
    mu = (ref.mean - pred.y_mean) / pred.y_scale
    absolute = dataclasses.replace(
        pred,
        beta=pred.beta.abs(),
        iK=-pred.iK.abs(),
        y_mean=torch.zeros_like(pred.y_mean),
        y_scale=torch.ones_like(pred.y_scale),
    )
    g = _reference_moment_match(absolute, m, S)
    terms = g.cov + g.mean[:, None] * g.mean[None, :] + (mu[:, None] * mu[None, :]).abs()
    s = pred.y_scale
    return s[:, None] * terms * s[None, :]


def _assert_same_prediction(
    new: GaussianPrediction, old: GaussianPrediction, pred=None, m=None, S=None
) -> None:
    """Mean and cov(z, y) to 1e-10 relative; cov(y) to 1e-10 relative to max|cov| or, entry
    by entry, to the magnitude of its terms (:func:`_term_scale`, when ``pred`` is given)."""
    _assert_same(new.mean, old.mean, what="mean")
    _assert_same(new.input_output_cov, old.input_output_cov, what="input_output_cov")
    err = (new.cov - old.cov).abs()
    bound = RTOL * float(old.cov.abs().max())
    if pred is not None:
        bound = torch.clamp_min(RTOL * _term_scale(pred, m, S), bound)
    assert bool((err <= bound).all()), f"cov: errors {err} vs bounds {bound}"


def _random_model(kind: str, seed: int, D: int, E: int, N: int = 60, M: int = 20, spread=1.0):
    rng = np.random.default_rng(seed)
    X = spread * rng.normal(size=(N, D))
    Y = np.sin(X @ rng.normal(size=(D, E))) + 0.1 * rng.normal(size=(N, E)) + rng.normal(size=E)
    # A few optimiser steps from random length-scales: per-output σ_f², σ_ε² and w.
    kw = dict(
        lengthscale=rng.uniform(0.5, 2.0, size=(E, D)),
        outputscale=1.0,
        noise=0.01,
        n_steps=3,
        additive_noise=0.0,
    )
    if kind == "exact":
        return ExactGP(**kw).fit(X, Y)
    return FITC(inducing=spread * rng.normal(size=(M, D)), optimize_inducing=False, **kw).fit(X, Y)


def _random_gaussian(seed: int, D: int, scale: float = 0.3, rank: int | None = None):
    rng = np.random.default_rng(seed + 1000)
    A = scale * rng.normal(size=(D, rank or D))
    return (
        torch.as_tensor(0.5 * rng.normal(size=D), dtype=DTYPE),
        torch.as_tensor(A @ A.T, dtype=DTYPE),
    )


@pytest.mark.parametrize(
    "kind,seed,D,E,rank",
    [
        ("exact", 0, 3, 2, None),
        ("exact", 1, 5, 4, 3),
        ("fitc", 2, 4, 3, None),
        ("fitc", 3, 6, 5, 4),
        ("exact", 4, 1, 1, None),
        ("fitc", 5, 12, 8, 8),
    ],
)
@pytest.mark.parametrize("include_noise", [True, False])
def test_moment_match_equals_the_reference(kind, seed, D, E, rank, include_noise):
    """Random SE models with per-output hyper-parameters, full-rank and degenerate inputs
    (z = [x, Kx + k] has rank n_x)."""
    pred = _random_model(kind, seed, D, E).predictor
    for j, scale in enumerate((0.05, 0.5, 2.0)):
        m, S = _random_gaussian(10 * seed + j, D, scale, rank)
        new = moment_match(pred, m, S, include_noise=include_noise)
        old = _reference_moment_match(pred, m, S, include_noise)
        _assert_same_prediction(new, old, pred, m, S)


@pytest.mark.parametrize("kind,M", [("exact", 370), ("fitc", 50)])
def test_every_block_shape_gives_the_same_second_moments(kind, M):
    """Whole pairs grouped, one pair per block, row ranges with a remainder, single rows; and
    the default block at M = 370 (row ranges, since M² exceeds it)."""
    pred = _random_model(kind, 7, 4, 3, N=M if kind == "exact" else 80, M=M).predictor
    m, S = _random_gaussian(7, 4, 0.4)
    iL = 1.0 / pred.lengthscale
    nut = (pred.support - m) * iL[:, None, :]
    ref = _reference_moment_match(pred, m, S, include_noise=False)
    mu = ref.mean - pred.y_mean
    s = pred.y_scale
    # cov = s (second − μμᵀ + diag latent) s for the latent prediction: recover second + diag.
    target = ref.cov / (s[:, None] * s[None, :]) + (mu / s)[:, None] * (mu / s)[None, :]
    results = []
    for block in (1, M, 3 * M + 1, M * M, 5 * M * M, 100 * M * M):
        second, latent = _second_moments(pred, S, nut, iL, block=block)
        assert torch.equal(second, second.T)
        results.append(second + torch.diag(latent))
        _assert_same(results[-1], target, what=f"block={block}")
    for r in results[1:]:
        _assert_same(r, results[0])


@pytest.mark.parametrize("kind", ["exact", "fitc"])
@pytest.mark.parametrize("target", ["delta", "next"])
def test_propagate_equals_the_reference_over_many_steps(kind, target):
    """8 steps of a 3-state, 2-control model under u_t = K_t x_t + k_t, with and without the
    offsets k_t, with a time-varying gain."""
    rng = np.random.default_rng(11)
    x = rng.uniform(-1.5, 1.5, size=(150, 3))
    u = rng.uniform(-1.5, 1.5, size=(150, 2))
    xn = x + 0.2 * np.tanh(np.concatenate([x, u], 1) @ rng.normal(size=(5, 3)))
    gp_kw = dict(n_steps=0, additive_noise=0.0, noise=1e-3, lengthscale=1.2)
    gp = ExactGP(**gp_kw) if kind == "exact" else FITC(n_inducing=40, **gp_kw)
    fm = ForwardModel(gp, target=target).fit(x, u, xn, rng=0)
    T = 8
    K = -0.3 * rng.uniform(0.5, 1.5, size=(T, 2, 3))
    m0, S0 = np.array([0.3, -0.2, 0.5]), np.diag([0.02, 0.05, 0.01])
    for k in (np.zeros((T, 2)), rng.normal(0.0, 0.5, size=(T, 2))):
        means, covs = propagate(fm, m0, S0, T, K, k)
        ref_means = torch.zeros((T + 1, 3), dtype=DTYPE)
        ref_covs = torch.zeros((T + 1, 3, 3), dtype=DTYPE)
        ref_means[0], ref_covs[0] = torch.as_tensor(m0), torch.as_tensor(S0)
        for t in range(T):
            mt, St = _reference_propagate(fm, ref_means[t], ref_covs[t], 1, K[t], k[t])
            ref_means[t + 1], ref_covs[t + 1] = mt[1], St[1]
        for t in range(1, T + 1):
            _assert_same(means[t], ref_means[t], what=f"mean t={t}")
            _assert_same(covs[t], ref_covs[t], what=f"cov t={t}")
        # The constant-gain form and the reference's own multi-step loop agree too.
        means_c, covs_c = propagate(fm, m0, S0, T, K[0], k[0])
        ref_mc, ref_cc = _reference_propagate(fm, m0, S0, T, K[0], k[0])
        _assert_same(means_c, ref_mc, what="constant-gain means")
        _assert_same(covs_c, ref_cc, what="constant-gain covs")


def test_exponents_below_the_floor_give_the_same_numbers():
    """Support points about 50 length-scales from the input: log k_a(z_i, m) < −600 there, so
    log Q_ii ≈ 2 log k_a(z_i, m) is far below :data:`LOG_FLOOR` (the reference underflows such
    entries to 0 or to denormals; the floor turns them into e^-600). Same numbers."""
    rng = np.random.default_rng(12)
    near = rng.normal(size=(40, 2))
    far = rng.normal(size=(20, 2)) + np.array([60.0, 0.0])
    X = np.concatenate([near, far])
    Y = np.stack([np.sin(X[:, 0]), np.cos(X[:, 1])], 1)
    gp = ExactGP(lengthscale=1.0, noise=1e-2, n_steps=0, additive_noise=0.0).fit(X, Y)
    pred = gp.predictor
    m, S = torch.zeros(2, dtype=DTYPE), 0.05 * torch.eye(2, dtype=DTYPE)
    nut = (pred.support - m) / pred.lengthscale[:, None, :]
    logk = torch.log(pred.outputscale)[:, None] - 0.5 * (nut**2).sum(-1)
    assert float(logk.min()) < LOG_FLOOR
    new = moment_match(pred, m, S)
    _assert_same_prediction(new, _reference_moment_match(pred, m, S), pred, m, S)


def test_gradients_equal_the_reference_gradients():
    """PILCO differentiates through ``moment_match_step`` (strict): the recorded path (no in-place
    operations) has the reference's gradient with respect to m and S."""
    pred = _random_model("fitc", 13, 4, 3).predictor
    m0, S0 = _random_gaussian(13, 4, 0.4)
    grads = []
    for fn in (
        lambda m, S: moment_match_step(pred, m, S, strict=True),
        lambda m, S: _reference_moment_match(pred, m, S),
    ):
        m, S = m0.clone().requires_grad_(True), S0.clone().requires_grad_(True)
        g = fn(m, S)
        w = torch.arange(1.0, 1.0 + g.cov.numel(), dtype=DTYPE).reshape(g.cov.shape)
        obj = (g.mean**2).sum() + (w * g.cov).sum() + g.input_output_cov.sum()
        grads.append(torch.autograd.grad(obj, (m, S)))
    # Round-off of the gradient: each of the E² outputs' backward pass sums the same ≤ 2M
    # log-domain terms as the forward one (RTOL's estimate ε (2M + 50 (D + 2))), weighted by
    # w ≤ E² and passed through a solve with Sa = Λ^{-1/2} S Λ^{-1/2} + I (its condition).
    E, M, D = pred.support.shape
    iL = 1.0 / pred.lengthscale
    Sa = iL[:, :, None] * S0 * iL[:, None, :] + torch.eye(D, dtype=DTYPE)
    cond = float(torch.linalg.cond(Sa).max())
    rtol = fp_tol((2 * M + 50 * (D + 2)) * E**2 * E**2, cond=cond)
    for new, old in zip(grads[0], grads[1], strict=True):
        _assert_same(new, old, rtol=rtol, what="gradient")


def test_a_negative_latent_variance_is_reported_clamped_or_nan_as_before():
    """Inflating iK forces σ_f² − tr(iK Q) < 0: the warning and the clamp to 0 as before (same
    numbers as the reference, which clamps too), NaN in strict mode."""
    pred = _random_model("fitc", 14, 3, 2).predictor
    bad = dataclasses.replace(pred, iK=pred.iK * 1e3)
    m, S = _random_gaussian(14, 3, 0.2)
    with pytest.warns(GPNumericalWarning, match="negative"):
        clamped = moment_match(bad, m, S)
    # cov(y) entry by entry against the size of its terms (_term_scale): the variance of
    # output 1 is ~1e3 times smaller than they are (σ_f² − tr(iK Q) cancels), so 1e-10 of
    # max|cov| sat below its round-off (3.7e-11 against 2.1e-11 with ATEN_CPU_CAPABILITY=default).
    _assert_same_prediction(clamped, _reference_moment_match(bad, m, S), bad, m, S)
    assert torch.isnan(moment_match_step(bad, m, S, strict=True).cov).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _assert_same_prediction(
            moment_match(pred, m, S), _reference_moment_match(pred, m, S), pred, m, S
        )


def test_gradients_of_every_block_shape_agree():
    """The recorded (differentiable) path with row ranges of one pair (small ``block``) has
    the gradient of whole-pair blocks."""
    pred = _random_model("fitc", 15, 3, 3, M=30).predictor
    m0, S0 = _random_gaussian(15, 3, 0.4)
    grads = []
    for block in (7 * 30, 100 * 30 * 30):
        m, S = m0.clone().requires_grad_(True), S0.clone().requires_grad_(True)
        iL = 1.0 / pred.lengthscale
        nut = (pred.support - m) * iL[:, None, :]
        second, latent = _second_moments(pred, S, nut, iL, block=block)
        w = torch.arange(1.0, 10.0, dtype=DTYPE).reshape(3, 3)
        grads.append(torch.autograd.grad((w * second).sum() + latent.sum(), (m, S)))
    for new, old in zip(grads[0], grads[1], strict=True):
        _assert_same(new, old, what="gradient")  # RTOL: the same sums, reassociated


def test_flop_count():
    """The counted flops of one step: the closed form at E = 1, M = 2, D = 1 (Q block 36,
    operands 16, mean and input–output covariance 12) and the P = E(E + 1)/2 pair scaling."""
    from skillkit.models.moment_matching import moment_matching_flops_per_step as flops

    assert flops(1, 2, 1) == 64
    E, M, D = 8, 300, 12
    P = E * (E + 1) // 2
    q = P * M * M * (2 * D + 5) + E * M * M * 2
    assert flops(E, M, D) - q == P * (4 * M * D * D + 4 * M * D) + E * (2 * M * D * D + 4 * M * D)
    with pytest.raises(ValueError, match="n_support: expected an integer"):
        flops(8, 0, 12)
