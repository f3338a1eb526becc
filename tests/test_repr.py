"""Short, informative ``repr`` of the objects people print in notebooks: policies, DMPs,
trajectories, GP models and their predictors, sampled and moment-matched predictions, kernel
embeddings. Each is one line under 300 characters, holds the key numbers, dumps no array and
is not Python's default ``<... at 0x...>``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from skillkit._repr import number, span, vector
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.trajectory import Trajectory


def check(obj, *needles: str) -> str:
    text = repr(obj)
    assert "\n" not in text and len(text) < 300, text
    assert " at 0x" not in text and "array(" not in text and "tensor(" not in text, text
    for needle in needles:
        assert needle in text, (needle, text)
    return text


# ----------------------------------------------------------------------------- helpers
def test_summary_helpers():
    assert span([3.0, -1.0, 2.0]) == "-1…3" and span([2.0, 2.0]) == "2" and span([]) == "-"
    assert span([1.0, np.nan, np.inf]) == "1 (2 non-finite)"
    assert span(torch.tensor([0.5, 0.25])) == "0.25…0.5"
    assert vector([1.0, -2.5]) == "[1, -2.5]"
    assert vector(np.arange(10.0)) == "0…9 (10 values)"
    assert number(1234567.0) == "1.23e+06" and number(0.1, ".2f") == "0.10"


# ----------------------------------------------------------------------------- policies
def test_gaussian_policies():
    p = GaussianPolicy(np.array([1.0, -2.0]), np.diag([4.0, 1.0]))
    assert check(p, "GaussianPolicy(dim=2", "mean=[1, -2]", "std=1…2", "cond(cov)=4")
    gain = np.array([[0.2, 0.0], [0.0, -0.7]])
    q = LinearGaussianPolicy(np.zeros(2), np.eye(2), gain, context_dim=2)
    check(q, "dim=2, context_dim=2, features='linear'", "std=1,", "max|gain|=0.7")
    big = LinearGaussianPolicy(np.arange(30.0), np.eye(30), context_dim=3, features="quadratic")
    check(big, "mean=0…29 (30 values)", "features='quadratic'")


def test_dmps():
    dmp = DMP(3, n_basis=5, duration=0.5)
    check(dmp, "n_joints=3, n_basis=5", "duration=0.5 s", "goal=None", "weights=0")
    dmp.goal = np.array([0.1, 0.2, 0.3])
    dmp.weights = np.linspace(-4.0, 6.0, 15).reshape(3, 5)
    check(dmp, "goal=[0.1, 0.2, 0.3]", "weights=-4…6")
    params = DMPParameters(dmp, learn=("goal", "tau"))
    check(params, "dim=4", "learn=('goal', 'tau')", "omega=[0.1, 0.2, 0.3, 1]")


# ----------------------------------------------------------------------------- trajectories
def test_trajectory():
    times = np.linspace(0.0, 2.0, 201)
    traj = Trajectory(times, np.zeros((201, 4)), np.zeros((201, 2)), {"ball": np.zeros((80, 3))})
    check(traj, "n_steps=201", "t=0…2 s", "state_dim=4", "control_dim=2", "ball (80, 3)")
    assert repr(traj).endswith("failed=False)")
    traj.failed, traj.message = True, "non-finite state at t=0.3 s " + "x" * 200
    check(traj, "failed=True: 'non-finite state at t=0.3 s")
    many = Trajectory(
        times[:3], np.zeros((3, 1)), np.zeros((3, 1)), {f"s{i}": [1, 2, 3] for i in range(30)}
    )
    check(many, "signals=['s0', 's1'")


# ----------------------------------------------------------------------------- GP models
@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    X = rng.uniform(-2.0, 2.0, (40, 2))
    Y = np.column_stack([np.sin(X[:, 0]), 3.0 * np.cos(X[:, 1])]) + 0.05 * rng.standard_normal(
        (40, 2)
    )
    return X, Y


def test_exact_and_sparse_gps(data):
    from skillkit.models.gp import ExactGP
    from skillkit.models.sparse import FITC, VFE

    X, Y = data
    check(ExactGP(n_steps=5), "ExactGP(unfitted, n_steps=5, additive_noise=")
    gp = ExactGP(n_steps=20, additive_noise=0.0).fit(X, Y, rng=0)
    h = gp.hyperparameters
    text = check(gp, "ExactGP(N=40, inputs=2, outputs=2", f"noise_var={span(h['noise'])}")
    assert f"lengthscale={span(h['lengthscale'])}" in text
    assert f"signal_var={span(h['outputscale'])}" in text and "log_ml=" in text
    for cls in (FITC, VFE):
        sparse = cls(10, n_steps=5, additive_noise=0.0).fit(X, Y, rng=0)
        check(sparse, f"{cls.__name__}(N=40, M=10, inputs=2, outputs=2", "signal_var=")
    check(gp.predictor, "GPPredictor(outputs=2, support=40, inputs=2", "torch.float64", "cpu")


def test_forward_model_sampling_and_moment_matching(data):
    from skillkit.models.gp import ExactGP, ForwardModel
    from skillkit.models.moment_matching import moment_match
    from skillkit.models.sampling import sample_trajectories

    X, Y = data
    model = ForwardModel(ExactGP(n_steps=5))
    check(model, "ForwardModel(target='next', unfitted, gp=ExactGP(unfitted")
    x, u = X[:, :1], X[:, 1:]
    model.fit(x, u, x + 0.1 * Y[:, :1], rng=0)
    check(model, "state_dim=1, control_dim=1", "gp=ExactGP(N=40, inputs=2, outputs=1")

    def policy(t, state, pair):
        return torch.zeros((state.shape[0], 1), dtype=state.dtype)

    sampled = sample_trajectories(model, np.zeros((3, 1)), policy, 6, 4, rng=0)
    check(sampled, "SampledTrajectories(B=3, L=4, T=6, state_dim=1, control_dim=1", "n_saturated=0")
    g = moment_match(model.predictor, np.zeros(2), 0.1 * np.eye(2))
    check(g, "GaussianPrediction(outputs=1, inputs=2, mean=[", "std=")


def test_embeddings(data):
    from skillkit.models.embedding import ConditionalEmbedding
    from skillkit.models.embedding_prediction import predict
    from skillkit.models.embedding_training import (
        fit_hyperparameters,
        kfold_splits,
        state_embedding_loss,
    )
    from skillkit.models.kernels import SquaredExponential

    X, _ = data
    targets = 0.9 * X
    kern = SquaredExponential(2, lengthscale=[0.5, 2.0])
    emb = ConditionalEmbedding(X, targets, kern, lam=1e-2)
    check(
        emb, "ConditionalEmbedding(N=40, input_dim=2, target_dim=2, lam=0.01", "lengthscale=0.5…2"
    )
    pred = predict(emb, X[:3], 5, reward=lambda s, c: -(s**2).sum(-1))
    check(pred, "TrajectoryEmbedding(B=3, T=5, N=40, state_dim=2", "total_reward=")
    loss = state_embedding_loss(X, targets, kfold_splits(40, 4, rng=0), kern)
    check(loss, "CrossValidatedLoss(folds=4, dim=2")
    fit = fit_hyperparameters(loss, [1.0, 1.0], max_iter=3)
    check(fit, "FitResult(lengthscale=[", "lam=", "loss=", "n_evaluations=")
