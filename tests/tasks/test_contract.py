"""The Task contract (DESIGN.md), checked for every registered task.

Every task — the pendulum and each robot task — must pass these; a new task is covered by
registering it.
"""

from __future__ import annotations

import json
import warnings

import mujoco
import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.tasks import ModelSignals, Task, make, names, tags
from skillkit.tasks.base import SimulationFailure
from skillkit.trajectory import Trajectory
from skillkit.viz.scenes import task_model

TASKS = names()


@pytest.fixture(scope="module", params=TASKS)
def task(request) -> Task:
    return make(request.param)


def _omega(task: Task, context: np.ndarray, seed: int = 0) -> np.ndarray:
    policy = task.initial_policy()
    return policy.sample(context, np.random.default_rng(seed))


def _reward_rtol(states, controls, signals=None):
    """Relative round-off of one trajectory's reward evaluated in two summation orders (batched
    or not, numpy or torch): every reward here is a sum of same-sign costs of the trajectory's
    values (no cancellation), so ≲ n ε with n the number of values entering it."""
    n = np.size(states) + np.size(controls) + sum(np.size(v) for v in (signals or {}).values())
    return fp_tol(n)


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
    assert task.sample_context(3, n=0).shape == (0, task.context_dim)
    for bad in (-1, 2.5, True):  # a fractional count is refused, not truncated silently
        with pytest.raises(ValueError, match="n: expected an integer"):
            task.sample_context(3, n=bad)


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
        # the rollout does not read the context: same ω and seed give the same floats, and the
        # reward is a pure function of (τ, s), so the two are equal exactly
        direct = task.reward(task.rollout(omega, s2, rng=3), s2)
        assert rescored == direct


def test_bad_omega_and_context_raise(task):
    s = task.sample_context(0)
    omega = _omega(task, s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(omega[:-1], s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(np.full(task.parameter_dim, np.nan), s)
    with pytest.raises(ValueError, match="omega: expected real"):  # not cast with a warning
        task.rollout(omega + 1j, s)
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


def test_failed_batch_passes_working_rollouts_and_flags_non_finite_paths(task):
    """The divergence rule on paths (scores predicted paths as a real failure): a working
    rollout's states pass it; where the task has a rule, a non-finite state fails it."""
    s = task.sample_context(2)
    traj = task.rollout(_omega(task, s), s, rng=5)
    paths = np.stack([traj.states, traj.states])
    paths[1, 1, 0] = np.nan
    flags = task.failed_batch(paths)
    assert flags.shape == (2,) and flags.dtype == bool and not flags[0]
    assert flags[1] == (type(task).failed_batch is not Task.failed_batch)
    with pytest.raises(ValueError, match="states"):
        task.failed_batch(traj.states)  # one path without the batch axis


def test_trajectory_save_load_roundtrip(task, tmp_path):
    s = task.sample_context(0)
    traj = task.rollout(_omega(task, s), s, rng=0)
    path = traj.save(tmp_path / "traj.npz")
    back = Trajectory.load(path)
    np.testing.assert_array_equal(back.states, traj.states)
    np.testing.assert_array_equal(back.controls, traj.controls)
    np.testing.assert_array_equal(back.times, traj.times)
    assert back.signals.keys() == traj.signals.keys()
    for key, value in traj.signals.items():  # every named signal, bit for bit
        assert back.signals[key].dtype == np.float64, key
        np.testing.assert_array_equal(back.signals[key], value)
    assert back.info == json.loads(json.dumps(traj.info))  # JSON: tuples come back as lists
    assert (back.failed, back.message) == (traj.failed, traj.message)
    assert task.reward(back, s) == task.reward(traj, s)


def test_trajectory_save_load_keeps_a_failure_and_refuses_bad_records(tmp_path):
    failed = Trajectory(
        np.zeros(1),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        info={"k": [1.5]},
        failed=True,
        message="diverged",
    )
    path = failed.save(tmp_path / "failed")  # ".npz" is appended, as numpy does
    assert path == tmp_path / "failed.npz" and path.exists()
    back = Trajectory.load(path)
    assert back.failed and back.message == "diverged" and back.info == {"k": [1.5]}
    with pytest.raises(ValueError, match="info: expected JSON"):
        Trajectory(np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), info={"n": np.int64(3)}).save(
            tmp_path / "bad.npz"
        )
    assert not (tmp_path / "bad.npz").exists()
    with pytest.raises(ValueError, match="signals"):
        Trajectory(np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), signals=[np.zeros(1)])
    with pytest.raises(ValueError, match="info"):
        Trajectory(np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), info=None)


# ------------------------------------------------------------------ model-based search protocol
def _noise_free(name: str) -> Task:
    """The task with its control noise off: the pendulum records the applied (noisy) torque,
    every other task the commanded one."""
    return make(name, control_noise=0.0) if "pendulum" in tags(name) else make(name)


def _rollouts(task: Task, n: int = 3) -> tuple[np.ndarray, np.ndarray, list[Trajectory]]:
    contexts = task.sample_context(np.random.default_rng(21), n=n)
    omegas = np.stack([_omega(task, s, seed=30 + i) for i, s in enumerate(contexts)])
    trajs = [
        task.rollout(w, s, rng=40 + i)
        for i, (w, s) in enumerate(zip(omegas, contexts, strict=True))
    ]
    assert not any(t.failed for t in trajs)
    return omegas, contexts, trajs


def test_model_signals_name_the_model_state(task):
    sig = task.model_signals()
    assert isinstance(sig, ModelSignals)
    assert sig.state_dim >= 1 and sig.state_dim == len(sig.state)
    x0 = task.initial_states(task.sample_context(5), 4, rng=0)
    assert x0.shape == (4, sig.state_dim) and x0.dtype == np.float64
    assert np.all(np.isfinite(x0))


def test_initial_states_seeded_and_validated(task):
    s = task.sample_context(6)
    np.testing.assert_array_equal(task.initial_states(s, 3, rng=1), task.initial_states(s, 3, 1))
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match="n"):
            task.initial_states(s, bad, rng=0)
    if task.context_dim:
        with pytest.raises(ValueError, match="context"):
            task.initial_states(np.full(task.context_dim, 1e6), 2, rng=0)


def test_initial_states_are_the_simulators_start(task):
    """A deterministic start equals the simulator's first state; a random one (balancing) has
    the simulator's distribution: N(x_up, σ² I), checked by its moments."""
    if not task.supports_model_rollout:
        pytest.skip("no step-based model state")
    _, contexts, trajs = _rollouts(task, 2)
    a = task.initial_states(contexts[0], 2000, rng=0)
    if np.all(a == a[0]):
        for s, t in zip(contexts, trajs, strict=True):
            np.testing.assert_array_equal(task.initial_states(s, 1, rng=3)[0], t.states[0])
    else:
        short = make(task.name, n_steps=1)  # random starts: balancing; one step suffices
        omega = short.initial_policy().mean_of(np.zeros(0))
        starts = np.stack([short.rollout(omega, None, rng=i).states[0] for i in range(400)])
        np.testing.assert_allclose(a.mean(0), starts.mean(0), atol=0.1)
        np.testing.assert_allclose(a.std(0), starts.std(0), rtol=0.2)


def test_transitions_are_consecutive_or_unsupported(task):
    s = task.sample_context(7)
    traj = task.rollout(_omega(task, s), s, rng=2)
    if not task.supports_model_rollout:
        assert task.no_model_rollout_reason
        with pytest.raises(NotImplementedError, match="not available"):
            task.transitions(traj)
        with pytest.raises(NotImplementedError, match="not available"):
            task.controller(_omega(task, s)[None], s[None])
        return
    sig = task.model_signals()
    x, u, x_next = task.transitions(traj)
    T = traj.n_steps
    assert x.shape == (T - 1, sig.state_dim) and x_next.shape == x.shape
    assert u.shape == (T - 1, sig.control_dim)
    np.testing.assert_array_equal(x[1:], x_next[:-1])
    np.testing.assert_array_equal(u, traj.controls[:-1])
    failed = Trajectory(np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), failed=True, message="x")
    with pytest.raises(ValueError, match="failed"):
        task.transitions(failed)


@pytest.mark.parametrize("name", [n for n in TASKS if make(n).supports_model_rollout])
def test_controller_reproduces_the_simulators_controls(name):
    """The batched torch controller on the simulator's own states gives its controls."""
    task = _noise_free(name)
    omegas, contexts, trajs = _rollouts(task, 2)
    policy = task.controller(omegas, contexts)
    states = np.stack([t.states for t in trajs])
    controls = np.stack([t.controls for t in trajs])
    pair = torch.arange(2)
    got = np.stack(
        [
            policy(t, torch.as_tensor(states[:, t]), pair).numpy()
            for t in range(states.shape[1] - 1)
        ],
        axis=1,
    )
    scale = max(1.0, np.abs(controls).max())
    np.testing.assert_allclose(got, controls[:, :-1], rtol=0, atol=1e-9 * scale)
    # dtype and pair indexing follow the sampler's contract
    p32 = task.controller(omegas, contexts, dtype=torch.float32)
    u = p32(0, torch.as_tensor(states[[1, 0, 1], 0], dtype=torch.float32), torch.tensor([1, 0, 1]))
    assert u.dtype == torch.float32 and u.shape == (3, task.model_signals().control_dim)
    np.testing.assert_allclose(u.numpy(), controls[[1, 0, 1], 0], rtol=1e-4, atol=1e-4 * scale)


def test_reward_batch_is_the_reward(task):
    """One definition: the batch of every trajectory (stacked where lengths agree) scores
    exactly what :meth:`Task.reward` does, in the rollout's and in other contexts."""
    _, contexts, trajs = _rollouts(task, 3)
    other = task.sample_context(np.random.default_rng(8), n=3)
    for ss in (contexts, other):
        expected = np.array([task.reward(t, s) for t, s in zip(trajs, ss, strict=True)])
        inputs = [(t.states, t.controls, task.reward_signals(t)) for t in trajs]
        same = all(
            a[0].shape == inputs[0][0].shape
            and all(np.shape(a[2][k]) == np.shape(inputs[0][2][k]) for k in a[2])
            for a in inputs
        )
        groups = [list(range(3))] if same else [[i] for i in range(3)]
        for g in groups:
            got = task.reward_batch(
                np.stack([inputs[i][0] for i in g]),
                np.stack([inputs[i][1] for i in g]),
                {k: np.stack([inputs[i][2][k] for i in g]) for k in inputs[0][2]},
                ss[g],
            )
            assert np.shape(got) == (len(g),)
            rtol = max(_reward_rtol(*inputs[i]) for i in g)  # batch of len(g) vs batch of 1
            np.testing.assert_allclose(got, expected[g], rtol=rtol, atol=0)


def test_reward_batch_takes_torch_where_models_predict_states(task):
    if not task.supports_model_rollout or task.name.startswith("throwing"):
        pytest.skip("numpy-only reward (event signals)")
    _, contexts, trajs = _rollouts(task, 2)
    states = np.stack([t.states for t in trajs])
    controls = np.stack([t.controls for t in trajs])
    r_np = task.reward_batch(states, controls, {}, contexts)
    r_t = task.reward_batch(torch.as_tensor(states), torch.as_tensor(controls), {}, contexts)
    assert isinstance(r_t, torch.Tensor) and r_t.shape == (2,)
    np.testing.assert_allclose(r_t.numpy(), r_np, rtol=_reward_rtol(states[0], controls[0]))


def test_scene_model(task):
    model = task.scene_model()
    if "pendulum" in tags(task.name):
        assert model is None  # drawn by the viewer's dedicated pendulum scene
    else:
        assert isinstance(model, mujoco.MjModel)
        assert task_model(task) is model
