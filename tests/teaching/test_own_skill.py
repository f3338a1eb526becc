"""skillkit.teaching.own_skill: notebook 06's sizes, context grid, mapping figure and
comparison table."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search import ContextualREPS, learn
from skillkit.search.cmaes import CMAES
from skillkit.tasks.functional import FunctionTask, TrajectoryTask
from skillkit.teaching import own_skill

LOW, HIGH = [0.0, -1.0], [1.0, 1.0]


# ------------------------------------------------------------------ a tiny goal-reaching task
def _jump(omega, context, rng):
    """The state jumps from 0 to ω plus a little noise: the outcome is ω + noise."""
    end = omega + 0.01 * rng.standard_normal(2)
    return np.stack([np.zeros(2), end]), np.zeros((2, 0))


def _miss(states, controls, contexts):
    return -np.sum((states[:, -1] - contexts) ** 2, axis=1)


def _end(trajectory):
    return trajectory.states[-1]


def _task(rollout=_jump) -> TrajectoryTask:
    return TrajectoryTask(
        rollout, _miss, 2, 2, 0, context_low=LOW, context_high=HIGH, initial_std=0.5
    )


def _identity_policy() -> LinearGaussianPolicy:
    """ω(s) = s: the optimal policy of the tiny task."""
    return LinearGaussianPolicy(np.zeros(2), 0.01 * np.eye(2), gain=np.eye(2), context_dim=2)


def _curve(x, y, failed) -> dict:
    return {"rollouts": np.array(x), "mean_reward": np.array(y), "n_failed": np.array(failed)}


# ------------------------------------------------------------------ sizes
def test_sizes_grow_from_smoke_to_paper_and_unknown_scales_are_named():
    smoke, quick, paper = (own_skill.run_sizes(s) for s in ("smoke", "quick", "paper"))
    for field in dataclasses.fields(own_skill.RunSizes):
        assert getattr(smoke, field.name) <= getattr(quick, field.name), field.name
    for name in ("reps_updates", "cmaes_generations", "gpreps_updates", "n_trajectories"):
        assert getattr(quick, name) <= getattr(paper, name), name
    # "paper" is the thesis's GPREPS setting (Table 4.1 on throwing, Sec. 4.3.2)
    assert (paper.gpreps_initial, paper.gpreps_rollouts) == (10, 1)
    assert (paper.n_artificial, paper.n_trajectories, paper.gp_steps) == (500, 25, 150)
    with pytest.raises(ValueError, match="scale: expected one of"):
        own_skill.run_sizes("huge")


# ------------------------------------------------------------------ contexts
def test_context_grid_spans_the_task_range():
    grid = own_skill.context_grid(_task(), 3)
    assert grid.shape == (9, 2)
    np.testing.assert_array_equal(grid[0], LOW)
    np.testing.assert_array_equal(grid[-1], HIGH)
    np.testing.assert_array_equal(grid[1], [0.0, 0.0])  # the last dimension varies fastest
    np.testing.assert_array_equal(own_skill.context_grid(_task(), 1), [[0.5, 0.0]])


def test_context_grid_names_bad_input():
    with pytest.raises(ValueError, match="task: expected a Task"):
        own_skill.context_grid("task", 3)
    free = FunctionTask(lambda omega, context, rng: 0.0, 1)
    with pytest.raises(ValueError, match="has no context"):
        own_skill.context_grid(free, 3)
    with pytest.raises(ValueError, match="n_per_dim"):
        own_skill.context_grid(_task(), 0)


# ------------------------------------------------------------------ the mapping figure
def _traces(fig, name):
    return [t for t in fig.data if t.name == name]


def test_mapping_figure_draws_omega_and_the_segments_to_the_outcomes():
    task, grid = _task(), own_skill.context_grid(_task(), 2)
    fig = own_skill.mapping_figure(
        task, {"identity": _identity_policy(), "zero": task.initial_policy()}, _end, grid
    )
    left, right = _traces(fig, "identity")
    np.testing.assert_allclose(np.column_stack([left.x, left.y]), grid)  # ω(s) = s
    segments = np.column_stack([right.x, right.y]).reshape(4, 3, 2)
    np.testing.assert_allclose(segments[:, 0], grid)  # from each context …
    np.testing.assert_allclose(segments[:, 1], grid, atol=0.05)  # … to where it ended (≈ s)
    assert np.all(np.isnan(segments[:, 2]))  # a gap between segments
    zero = np.column_stack([_traces(fig, "zero")[1].x, _traces(fig, "zero")[1].y])
    np.testing.assert_allclose(zero.reshape(4, 3, 2)[:, 1], 0.0, atol=0.05)
    (targets,) = _traces(fig, "contexts s")
    np.testing.assert_allclose(np.column_stack([targets.x, targets.y]), grid)
    assert fig.data[-1].name == "contexts s"  # drawn over the segments


def test_mapping_figure_rolls_every_policy_out_on_the_same_noise():
    task, grid = _task(), own_skill.context_grid(_task(), 2)
    policy = _identity_policy()
    fig = own_skill.mapping_figure(task, {"a": policy, "b": policy}, _end, grid, seed=3)
    (a,), (b,) = _traces(fig, "a")[1:], _traces(fig, "b")[1:]
    np.testing.assert_array_equal(a.x, b.x)
    again = own_skill.mapping_figure(task, {"a": policy}, _end, grid, seed=3)
    np.testing.assert_array_equal(_traces(again, "a")[1].y, a.y)


def test_mapping_figure_draws_a_failed_rollout_as_a_gap():
    def fails_right(omega, context, rng):
        if context[0] > 0.5:
            raise RuntimeError("lost")
        return _jump(omega, context, rng)

    task, grid = _task(fails_right), own_skill.context_grid(_task(), 2)
    with pytest.warns(RuntimeWarning, match="rollout raised RuntimeError: lost"):
        fig = own_skill.mapping_figure(task, {"p": _identity_policy()}, _end, grid)
    ends = np.column_stack([_traces(fig, "p")[1].x, _traces(fig, "p")[1].y]).reshape(4, 3, 2)
    assert np.all(np.isfinite(ends[:2, 1])) and np.all(np.isnan(ends[2:, 1]))


def test_mapping_figure_names_bad_input():
    task, grid, pol = _task(), own_skill.context_grid(_task(), 2), {"p": _identity_policy()}
    one_d = TrajectoryTask(_jump, _miss, 2, 2, 0, context_low=[0.0], context_high=[1.0])
    with pytest.raises(ValueError, match="task: .*context_dim = 1"):
        own_skill.mapping_figure(one_d, pol, _end, [[0.5]])
    with pytest.raises(ValueError, match="policies: expected a non-empty mapping"):
        own_skill.mapping_figure(task, {}, _end, grid)
    with pytest.raises(ValueError, match=r"policies\['p'\]: expected a policy with mean_of"):
        own_skill.mapping_figure(task, {"p": "policy"}, _end, grid)
    with pytest.raises(ValueError, match="outcome: expected a callable"):
        own_skill.mapping_figure(task, pol, None, grid)
    with pytest.raises(ValueError, match=r"outcome: expected shape \(2,\)"):
        own_skill.mapping_figure(task, pol, lambda trajectory: trajectory.states, grid)
    with pytest.raises(ValueError, match="contexts: expected shape"):
        own_skill.mapping_figure(task, pol, _end, [0.5, 0.5])
    with pytest.raises(ValueError, match="omega_dims"):
        own_skill.mapping_figure(task, pol, _end, grid, omega_dims=(0, 2))
    with pytest.raises(ValueError, match="omega_dims"):
        own_skill.mapping_figure(task, pol, _end, grid, omega_dims=(1, 1))


def test_mapping_figure_draws_with_matplotlib_too():
    task = _task()
    fig = own_skill.mapping_figure(
        task, {"p": _identity_policy()}, _end, own_skill.context_grid(task, 2), backend="matplotlib"
    )
    assert len(fig.axes) == 2


# ------------------------------------------------------------------ the comparison table
def test_comparison_table_reads_rewards_and_rollouts_to_reach_off_the_curves():
    runs = {
        "fast": _curve([0, 10, 12, 14], [-3.0, -0.5, -0.05, -0.04], [0, 1, 0]),
        "slow": _curve([0, 20, 40], [-3.0, -2.0, -0.5], [0, 0]),
    }
    table = own_skill.comparison_table(runs, levels=[-1.0, -0.1])
    assert list(table.index) == ["fast", "slow"] and table.index.name == "method"
    assert table.loc["fast", "real rollouts"] == 14 and table.loc["slow", "updates"] == 2
    assert table.loc["fast", "reward before"] == -3.0
    assert table.loc["fast", "final reward"] == -0.04 and table.loc["fast", "best reward"] == -0.04
    assert table.loc["fast", "rollouts to R ≥ -1"] == 10
    assert table.loc["fast", "rollouts to R ≥ -0.1"] == 12
    assert table.loc["slow", "rollouts to R ≥ -1"] == 40
    assert np.isnan(table.loc["slow", "rollouts to R ≥ -0.1"])  # not within the run
    assert table.loc["fast", "failed rollouts"] == 1
    assert "rollouts to R ≥ -1" not in own_skill.comparison_table(runs).columns


def test_comparison_table_of_real_learn_runs():
    task = _task()
    grid = own_skill.context_grid(task, 2)
    common = {"rng": 0, "eval_contexts": grid, "eval_seed": 0, "progress": False}
    reps = learn(task, ContextualREPS(task.initial_policy(), 0.5), 3, 10, **common)
    cmaes_algorithm = CMAES.for_task(task, rng=1)
    cmaes = learn(task, cmaes_algorithm, 2, cmaes_algorithm.rollouts_per_update, **common)
    table = own_skill.comparison_table({"REPS": reps, "CMA-ES": cmaes}, levels=[-0.5])
    assert table.loc["REPS", "real rollouts"] == 30
    assert table.loc["CMA-ES", "real rollouts"] == 2 * cmaes_algorithm.rollouts_per_update
    assert table.loc["REPS", "reward before"] == table.loc["CMA-ES", "reward before"]


def test_comparison_table_names_bad_input():
    with pytest.raises(ValueError, match="runs: expected a non-empty mapping"):
        own_skill.comparison_table({})
    with pytest.raises(ValueError, match=r"runs\['a'\]: expected a learn\(\) result"):
        own_skill.comparison_table({"a": [1, 2]})
    with pytest.raises(ValueError, match=r"runs\['a'\]: not a learn\(\) result, missing"):
        own_skill.comparison_table({"a": {"rollouts": [0, 1]}})
    with pytest.raises(ValueError, match=r"mean_reward'\]: expected shape"):
        own_skill.comparison_table({"a": _curve([0, 1], [0.0], [0])})
    with pytest.raises(ValueError, match="levels"):
        own_skill.comparison_table({"a": _curve([0, 1], [0.0, 1.0], [0])}, levels=[np.nan])


def test_failed_rollouts_of_a_run_are_counted():
    def flaky(omega, context, rng):
        if rng.random() < 0.3:
            raise RuntimeError("lost")
        return -float(np.sum((omega - context) ** 2))

    task = FunctionTask(flaky, 2, context_low=LOW, context_high=HIGH, worst_reward=-100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        run = learn(task, ContextualREPS(task.initial_policy(), 0.5), 2, 20, 0, progress=False)
    table = own_skill.comparison_table({"flaky": run})
    assert table.loc["flaky", "failed rollouts"] == run["n_failed"].sum() > 0
