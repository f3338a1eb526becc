"""TrajectoryRewardModel's sampling precision: chosen per fit by the float32 moment check and
recorded in the fit statistics; float32 predicts the float64 expected rewards (Eq. 4.1)
within Monte Carlo error."""

from __future__ import annotations

import copy
import warnings
from functools import partial

import numpy as np
import pytest
import torch
from _tolerances import EPS32

from skillkit.models.gp import ForwardModel, GPNumericalWarning
from skillkit.models.sampling import sampling_dtype
from skillkit.models.sparse import FITC
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.search import GPREPS, GPREPSSettings, TrajectoryRewardModel, collect
from skillkit.tasks.balancing import Balancing

T = 10


@pytest.fixture(scope="module")
def fitted():
    """A FITC forward model of 20 rollouts of noisy LQR gains (torque noise 0.5 N·m)."""
    task = Balancing(n_steps=T, torque_noise_std=0.5)
    policy = GaussianPolicy(task.lqr_gain().reshape(-1), 1e-3 * np.eye(32))
    make = partial(ForwardModel, FITC(n_inducing=40, n_steps=20), target="delta")
    model = TrajectoryRewardModel(task, make_model=make, dtype=None)  # chosen at each fit
    batch = collect(task, policy, 20, np.random.default_rng(0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        stats = model.fit(None, batch.omegas, batch.rewards, batch.trajectories, rng=1)
    return task, policy, model, stats, batch


def test_fit_chooses_and_records_the_sampling_precision(fitted):
    task, policy, model, stats, batch = fitted
    x, u, _ = (
        np.concatenate(p) for p in zip(*map(task.transitions, batch.trajectories), strict=True)
    )
    dtype, error = sampling_dtype(model.model, x, u)
    assert model.dtype is None and model.sample_dtype == dtype
    assert stats["sampling_dtype"] == str(dtype).removeprefix("torch.")
    assert stats["precision_error"] == error
    pinned = TrajectoryRewardModel(task, make_model=model.make_model, dtype=torch.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        st = pinned.fit(None, batch.omegas, batch.rewards, batch.trajectories, rng=1)
    assert st["sampling_dtype"] == "float64" and st["precision_error"] is None
    diag = GPREPS(
        policy,
        model,
        GPREPSSettings(n_artificial=40, n_trajectories=2, min_effective_samples=2),
        rng=0,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        d = diag.update(batch)
    assert d.model_fit["sampling_dtype"] in ("float32", "float64")


def test_float32_expected_rewards_match_float64_within_monte_carlo_error(fitted):
    """B = 60 pairs × L = 50: with independent seeds the mean predicted rewards differ by
    less than 4 standard errors (from the per-pair spreads of both); with the same seed the
    float32 states follow the float64 ones (each step off by ≤ the float32 moment error in sds
    plus the rounding of the state, over T steps at most T times that; twice it) and the
    paired mean is well within one standard error."""
    task, policy, model, _, _ = fitted
    omegas = policy.sample(np.zeros((60, 0)), np.random.default_rng(3))
    double, single = copy.copy(model), copy.copy(model)
    double.sample_dtype, single.sample_dtype = torch.float64, torch.float32
    s, L = np.zeros((60, 0)), 50
    x0 = np.stack([task.initial_states(None, L, np.random.default_rng(4))] * 60)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        a = _predict(double, s, omegas, L, 5, x0)
        b = _predict(single, s, omegas, L, 6, x0)
        c = _predict(single, s, omegas, L, 5, x0)
    se = np.sqrt((a.rewards.var(1, ddof=1) + b.rewards.var(1, ddof=1)).sum() / L) / 60
    diff = a.expected_rewards.mean() - b.expected_rewards.mean()
    assert abs(diff) < 4 * se, (diff, se)
    spread = a.states[:, :, -1].std(1).max()
    x_max = np.abs(a.states).max()
    error = c.sampled.precision_error
    tol = 2 * T * (error * spread + EPS32 / 2 * x_max)
    assert np.abs(c.states - a.states).max() < tol
    assert abs(c.expected_rewards.mean() - a.expected_rewards.mean()) < se


def _predict(model, s, omegas, L, seed, x0):
    from skillkit.search.model_rollouts import predict_trajectories

    return predict_trajectories(
        model.task,
        model.model,
        omegas,
        horizon=T,
        n_samples=L,
        rng=seed,
        x0=x0,
        dtype=model.sample_dtype,
    )
