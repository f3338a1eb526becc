"""Predicted rollouts: the task's controller and reward on model states (GPREPS Eq. 4.1)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.reward import worst_if_failed
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


def _rollout_tols(task, A, B, G, states):
    """Bounds on |library − test| for the noise-free closed loop x̃' = A x̃ + B G x̃, x = x_up + x̃,
    two evaluations (the library carries x, the test x̃). One step rounds its 8- and 4-term dot
    products and 3-term sum, locally ε (8 + 4 + 2)(|x_up| + |A||x̃| + |B||G||x̃|); errors
    propagate through M = A + BG, amplified by at most Σ_k ‖Mᵏ‖∞ over the horizon (the
    recursion's condition). Controls u = G x̃: ‖G‖∞ times the state bound plus an 8-term dot.
    The cost Σ_t x̃ᵀQx̃ + r_u uᵀu: twice the first-order change from those bounds, plus sums of
    T·(n² + m) terms relative to their absolute values. Magnitudes from the library's states."""
    xt = np.abs(states - X_UP).reshape(-1, states.shape[-1])  # (L·(T+1), 8)
    T = states.shape[-2] - 1
    M = A + B @ G
    amp = sum(np.linalg.norm(np.linalg.matrix_power(M, k), np.inf) for k in range(T + 1))
    local = np.abs(X_UP) + xt @ np.abs(A).T + xt @ (np.abs(B) @ np.abs(G)).T
    state = 2 * fp_tol(8 + 4 + 2, scale=local.max(), cond=amp)
    gx = xt @ np.abs(G).T
    control = np.linalg.norm(G, np.inf) * state + 2 * fp_tol(8, scale=gx.max())
    q, r_u = np.abs(task.state_weights), task.control_weight
    first = 2 * ((xt @ q).sum(1) * state + r_u * gx.sum(1) * control).max() * T
    terms = ((xt @ q) * xt).sum(1).max() * T + r_u * (gx**2).sum(1).max() * T
    n, m = q.shape[0], G.shape[0]
    reward = first + 2 * fp_tol(T * (n * n + m), scale=terms)
    return state, control, reward


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
        # states: |B||G||x̃| ≤ 210 per step (|G| ≈ 1.4e3), amplified ≤ 30 by the closed loop
        # (‖Mᵏ‖∞ ≤ 4.5): ≤ 4e-10; controls: ‖G‖∞ ≈ 4e3 times that (see _rollout_tols). Looser
        # than the former literals, which left out the rounding of u = G x̃ fed back through B.
        state_tol, control_tol, reward_tol = _rollout_tols(task, A, B, G, out.states[b])
        for t in range(13):
            u = G @ x
            np.testing.assert_allclose(out.states[b, 0, t], x + X_UP, rtol=0, atol=state_tol)
            np.testing.assert_allclose(out.controls[b, 1, t], u, rtol=0, atol=control_tol)
            if t:
                cost += x @ task.state_weights @ x + task.control_weight * u @ u
            x = A @ x + B @ u
        np.testing.assert_allclose(out.rewards[b], -cost, rtol=0, atol=reward_tol)
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


def test_a_predicted_path_beyond_the_limits_scores_as_a_real_fall(setup):
    """A model whose paths blow up: the paths the task's divergence rule stops score
    ``worst_reward`` (a real fall's reward), the others keep ``reward_batch``'s value."""
    task, A, B, omegas = setup
    unstable = LinearModel(1.2 * A, B)  # open loop scaled up: most of the gains lose the robot
    out = predict_trajectories(task, unstable, omegas, horizon=30, n_samples=2, rng=0)
    flat = out.states.reshape(-1, 31, 8)
    raw = task.reward_batch(flat, out.controls.reshape(-1, 31, 4))
    failed = task.failed_batch(flat).reshape(out.failed.shape)
    np.testing.assert_array_equal(out.failed, failed)
    assert out.failed.any() and not out.failed.all()
    # the model's own cost of a fall is no fixed number (here −8e4 … −6e6; −1e20 at 1.6 A)
    assert np.all(raw.reshape(failed.shape)[failed] != task.worst_reward)
    np.testing.assert_array_equal(out.rewards[failed], task.worst_reward)
    np.testing.assert_array_equal(out.rewards[~failed], raw.reshape(failed.shape)[~failed])
    r, f = worst_if_failed(raw, flat, task)
    np.testing.assert_array_equal(r, out.rewards.ravel())
    np.testing.assert_array_equal(f, failed.ravel())
