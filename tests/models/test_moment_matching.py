"""Moment matching (PILCO) and linearisation vs Monte Carlo, closed forms, finite differences."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.gp import ExactGP, ForwardModel, GPNumericalWarning
from skillkit.models.moment_matching import (
    MomentPrecisionError,
    gaussian_kl,
    linearize,
    moment_match,
    moment_match_step,
    propagate,
)
from skillkit.models.sampling import sample_trajectories
from skillkit.models.sparse import FITC


def _random_gp(kind: str, seed: int, D=3, E=2, N=25):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(N, D))
    Y = rng.normal(size=(N, E)) + 0.5
    kw = dict(
        lengthscale=rng.uniform(0.6, 1.5, size=(E, D)),
        outputscale=float(rng.uniform(0.5, 2.0)),
        noise=0.05,
        n_steps=0,
        additive_noise=0.0,
    )
    if kind == "exact":
        return ExactGP(**kw).fit(X, Y)
    return FITC(inducing=rng.normal(size=(8, D)), optimize_inducing=False, **kw).fit(X, Y)


def _predict_chunked(gp, z, chunk=20_000):
    """Predict in chunks that keep the work arrays small (large fresh allocations are slow here)."""
    out = [gp.predict(z[lo : lo + chunk]) for lo in range(0, len(z), chunk)]
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


def _point_tols(pred, m):
    """Round-off bounds (mean, cov) between moment matching at a point input (S = 0) and the
    GP's own prediction there: two evaluations of μ = βᵀk and V = σ_f² − kᵀ iK k + (βᵀk)²-type
    sums in other orders. k_i = σ_f² exp(−½‖a_i‖²), a = (x_i − m)/w, carries ε (D + 2)(1 + ‖a‖²)
    relative from the exponent; the sums (and the mean's y_mean) add M (mean) and M² (second
    moments) ε times their magnitudes Σ|β||k| and (Σ|β||k|)² + kᵀ|iK|k + σ_f²; moment
    matching's kᵀ iK k against the prediction's ‖Rk‖² (RᵀR = iK, both from one Cholesky factor)
    adds the condition κ(iK) to the second moments. In output units (y_scale)."""
    sup, ell = pred.support.numpy(), pred.lengthscale.numpy()
    fields = ("outputscale", "beta", "iK", "y_mean", "y_scale")
    sf2, beta, iK, ym, ys = (getattr(pred, f).numpy() for f in fields)
    E, M, D = sup.shape
    a2 = (((sup - np.asarray(m)) / ell[:, None, :]) ** 2).sum(-1)  # (E, M)
    k = sf2[:, None] * np.exp(-0.5 * a2)  # (E, M)
    n_exp = (D + 2) * (1 + a2.max())
    first = (np.abs(beta) * k).sum(-1)  # Σ|β||k| per output
    second = first**2 + np.einsum("ai,aij,aj->a", k, np.abs(iK), k) + sf2
    kappa = max(np.linalg.cond(iK[a]) for a in range(E))
    mean_tol = fp_tol(M + n_exp, scale=float((ys * first + np.abs(ym)).max()))
    cov_tol = fp_tol(M * M + 2 * n_exp, scale=float((ys**2 * second).max()), cond=kappa)
    return mean_tol, cov_tol


def _random_gaussian(seed: int, D=3):
    rng = np.random.default_rng(seed + 100)
    A = 0.5 * rng.normal(size=(D, D))
    return 0.4 * rng.normal(size=D), A @ A.T + 0.05 * np.eye(D)


@pytest.mark.parametrize("kind,seed", [("exact", 0), ("exact", 1), ("fitc", 2)])
def test_moments_equal_monte_carlo(kind, seed):
    gp = _random_gp(kind, seed)
    m, S = _random_gaussian(seed)
    mm = moment_match(gp.predictor, m, S)
    n = 10**6
    z = np.random.default_rng(seed + 7).multivariate_normal(m, S, size=n)
    mu, var = _predict_chunked(gp, z)
    # Law of total (co)variance: E[y] = E[μ(z)], cov(y) = cov(μ(z)) + diag E[σ²(z)],
    # cov(z, y) = cov(z, μ(z)).
    dmu, dz = mu - mu.mean(0), z - z.mean(0)
    mean_mc, se_mean = mu.mean(0), mu.std(0) / np.sqrt(n)
    prod = dmu[:, :, None] * dmu[:, None, :] + np.einsum("na,ab->nab", var, np.eye(2))
    cov_mc, se_cov = prod.mean(0), prod.std(0) / np.sqrt(n)
    io = dz[:, :, None] * dmu[:, None, :]
    io_mc, se_io = io.mean(0), io.std(0) / np.sqrt(n)
    assert np.all(np.abs(mm.mean.numpy() - mean_mc) < 5 * se_mean)
    assert np.all(np.abs(mm.cov.numpy() - cov_mc) < 5 * se_cov + 1e-12)
    assert np.all(np.abs(mm.input_output_cov.numpy() - io_mc) < 5 * se_io + 1e-12)


def test_point_input_reduces_to_gp_prediction():
    gp = _random_gp("exact", 3)
    m = np.array([0.3, -0.2, 0.1])
    mean, var = gp.predict(m[None])
    for fn in (moment_match, linearize):
        g = fn(gp.predictor, m, np.zeros((3, 3)))
        mean_tol, cov_tol = _point_tols(gp.predictor, m)
        np.testing.assert_allclose(g.mean.numpy(), mean[0], rtol=0, atol=mean_tol)
        np.testing.assert_allclose(g.cov.numpy(), np.diag(var[0]), rtol=0, atol=cov_tol)
        np.testing.assert_array_equal(g.input_output_cov.numpy(), 0.0)  # S (Jᵀ or …) with S = 0
    latent = moment_match(gp.predictor, m, np.zeros((3, 3)), include_noise=False)
    np.testing.assert_allclose(
        np.diag(latent.cov.numpy()), var[0] - gp.hyperparameters["noise"], rtol=1e-7
    )


def test_linearization_jacobian_equals_finite_differences():
    gp = _random_gp("fitc", 4)
    m = np.array([0.2, 0.1, -0.4])
    J = linearize(gp.predictor, m, np.eye(3)).input_output_cov.numpy().T  # S Jᵀ with S = I
    h = 1e-6
    fd = np.stack(
        [
            (gp.predict((m + h * e)[None])[0][0] - gp.predict((m - h * e)[None])[0][0]) / (2 * h)
            for e in np.eye(3)
        ],
        axis=1,
    )
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-8)


def test_linearization_is_worse_than_moment_matching_for_a_wide_input():
    rng = np.random.default_rng(5)
    X = rng.uniform(-3, 3, size=(40, 1))
    gp = ExactGP(lengthscale=0.7, outputscale=1.0, noise=1e-3, n_steps=0, additive_noise=0.0).fit(
        X, np.sin(2 * X)
    )
    m, S = np.array([0.3]), np.array([[0.6]])
    z = rng.normal(0.3, np.sqrt(0.6), size=200_000)[:, None]
    mu, var = _predict_chunked(gp, z)
    true_mean, true_var = mu.mean(), mu.var() + var.mean()
    mm, lin = moment_match(gp.predictor, m, S), linearize(gp.predictor, m, S)
    assert abs(float(mm.mean[0]) - true_mean) < 0.01 < abs(float(lin.mean[0]) - true_mean)
    assert abs(float(mm.cov[0, 0]) - true_var) < 0.01 < abs(float(lin.cov[0, 0]) - true_var)


def _forward_model():
    rng = np.random.default_rng(6)
    x = rng.uniform(-1.5, 1.5, size=(120, 2))
    u = rng.uniform(-1.5, 1.5, size=(120, 1))
    xn = x + 0.2 * np.stack([x[:, 1], -np.sin(2 * x[:, 0]) + u[:, 0]], axis=1)
    return ForwardModel(
        ExactGP(additive_noise=0.0, noise=1e-3, n_steps=0, lengthscale=[1.0, 1.0, 1.5])
    ).fit(x, u, xn, rng=0)


def test_propagate_first_step_equals_sampling_and_point_prediction():
    fm = _forward_model()
    K = np.array([[-0.5, -0.3]])
    k = np.array([0.1])
    x0 = np.array([0.4, -0.2])
    means, covs = propagate(fm, x0, np.zeros((2, 2)), 1, K, k)
    mean, var = fm.predict(x0[None], (K @ x0 + k)[None])
    # A point input: moment matching vs the GP's prediction, as in the test above.
    mean_tol, cov_tol = _point_tols(fm.predictor, np.r_[x0, K @ x0 + k])
    np.testing.assert_allclose(means[1].numpy(), mean[0], rtol=0, atol=mean_tol)
    np.testing.assert_allclose(covs[1].numpy(), np.diag(var[0]), rtol=0, atol=cov_tol)
    # From a Gaussian start the first step's moments are exact: compare with the sampler.
    S0 = np.array([[0.05, 0.01], [0.01, 0.03]])
    means, covs = propagate(fm, x0, S0, 3, K, k)
    L = 100_000
    x_start = np.random.default_rng(7).multivariate_normal(x0, S0, size=L)[None]
    Kt, kt = torch.as_tensor(K), torch.as_tensor(k)
    res = sample_trajectories(fm, x_start, lambda t, x, p: x @ Kt.T + kt, 1, L, rng=8)
    x1 = res.states[0, :, 1].numpy()
    S1 = covs[1].numpy()
    assert np.all(np.abs(x1.mean(0) - means[1].numpy()) < 5 * np.sqrt(np.diag(S1) / L))
    se = np.sqrt((np.outer(np.diag(S1), np.diag(S1)) + S1**2) / L)
    assert np.all(np.abs(np.cov(x1.T) - S1) < 5 * se)
    assert np.all(np.linalg.eigvalsh(covs.numpy()) > 0)


def test_propagate_time_varying_gain_and_linearization():
    fm = _forward_model()
    T = 4
    K = np.stack([[[-0.5, -0.3]]] * T) * np.linspace(1, 2, T)[:, None, None]
    k = np.linspace(0, 0.3, T)[:, None]
    for method in ("moment_matching", "linearization"):
        means, covs = propagate(fm, [0.2, 0.1], 0.01 * np.eye(2), T, K, k, method=method)
        assert means.shape == (T + 1, 2) and covs.shape == (T + 1, 2, 2)
        np.testing.assert_allclose(covs.numpy(), np.swapaxes(covs.numpy(), 1, 2))
    # A time-varying gain equals the constant gain when all slices are equal.
    a = propagate(fm, [0.2, 0.1], 0.01 * np.eye(2), T, np.stack([K[0]] * T))
    b = propagate(fm, [0.2, 0.1], 0.01 * np.eye(2), T, K[0])
    torch.testing.assert_close(a[1], b[1])


def _kl_tol(mp, Sp, mq, Sq):
    """Round-off of KL(N(mp, Sp) ‖ N(mq, Sq)) = ½(tr(Sq⁻¹Sp) + dᵀSq⁻¹d − D + log|Sq|/|Sp|):
    a sum of terms of size T = tr + dᵀSq⁻¹d + D + |log|Sq|| + |log|Sp||, each from a
    D×D factorisation (forward error ~ D ε κ(Sq)); absolute, D + 4 dependent steps."""
    Sp, Sq, d = np.asarray(Sp), np.asarray(Sq), np.asarray(mq) - np.asarray(mp)
    iq = np.linalg.inv(Sq)
    terms = (
        np.trace(iq @ Sp)
        + d @ iq @ d
        + len(d)
        + abs(np.linalg.slogdet(Sq)[1])
        + abs(np.linalg.slogdet(Sp)[1])
    )
    return fp_tol(len(d) + 4, scale=float(terms), cond=np.linalg.cond(Sq))


def test_gaussian_kl_closed_form():
    z, eye = np.zeros(2), np.eye(2)
    assert gaussian_kl(z, eye, z, eye) == pytest.approx(0.0, abs=_kl_tol(z, eye, z, eye))
    m1, s1, m2, s2 = 0.3, 0.7, -0.2, 1.3
    ref = np.log(s2 / s1) + (s1**2 + (m1 - m2) ** 2) / (2 * s2**2) - 0.5
    # Diagonal case = sum of 1-D KLs.
    args = ([m1, 0.0], np.diag([s1**2, 1.0]), [m2, 0.0], np.diag([s2**2, 1.0]))
    assert gaussian_kl(*args) == pytest.approx(ref, rel=0, abs=_kl_tol(*args))
    batch = gaussian_kl(
        np.zeros((3, 2)),
        np.eye(2)[None].repeat(3, 0),
        np.ones((3, 2)),
        2 * np.eye(2)[None].repeat(3, 0),
    )
    # KL(N(0, I) || N(1, 2I)) in 2-D: ½(tr(I/2) + 1ᵀ(I/2)1 − 2 + log 4) = log 2 per batch entry.
    assert batch.shape == (3,)
    tol = _kl_tol(z, eye, np.ones(2), 2 * eye)
    np.testing.assert_allclose(batch, np.log(2.0), rtol=0, atol=tol)
    # A full (correlated) pair against the closed form written with explicit inverses.
    Sp, Sq = np.array([[1.0, 0.3], [0.3, 0.5]]), np.array([[2.0, -0.4], [-0.4, 1.0]])
    mp, mq = np.array([0.1, -0.2]), np.array([0.5, 0.4])
    iq, diff = np.linalg.inv(Sq), mq - mp
    ref = 0.5 * (
        np.trace(iq @ Sp) + diff @ iq @ diff - 2 + np.log(np.linalg.det(Sq) / np.linalg.det(Sp))
    )
    assert gaussian_kl(mp, Sp, mq, Sq) == pytest.approx(ref, rel=0, abs=_kl_tol(mp, Sp, mq, Sq))


def test_bad_input():
    gp = _random_gp("exact", 0)
    m, S = _random_gaussian(0)
    with pytest.raises(ValueError, match="mean"):
        moment_match(gp.predictor, m[:2], S)
    with pytest.raises(ValueError, match="cov"):
        moment_match(gp.predictor, m, S[:2])
    with pytest.raises(ValueError, match="cov"):
        moment_match(gp.predictor, m, S + np.triu(np.ones((3, 3)), 1))
    with pytest.raises(ValueError, match="cov"):
        moment_match(gp.predictor, m, -np.eye(3))
    with pytest.raises(ValueError, match="mean"):
        linearize(gp.predictor, np.full(3, np.nan), S)
    fm = _forward_model()
    with pytest.raises(ValueError, match="gain"):
        propagate(fm, [0.0, 0.0], np.eye(2), 3, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="offset"):
        propagate(fm, [0.0, 0.0], np.eye(2), 3, np.zeros((1, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="method"):
        propagate(fm, [0.0, 0.0], np.eye(2), 3, np.zeros((1, 2)), method="unscented")
    with pytest.raises(ValueError, match="horizon"):
        propagate(fm, [0.0, 0.0], np.eye(2), 0, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="mean0"):
        propagate(fm, [0.0], np.eye(2), 2, np.zeros((1, 2)))


def test_gaussian_kl_names_a_bad_shape_and_passes_non_finite_entries_through():
    I2 = np.eye(2)
    with pytest.raises(ValueError, match=r"mean_q: expected shape \(\.\.\., 2\)"):
        gaussian_kl(np.zeros(2), I2, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match=r"cov_p: expected shape \(\.\.\., 2, 2\)"):
        gaussian_kl(np.zeros(2), np.eye(3), np.zeros(2), I2)
    with pytest.raises(ValueError, match="mean_p: expected shape"):
        gaussian_kl(0.0, I2, np.zeros(2), I2)
    with pytest.raises(ValueError, match="do not broadcast"):
        gaussian_kl(np.zeros((3, 2)), I2, np.zeros((4, 2)), I2)
    # one batch entry with a NaN mean: that entry is NaN, the others are exact (fig4.3 stores it)
    mq = np.array([[1.0, 1.0], [np.nan, 0.0], [0.0, 0.0]])
    out = gaussian_kl(np.zeros(2), I2, mq, I2)
    tol = _kl_tol(np.zeros(2), I2, mq[0], I2)
    assert out[0] == pytest.approx(1.0, rel=0, abs=tol) and np.isnan(out[1]) and out[2] == 0.0


# -------------------------------------------------------------------------------- round-off
def _reference_moments(pred, m, S, digits: int = 40):
    """The moments from the predictor's fields (taken as exact) in ``digits``-digit arithmetic
    (mpmath), straight from the formulas of the module docstring: mean, cov, cov(z, y)."""
    mp = pytest.importorskip("mpmath")
    ctx = mp.mp.clone()
    ctx.dps = digits
    f = ctx.mpf
    sup, ell, sf2 = pred.support.numpy(), pred.lengthscale.numpy(), pred.outputscale.numpy()
    beta, iK, noise = pred.beta.numpy(), pred.iK.numpy(), pred.noise.numpy()
    E, M, D = sup.shape
    Sm = ctx.matrix([[f(float(v)) for v in row] for row in np.asarray(S)])
    nu = [
        [ctx.matrix([f(float(sup[a, i, d])) - f(float(m[d])) for d in range(D)]) for i in range(M)]
        for a in range(E)
    ]
    inv_lam = [ctx.diag([1 / f(float(ell[a, d])) ** 2 for d in range(D)]) for a in range(E)]
    mu, io = [], []
    for a in range(E):
        A = ctx.inverse(Sm + ctx.inverse(inv_lam[a]))
        c = f(float(sf2[a])) / ctx.sqrt(ctx.det(Sm * inv_lam[a] + ctx.eye(D)))
        q = [c * ctx.exp(-(nu[a][i].T * A * nu[a][i])[0] / 2) for i in range(M)]
        mu.append(ctx.fsum(f(float(beta[a, i])) * q[i] for i in range(M)))
        v = ctx.matrix(D, 1)
        for i in range(M):
            v += f(float(beta[a, i])) * q[i] * (A * nu[a][i])
        io.append(Sm * v)
    V = ctx.matrix(E, E)
    for a in range(E):
        for b in range(a, E):
            R = Sm * (inv_lam[a] + inv_lam[b]) + ctx.eye(D)
            T, root_det = ctx.inverse(R) * Sm, ctx.sqrt(ctx.det(R))
            ka = [f(float(sf2[a])) * ctx.exp(-(n.T * inv_lam[a] * n)[0] / 2) for n in nu[a]]
            kb = [f(float(sf2[b])) * ctx.exp(-(n.T * inv_lam[b] * n)[0] / 2) for n in nu[b]]
            za, zb = [inv_lam[a] * n for n in nu[a]], [inv_lam[b] * n for n in nu[b]]
            zeta = [[za[i] + zb[j] for j in range(M)] for i in range(M)]
            Q = [
                [
                    ka[i] * kb[j] / root_det * ctx.exp((zeta[i][j].T * T * zeta[i][j])[0] / 2)
                    for j in range(M)
                ]
                for i in range(M)
            ]
            val = (
                ctx.fsum(
                    f(float(beta[a, i])) * Q[i][j] * f(float(beta[b, j]))
                    for i in range(M)
                    for j in range(M)
                )
                - mu[a] * mu[b]
            )
            if a == b:
                trace = ctx.fsum(
                    f(float(iK[a, i, j])) * Q[j][i] for i in range(M) for j in range(M)
                )
                val += f(float(sf2[a])) - trace + f(float(noise[a]))
            V[a, b] = V[b, a] = val
    ym, ys = pred.y_mean.numpy(), pred.y_scale.numpy()
    mean = np.array([float(f(float(ym[a])) + f(float(ys[a])) * mu[a]) for a in range(E)])
    cov = np.array(
        [[float(f(float(ys[a])) * V[a, b] * f(float(ys[b]))) for b in range(E)] for a in range(E)]
    )
    iom = np.array([[float(io[a][d] * f(float(ys[a]))) for a in range(E)] for d in range(D)])
    return mean, cov, iom


def _relative_errors(g, reference, S) -> float:
    """The errors of a prediction in the units of :class:`RoundoffEstimate`: cov relative to
    √(V_aa V_bb), mean in predictive standard deviations, cov(z, y) relative to √(S_dd V_aa),
    with V the computed covariance (what the estimate scales by)."""
    mean, cov, io = reference
    sd = np.sqrt(np.diag(g.cov.numpy()))
    sd_in = np.sqrt(np.diag(np.asarray(S)))[:, None] * sd[None, :]
    return max(
        float(np.max(np.abs(g.cov.numpy() - cov) / np.outer(sd, sd))),
        float(np.max(np.abs(g.mean.numpy() - mean) / sd)),
        float(np.max(np.abs(g.input_output_cov.numpy() - io)[sd_in > 0] / sd_in[sd_in > 0])),
    )


def _limit_gp(kind: str, lengthscale: float, signal_to_noise: float, seed: int = 0):
    """Linear data y = Wx + b + 0.01 ε (N = 20, 2 inputs, 2 outputs), σ_ε² = 1e-4 var(y),
    σ_f = ``signal_to_noise`` σ_ε, fixed hyper-parameters: with length-scales and σ_f/σ_ε of
    ~1.5e3 the GP is at its linear limit (|β| huge)."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(20, 2))
    Y = X @ rng.normal(size=(2, 2)) + 3.0 + 0.01 * rng.normal(size=(20, 2))
    v = float(Y.var(0).mean())
    kw = dict(
        lengthscale=lengthscale,
        outputscale=signal_to_noise**2 * 1e-4 * v,
        noise=1e-4 * v,
        n_steps=0,
        additive_noise=0.0,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # noise at its floor, jitter
        if kind == "exact":
            return ExactGP(**kw).fit(X, Y)
        return FITC(inducing=rng.normal(size=(8, 2)), optimize_inducing=False, **kw).fit(X, Y)


M_IN = np.array([0.3, -0.2])
S_IN = np.array([[2.0, 0.5], [0.5, 1.0]])


@pytest.mark.parametrize("kind", ["exact", "fitc"])
def test_roundoff_bound_on_a_well_conditioned_model(kind):
    """Length-scale 1, σ_f/σ_ε = 10: no warning, the bound is tiny, and the moments agree with
    a 40-digit computation to within it (the tolerance is the bound: u × magnitudes ×
    conditions). Computing the bound does not change a number."""
    pred = _limit_gp(kind, 1.0, 10.0).predictor
    S = 0.01 * S_IN
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = moment_match(pred, M_IN, S)
    assert g.roundoff.relative_error < 1e-8
    actual = _relative_errors(g, _reference_moments(pred, M_IN, S), S)
    assert actual <= g.roundoff.relative_error
    plain = moment_match_step(
        pred.to("cpu", torch.float64), torch.as_tensor(M_IN), torch.as_tensor(S), roundoff=False
    )
    assert plain.roundoff is None
    for a, b in zip(
        (g.mean, g.cov, g.input_output_cov),
        (plain.mean, plain.cov, plain.input_output_cov),
        strict=True,
    ):
        assert torch.equal(a, b)


@pytest.mark.parametrize("kind", ["exact", "fitc"])
def test_roundoff_at_the_linear_limit_is_warned_about_and_bounded(kind):
    """Length-scales and σ_f/σ_ε of 1.5e3 (the GP's linear limit): the second moments lose
    digits (measured against 40 digits), the warning fires once, names the cause, and the
    bound it states is at least the actual error."""
    pred = _limit_gp(kind, 1.5e3, 1.5e3).predictor
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = moment_match(pred, M_IN, S_IN)
    assert len(caught) == 1 and issubclass(caught[0].category, GPNumericalWarning)
    text = str(caught[0].message)
    assert "cancellation" in text and "linear limit" in text
    stated = float(re.search(r"lost up to ([0-9.e+-]+) relative", text).group(1))
    actual = _relative_errors(g, _reference_moments(pred, M_IN, S_IN), S_IN)
    assert 1e-6 < actual <= stated  # a real loss (float64 would give ~1e-15), within the bound
    assert stated == pytest.approx(g.roundoff.relative_error, rel=0.06)  # printed to 2 digits
    assert g.roundoff.where == "covariance" and g.roundoff.cancellation > 1e10


def test_strict_moment_matching_raises_on_lost_precision():
    pred = _limit_gp("exact", 1.5e3, 1.5e3).predictor
    with pytest.raises(MomentPrecisionError, match="round-off"):
        moment_match(pred, M_IN, S_IN, strict=True)
    assert issubclass(MomentPrecisionError, RuntimeError)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        moment_match(_limit_gp("exact", 1.0, 10.0).predictor, M_IN, S_IN, strict=True)


def test_propagate_checks_roundoff_once_per_call():
    """A 3-step propagation through a linear-limit forward model: one warning for the call
    (the worst step), an error with ``strict``; none through a well-conditioned one."""
    rng = np.random.default_rng(9)
    x, u = rng.normal(size=(30, 2)), rng.normal(size=(30, 1))
    xn = x @ np.array([[0.9, 0.1], [-0.1, 0.8]]).T + 0.3 * u + 0.01 * rng.normal(size=(30, 2))
    K = np.array([[-0.2, -0.1]])
    for ell, snr, n_warnings in ((1.5e3, 1.5e3, 1), (1.0, 10.0, 0)):
        gp = ExactGP(
            lengthscale=ell,
            outputscale=snr**2 * 1e-4,
            noise=1e-4,
            n_steps=0,
            additive_noise=0.0,
            standardize=False,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fm = ForwardModel(gp, target="next").fit(x, u, xn, rng=0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            propagate(fm, [0.2, 0.1], 0.05 * np.eye(2), 3, K)
        assert len(caught) == n_warnings
        if n_warnings:
            assert "propagate" in str(caught[0].message)
            with pytest.raises(MomentPrecisionError, match="propagate"):
                propagate(fm, [0.2, 0.1], 0.05 * np.eye(2), 3, K, strict=True)
