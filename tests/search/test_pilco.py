"""PILCO (Table 4.2's baseline): the expected return against closed forms and the existing
moment-matching propagation, its gradient against finite differences, the optimised gain
against the discrete-time LQR gain where moment matching is exact, determinism, resume and
bad input."""

import warnings

import numpy as np
import pytest
import scipy.linalg
import torch
from _tolerances import fp_tol

from skillkit.models.gp import ExactGP, ForwardModel, GPNumericalWarning
from skillkit.models.moment_matching import ROUNDOFF_TOL, MomentPrecisionError, propagate
from skillkit.models.sparse import FITC
from skillkit.search import collect, learn
from skillkit.search.pilco import (
    PILCO,
    DeterministicPolicy,
    GPMomentStep,
    PILCOSettings,
    expected_return,
    linear_gaussian_step,
    optimize_gain,
)
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP
from skillkit.trial import TrialContext


def _linear_system(seed=0, n=3, m=2):
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    B = 0.5 * rng.standard_normal((n, m))
    return A, B


def _dlqr(A, B, Q, r):
    R = r * np.eye(B.shape[1])
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)  # u = G x


def _random_fitc(seed, n=3, m=2, n_data=150, mean="zero", target="delta"):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n_data, n))
    U = rng.standard_normal((n_data, m))
    W = rng.standard_normal((m, n))
    Xn = X + 0.2 * np.sin(X) + 0.1 * U @ W + 0.01 * rng.standard_normal((n_data, n))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = ForwardModel(FITC(n_inducing=25, n_steps=8), target=target, mean=mean)
        return model.fit(X, U, Xn, rng=seed)


# --------------------------------------------------------------------------- the objective
def test_expected_return_of_a_linear_system_equals_the_lyapunov_recursion():
    """Independent closed form: with x' = Φx + w (Φ = A + BG), S_{t+1} = Φ S_t Φᵀ + W,
    m_{t+1} = Φ m_t, and the expected stage cost is tr((Q + r GᵀG) S) + mᵀ(Q + r GᵀG) m."""
    A, B = _linear_system(1)
    G = _dlqr(A, B, np.eye(3), 0.5) * 0.8
    W = 0.02 * np.eye(3) + 0.01
    Q = np.diag([1.0, 2.0, 0.5])
    m, S = np.array([0.5, -0.2, 0.1]), 0.1 * np.eye(3)
    value = expected_return(
        linear_gaussian_step(A, B, W), torch.tensor(G), m, S, 25, np.zeros(3), Q, 0.3
    )
    Phi, C = A + B @ G, Q + 0.3 * G.T @ G
    ref = 0.0
    for _ in range(25):
        m, S = Phi @ m, Phi @ S @ Phi.T + W
        ref -= np.trace(C @ S) + m @ C @ m
    # 25 steps of two 3×3 products (m, S), a sum of positive terms: relative round-off
    # 25 · 2 · 3 ε, an error made at step t amplified by ‖Φᵏ‖² in the later steps (‖Φ‖ = 1.2
    # but ρ(Φ) = 0.89: the largest ‖Φᵏ‖², k ≤ 25, bounds it).
    amp = max(np.linalg.norm(np.linalg.matrix_power(Phi, k), 2) ** 2 for k in range(26))
    assert float(value) == pytest.approx(ref, rel=fp_tol(25 * 2 * 3, cond=amp))


@pytest.mark.parametrize("target", ["delta", "next"])
def test_gp_moment_step_chain_equals_moment_matching_propagate(target):
    """The z = [x; G(x − x*)] construction agrees with propagate()'s linear controller
    u = K x + k (K = G, k = −G x*), and the stage sum is the expected reward of its moments
    (to round-off: the two symmetrise the covariances at different points)."""
    model = _random_fitc(2, target=target)
    G = 0.3 * np.random.default_rng(3).standard_normal((2, 3))
    target = np.array([0.1, -0.1, 0.0])
    m0, S0 = np.array([0.2, 0.1, -0.3]), 0.05 * np.eye(3)
    means, covs = propagate(model, m0, S0, 6, G, -G @ target)
    value = expected_return(GPMomentStep(model), torch.tensor(G), m0, S0, 6, target, np.eye(3))
    d = means[1:].numpy() - target
    ref = -(np.trace(covs[1:].numpy(), axis1=1, axis2=2).sum() + (d**2).sum())
    assert float(value) == pytest.approx(ref, rel=1e-8)


@pytest.mark.parametrize("seed, mean", [(0, "zero"), (1, "zero"), (2, "linear")])
def test_policy_gradient_equals_finite_differences(seed, mean):
    """∂J/∂G by autograd through the whole moment-matching propagation equals central
    differences (relative 1e-5) on random FITC models (zero or linear prior mean), gains and
    control weights."""
    rng = np.random.default_rng(10 + seed)
    model = _random_fitc(seed, mean=mean)
    step = GPMomentStep(model)
    G0 = torch.tensor(0.3 * rng.standard_normal((2, 3)), requires_grad=True)
    Q = np.diag(rng.uniform(0.5, 2.0, 3))

    def J(G):
        return expected_return(
            step,
            G,
            np.full(3, 0.2),
            0.05 * np.eye(3),
            12,
            np.zeros(3),
            Q,
            0.1,
        )

    (grad,) = torch.autograd.grad(J(G0), G0)
    fd = np.zeros((2, 3))
    h = 1e-4
    with torch.no_grad():
        for i in range(2):
            for j in range(3):
                E = torch.zeros(2, 3, dtype=torch.float64)
                E[i, j] = h
                fd[i, j] = (float(J(G0 + E)) - float(J(G0 - E))) / (2 * h)
    assert np.abs(grad.numpy() - fd).max() <= 1e-5 * np.abs(fd).max()


def test_optimised_gain_equals_the_discrete_lqr_gain_where_moment_matching_is_exact():
    """Linear system with Gaussian noise and a quadratic reward (Σ_{t≥0} over a long horizon):
    PILCO's optimum from a different stabilising gain is scipy's DARE gain to 1e-2."""
    A, B = _linear_system(0)
    Q, r = np.eye(3), 0.1
    lqr = _dlqr(A, B, Q, r)
    start = _dlqr(A, B, np.diag([10.0, 0.1, 1.0]), 3.0)
    assert np.abs(start - lqr).max() > 0.2 * np.abs(lqr).max()
    step = linear_gaussian_step(A, B, 0.01 * np.eye(3))

    def J(G):
        return expected_return(
            step, G, np.ones(3), 0.1 * np.eye(3), 300, np.zeros(3), Q, r, score_initial=True
        )

    G, info = optimize_gain(J, start, max_iterations=500, tolerance=1e-15)
    assert info["value"] > info["value0"]
    assert np.abs(G - lqr).max() <= 1e-2 * np.abs(lqr).max()


def test_optimizer_returns_only_completed_iterates_and_survives_non_finite_values():
    """A cost that is non-finite beyond |g| > 2 (a diverging prediction): the result is a
    finite accepted iterate, never worse than the start."""

    def J(G):
        if float(G.abs().max()) > 2.0:
            return torch.tensor(float("nan"), dtype=torch.float64) * G.sum()
        return -((G - 1.5) ** 2).sum()

    G, info = optimize_gain(J, np.zeros((1, 2)), max_iterations=50)
    assert np.isfinite(info["value"]) and info["value"] >= info["value0"]
    np.testing.assert_allclose(G, 1.5, atol=1e-6)


# --------------------------------------------------------------------------- the algorithm
def _pilco_run(seed, trial=None, n_updates=2, callback=None):
    task = make("balancing", initial_std=0.1, n_steps=8)
    excited = make("balancing", initial_std=0.1, n_steps=8, excitation_std=30.0)
    pi0 = task.lqr_policy(control_weight=1.0, exploration_std_fraction=0.005)
    prior = collect(excited, pi0, 2, np.random.default_rng(seed)).trajectories
    alg = PILCO(
        task,
        pi0,
        make_model=_small_model,
        settings=PILCOSettings(policy_iterations=3),
        rng=seed,
        prior_trajectories=prior,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = learn(task, alg, n_updates, 1, seed, trial=trial, progress=False, callback=callback)
    return out, alg


def _small_model():
    return ForwardModel(FITC(n_inducing=15, n_steps=5))


def test_pilco_learns_through_the_loop_same_seed_same_numbers_and_resumes():
    a, alg = _pilco_run(0)
    b, _ = _pilco_run(0)
    np.testing.assert_array_equal(a["mean_reward"], b["mean_reward"])
    np.testing.assert_array_equal(alg.gain, b["policy"].mean.reshape(4, 8))
    d = a["diagnostics"]
    assert [x.n_data for x in d] == [3 * 8, 4 * 8]  # 2 prior rollouts + 1, + 2
    assert d[0].predicted_real_reward is None and d[1].predicted_real_reward is not None
    assert all(x.return_after >= x.return_before for x in d)
    assert isinstance(a["policy"], DeterministicPolicy)

    class Stop(Exception):
        pass

    trial = TrialContext()
    with pytest.raises(Stop):
        _pilco_run(
            0, trial=trial, callback=lambda k, _: (_ for _ in ()).throw(Stop()) if k == 2 else None
        )
    assert trial.resume("learn", np.random.default_rng()).k == 1
    resumed, _ = _pilco_run(0, trial=trial)
    np.testing.assert_array_equal(a["mean_reward"], resumed["mean_reward"])


def test_expected_return_of_the_true_linearisation_matches_the_simulator_near_upright():
    """Moment matching is exact for the linearised balancing dynamics: its expected return of
    the LQR gain matches the simulator's mean reward (2000 rollouts) within Monte Carlo error
    plus the linearisation's error."""
    task = make("balancing", initial_std=0.02)
    A, B = task.linearization()
    G = task.lqr_gain()
    step = linear_gaussian_step(A, B, np.zeros((8, 8)))
    # The linearisation is about x̃ = x − x_up: shift the mean accordingly.
    J = expected_return(
        step,
        torch.tensor(G),
        np.zeros(8),
        0.02**2 * np.eye(8),
        task.n_steps,
        np.zeros(8),
        task.state_weights,
    )
    rng = np.random.default_rng(0)
    r = np.array([task.reward(task.rollout(G.ravel(), rng=rng)) for _ in range(400)])
    tol = 3 * r.std() / np.sqrt(r.size) + 0.02 * abs(r.mean())
    assert float(J) == pytest.approx(r.mean(), abs=tol)


def test_bad_input_names_the_argument():
    task = make("balancing")
    pi0 = task.initial_policy()
    with pytest.raises(ValueError, match="task"):
        PILCO(make("throwing"), pi0)
    with pytest.raises(ValueError, match="initial_policy"):
        PILCO(task, DeterministicPolicy(np.zeros(32)))
    with pytest.raises(ValueError, match="settings"):
        PILCO(task, pi0, settings={"policy_iterations": 3})
    with pytest.raises(ValueError, match="policy_iterations"):
        PILCOSettings(policy_iterations=0)
    with pytest.raises(ValueError, match="prior_trajectories"):
        PILCO(task, pi0, prior_trajectories=[np.zeros(3)])
    with pytest.raises(ValueError, match="noise_cov"):
        linear_gaussian_step(np.eye(2), np.ones((2, 1)), np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="B"):
        linear_gaussian_step(np.eye(2), np.ones((3, 1)), np.eye(2))
    step = linear_gaussian_step(np.eye(2), np.ones((2, 1)), np.eye(2))
    args = (np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="gain"):
        expected_return(step, np.zeros((1, 2)), *args, 3, np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="horizon"):
        expected_return(step, torch.zeros(1, 2), *args, 0, np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="contexts"):
        DeterministicPolicy(np.zeros(3)).sample(np.zeros((2, 1)))
    with pytest.raises(RuntimeError, match="update"):
        PILCO(task, pi0).expected_return(np.zeros((4, 8)))
    with pytest.raises(ValueError, match="model"):
        GPMomentStep(object())


def test_policy_shapes_and_repr():
    p = DeterministicPolicy(np.arange(3.0))
    assert p.sample(np.zeros((4, 0))).shape == (4, 3)
    np.testing.assert_array_equal(p.mean_of(None), np.arange(3.0))
    task = make("balancing")
    alg = PILCO(task, task.initial_policy())
    assert alg.policy is not None and "random initial policy" in repr(alg)
    np.testing.assert_array_equal(alg.gain.ravel(), task.initial_policy().mean)
    assert X_UP.shape == (8,)


def test_a_moment_matching_step_that_loses_precision_is_nan_not_clamped():
    """An expected latent variance negative beyond round-off (here forced by inflating the
    predictor's iK, as catastrophic cancellation does at extreme input covariances): plain
    moment matching clamps and warns; PILCO's strict step returns NaN, so the optimiser
    rejects the point instead of profiting from an optimistic variance."""
    import dataclasses

    from skillkit.models.gp import GPNumericalWarning
    from skillkit.models.moment_matching import moment_match_step

    pred = _random_fitc(4).predictor
    bad = dataclasses.replace(pred, iK=pred.iK * 1e3)
    m, S = torch.zeros(5, dtype=torch.float64), 0.01 * torch.eye(5, dtype=torch.float64)
    assert torch.isfinite(moment_match_step(pred, m, S, strict=True).mean).all()
    with pytest.warns(GPNumericalWarning, match="negative"):
        clamped = moment_match_step(bad, m, S)
    assert torch.isfinite(clamped.cov).all()
    assert torch.isnan(moment_match_step(bad, m, S, strict=True).mean).all()


def test_expected_return_stops_at_a_failed_step_and_the_optimizer_survives_linalg_errors():
    """A NaN step ends the propagation with NaN (no Cholesky of a NaN covariance later), and
    an objective that raises LinAlgError counts as a failed evaluation."""
    calls = []

    def step(mean_z, cov_z):
        calls.append(1)
        return mean_z[:2] + float("nan"), cov_z[:2, :2]

    J = expected_return(
        step,
        torch.zeros(1, 2, dtype=torch.float64),
        np.zeros(2),
        np.eye(2),
        10,
        np.zeros(2),
        np.eye(2),
    )
    assert torch.isnan(J) and len(calls) == 1

    def J2(G):
        if float(G.abs().max()) > 1.0:
            torch.linalg.cholesky(-torch.eye(2, dtype=torch.float64))
        return -((G - 0.5) ** 2).sum()

    G, info = optimize_gain(J2, np.zeros((1, 2)), max_iterations=50)
    np.testing.assert_allclose(G, 0.5, atol=1e-6)


# -------------------------------------------------------------------------------- round-off
def _linear_limit_model():
    """An exact GP driven to its linear limit: length-scales 1.5e3 (the balancing data spread
    0.1–30), σ_f/σ_ε = 1.5e3, fixed."""
    gp = ExactGP(lengthscale=1.5e3, outputscale=2.25, noise=1e-6, n_steps=0, additive_noise=0.0)
    return ForwardModel(gp)


def _pilco_roundoff_run(make_model, strict=False, n_updates=1):
    task = make("balancing", initial_std=0.1, n_steps=8)
    excited = make("balancing", initial_std=0.1, n_steps=8, excitation_std=30.0)
    pi0 = task.lqr_policy(control_weight=1.0, exploration_std_fraction=0.005)
    prior = collect(excited, pi0, 2, np.random.default_rng(0)).trajectories
    settings = PILCOSettings(policy_iterations=1, strict=strict)
    alg = PILCO(task, pi0, make_model, settings, rng=0, prior_trajectories=prior)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = learn(task, alg, n_updates, 1, 0, progress=False)
    return out, [w for w in caught if "round-off" in str(w.message)]


def test_pilco_checks_the_roundoff_of_its_optimised_gain_once_per_update():
    """A well-conditioned FITC model: the bound is reported and small, no warning. The
    linear-limit exact GP: one warning per update naming PILCO, the bound in the
    diagnostics; ``strict`` raises instead. The gain step records the worst of its steps."""
    out, caught = _pilco_roundoff_run(_small_model, n_updates=2)
    assert not caught
    assert all(0.0 < d.roundoff < ROUNDOFF_TOL for d in out["diagnostics"])
    out, caught = _pilco_roundoff_run(_linear_limit_model, n_updates=2)
    assert len(caught) == 2 and all("PILCO.update" in str(w.message) for w in caught)
    assert all(d.roundoff > ROUNDOFF_TOL for d in out["diagnostics"])
    assert issubclass(caught[0].category, GPNumericalWarning)
    with pytest.raises(MomentPrecisionError, match="PILCO.update.*round-off"):
        _pilco_roundoff_run(_linear_limit_model, strict=True)
    step = GPMomentStep(_random_fitc(5))
    assert step.roundoff is None and "none" in repr(step)
    J = expected_return(
        step,
        torch.zeros(2, 3, dtype=torch.float64),
        np.zeros(3),
        0.05 * np.eye(3),
        4,
        np.zeros(3),
        np.eye(3),
    )
    assert torch.isfinite(J) and 0.0 < step.roundoff.relative_error < ROUNDOFF_TOL
    step.reset()
    assert step.roundoff is None
