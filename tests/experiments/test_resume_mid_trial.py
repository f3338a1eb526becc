"""Experiments whose single trials are long checkpoint mid-trial: resuming from any saved state
gives the same result as the uninterrupted trial (contract over those experiments)."""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest

from skillkit.experiments import ch5, get
from skillkit.trial import TrialContext

_BALANCING = {
    **ch5._BALANCING_COMMON,
    "horizon": 5,
    "gp_samples": 4,
    "initial_samples": 4,
    "test_pairs": 3,
    "truth_rollouts": 3,
    "max_iter": 2,
    "gp_steps": 2,
    "n_trajectories": 2,
}
TINY = {
    "fig4.3": dict(
        n_data=120,
        n_pseudo=20,
        horizon=6,
        n_start=3,
        n_ground_truth=150,
        sample_sizes=[10, 40],
        n_opt_steps=5,
    ),
    "fig4.5": dict(
        defaults={"additive_noise": 1.0, "n_opt_steps": 5, "torque_noise_std": 0.5, "n_train": 2},
        additive_noise_values=[1.0, 10.0],
        n_opt_steps_values=[5],
        torque_noise_std_values=[0.5],
        n_train_values=[2],
        n_pairs=3,
        horizon=5,
        n_predicted=3,
    ),
    # the model-free experiments checkpoint through skillkit.search.loop.learn (one key per run)
    "sanity3": dict(n_updates=3),
    "fig3.3": dict(
        n_updates=2,
        rollouts_per_update=4,
        n_reuse_batches=2,
        extra_contexts=2,
        n_eval_contexts=1,
        grid_x=[6.0, 14.0],
        grid_y=[2.0],
    ),
    "fig3.7": dict(
        rollouts_per_update=12,
        n_reuse_batches=2,
        min_effective_samples=3.0,
        n_updates=2,
        n_eval_contexts=2,
        n_final_contexts=3,
    ),
    "fig5.6": {**_BALANCING, "torque_noise": 4.0, "n_trajectories": [2, 3]},
    "fig5.7": {**_BALANCING, "torque_noise": [1.0, 4.0]},
}


class _Recorder(TrialContext):
    """An in-memory trial context that keeps every key's snapshots after every save."""

    def __init__(self, states=None):
        super().__init__(states=states)
        self.history: list[dict] = []

    def save(self, key, state, rng):
        super().save(key, state, rng)
        self.history.append(copy.deepcopy(self.snapshots))


def _run(exp_id: str, ctx: TrialContext) -> dict:
    exp = get(exp_id)
    settings = exp.settings_for("quick", **TINY[exp_id])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return exp.run_trial(settings, np.random.default_rng(11), ctx)


def _assert_same(a, b, where="result"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            if "time" in str(k):  # wall-clock measurements differ between runs
                continue
            _assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, float, np.floating)):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


@pytest.mark.parametrize("exp_id", sorted(TINY))
def test_resuming_from_every_saved_state_gives_the_uninterrupted_result(exp_id):
    full = _Recorder()
    reference = _run(exp_id, full)
    assert len(full.history) >= 2, "the trial must checkpoint more than once"
    # the first snapshot (setup done) and one from the middle of the work
    for k in sorted({0, len(full.history) // 2}):
        resumed = _run(exp_id, _Recorder(states=copy.deepcopy(full.history[k])))
        _assert_same(reference, resumed, f"{exp_id} resumed from save {k + 1}")
