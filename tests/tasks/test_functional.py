"""A task from a few functions: FunctionTask (model-free) and TrajectoryTask
(model-based) run through learn() with contextual REPS, CrKR, RWR, GPREPS and CMA-ES; bad
input is named; a rollout that raises becomes a failed rollout and the run goes on."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from skillkit.models.kernels import Linear
from skillkit.models.linear import LinearGaussianModel
from skillkit.search.cmaes import CMAES
from skillkit.search.crkr import CrKR
from skillkit.search.gpreps import GPREPS, GPREPSSettings, TrajectoryRewardModel
from skillkit.search.loop import learn
from skillkit.search.reps import ContextualREPS
from skillkit.search.rwr import RWR
from skillkit.tasks.base import Task
from skillkit.tasks.functional import FunctionTask, TrajectoryTask

# ------------------------------------------------------------------ a black box: the reward only
LOW, HIGH = [-1.0, -1.0], [1.0, 1.0]


def _black_box(omega, context, rng):
    """R = −‖ω − 2 s‖² plus a little noise (the optimal mean is ω = 2 s)."""
    return -float(np.sum((omega - 2.0 * context) ** 2)) + 0.01 * rng.standard_normal()


def _flaky(omega, context, rng):
    """Fails on one rollout in five, as a robot might."""
    if rng.random() < 0.2:
        raise RuntimeError("robot lost the ball")
    return _black_box(omega, context, rng)


def _model_free(rollout=_black_box, **kwargs) -> FunctionTask:
    return FunctionTask(rollout, 2, context_low=LOW, context_high=HIGH, **kwargs)


# ------------------------------------------------------------------ a simulator: the trajectory
# A point on a line driven to the target s: x_{t+1} = x_t + dt u_t, u_t = ω₀ (s − x_t) + ω₁.
DT, HORIZON = 0.2, 8


def _control(t, x, omegas, contexts):
    return omegas[:, :1] * (contexts - x) + omegas[:, 1:2]


def _simulate(omega, context, rng):
    x = np.empty((HORIZON + 1, 1))
    u = np.zeros((HORIZON + 1, 1))
    x[0] = 0.0
    for t in range(HORIZON + 1):
        u[t] = _control(t, x[t][None], omega[None], context[None])[0]
        if t < HORIZON:
            x[t + 1] = x[t] + DT * u[t]
    return x, u


def _reward(states, controls, contexts):
    return -np.sum((states[:, 1:, 0] - contexts[:, :1]) ** 2, axis=1)


def _start(context, n, rng):
    return np.zeros((n, 1))


def _model_based(**kwargs) -> TrajectoryTask:
    kwargs.setdefault("controller", _control)
    kwargs.setdefault("initial_states", _start)
    return TrajectoryTask(
        _simulate,
        _reward,
        2,
        1,
        1,
        dt=DT,
        context_low=[0.5],
        context_high=[1.5],
        initial_mean=[0.5, 0.0],
        initial_std=0.5,
        **kwargs,
    )


# ------------------------------------------------------------ REPS, GPREPS and CMA-ES end to end
def test_a_task_from_functions_runs_through_reps_gpreps_and_cmaes():
    task = _model_based()
    reps = learn(task, ContextualREPS(task.initial_policy(), 1.0), 4, 15, rng=0, progress=False)
    assert reps["mean_reward"][-1] > reps["mean_reward"][0]
    settings = GPREPSSettings(n_artificial=40, n_trajectories=1, context_model="prior")
    # The linear-Gaussian forward model: exact for these dynamics, and fast (a GP model, the
    # default, runs the same code path: fit on task.transitions, predict through the
    # task's initial_states, controller and reward).
    model = TrajectoryRewardModel(task, LinearGaussianModel)
    gpreps = GPREPS(task.initial_policy(), model, settings, rng=1, task=task)
    res = learn(task, gpreps, 3, 2, rng=0, initial_rollouts=4, progress=False)
    diag = res["diagnostics"][-1]
    assert diag.n_real == 8 and diag.model_fit["n_data"] == 8 * HORIZON
    # The model predicts the new real rollouts' rewards (deterministic, linear dynamics).
    assert abs(diag.prediction_bias) < 1e-6 * (1.0 + abs(diag.real_reward))
    assert res["mean_reward"][-1] > res["mean_reward"][0]
    cmaes = CMAES.for_task(task, rng=2)
    res = learn(task, cmaes, 3, cmaes.rollouts_per_update, rng=0, progress=False)
    assert len(res["diagnostics"]) == 3 and np.all(np.isfinite(res["mean_reward"]))


@pytest.mark.parametrize("method", ["reps", "crkr", "rwr", "cmaes"])
def test_a_black_box_runs_through_every_model_free_method(method):
    task = _model_free()
    pol = task.initial_policy()
    alg = {
        "reps": lambda: ContextualREPS(pol, 0.5),
        "crkr": lambda: CrKR(pol, Linear(), lam=0.5),
        "rwr": lambda: RWR(pol),
        "cmaes": lambda: CMAES.for_task(task, rng=0),
    }[method]()
    n = alg.rollouts_per_update if method == "cmaes" else 20
    res = learn(task, alg, 5, n, rng=0, progress=False)
    assert res["mean_reward"][-1] > res["mean_reward"][0]


# ------------------------------------------------------------------ failures are kept, not lost
def test_a_rollout_that_raises_is_a_failed_rollout_and_the_run_goes_on():
    task = _model_free(_flaky, worst_reward=-50.0)
    with pytest.warns(RuntimeWarning, match="robot lost the ball"):
        traj = next(
            t for t in (task.rollout([0.0, 0.0], [0.1, 0.1], rng=i) for i in range(50)) if t.failed
        )
    assert "rollout raised RuntimeError: robot lost the ball" in traj.message
    assert task.reward(traj, [0.1, 0.1]) == -50.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = learn(task, ContextualREPS(task.initial_policy(), 0.5), 3, 20, rng=0, progress=False)
    assert res["n_failed"].sum() > 0 and len(res["diagnostics"]) == 3


def test_non_finite_results_are_failed_rollouts():
    task = _model_free(lambda omega, context, rng: float("nan"))
    with pytest.warns(RuntimeWarning, match="non-finite reward"):
        traj = task.rollout([0.0, 0.0], [0.0, 0.0])
    assert traj.failed and task.reward(traj, [0.0, 0.0]) == task.worst_reward

    def diverging(omega, context, rng):
        x, u = _simulate(omega, context, rng)
        x[-1] = np.inf
        return x, u

    mb = TrajectoryTask(diverging, _reward, 2, 1, 1, context_low=[0.5], context_high=[1.5])
    with pytest.warns(RuntimeWarning, match="non-finite values"):
        assert mb.rollout([0.5, 0.0], [1.0]).failed


# ------------------------------------------------------------------ bad input is named
def test_what_the_functions_return_is_checked_and_named():
    bad_reward = _model_free(lambda omega, context, rng: np.ones(2))
    with pytest.raises(ValueError, match="rollout: expected a scalar reward"):
        bad_reward.rollout([0.0, 0.0], [0.0, 0.0])
    pair = _model_free(lambda omega, context, rng: (np.zeros((2, 1)), np.zeros((2, 1))))
    with pytest.raises(ValueError, match="rollout: .*TrajectoryTask"):
        pair.rollout([0.0, 0.0], [0.0, 0.0])

    def flat_states(omega, context, rng):
        return np.zeros(5), np.zeros((5, 1))

    task = TrajectoryTask(flat_states, _reward, 2, 1, 1, context_low=[0.5], context_high=[1.5])
    with pytest.raises(ValueError, match=r"rollout \(states\): expected shape \(\?, 1\)"):
        task.rollout([0.0, 0.0], [1.0])

    def short_controls(omega, context, rng):
        return np.zeros((5, 1)), np.zeros((4, 1))

    task = TrajectoryTask(short_controls, _reward, 2, 1, 1, context_low=[0.5], context_high=[1.5])
    with pytest.raises(ValueError, match=r"rollout \(controls\): expected shape \(5, 1\)"):
        task.rollout([0.0, 0.0], [1.0])

    task = _model_based()
    traj = task.rollout([0.5, 0.0], [1.0], rng=0)
    wrong = _model_based()
    wrong._reward_fn = lambda states, controls, contexts: np.zeros((states.shape[0], 2))
    with pytest.raises(ValueError, match=r"reward: expected shape \(1,\)"):
        wrong.reward(traj, [1.0])
    wrong = _model_based(controller=lambda t, x, omegas, contexts: omegas)
    policy = wrong.controller(np.zeros((2, 2)), np.ones((2, 1)))
    with pytest.raises(ValueError, match=r"controller: expected shape \(3, 1\)"):
        policy(0, torch.zeros(3, 1, dtype=torch.float64), torch.tensor([0, 1, 1]))
    wrong = _model_based(initial_states=lambda context, n, rng: np.zeros(n))
    with pytest.raises(ValueError, match="initial_states: expected shape"):
        wrong.initial_states([1.0], 3)
    outside = _model_free(context_sampler=lambda rng, n: np.full((n, 2), 3.0))
    with pytest.raises(ValueError, match="context_sampler: .*outside"):
        outside.sample_context(0, n=4)


def test_constructor_arguments_are_checked_and_named():
    with pytest.raises(ValueError, match="rollout: expected a callable"):
        FunctionTask("sim", 2)
    with pytest.raises(ValueError, match="parameter_dim"):
        FunctionTask(_black_box, 0)
    with pytest.raises(ValueError, match="context_low, context_high: give both"):
        FunctionTask(_black_box, 2, context_low=LOW)
    with pytest.raises(ValueError, match="context_high: expected ≥ context_low"):
        FunctionTask(_black_box, 2, context_low=HIGH, context_high=LOW)
    with pytest.raises(ValueError, match="context_high: expected shape"):
        FunctionTask(_black_box, 2, context_low=LOW, context_high=[1.0])
    with pytest.raises(ValueError, match="initial_std"):
        FunctionTask(_black_box, 2, initial_std=-1.0)
    with pytest.raises(ValueError, match="initial_mean: expected shape"):
        FunctionTask(_black_box, 2, initial_mean=[0.0])
    with pytest.raises(ValueError, match="reward: expected a callable"):
        TrajectoryTask(_simulate, None, 2, 1, 1)
    with pytest.raises(ValueError, match="state_dim"):
        TrajectoryTask(_simulate, _reward, 2, 0, 1)


# ------------------------------------------------------------------ the Task contract holds
def test_black_box_rewards_belong_to_their_own_context():
    task = _model_free()
    traj = task.rollout([0.2, 0.4], [0.1, 0.2], rng=3)
    assert task.reward(traj, [0.1, 0.2]) == task.evaluate([0.2, 0.4], [0.1, 0.2], rng=3)[0]
    with pytest.raises(ValueError, match="context: a black-box rollout"):
        task.reward(traj, [0.5, 0.5])
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(task, ContextualREPS(task.initial_policy(), 0.5), 1, 5, 0, extra_contexts=2)
    with pytest.raises(ValueError, match="outside"):
        task.rollout([0.0, 0.0], [2.0, 0.0])
    free = FunctionTask(
        lambda omega, context, rng: -float(omega @ omega) if context is None else 0, 1
    )
    assert free.context_dim == 0 and free.evaluate(np.ones(1))[0] == -1.0


def test_model_based_task_keeps_the_contract():
    task = _model_based()
    assert isinstance(task, Task) and task.supports_model_rollout
    s = np.array([1.2])
    a, b = task.rollout([0.5, 0.1], s, rng=4), task.rollout([0.5, 0.1], s, rng=4)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_allclose(a.times, DT * np.arange(HORIZON + 1))
    assert task.controller_mismatch([0.5, 0.1], s, a) < 1e-12
    assert task.controller_mismatch([0.9, 0.1], s, a) > 0.01  # another policy: detected
    x, u, xn = task.transitions(a)
    np.testing.assert_array_equal(x[1:], xn[:-1])
    np.testing.assert_array_equal(task.initial_states(s, 3, rng=0), np.zeros((3, 1)))
    assert task.reward(a, s) == pytest.approx(float(_reward(a.states[None], None, s[None])[0]))
    policy = task.controller(np.array([[0.5, 0.1]]), s[None], dtype=torch.float32)
    got = policy(0, torch.zeros(1, 1, dtype=torch.float32), torch.tensor([0]))
    assert got.dtype == torch.float32 and got.shape == (1, 1)
    assert got.item() == pytest.approx(0.5 * 1.2 + 0.1, rel=1e-6)


def test_without_controller_there_is_no_model_rollout():
    task = _model_based(controller=None)
    assert not task.supports_model_rollout
    assert "controller" in task.no_model_rollout_reason
    with pytest.raises(ValueError, match="no step-based model rollouts"):
        TrajectoryRewardModel(task)
    with pytest.raises(NotImplementedError, match="not available"):
        task.initial_states([1.0], 2)


def _returns_a_string(omega, context, rng):
    return "-1.23"


@pytest.mark.parametrize(
    ("value", "type_name"),
    [
        ("-1.23", "str"),
        (b"-1", "bytes"),
        (True, "bool"),
        (np.bool_(False), "bool"),
        (1 + 0j, "complex"),
        (np.array("-1.0"), "ndarray"),
    ],
)
def test_a_reward_that_is_no_real_number_is_refused_naming_function_and_type(value, type_name):
    task = _model_free(lambda omega, context, rng: value)
    with pytest.raises(ValueError, match=rf"rollout \(.*<lambda>\): expected a real .*{type_name}"):
        task.rollout([0.0, 0.0], [0.0, 0.0])
    task = _model_free(_returns_a_string)
    with pytest.raises(ValueError, match=r"rollout \(_returns_a_string\): .* got str '-1.23'"):
        task.rollout([0.0, 0.0], [0.0, 0.0])


@pytest.mark.parametrize("value", [-2, -2.0, np.float32(-2.0), np.int64(-2), np.array(-2.0)])
def test_real_rewards_of_any_real_type_are_accepted(value):
    task = _model_free(lambda omega, context, rng: value)
    traj = task.rollout([0.0, 0.0], [0.0, 0.0])
    assert task.reward(traj, [0.0, 0.0]) == -2.0
    assert type(task.reward(traj, [0.0, 0.0])) is float
