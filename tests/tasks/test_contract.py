"""The Task contract (DESIGN.md), checked for every registered task.

Every task — the pendulum and each robot task — must pass these; a new task is covered by
registering it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skillkit.tasks import Task, make, names
from skillkit.tasks.base import SimulationFailure
from skillkit.trajectory import Trajectory

TASKS = names()


@pytest.fixture(scope="module", params=TASKS)
def task(request) -> Task:
    return make(request.param)


def _omega(task: Task, context: np.ndarray, seed: int = 0) -> np.ndarray:
    policy = task.initial_policy()
    return policy.sample(context, np.random.default_rng(seed))


def test_registry_is_not_empty():
    assert "pendulum" in TASKS


def test_dimensions_and_context_distribution(task):
    assert isinstance(task, Task)
    assert task.parameter_dim >= 1
    assert np.shape(task.context_low) == np.shape(task.context_high) == (task.context_dim,)
    assert np.all(np.asarray(task.context_low) <= np.asarray(task.context_high))
    contexts = task.sample_context(np.random.default_rng(0), n=200)
    assert contexts.shape == (200, task.context_dim)
    assert np.all(contexts >= task.context_low) and np.all(contexts <= task.context_high)
    one = task.sample_context(3)
    assert one.shape == (task.context_dim,)
    np.testing.assert_array_equal(one, task.sample_context(3))


def test_initial_policy_matches_task(task):
    policy = task.initial_policy()
    assert policy.dim == task.parameter_dim
    assert policy.context_dim == task.context_dim
    omega = _omega(task, task.sample_context(1))
    assert omega.shape == (task.parameter_dim,)
    assert np.all(np.isfinite(omega))


def test_rollout_shapes_dtypes_finite(task):
    s = task.sample_context(2)
    traj = task.rollout(_omega(task, s), s, rng=5)
    assert isinstance(traj, Trajectory)
    assert not traj.failed, traj.message
    T = traj.n_steps
    assert T >= 2
    for arr in (traj.times, traj.states, traj.controls):
        assert arr.dtype == np.float64
        assert np.all(np.isfinite(arr))
    assert traj.states.shape[0] == T and traj.controls.shape[0] == T
    assert np.all(np.diff(traj.times) > 0)
    for key, sig in traj.signals.items():
        assert sig.dtype == np.float64, key
        assert np.all(np.isfinite(sig)), key
    r = task.reward(traj, s)
    assert isinstance(r, float) and np.isfinite(r)
    assert r > task.worst_reward


def test_same_seed_same_trajectory(task):
    s = task.sample_context(4)
    omega = _omega(task, s, seed=4)
    a = task.rollout(omega, s, rng=11)
    b = task.rollout(omega, s, rng=11)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.controls, b.controls)
    assert a.signals.keys() == b.signals.keys()
    for key in a.signals:
        np.testing.assert_array_equal(a.signals[key], b.signals[key])
    assert task.reward(a, s) == task.reward(b, s)


def test_rescoring_in_other_contexts(task):
    """Re-scoring a trajectory in context s' equals the reward of running in s' (when the
    trajectory does not depend on the context) — the extra-context trick of Sec. 3.4."""
    s1, s2 = task.sample_context(np.random.default_rng(7), n=2)
    omega = _omega(task, s1, seed=7)
    traj = task.rollout(omega, s1, rng=3)
    rescored = task.reward(traj, s2)
    assert np.isfinite(rescored)
    if not task.trajectory_depends_on_context:
        direct = task.reward(task.rollout(omega, s2, rng=3), s2)
        assert rescored == pytest.approx(direct, rel=1e-12, abs=1e-12)


def test_bad_omega_and_context_raise(task):
    s = task.sample_context(0)
    omega = _omega(task, s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(omega[:-1], s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(np.full(task.parameter_dim, np.nan), s)
    if task.context_dim:
        with pytest.raises(ValueError, match="context"):
            task.rollout(omega, s[:-1])
        with pytest.raises(ValueError, match="context"):
            task.rollout(omega, np.full(task.context_dim, np.inf))
        outside = np.asarray(task.context_high, dtype=float) + 1.0
        with pytest.raises(ValueError, match="outside"):
            task.rollout(omega, outside)


def test_physics_failure_is_reported_not_raised(task, monkeypatch):
    s = task.sample_context(0)
    omega = _omega(task, s)

    def broken(*args, **kwargs):
        raise SimulationFailure("state became NaN")

    monkeypatch.setattr(task, "_simulate", broken)
    with pytest.warns(RuntimeWarning, match="failed"):
        traj = task.rollout(omega, s)
    assert traj.failed and "NaN" in traj.message
    assert task.reward(traj, s) == task.worst_reward


def test_nan_trajectory_is_reported(task, monkeypatch):
    s = task.sample_context(0)
    omega = _omega(task, s)
    good = task.rollout(omega, s, rng=0)
    states = good.states.copy()
    states[-1, 0] = np.nan
    monkeypatch.setattr(
        task, "_simulate", lambda *a, **k: Trajectory(good.times, states, good.controls)
    )
    with pytest.warns(RuntimeWarning, match="non-finite"):
        traj = task.rollout(omega, s)
    assert traj.failed
    assert task.reward(traj, s) == task.worst_reward


def test_extreme_parameters_do_not_crash(task):
    """Absurd (but finite) ω either simulates to finite values or is reported as a failure."""
    s = task.sample_context(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        traj = task.rollout(np.full(task.parameter_dim, 1e8), s, rng=0)
    r = task.reward(traj, s)
    assert np.isfinite(r)
    if traj.failed:
        assert r == task.worst_reward


def test_trajectory_save_load_roundtrip(task, tmp_path):
    s = task.sample_context(0)
    traj = task.rollout(_omega(task, s), s, rng=0)
    path = traj.save(tmp_path / "traj.npz")
    back = Trajectory.load(path)
    np.testing.assert_array_equal(back.states, traj.states)
    np.testing.assert_array_equal(back.controls, traj.controls)
    np.testing.assert_array_equal(back.times, traj.times)
    assert back.signals.keys() == traj.signals.keys()
    assert task.reward(back, s) == task.reward(traj, s)
