"""Balancing domain code (:mod:`skillkit.tasks.balancing`): the upright state, gain
helpers, data collection, the sampler's feedback policy and the rewards of sampled states."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg
import torch
from _tolerances import fp_tol

from skillkit.tasks import make
from skillkit.tasks.balancing import (
    X_UP,
    collect_balancing,
    design_policy,
    feedback_policy,
    random_lqr_gains,
    sampled_rewards,
)
from skillkit.tasks.base import SimulationFailure
from skillkit.tasks.planar_model import UPRIGHT
from skillkit.trajectory import Trajectory


def _feedback_tol(x, gains):
    """Absolute round-off of u = G (x − x_up), an 8-term dot product after a subtraction, on
    terms of size |G| |x − x_up| (the entries can cancel), evaluated along two paths (matvec in
    the rollout, a batched product here); ``x`` (..., 8), ``gains`` (..., 4, 8)."""
    terms = np.einsum("...ij,...j->...i", np.abs(gains), np.abs(np.asarray(x) - X_UP))
    return fp_tol(9, scale=terms.max())


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
    # the same reward_batch on differently batched states: Q = I (its zeros add exactly) and
    # r_u = 0, so a sum of T·8 same-sign squares, ≲ (n + 2) ε relatively
    rel = fp_tol(states[0, 0, 1:].size + 2)
    np.testing.assert_allclose(got, [task.reward(t) for t in data["trajectories"]], rtol=rel)
    pol = feedback_policy(torch.as_tensor(G))
    x = torch.as_tensor(states[:, 0, 0])
    u = pol(0, x, torch.arange(2)).numpy()
    tol = _feedback_tol(states[:, 0, 0], G)  # torch einsum vs the rollout's numpy G x̃
    np.testing.assert_allclose(u, data["u"][[0, 5]], rtol=0, atol=tol)


def test_balancing_reward_matches_the_task_reward():
    task = make("balancing-noisy", n_steps=10)
    gain = random_lqr_gains(task, 1, 1.0, 1e-3, np.random.default_rng(0))[0]
    traj = task.rollout(gain.ravel(), None, np.random.default_rng(1))
    assert not traj.failed
    r = task.immediate_reward(traj.states, traj.controls)
    # both sum the same same-sign terms (diagonal Q, r_u uᵀu) in different orders: T·12 terms
    rel = fp_tol(traj.states[1:].size + traj.controls[1:].size + 2)
    np.testing.assert_allclose(r[1:].sum(), task.reward(traj), rtol=rel)


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


def test_initial_policy_samples_all_balance_and_wider_exploration_does_not():
    """The default exploration (0.2% of |G_lqr|) gives closed loops that are stable at upright
    for every one of 2000 samples, on both variants; 1% (what the ch4 model experiments' data
    use) leaves a sizeable unstable fraction."""
    rng = np.random.default_rng(0)

    def unstable(task, policy):
        A, B = task.linearization()
        W = policy.sample(np.zeros((2000, 0)), rng=rng)
        rho = np.abs(np.linalg.eigvals(A + B @ W.reshape(-1, 4, 8))).max(-1)
        return np.mean(rho >= 1.0)

    for name in ("balancing", "balancing-noisy"):
        task = make(name)
        assert unstable(task, task.initial_policy()) == 0.0
        assert unstable(task, task.lqr_policy(exploration_std_fraction=0.01)) > 0.05
    np.testing.assert_allclose(
        np.sqrt(np.diag(task.initial_policy().cov)), 0.002 * np.abs(task.lqr_gain().ravel())
    )


def test_initial_policy_rollouts_do_not_fail_on_either_variant():
    for name in ("balancing", "balancing-noisy"):
        task = make(name)
        rng = np.random.default_rng(1)
        W = task.initial_policy().sample(np.zeros((30, 0)), rng=rng)
        assert not any(task.rollout(w, rng=rng).failed for w in W)


def test_excitation_is_recorded_in_the_controls_and_off_by_default():
    """u_t = G x̃_t + ξ_t: the recorded control minus the feedback is the excitation signal,
    which is zero by default."""
    G = make("balancing").lqr_gain()
    task = make("balancing", excitation_std=20.0)
    traj = task.rollout(G.ravel(), rng=np.random.default_rng(2))
    fb = (traj.states[:-1] - X_UP) @ G.T
    xi = traj.signals["excitation"]
    np.testing.assert_allclose(traj.controls[:-1] - fb, xi, atol=1e-9)
    assert 10.0 < xi.std() < 30.0
    plain = make("balancing").rollout(G.ravel(), rng=np.random.default_rng(2))
    assert not plain.signals["excitation"].any()
    with pytest.raises(ValueError, match="excitation_std"):
        make("balancing", excitation_std=-1.0)


def test_pd_gain_places_the_continuous_poles():
    """Independent check: the 1 ms linearisation (≈ the continuous dynamics, A_c = logm(A)/dt)
    closed with the PD gain has the poles −ζω ± ω√(ζ² − 1), each four times."""
    fine = make("balancing", control_dt=0.001)
    A, B = fine.linearization()
    Ac = scipy.linalg.logm(A).real / 0.001
    Bc = np.linalg.solve(A - np.eye(8), Ac @ B)  # B = (A − I) Ac⁻¹ Bc for a held input
    for w, z in ((3.0, 1.5), (5.0, 2.0)):  # distinct roots (ζ = 1 is defective: they split)
        G = fine.pd_gain(w, z)
        poles = np.sort_complex(np.linalg.eigvals(Ac + Bc @ G))
        root = np.sqrt(complex(z**2 - 1))
        expected = np.sort_complex(np.repeat([-z * w - w * root, -z * w + w * root], 4))
        np.testing.assert_allclose(poles, expected, rtol=0.05)  # joint damping, 1 ms hold
    # the default balances robustly at 20 Hz; a lower stiffness does not
    task = make("balancing")
    A20, B20 = task.linearization()
    assert np.abs(np.linalg.eigvals(A20 + B20 @ task.pd_gain())).max() < 0.95
    assert np.abs(np.linalg.eigvals(A20 + B20 @ task.pd_gain(3.0, 1.0))).max() > 1.0
    with pytest.raises(ValueError, match="natural_frequency"):
        task.pd_gain(0.0)


def test_pd_gain_balances_from_the_thesis_start_states():
    """Sec. 5.4's setting (initial std 0.3, torque noise 4 N m) and Sec. 4.2.3's (0.1, 0.5):
    no rollout falls, and over the second half the joint angles' RMS deviation from upright is
    below the initial σ (0.256 and 0.040 over 30 rollouts measured over a grid of gains)."""
    rng = np.random.default_rng(0)
    for s0, noise in ((0.3, 4.0), (0.1, 0.5)):
        task = make("balancing", initial_std=s0, torque_noise_std=noise, n_steps=40)
        G = task.pd_gain().ravel()
        trajs = [task.rollout(G, rng=rng) for _ in range(10)]
        assert not any(t.failed for t in trajs)
        q = np.array([t.states[20:, :4] - UPRIGHT for t in trajs])
        assert np.sqrt((q**2).mean()) < s0


def test_collect_balancing_with_a_fixed_gain():
    task = make("balancing", n_steps=6, torque_noise_std=0.5, initial_std=0.1)
    G = task.pd_gain()
    data = collect_balancing(task, 3, np.random.default_rng(0), gain=G)
    assert np.array_equal(data["omegas"], np.tile(G.ravel(), (3, 1)))
    # the commanded torque is G x̃ at every recorded step
    tol = _feedback_tol(data["x"], G)
    np.testing.assert_allclose(data["u"], (data["x"] - X_UP) @ G.T, rtol=0, atol=tol)
    with pytest.raises(ValueError, match="gain: expected shape"):
        collect_balancing(task, 1, np.random.default_rng(0), gain=np.zeros(31))
    with pytest.raises(ValueError, match="not both"):
        collect_balancing(task, 1, np.random.default_rng(0), gain=G, policy=task.lqr_policy())


def test_rollout_from_starts_at_x0_and_tracks_the_reference_law():
    task = make("balancing", n_steps=8, torque_noise_std=0.0)
    G = task.pd_gain().ravel()
    x0 = X_UP + 0.05 * np.arange(8) / 8
    a, b = task.rollout_from(G, x0, rng=0), task.rollout_from(G, x0, rng=1)
    np.testing.assert_array_equal(a.states[0], x0)
    np.testing.assert_array_equal(a.states, b.states)  # no noise: x_0 fixes the episode
    # the default reference is the upright feedback of rollout()
    np.testing.assert_allclose(a.controls, (a.states - X_UP) @ task.gain_matrix(G).T)
    T1 = task.n_steps + 1
    ref = X_UP + 0.1 * np.sin(np.linspace(0, 3, T1))[:, None]
    ff = np.full((T1, 4), 2.0)
    c = task.rollout_from(G, x0, rng=0, reference=ref, feedforward=ff)
    np.testing.assert_allclose(c.controls, (c.states - ref) @ task.gain_matrix(G).T + ff)
    assert not np.allclose(c.states, a.states)
    with pytest.raises(ValueError, match="reference"):
        task.rollout_from(G, x0, reference=ref[:-1])
    with pytest.raises(ValueError, match="initial_state"):
        task.rollout_from(G, x0[:4])
    # rollout() afterwards draws its own x_0 again
    assert not np.array_equal(task.rollout(G, rng=0).states[0], x0)


def test_swing_reference_feedforward_is_the_inverse_dynamics_and_tracks():
    """Independent check of u_ff: with no feedback (G = 0), no noise and x_0 = r_0 the robot
    driven by u_ff alone follows the reference for a while (the 50 ms hold of u_ff is the
    only error); with the PD it tracks it over the whole horizon."""
    task = make("balancing", n_steps=40, torque_noise_std=0.0)
    ref, ff = task.swing_reference(0.6)
    assert ref.shape == (41, 8) and ff.shape == (41, 4)
    np.testing.assert_allclose(ref[0, :4], UPRIGHT + 0.6 * np.sin([0.0, 0.5, 1.0, 1.5]))
    open_loop = task.rollout_from(np.zeros(32), ref[0], rng=0, reference=ref, feedforward=ff)
    early = np.abs(open_loop.states[:4, :4] - ref[:4, :4]).max()
    assert early < 0.05
    tracked = task.rollout_from(
        task.pd_gain().ravel(), ref[0], rng=0, reference=ref, feedforward=ff
    )
    assert np.abs(tracked.states[:, :4] - ref[:, :4]).max() < 0.1
    # the sampler policy is the same law
    G = torch.as_tensor(task.pd_gain()[None])
    policy = feedback_policy(G, reference=ref, feedforward=ff)
    x = torch.as_tensor(tracked.states[5:6])
    np.testing.assert_allclose(policy(5, x, torch.tensor([0])).numpy()[0], tracked.controls[5])
    with pytest.raises(ValueError, match="period"):
        task.swing_reference(0.5, period=0.0)


def test_data_helpers_thread_an_integer_seed_through_every_draw():
    """An int seed is one stream: every rollout gets its own start state and noise, and the
    same seed gives the same data (the stream is not restarted for every rollout)."""
    task = make("balancing", n_steps=3, torque_noise_std=0.5)
    data = collect_balancing(task, 3, 0)
    starts = {tuple(t.info["initial_state"]) for t in data["trajectories"]}
    assert len(starts) == 3
    again = collect_balancing(task, 3, 0)
    np.testing.assert_array_equal(again["x"], data["x"])
    gains = random_lqr_gains(task, 2, 1.0, 1e-3, 5)
    np.testing.assert_array_equal(gains, random_lqr_gains(task, 2, 1.0, 1e-3, 5))
    assert not np.array_equal(gains[0], gains[1])
    with pytest.raises(ValueError, match="n"):
        random_lqr_gains(task, 1.5, 1.0, 1e-3, 0)
    with pytest.raises(ValueError, match="spread"):
        random_lqr_gains(task, 1, np.nan, 1e-3, 0)


def test_design_policy_explores_along_balancing_gains():
    """π(ω) from LQR designs: the same seed gives the same policy; its covariance is
    symmetric positive definite and scales with c²; most samples balance at upright although
    the exploration reaches the tight LQR gain (isotropic 3% exploration does not balance)."""
    task = make("balancing")
    mean = 0.8 * task.lqr_gain(control_weight=1.0)
    a = design_policy(task, mean, exploration=0.7, n_designs=100, rng=3)
    b = design_policy(task, mean.ravel(), exploration=0.7, n_designs=100, rng=3)
    np.testing.assert_array_equal(a.cov, b.cov)
    np.testing.assert_array_equal(a.mean, mean.ravel())
    np.testing.assert_allclose(a.cov, a.cov.T, rtol=0, atol=0)
    assert np.linalg.eigvalsh(a.cov).min() > 0
    c = design_policy(task, mean, exploration=1.4, n_designs=100, rng=3)
    # the same designs: c² (1.4² vs 4 · 0.7², each off by an ulp), the product, the
    # symmetrisation and × 4, relatively
    np.testing.assert_allclose(c.cov, 4.0 * a.cov, rtol=fp_tol(4))
    A, B = task.linearization()
    w = a.sample(np.zeros((200, 0)), rng=np.random.default_rng(0))
    stable = np.mean([np.abs(np.linalg.eigvals(A + B @ x.reshape(4, 8))).max() < 1 for x in w])
    assert stable > 0.3  # measured 0.5 (isotropic 3% of |G|: 0 of 50)
    d = task.lqr_gain(control_weight=1e-4).ravel() - a.mean
    iso = task.lqr_policy(1.0, 0.005)  # an isotropic π₀: 0.5% of |G| entry-wise
    far = np.sqrt(d @ np.linalg.solve(iso.cov, d))
    near = np.sqrt(d @ np.linalg.solve(a.cov, d))
    assert near < 0.05 * far  # measured 35 against ≈ 2000 standard deviations


def test_design_policy_names_bad_arguments():
    task = make("balancing")
    g = task.lqr_gain(control_weight=1.0)
    with pytest.raises(ValueError, match="mean"):
        design_policy(task, np.zeros(31))
    with pytest.raises(ValueError, match="exploration"):
        design_policy(task, g, exploration=0.0)
    with pytest.raises(ValueError, match="n_designs"):
        design_policy(task, g, n_designs=1)
    with pytest.raises(ValueError, match="scale_std"):
        design_policy(task, g, scale_std=-1.0)


def test_a_diverged_rollout_keeps_its_states_before_the_divergence():
    """The failed trajectory holds x_0 … x_{t−1}, all within the limits, and they are the
    same states (bit for bit: the same computation and random stream) as a run that ends at
    step t with limits it does not reach."""
    task = make("balancing")
    gain = -task.lqr_gain().ravel()  # the LQR gain with the wrong sign: it topples the robot
    with pytest.warns(RuntimeWarning, match="diverged: a joint speed exceeds 100 rad/s"):
        failed = task.rollout(gain, rng=0)
    assert failed.failed and failed.has_transitions
    assert task.reward(failed) == task.worst_reward
    k = failed.n_steps
    assert failed.info["steps_before_failure"] == k - 1
    assert np.abs(failed.states[:, 4:]).max() <= task.max_joint_speed
    assert np.abs(failed.states[:, :4] - UPRIGHT).max() <= task.max_angle
    wide = make("balancing", n_steps=k, max_joint_speed=1e6, max_angle=1e6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the wide limits are not reached by step k
        whole = wide.rollout(gain, rng=0)
    assert np.abs(whole.states[k, 4:]).max() > task.max_joint_speed  # x_k is where it stopped
    np.testing.assert_array_equal(failed.states, whole.states[:k])
    np.testing.assert_array_equal(failed.controls, whole.controls[:k])
    np.testing.assert_array_equal(
        failed.signals["torque_noise"], whole.signals["torque_noise"][: k - 1]
    )
    x, u, xn = task.transitions(failed)
    np.testing.assert_array_equal(xn, whole.states[1:k])
    assert x.shape == (k - 1, 8) and u.shape == (k - 1, 4)


def test_a_failure_checks_its_partial_trajectory():
    one_row = Trajectory(np.zeros(1), np.zeros((1, 8)), np.zeros((1, 4)))
    with pytest.raises(ValueError, match="partial: expected a Trajectory with at least two"):
        SimulationFailure("diverged", partial=one_row)
    with pytest.raises(ValueError, match="partial"):
        SimulationFailure("diverged", partial=np.zeros((3, 8)))


def test_the_divergence_rule_on_paths_is_the_rule_a_rollout_is_stopped_by():
    """``failed_batch`` flags exactly the paths a rollout would have been stopped on: the
    whole run (with limits it never reaches) of a gain that topples the robot, not its states
    before the stop, not a balancing run; non-finite states count as diverged."""
    task = make("balancing")
    gain = -task.lqr_gain().ravel()
    with pytest.warns(RuntimeWarning, match="diverged"):
        failed = task.rollout(gain, rng=0)
    k = failed.n_steps
    wide = make("balancing", n_steps=k, max_joint_speed=1e6, max_angle=1e6)
    whole = wide.rollout(gain, rng=0)
    good = task.rollout(task.lqr_gain().ravel(), rng=0)
    assert not good.failed
    nan = good.states.copy()
    nan[3, 5] = np.nan
    paths = np.stack(
        [
            whole.states,
            np.vstack([failed.states, failed.states[-1:]]),
            good.states[: k + 1],
            nan[: k + 1],
        ]
    )
    np.testing.assert_array_equal(task.failed_batch(paths), [True, False, False, True])
    far = good.states[None, : k + 1].copy()
    far[0, 2, 1] = UPRIGHT[1] + 1.01 * task.max_angle  # beyond the angle limit only
    assert task.failed_batch(far)[0] and not wide.failed_batch(far)[0]
    with pytest.raises(ValueError, match="states: expected shape"):
        task.failed_batch(np.zeros((2, 5, 6)))
