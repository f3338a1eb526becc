"""Balancing domain code (:mod:`skillkit.tasks.balancing`): the upright state, gain
helpers, data collection, the sampler's feedback policy and the rewards of sampled states."""

from __future__ import annotations

import numpy as np
import torch

from skillkit.tasks import make
from skillkit.tasks.balancing import (
    X_UP,
    collect_balancing,
    feedback_policy,
    random_lqr_gains,
    sampled_rewards,
)
from skillkit.tasks.planar_model import UPRIGHT


def test_upright_state():
    np.testing.assert_array_equal(X_UP, np.concatenate([UPRIGHT, np.zeros(4)]))


def test_collect_balancing_transitions_are_consecutive():
    task = make("balancing", n_steps=5, torque_noise_std=0.5)
    data = collect_balancing(task, 3, np.random.default_rng(0))
    assert (
        data["x"].shape == (15, 8)
        and data["u"].shape == (15, 4)
        and data["omegas"].shape == (3, 32)
    )
    np.testing.assert_array_equal(data["x"][1:5], data["x_next"][:4])
    np.testing.assert_allclose(data["u"][:5], data["trajectories"][0].controls[:5])


def test_reward_of_states_equals_task_reward_and_policy_is_the_feedback():
    task = make("balancing", n_steps=5, torque_noise_std=0.0)
    data = collect_balancing(task, 2, np.random.default_rng(1))
    G = data["omegas"].reshape(-1, 4, 8)
    states = np.stack([t.states for t in data["trajectories"]])[:, None]  # (B, 1, T+1, 8)
    got = sampled_rewards(task, states, G)[:, 0]
    np.testing.assert_allclose(got, [task.reward(t) for t in data["trajectories"]], rtol=1e-12)
    pol = feedback_policy(torch.as_tensor(G))
    x = torch.as_tensor(states[:, 0, 0])
    u = pol(0, x, torch.arange(2)).numpy()
    np.testing.assert_allclose(u, data["u"][[0, 5]], rtol=1e-10, atol=1e-10)


def test_balancing_reward_matches_the_task_reward():
    task = make("balancing-noisy", n_steps=10)
    gain = random_lqr_gains(task, 1, 1.0, 1e-3, np.random.default_rng(0))[0]
    traj = task.rollout(gain.ravel(), None, np.random.default_rng(1))
    assert not traj.failed
    r = task.immediate_reward(traj.states, traj.controls)
    np.testing.assert_allclose(r[1:].sum(), task.reward(traj), rtol=1e-12)


def test_random_lqr_gains_stabilise_the_linearised_robot():
    task = make("balancing-noisy")
    a, b = task.linearization()
    gains = random_lqr_gains(task, 4, 1.0, 1e-3, np.random.default_rng(2))
    assert gains.shape == (4, 4, 8)
    assert len({g.tobytes() for g in gains}) == 4
    for g in gains:
        assert np.abs(np.linalg.eigvals(a + b @ g)).max() < 1.0


def test_sampled_rewards_score_diverged_samples_as_worst():
    task = make("balancing", n_steps=3)
    states = np.tile(X_UP, (1, 2, 4, 1))
    states[0, 1, 2, 0] = np.inf
    r = sampled_rewards(task, states, np.zeros((1, 4, 8)))
    assert r.shape == (1, 2)
    assert r[0, 0] == 0.0 and r[0, 1] == task.worst_reward
