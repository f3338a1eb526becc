"""The probabilistic ensemble forward model: fits known dynamics to the noise floor, is
deterministic per seed, its bootstrap members differ and disagree away from the data, the
sampler draws TS-∞ trajectories with the predicted moments, it serves GPREPS as a
``make_model``, and bad input is named."""

from __future__ import annotations

import math
import pickle
import warnings
from functools import partial

import numpy as np
import pytest
import torch
from _tolerances import EPS32, fp_tol, mc_tol

from skillkit.models.ensemble import EnsembleSettings, ProbabilisticEnsemble
from skillkit.models.sampling import PRECISION_TOL, sample_trajectories
from skillkit.search import GPREPS, GPREPSSettings, TrajectoryRewardModel, collect
from skillkit.tasks.pendulum import Pendulum

SIGMA = 0.05  # noise std of the synthetic transitions
A = np.array([[1.0, 0.1], [-0.2, 0.9]])
B = np.array([[0.0], [0.5]])


def _linear(x, u):
    return x @ A.T + u @ B.T + 0.1


def _nonlinear(x, u):
    return np.column_stack([np.sin(2 * x[:, 0]) + 0.5 * u[:, 0], x[:, 1] * np.cos(x[:, 0])])


def _data(f, n, seed):
    rng = np.random.default_rng(seed)
    x, u = rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-1.0, 1.0, (n, 1))
    return x, u, f(x, u) + SIGMA * rng.standard_normal((n, 2))


def _zero_control(t, x, pair):
    return x.new_zeros((x.shape[0], 0))


@pytest.fixture(scope="module")
def one_dim():
    """x' = 1.5 x + 0.3 sin(3x) + noise on x ∈ [−1, 1], no control: an expanding map whose
    trajectories leave the data (at |x| = 1), where the members disagree."""
    rng = np.random.default_rng(5)
    x = rng.uniform(-1.0, 1.0, (400, 1))
    xn = 1.5 * x + 0.3 * np.sin(3 * x) + SIGMA * rng.standard_normal(x.shape)
    st = EnsembleSettings(hidden_sizes=(32, 32), epochs=100)
    return ProbabilisticEnsemble(st, target="next").fit(x, np.zeros((400, 0)), xn, rng=0)


# --------------------------------------------------------------------------- accuracy
@pytest.mark.parametrize("f", [_linear, _nonlinear], ids=["linear", "nonlinear"])
def test_fits_known_dynamics_to_the_noise_floor(f):
    """On held-out transitions the squared error of the predicted mean against the noisy
    next states is the noise variance σ² (what a perfect mean scores) within 5 Monte Carlo
    standard errors (√2 σ² / √n for Gaussian noise), so the model's own error is below that
    margin; and the predicted variance σ̂² (noise, plus the members' misfit and disagreement)
    is calibrated: mean(r² / σ̂²) = 1 within 5 standard errors (√2 / √n)."""
    n_train, n_test = 1000, 1000
    x, u, xn = _data(f, n_train, seed=1)
    model = ProbabilisticEnsemble(EnsembleSettings(epochs=100)).fit(x, u, xn, rng=0)
    xt, ut, xnt = _data(f, n_test, seed=2)
    mean, var = model.predict(xt, ut)
    r2 = (xnt - mean) ** 2
    assert np.all(np.abs(r2.mean(0) - SIGMA**2) < mc_tol(math.sqrt(2) * SIGMA**2, n_test))
    assert np.all(np.abs((r2 / var).mean(0) - 1.0) < mc_tol(math.sqrt(2), n_test))


def test_same_seed_same_predictions_and_bootstrap_members_differ():
    x, u, xn = _data(_nonlinear, 200, seed=3)
    st = EnsembleSettings(hidden_sizes=(16,), epochs=10)
    a, b, c = (ProbabilisticEnsemble(st).fit(x, u, xn, rng=s) for s in (0, 0, 1))
    pa, pb, pc = a.predict(x, u), b.predict(x, u), c.predict(x, u)
    np.testing.assert_array_equal(pa[0], pb[0])
    np.testing.assert_array_equal(pa[1], pb[1])
    assert not np.array_equal(pa[0], pc[0])
    # Members trained on different resamples from different initial weights differ by far
    # more than the round-off of one forward pass (a few products of length ≤ 16).
    mean, _ = a.member_moments(torch.as_tensor(x), torch.as_tensor(u))
    spread = (mean[:, None] - mean[None]).abs().amax(dim=(2, 3))  # (K, K)
    off = spread[~torch.eye(a.n_members, dtype=torch.bool)]
    assert float(off.min()) > fp_tol(4 * 16, float(np.abs(xn).max()))


def test_variance_grows_away_from_the_data(one_dim):
    """Inside the data the mixture variance is the noise σ² (within 5 standard errors of a
    variance estimate from 400 points); beyond the data the members disagree more the
    farther the query, so the variance grows with the distance."""
    mean, var = one_dim.predict(np.array([[-0.5], [0.0], [0.5]]), np.zeros((3, 0)))
    assert np.all(np.abs(var - SIGMA**2) < mc_tol(math.sqrt(2) * SIGMA**2, 400))
    q = np.array([1.5, 2.0, 3.0, 4.0])
    for side in (1.0, -1.0):
        _, v = one_dim.predict(side * q[:, None], np.zeros((4, 0)))
        assert v[0, 0] > var.max() and np.all(np.diff(v[:, 0]) > 0), v[:, 0]


# --------------------------------------------------------------------------- sampling
def test_next_state_moments_give_row_i_member_i_mod_k(one_dim):
    """TS-∞: the sampler's row i is predicted by member i mod K (n not a multiple of K)."""
    K, n = one_dim.n_members, 13
    x = torch.linspace(-1.0, 1.0, n, dtype=torch.float64)[:, None]
    u = x.new_zeros((n, 0))
    m = one_dim.next_state_moments(x, u)
    mean, var = one_dim.member_moments(x, u)
    rows = torch.arange(n)
    # The same products on a different grouping of rows: round-off of a 32-wide network.
    tol = fp_tol(3 * 32, 1.0)
    np.testing.assert_allclose(m.mean, mean[rows % K, rows], rtol=tol, atol=tol)
    np.testing.assert_allclose(m.var, var[rows % K, rows], rtol=tol, atol=0)
    assert int(m.n_clamped) == 0 and float(m.worst) == 0.0


def test_sampled_next_states_have_the_predicted_moments(one_dim):
    """Two start states, one inside the data and one at its edge, L trajectories each. After
    one step the trajectories of each member have that member's mean and variance, and from
    the start inside the data all of them have the mixture's (:meth:`predict`), within 5
    Monte Carlo standard errors. After two steps from the edge (beyond the data, where the
    members disagree) each state is a draw from its own member's Gaussian at its first state
    (TS-∞: the member is kept), and not from the next member's."""
    K, L = one_dim.n_members, 4000
    x0 = np.array([[0.3], [1.0]])
    s = sample_trajectories(one_dim, x0, _zero_control, 2, L, rng=7)
    mean, var = one_dim.member_moments(torch.as_tensor(x0), torch.zeros((2, 0)))
    member = torch.arange(L) % K  # pair b's row b L + l, L a multiple of K
    for b in range(2):
        x1 = s.states[b, :, 1, 0]
        for k in range(K):
            draws = x1[member == k].numpy()
            sd = math.sqrt(float(var[k, b, 0]))
            assert abs(draws.mean() - float(mean[k, b, 0])) < mc_tol(sd, draws.size)
            assert abs(draws.var(ddof=1) / sd**2 - 1) < mc_tol(math.sqrt(2), draws.size)
    x1 = s.states[0, :, 1, 0]
    mix_mean, mix_var = one_dim.predict(x0[:1], np.zeros((1, 0)))
    assert abs(x1.mean().item() - mix_mean[0, 0]) < mc_tol(math.sqrt(mix_var[0, 0]), L)
    # Inside the data the members agree to well below the noise, so the mixture is nearly
    # Gaussian and its sample variance has the Gaussian standard error √2 var / √L.
    assert abs(x1.var().item() / mix_var[0, 0] - 1) < mc_tol(math.sqrt(2), L)
    # step 2 from the edge: z = (x2 − μ_k(x1)) / σ_k(x1) with k = i mod K is standard normal
    x1, x2 = s.states[1, :, 1], s.states[1, :, 2]  # (L, 1)
    m2, v2 = one_dim.member_moments(x1, x1.new_zeros((L, 0)))
    rows = torch.arange(L)
    z = ((x2 - m2[member, rows]) / v2[member, rows].sqrt()).numpy()
    assert abs(z.mean()) < mc_tol(1.0, L) and abs((z**2).mean() - 1) < mc_tol(math.sqrt(2), L)
    other = (member + 1) % K
    z_other = ((x2 - m2[other, rows]) / v2[other, rows].sqrt()).numpy()
    assert (z_other**2).mean() - 1 > mc_tol(math.sqrt(2), L), (z_other**2).mean()


def test_float32_copy_predicts_like_float64(one_dim):
    """``to(dtype=float32)`` rounds weights and inputs to float32: the means agree to float32
    round-off through the network; the sampler's own float32 check stays below its bound."""
    x = torch.linspace(-1.0, 1.0, 50, dtype=torch.float64)[:, None]
    u = x.new_zeros((50, 0))
    m64 = one_dim.next_state_moments(x, u)
    lo = one_dim.to(dtype=torch.float32)
    m32 = lo.next_state_moments(x.float(), u.float())
    assert one_dim.dtype == torch.float64 and m32.mean.dtype == torch.float32
    tol = fp_tol(3 * 32, 1.0, eps=EPS32)
    np.testing.assert_allclose(m32.mean.double(), m64.mean, atol=tol)
    np.testing.assert_allclose(m32.var.double(), m64.var, rtol=tol)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = sample_trajectories(
            one_dim, np.array([[0.2]]), _zero_control, 5, 20, rng=0, dtype=torch.float32
        )
    assert s.precision_error < PRECISION_TOL


# --------------------------------------------------------------------------- GPREPS
def test_serves_gpreps_as_make_model_on_the_pendulum():
    """Two GPREPS updates on the pendulum with the ensemble as ``make_model``: the model is
    fitted on the real transitions, its predictions of the second batch's pairs beat the
    trivial predictor (the batch mean, whose RMSE is the rewards' std) and have no bias
    beyond 4 standard errors of the batch mean; the whole state pickles and resumes to the
    same numbers (checkpoints)."""
    task = Pendulum(horizon=10)
    rng = np.random.default_rng(0)
    make = partial(ProbabilisticEnsemble, EnsembleSettings(hidden_sizes=(32, 32), epochs=100))
    model = TrajectoryRewardModel(task, make_model=make)
    st = GPREPSSettings(n_artificial=100, n_trajectories=5, context_model="prior")
    alg = GPREPS(task.initial_policy(), model, st, task=task, rng=1)
    d1 = alg.update(collect(task, alg.policy, 20, rng))
    assert isinstance(model.model, ProbabilisticEnsemble) and d1.model_fit["n_data"] == 200
    assert np.isfinite(d1.artificial_reward_mean)
    batch = collect(task, alg.policy, 20, rng)
    copy = pickle.loads(pickle.dumps(alg))
    d2, d2_copy = alg.update(batch), copy.update(batch)
    std = batch.rewards.std()
    assert d2.prediction_rmse < std, (d2.prediction_rmse, std)
    assert abs(d2.prediction_bias) < 4 * std / math.sqrt(20)
    assert d2.prediction_bias == d2_copy.prediction_bias
    np.testing.assert_array_equal(alg.policy.mean, copy.policy.mean)


# --------------------------------------------------------------------------- input
def test_bad_input_names_the_argument():
    x, u, xn = np.zeros((5, 2)), np.zeros((5, 1)), np.zeros((5, 2))
    for field, value in [
        ("hidden_sizes", ()),
        ("hidden_sizes", [64]),
        ("hidden_sizes", (64, 0)),
        ("n_members", 0),
        ("epochs", 1.5),
        ("lr", 0.0),
        ("weight_decay", -1.0),
        ("batch_size", True),
    ]:
        with pytest.raises(ValueError, match=field):
            EnsembleSettings(**{field: value})
    with pytest.raises(ValueError, match="settings"):
        ProbabilisticEnsemble({"epochs": 3})
    with pytest.raises(ValueError, match="target"):
        ProbabilisticEnsemble(target="x")
    with pytest.raises(ValueError, match="dtype"):
        ProbabilisticEnsemble(dtype=torch.float16)
    with pytest.raises(ValueError, match="device"):
        ProbabilisticEnsemble(device="tpu")
    model = ProbabilisticEnsemble(EnsembleSettings(epochs=1))
    with pytest.raises(ValueError, match="states"):
        model.fit(x[:1], u[:1], xn[:1])
    with pytest.raises(ValueError, match="controls"):
        model.fit(x, u[:4], xn)
    with pytest.raises(ValueError, match="next_states"):
        model.fit(x, u, xn[:, :1])
    with pytest.raises(ValueError, match="states"):
        model.fit(np.full((5, 2), np.nan), u, xn)
    with pytest.raises(ValueError, match="rng"):
        model.fit(x, u, xn, rng="seed")
    with pytest.raises(RuntimeError, match="fit"):
        model.next_state_moments(torch.zeros(1, 2), torch.zeros(1, 1))
    model.fit(x, u, xn, rng=0)
    with pytest.raises(ValueError, match="controls"):
        model.predict(x, np.zeros((5, 2)))
    with pytest.raises(ValueError, match="dtype"):
        model.to(dtype=torch.int64)


def test_repr_is_short_and_informative(one_dim):
    assert repr(ProbabilisticEnsemble()) == (
        "ProbabilisticEnsemble(members=5, hidden=(64, 64), target='delta', unfitted)"
    )
    text = repr(one_dim)
    assert "\n" not in text and len(text) < 300 and "tensor(" not in text
    assert "state_dim=1, control_dim=0, n_data=400" in text and "train_loss=" in text
