"""Pendulum (Sec. 5.4): dynamics against closed forms and independent integration."""

import numpy as np
import pytest
from _tolerances import fp_tol
from scipy.integrate import solve_ivp

from skillkit.tasks import make
from skillkit.tasks.pendulum import GRAVITY, TORQUE_LIMIT, feedback_torque, pendulum_dynamics


def test_rk4_step_matches_adaptive_ode_solver():
    rng = np.random.default_rng(0)
    for _ in range(5):
        x0 = rng.uniform([-3, -4], [3, 4])
        u = rng.uniform(-3, 3)
        sol = solve_ivp(
            lambda t, x, u=u: [x[1], -9.81 * np.sin(x[0]) + u], (0, 0.1), x0, rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(pendulum_dynamics(x0, u), sol.y[:, -1], atol=1e-8)


def test_small_angle_matches_linear_oscillator():
    # α̈ = −g α: α(t) = α0 cos(√g t) for α̇0 = 0, u = 0.
    a0, w = 1e-4, np.sqrt(9.81)
    x = pendulum_dynamics(np.array([a0, 0.0]), 0.0)
    assert x[0] == pytest.approx(a0 * np.cos(w * 0.1), rel=1e-6)
    assert x[1] == pytest.approx(-a0 * w * np.sin(w * 0.1), rel=1e-6)


def test_dynamics_is_vectorised():
    x = np.random.default_rng(1).normal(size=(7, 2))
    u = np.linspace(-2, 2, 7)
    batch = pendulum_dynamics(x, u)
    # Row by row the same IEEE operations, but for sin, which numpy may evaluate by another
    # SIMD path for the strided batch than for one state (a few ulp): 10 RK4 substeps × 4
    # stages of sin, each entering the state as g h δ (h = 0.01 s), the flow's Jacobian ~1.
    tol = fp_tol(10 * 4, scale=GRAVITY * 0.01)
    for i in range(7):
        np.testing.assert_allclose(batch[i], pendulum_dynamics(x[i], u[i]), rtol=0, atol=tol)


def test_torque_limit_is_the_actuator_limit():
    u = feedback_torque(np.array([[2.0, 0.0], [0.1, 0.0]]), np.array([-3.0, -1.0]))
    np.testing.assert_allclose(u, [-TORQUE_LIMIT, -0.3])


def test_controller_stabilises_from_small_angles_and_reward_matches_definition():
    task = make("pendulum", control_noise=0.0)
    s = np.array([0.3, 0.0])
    traj = task.rollout([-3.0, -1.0], s, rng=0)
    assert abs(traj.states[-1, 0]) < abs(s[0]) / 3
    x = traj.states[1:]
    assert task.reward(traj, s) == pytest.approx(-np.sum(x[:, 0] ** 2 + 0.1 * x[:, 1] ** 2))
    # The controls recorded are the ones applied: replaying them reproduces the states, exactly
    # (the rollout calls the same pendulum_dynamics on the same floats, dt = 0.1 as here).
    assert task.dt == 0.1
    replay = traj.states[0]
    for t in range(task.horizon):
        replay = pendulum_dynamics(replay, traj.controls[t, 0])
        np.testing.assert_array_equal(replay, traj.states[t + 1])


def test_control_noise_has_the_stated_spread():
    task = make("pendulum", control_noise=0.05, horizon=1)
    s = np.array([0.01, 0.0])  # far from the torque limit
    us = np.array([task.rollout([-3.0, -1.0], s, rng=i).controls[0, 0] for i in range(400)])
    assert np.std(us) == pytest.approx(0.05, rel=0.15)
    assert np.mean(us) == pytest.approx(-0.03, abs=0.01)


def test_stochastic_variant_has_wide_reward_distribution():
    task = make("pendulum-stochastic")
    s = np.array([1.0, 0.0])
    rewards = [task.reward(task.rollout([-3.0, -1.0], s, rng=i), s) for i in range(30)]
    quiet = make("pendulum")
    quiet_rewards = [quiet.reward(quiet.rollout([-3.0, -1.0], s, rng=i), s) for i in range(30)]
    assert np.std(rewards) > 5 * np.std(quiet_rewards)


@pytest.mark.parametrize(
    "kwargs, arg",
    [
        ({"horizon": 0}, "horizon"),
        ({"horizon": 2.5}, "horizon"),  # not truncated to 2 steps
        ({"control_noise": -1}, "control_noise"),
        ({"control_noise": np.inf}, "control_noise"),
        ({"dt": 0}, "dt"),
        ({"alpha_range": -1.0}, "alpha_range"),  # would give an empty context box
        ({"velocity_range": np.nan}, "velocity_range"),  # would give NaN contexts
    ],
)
def test_bad_settings_raise(kwargs, arg):
    with pytest.raises(ValueError, match=arg):
        make("pendulum", **kwargs)
