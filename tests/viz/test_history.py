"""Policy-history files (skillkit.viz.history): the recorder as the learning loop's callback,
round trips, run folders of ``skillkit reproduce``, format versions and malformed files."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.viz.history import (
    HISTORY_FORMAT,
    PolicyHistory,
    PolicyRecorder,
    load_policy_history,
    save_policy_history,
)

MEAN0, STEP = np.array([-3.0, -1.0]), np.array([0.5, 0.1])


def initial_policy() -> LinearGaussianPolicy:
    gain = np.array([[0.2, 0.0], [0.0, -0.3]])
    return LinearGaussianPolicy(MEAN0, np.diag([0.5, 0.2]), gain, context_dim=2)


class ShiftingSearch:
    """A stand-in policy search: every update moves the mean by a fixed step."""

    def __init__(self, policy: LinearGaussianPolicy, step) -> None:
        self.policy, self.step = policy, np.asarray(step, float)

    def update(self, *batch):  # ``update(batch)`` or ``update(contexts, omegas, rewards)``
        p = self.policy
        self.policy = LinearGaussianPolicy(p.mean + self.step, p.cov, p.gain, p.context_dim)
        return {}


def drive(recorder, algo, n_updates: int, rollouts: int) -> dict:
    """Call the recorder as ``skillkit.search.loop.learn`` does: k = 0, then after each update."""
    recorder(0, algo)
    for k in range(1, n_updates + 1):
        algo.update(None)
        recorder(k, algo)
    return {
        "rollouts": rollouts * np.arange(n_updates + 1),
        "mean_reward": -np.arange(n_updates + 1, 0, -1.0),
    }


@pytest.fixture(scope="module")
def history_file(tmp_path_factory):
    recorder = PolicyRecorder()
    result = drive(recorder, ShiftingSearch(initial_policy(), STEP), 3, 2)
    path = recorder.save(
        tmp_path_factory.mktemp("hist") / "history", result=result, task="pendulum"
    )
    return path, recorder, result


@pytest.mark.slow  # importing skillkit.search pulls in torch and gpytorch
def test_recorder_as_the_learning_loop_callback(tmp_path):
    from skillkit.search.loop import learn
    from skillkit.tasks import make

    pendulum = make("pendulum")
    recorder = PolicyRecorder()
    algo = ShiftingSearch(pendulum.initial_policy(), STEP)
    result = learn(pendulum, algo, n_updates=3, rollouts_per_update=2, rng=0, callback=recorder)
    history = load_policy_history(recorder.save(tmp_path / "history", result=result))
    assert len(history) == 4 and history[3].mean == pytest.approx([-1.5, -0.7])
    np.testing.assert_array_equal(history.mean_reward, result["mean_reward"])


def test_policy_history_round_trip(history_file):
    path, recorder, result = history_file
    with pytest.raises(ValueError, match="expected update 4"):
        recorder(7, None)
    assert path.suffix == ".npz"
    history = load_policy_history(path)
    assert len(history) == 4 and history.task == "pendulum"
    for k, p in enumerate(history.policies):
        np.testing.assert_array_equal(p.mean, recorder.policies[k].mean)
        np.testing.assert_array_equal(p.cov, recorder.policies[k].cov)
        np.testing.assert_array_equal(p.gain, recorder.policies[k].gain)
        assert (p.context_dim, p.features) == (2, "linear")
        np.testing.assert_allclose(p.mean, MEAN0 + k * STEP)
    np.testing.assert_array_equal(history.rollouts, [0, 2, 4, 6])
    np.testing.assert_array_equal(history.mean_reward, result["mean_reward"])


def test_the_file_holds_the_documented_keys_shapes_and_dtypes(history_file):
    path, _, _ = history_file
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    assert str(arrays["format"]) == HISTORY_FORMAT == "skillkit-policy-history-v1"
    assert arrays["policy_mean"].shape == (4, 2) and arrays["policy_mean"].dtype == np.float64
    assert arrays["policy_cov"].shape == (4, 2, 2)
    assert arrays["policy_gain"].shape == (4, 2, 2)
    assert int(arrays["policy_context_dim"]) == 2 and str(arrays["policy_features"]) == "linear"
    assert str(arrays["task"]) == "pendulum"
    assert arrays["rollouts"].shape == arrays["mean_reward"].shape == (4,)


def test_other_format_versions_are_refused_and_unversioned_files_read(tmp_path, history_file):
    path, recorder, _ = history_file
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(tmp_path / "v2.npz", **{**arrays, "format": np.asarray("skillkit-policy-history-v2")})
    with pytest.raises(ValueError, match="format 'skillkit-policy-history-v2', expected"):
        load_policy_history(tmp_path / "v2.npz")
    np.savez(tmp_path / "bare.npz", **recorder.arrays())  # the policy_* arrays alone
    history = load_policy_history(tmp_path / "bare.npz")
    assert len(history) == 4 and history.task == "" and history.rollouts is None


def test_history_from_a_reproduce_run_folder(tmp_path, history_file):
    _, recorder, result = history_file
    folder = tmp_path / "fig-quick-s0"
    folder.mkdir()
    arrays = {f"trial1__{k}": v for k, v in recorder.arrays().items()}
    arrays["trial1__mean_reward"] = result["mean_reward"]
    np.savez_compressed(folder / "trials.npz", trial0__other=np.zeros(3), **arrays)
    history = load_policy_history(folder, trial=1)
    assert len(history) == 4 and history.task == ""
    np.testing.assert_array_equal(history.mean_reward, result["mean_reward"])
    with pytest.raises(ValueError, match="policy_mean"):
        load_policy_history(folder, trial=0)
    with pytest.raises(ValueError, match="trial: .* no trial 7"):
        load_policy_history(folder, trial=7)


def test_malformed_policy_files(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"\x00junk")
    with pytest.raises(ValueError, match="policy: .* not a readable"):
        load_policy_history(tmp_path / "junk.npz")
    with pytest.raises(ValueError, match="policy: no such file"):
        load_policy_history(tmp_path / "missing.npz")
    np.savez(tmp_path / "partial.npz", policy_mean=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="policy_cov"):
        load_policy_history(tmp_path / "partial.npz")
    np.savez(
        tmp_path / "notpd.npz",
        policy_mean=np.zeros((1, 2)),
        policy_cov=-np.eye(2)[None],
        policy_gain=np.zeros((1, 2, 2)),
        policy_context_dim=2,
        policy_features="linear",
    )
    with pytest.raises(ValueError, match="invalid policy"):
        load_policy_history(tmp_path / "notpd.npz")


def test_bad_histories():
    p = initial_policy()
    with pytest.raises(ValueError, match="policies: expected at least one"):
        PolicyHistory(())
    with pytest.raises(ValueError, match="entry 1 is a str"):
        PolicyHistory((p, "p"))
    other = LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)
    with pytest.raises(ValueError, match="same dim and context_dim"):
        PolicyHistory((p, other))
    with pytest.raises(ValueError, match="rollouts"):
        PolicyHistory((p, p), rollouts=[0, 1, 2])
    with pytest.raises(ValueError, match="policies"):
        save_policy_history("unused.npz", [])


def test_repr_is_short_and_informative(history_file):
    history = load_policy_history(history_file[0])
    text = repr(history)
    assert text.startswith("PolicyHistory(K=3, dim=2, context_dim=2, task='pendulum'")
    assert "rollouts=0…6" in text and "mean_reward=-4…-1" in text
    assert "\n" not in text and len(text) < 300
    assert repr(history_file[1]) == "PolicyRecorder(4 policies)"
