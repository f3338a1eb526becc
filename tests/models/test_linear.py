"""The linear-Gaussian forward model and the GP forward model's linear prior mean: exact
recovery of linear dynamics, the exact Gaussian step against Monte Carlo, bad input."""

import warnings

import numpy as np
import pytest
import torch
from _tolerances import cov_se, fp_tol, mean_se

from skillkit.models.gp import ExactGP, ForwardModel
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.moment_matching import moment_match, propagate, with_linear_mean
from skillkit.models.sampling import sample_trajectories
from skillkit.models.sparse import FITC
from skillkit.search.pilco import expected_return, linear_gaussian_step, model_moment_step


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
    # Five Monte Carlo standard errors (from the samples; ~1e-3 each), was atol=5e-3.
    assert np.all(np.abs(mean.numpy() - y.mean(0)) < 5 * mean_se(y))
    assert np.all(np.abs(cov.numpy() - np.cov(y.T)) < 5 * cov_se(y))


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
    # Five Monte Carlo standard errors (from the samples), was atol=1e-2.
    assert np.all(np.abs(g.mean.numpy() - y.mean(0)) < 5 * mean_se(y))
    assert np.all(np.abs(g.cov.numpy() - np.cov(y.T)) < 5 * cov_se(y))
    zc = z - z.mean(0)
    io = zc.T @ (y - y.mean(0)) / len(z)
    assert np.all(np.abs(g.input_output_cov.numpy() - io) < 5 * cov_se(y, z))
    # propagate() adds the linear part the same way.
    means, _ = propagate(
        model, m[:2].numpy(), S[:2, :2].numpy(), 1, np.zeros((1, 2)), np.array([0.1])
    )
    S0 = S.clone()
    S0[2, 2] = 0.0
    g0 = with_linear_mean(model, moment_match(model.predictor, m, S0), m, S0)
    # The same input (u = 0·x + 0.1 = m_u, zero variance) taken through moment_match twice:
    # each within its own round-off bound (relative_error predictive standard deviations),
    # plus the 3-term linear mean Wᵀz + b.
    sd = np.sqrt(np.diag(g0.cov.numpy()))
    lin = fp_tol(3 + 1, scale=float(np.abs(g0.mean.numpy()).max()))
    tol = 2 * g0.roundoff.relative_error * sd + lin
    err = np.abs(means[1].numpy() - g0.mean.numpy())
    assert np.all(err <= tol), (err, tol)


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


# ------------------------------------------------------------------------------------ noise
def _correlated_noise_model(seed=4):
    """A linear-Gaussian model fitted to data whose noise enters through the control channel
    (w = B ξ + a little isotropic noise: residual correlation ~0.99, as on the balancing
    robot, where one unmodelled torque moves a position and its velocity)."""
    rng = np.random.default_rng(seed)
    A = np.array([[1.0, 0.1], [-0.3, 0.95]])
    B = np.array([[0.05], [0.5]])
    x, u = rng.standard_normal((400, 2)), rng.standard_normal((400, 1))
    w = 0.3 * rng.standard_normal((400, 1)) @ B.T + 0.002 * rng.standard_normal((400, 2))
    return LinearGaussianModel().fit(x, u, x @ A.T + u @ B.T + 0.02 + w)


def _sampler_draws_correlated_noise(model) -> bool:
    """Does sample_trajectories draw the model's correlated noise (``noise_factor_tensor``)?"""
    res = sample_trajectories(
        model,
        np.zeros((1, 2)),
        lambda t, x, p: torch.zeros((x.shape[0], 1), dtype=x.dtype),
        1,
        2000,
        rng=0,
    )
    return float(np.corrcoef(res.states[0, :, 1].numpy().T)[0, 1]) > 0.5


def test_one_noise_convention_sampled_return_equals_pilcos_closed_form():
    """The sampler (GPREPS's Eq. 4.1) and PILCO's exact step use the same Σ_w: the mean
    sampled reward of u = G(x − x*) over T = 15 steps equals J(G) to Monte Carlo error (4
    standard errors of the sampled mean), and so do the sampled mean and covariance of x_T;
    the diagonal-noise return is many standard errors away (the test can tell the two apart)."""
    model = _correlated_noise_model()
    fit_corr = model.noise_cov[0, 1] / np.sqrt(model.noise_cov[0, 0] * model.noise_cov[1, 1])
    assert fit_corr > 0.95
    # eigh's backward error and the product F Fᵀ: a few n·eps·‖Σ‖ (n = 2).
    tol = fp_tol(4, np.linalg.norm(model.noise_cov, 2))
    np.testing.assert_allclose(model.noise_factor @ model.noise_factor.T, model.noise_cov, atol=tol)
    assert _sampler_draws_correlated_noise(model)
    G = np.array([[-0.6, -0.8]])
    # Q weighs most the direction v ⟂ B the correlated noise avoids; start at the target.
    v = np.array([1.0, -0.1])
    target, Q, r, T = np.array([0.2, 0.0]), np.outer(v, v) + 0.01 * np.eye(2), 0.01, 15
    m0, S0 = target, 1e-6 * np.eye(2)
    J = float(expected_return(model_moment_step(model), torch.tensor(G), m0, S0, T, target, Q, r))
    L = 40_000
    x0 = np.random.default_rng(5).multivariate_normal(m0, S0, size=(1, L))
    Gt, xt = torch.tensor(G), torch.tensor(target)
    res = sample_trajectories(model, x0, lambda t, x, p: (x - xt) @ Gt.T, T, L, rng=6)
    x, u = res.states[0, :, 1:].numpy(), res.controls[0].numpy()  # x_1..x_T, u_0..u_{T-1}
    d = x - target
    u_next = np.concatenate([u[:, 1:], (d[:, -1:] @ G.T)], axis=1)  # u_t = G d_t, t = 1..T
    rewards = -(np.einsum("ltd,de,lte->l", d, Q, d) + r * (u_next**2).sum((1, 2)))
    se = rewards.std() / np.sqrt(L)
    assert abs(rewards.mean() - J) < 4 * se
    diag = linear_gaussian_step(model.A, model.B, np.diag(np.diag(model.noise_cov)), model.c)
    J_diag = float(expected_return(diag, torch.tensor(G), m0, S0, T, target, Q, r))
    assert abs(J_diag - J) > 10 * se
    # The state after T steps: mean and covariance against the propagated moments.
    mean, cov = m0, S0
    step = model_moment_step(model)
    for _ in range(T):
        z = torch.tensor(np.concatenate([mean, G @ (mean - target)]))
        F = np.vstack([np.eye(2), G])
        mean, cov = (v.numpy() for v in step(z, torch.tensor(F @ cov @ F.T)))
    xT = x[:, -1]
    assert np.all(np.abs(xT.mean(0) - mean) < 4 * np.sqrt(np.diag(cov) / L))
    se_cov = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / L)
    assert np.all(np.abs(np.cov(xT.T) - cov) < 4 * se_cov)


def test_noise_factor_of_a_rank_deficient_covariance():
    """Noise that enters through one channel only (rank-1 residuals): the factor reproduces
    Σ_w and its tensor form follows the model's dtype."""
    rng = np.random.default_rng(7)
    x, u = rng.standard_normal((50, 2)), rng.standard_normal((50, 1))
    xn = x + 0.1 * u + rng.standard_normal((50, 1)) @ np.array([[0.1, 0.2]])
    m = LinearGaussianModel().fit(x, u, xn)
    assert np.linalg.matrix_rank(m.noise_cov, tol=1e-10) == 1
    tol = fp_tol(4, np.linalg.norm(m.noise_cov, 2))  # as above: a few n·eps·‖Σ‖
    np.testing.assert_allclose(m.noise_factor @ m.noise_factor.T, m.noise_cov, atol=tol)
    assert m.noise_factor_tensor().dtype == torch.float64
    assert m.to(dtype=torch.float32).noise_factor_tensor().dtype == torch.float32
    with pytest.raises(RuntimeError, match="fit"):
        LinearGaussianModel().noise_factor_tensor()


def test_a_hand_built_model_samples_its_known_dynamics():
    """Known dynamics (no fit): one sampled step has mean A x + B u + c and covariance Σ_w
    within 5 Monte Carlo standard errors (the samples' own fourth moments), and the noise
    factor follows ``noise_cov`` when it is reassigned or changed in place."""
    A = np.array([[0.9, 0.2], [-0.1, 1.0]])
    B = np.array([[0.0], [0.3]])
    c = np.array([0.1, -0.2])
    cov = np.array([[0.04, 0.03], [0.03, 0.09]])
    model = LinearGaussianModel()
    model.A, model.B, model.c, model.noise_cov = A, B, c, cov
    assert (model.state_dim, model.control_dim) == (2, 1)
    x0, u0 = np.array([0.5, -1.0]), 0.7
    L = 20_000
    res = sample_trajectories(
        model,
        x0[None],
        lambda t, x, p: torch.full((x.shape[0], 1), u0, dtype=x.dtype),
        1,
        L,
        rng=3,
    )
    x1 = res.states[0, :, 1].numpy()  # (L, 2)
    expected = A @ x0 + B[:, 0] * u0 + c
    assert np.all(np.abs(x1.mean(0) - expected) < 5 * mean_se(x1))
    assert np.all(np.abs(np.cov(x1.T, bias=True) - cov) < 5 * cov_se(x1))
    tol = fp_tol(4, np.linalg.norm(cov, 2))
    np.testing.assert_allclose(model.noise_factor @ model.noise_factor.T, cov, atol=tol)
    model.noise_cov = 4.0 * cov  # reassigned: the factor follows
    np.testing.assert_allclose(model.noise_factor @ model.noise_factor.T, 4 * cov, atol=4 * tol)
    model.noise_cov[1, 1] = 1.0  # changed in place: so does the factor
    np.testing.assert_allclose(
        model.noise_factor @ model.noise_factor.T, model.noise_cov, atol=fp_tol(4, 1.0)
    )


def test_a_half_built_model_refuses_to_sample():
    half = LinearGaussianModel()
    half.A = np.eye(2)  # B, c, noise_cov still unset
    with pytest.raises(RuntimeError, match="fit"):
        half.noise_factor_tensor()
