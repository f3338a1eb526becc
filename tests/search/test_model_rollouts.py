"""Predicted rollouts: the task's controller and reward on model states (GPREPS Eq. 4.1)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from skillkit.search.model_rollouts import predict_trajectories
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP, stable_gains


class LinearModel:
    """x' = x_up + A (x − x_up) + B u + σ ε: the balancing robot's discrete linearisation."""

    def __init__(self, A, B, noise_std=0.0):
        self.A, self.B, self.noise_std = np.asarray(A), np.asarray(B), float(noise_std)
        self.state_dim, self.control_dim = self.B.shape
        self.dtype = torch.float64

    def to(self, device=None, dtype=None):
        self.dtype = dtype or self.dtype
        return self

    def next_state_moments(self, x, u):
        A = torch.as_tensor(self.A, dtype=x.dtype)
        B = torch.as_tensor(self.B, dtype=x.dtype)
        up = torch.as_tensor(X_UP, dtype=x.dtype)
        mean = up + (x - up) @ A.T + u @ B.T
        return mean, torch.full_like(mean, self.noise_std**2)


@pytest.fixture(scope="module")
def setup():
    task = make("balancing")
    A, B = task.linearization()
    omegas = stable_gains(task, 3, np.random.default_rng(0))
    return task, A, B, omegas


def test_noise_free_prediction_is_the_closed_loop_and_its_reward(setup):
    task, A, B, omegas = setup
    x0 = task.initial_states(None, 3, rng=1)
    out = predict_trajectories(task, LinearModel(A, B), omegas, horizon=12, n_samples=2, x0=x0)
    assert out.states.shape == (3, 2, 13, 8) and out.controls.shape == (3, 2, 13, 4)
    for b, w in enumerate(omegas):  # independent recursion and reward formula
        G = w.reshape(4, 8)
        x, cost = x0[b] - X_UP, 0.0
        # Round-off: states carry x_up (|x| ≤ π) through 12 closed-loop steps (‖A + BG‖ ≤ 3.1):
        # ≲ 13 · 3.1 · 8 eps π ≈ 2e-13 ≪ 1e-10; controls u = G x multiply that by ‖G‖ √8 ≈ 4e3
        # (|G| ≤ 1.5e3): ≈ 1e-9 ≤ 1e-8; the cost is a sum of 12 positive terms (relative).
        for t in range(13):
            u = G @ x
            np.testing.assert_allclose(out.states[b, 0, t], x + X_UP, rtol=0, atol=1e-10)
            np.testing.assert_allclose(out.controls[b, 1, t], u, rtol=0, atol=1e-8)
            if t:
                cost += x @ task.state_weights @ x + task.control_weight * u @ u
            x = A @ x + B @ u
        np.testing.assert_allclose(out.rewards[b], -cost, rtol=1e-10)
    np.testing.assert_array_equal(out.expected_rewards, out.rewards.mean(1))
    assert "pairs=3" in repr(out) and len(repr(out)) < 300


def test_same_seed_same_rollouts_and_noise_spreads_them(setup):
    task, A, B, omegas = setup
    model = LinearModel(A, B, noise_std=1e-3)
    a, b = (predict_trajectories(task, model, omegas, horizon=5, n_samples=4, rng=3) for _ in "ab")
    c = predict_trajectories(task, model, omegas, horizon=5, n_samples=4, rng=4)
    np.testing.assert_array_equal(a.states, b.states)
    assert not np.array_equal(a.states, c.states)
    assert np.all(a.rewards.std(axis=1) > 0)  # L distinct trajectories per pair


def test_bad_input_and_unsupported_tasks(setup):
    task, A, B, omegas = setup
    model = LinearModel(A, B)
    with pytest.raises(ValueError, match="omegas"):
        predict_trajectories(task, model, omegas[:, :5], horizon=3)
    with pytest.raises(ValueError, match="horizon"):
        predict_trajectories(task, model, omegas, horizon=0)
    with pytest.raises(ValueError, match="n_samples"):
        predict_trajectories(task, model, omegas, horizon=2, n_samples=0)
    with pytest.raises(ValueError, match="x0"):
        predict_trajectories(task, model, omegas, horizon=2, x0=np.zeros((3, 7)))
    with pytest.raises(NotImplementedError, match="hockey"):
        predict_trajectories(make("hockey"), model, np.zeros((1, 1)), horizon=2)
    with pytest.raises(NotImplementedError, match="signals"):
        predict_trajectories(make("throwing"), model, np.zeros((1, 1)), horizon=2)
