"""The model-free learning loop (Table 3.1): bookkeeping, extra contexts, determinism, bad input."""

import numpy as np
import pytest

from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.search.loop import N_EVAL_CONTEXTS, learn
from skillkit.search.reps import ContextualREPS
from skillkit.tasks.base import Task
from skillkit.trajectory import Trajectory


class Target(Task):
    """R(s, ω) = −‖ω − 2s‖²; the trajectory is ω itself (it does not depend on s)."""

    name = "target"
    context_dim = 2
    parameter_dim = 2
    context_low = np.array([-1.0, -1.0])
    context_high = np.array([1.0, 1.0])
    trajectory_depends_on_context = False

    def _simulate(self, omega, context, rng):
        return Trajectory(np.zeros(1), omega[None, :], np.zeros((1, 0)))

    def _reward(self, trajectory, context):
        return float(-np.sum((trajectory.states[0] - 2 * context) ** 2))

    def initial_policy(self):
        return LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)


class TargetInScene(Target):
    name = "target-in-scene"
    trajectory_depends_on_context = True


class Bowl(Task):
    """Context-free: R(ω) = −‖ω − 1‖²."""

    name = "bowl"
    parameter_dim = 2

    def _simulate(self, omega, context, rng):
        return Trajectory(np.zeros(1), omega[None, :], np.zeros((1, 0)))

    def _reward(self, trajectory, context):
        return float(-np.sum((trajectory.states[0] - 1.0) ** 2))

    def initial_policy(self):
        return GaussianPolicy(np.zeros(2), np.eye(2))


class Recorder:
    """A fake algorithm: fixed policy, records what update receives."""

    def __init__(self, policy):
        self.policy = policy
        self.batches = []

    def update(self, contexts, omegas, rewards):
        self.batches.append((contexts, omegas, rewards))
        return len(rewards)


class Progress:
    def __init__(self):
        self.total, self.count = None, 0

    def reset(self, total):
        self.total, self.count = total, 0

    def update(self, n=1):
        self.count += n


def test_bookkeeping_curves_and_callbacks():
    task = Target()
    alg = Recorder(task.initial_policy())
    bar, calls = Progress(), []
    eval_s = np.array([[0.5, -0.5], [0.0, 1.0]])
    res = learn(
        task,
        alg,
        4,
        6,
        0,
        progress=bar,
        eval_contexts=eval_s,
        callback=lambda k, a: calls.append(k),
    )
    assert bar.total == 4 and bar.count == 4 and calls == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(res["rollouts"], [0, 6, 12, 18, 24])
    np.testing.assert_array_equal(res["explore_rollouts"], [6, 12, 18, 24])
    assert res["diagnostics"] == [6, 6, 6, 6] and np.all(res["n_failed"] == 0)
    # the policy never changes: the mean reward is the initial mean's reward, computed directly
    expected = np.mean([-np.sum((np.zeros(2) - 2 * s) ** 2) for s in eval_s])
    np.testing.assert_allclose(res["mean_reward"], expected)
    for (s, w, r), er in zip(alg.batches, res["explore_reward"], strict=True):
        np.testing.assert_allclose(r, -np.sum((w - 2 * s) ** 2, axis=1))
        assert er == pytest.approx(r.mean())
        assert np.all(np.abs(s) <= 1)
    assert res["policy"] is alg.policy


def test_extra_contexts_rescore_each_trajectory():
    task = Target()
    alg = Recorder(task.initial_policy())
    res = learn(task, alg, 2, 5, 1, extra_contexts=3)
    for s, w, r in alg.batches:
        assert s.shape == (20, 2) and w.shape == (20, 2) and r.shape == (20,)
        # each ω appears once with its own context and then 3 times with fresh ones
        np.testing.assert_array_equal(w[5:], np.repeat(w[:5], 3, axis=0))
        np.testing.assert_allclose(r, -np.sum((w - 2 * s) ** 2, axis=1))
        assert len({tuple(c) for c in s}) == 20
    # the exploratory curve only counts the real rollouts
    assert res["explore_reward"][0] == pytest.approx(alg.batches[0][2][:5].mean())


def test_extra_contexts_refused_when_trajectory_depends_on_context():
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(TargetInScene(), Recorder(Target().initial_policy()), 1, 5, 0, extra_contexts=2)
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(Bowl(), Recorder(Bowl().initial_policy()), 1, 5, 0, extra_contexts=2)


def test_same_seed_same_curves_and_reps_learns():
    task = Target()

    def run(seed):
        alg = ContextualREPS(task.initial_policy(), 0.5, n_reuse_batches=4)
        return learn(task, alg, 15, 20, seed)

    a, b, c = run(3), run(3), run(4)
    for key in ("mean_reward", "explore_reward"):
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(a["explore_reward"], c["explore_reward"])
    np.testing.assert_array_equal(a["policy"].coefficients, b["policy"].coefficients)
    assert a["eval_contexts"].shape == (N_EVAL_CONTEXTS, 2)
    assert a["mean_reward"][-1] > 0.2 * a["mean_reward"][0]  # rewards are ≤ 0: closer to 0


def test_context_free_task():
    task = Bowl()
    res = learn(task, ContextualREPS(task.initial_policy(), 1.0), 5, 20, 0)
    assert res["eval_contexts"].shape == (N_EVAL_CONTEXTS, 0)
    assert res["mean_reward"][-1] > res["mean_reward"][0]


def test_bad_input_names_the_argument():
    task = Target()
    alg = Recorder(task.initial_policy())
    with pytest.raises(ValueError, match="n_updates"):
        learn(task, alg, 0, 5, 0)
    with pytest.raises(ValueError, match="rollouts_per_update"):
        learn(task, alg, 1, 0, 0)
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(task, alg, 1, 5, 0, extra_contexts=-1)
    with pytest.raises(ValueError, match="eval_contexts"):
        learn(task, alg, 1, 5, 0, eval_contexts=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="eval_contexts"):
        learn(task, alg, 1, 5, 0, eval_contexts=np.full((3, 2), 5.0))  # outside μ(s)'s range
    with pytest.raises(ValueError, match="algorithm"):
        learn(task, Recorder(GaussianPolicy(np.zeros(2), np.eye(2))), 1, 5, 0)
    with pytest.raises(ValueError, match="task"):
        learn("target", alg, 1, 5, 0)
    with pytest.raises(ValueError, match="rng"):
        learn(task, alg, 1, 5, -3)
