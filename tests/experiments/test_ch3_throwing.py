"""fig3.3 (throwing, contextual REPS vs REPS + extra context): a tiny run through the runner."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import get
from skillkit.experiments.ch3_throwing import target_grid
from skillkit.experiments.runner import run_trials

TINY = {
    "n_updates": 2,
    "rollouts_per_update": 4,
    "n_reuse_batches": 2,
    "extra_contexts": 2,
    "n_eval_contexts": 1,
    "grid_x": [6.0, 14.0],
    "grid_y": [2.0],
}


@pytest.fixture(scope="module")
def tiny_runs():
    first = run_trials("fig3.3", "quick", trials=2, seed=5, progress=False, **TINY)
    again = run_trials("fig3.3", "quick", trials=2, seed=5, progress=False, **TINY)
    other = run_trials("fig3.3", "quick", trials=1, seed=6, progress=False, **TINY)
    return first, again, other


def test_registered_with_the_thesis_settings():
    exp = get("fig3.3")
    for scale in ("quick", "paper"):
        s = exp.settings[scale]
        assert s["epsilon"] == 0.6 and s["rollouts_per_update"] == 25
        assert s["rollouts_per_update"] * s["n_reuse_batches"] == 200
    assert exp.settings["paper"]["n_updates"] * 25 >= 5000
    assert exp.trials["paper"] == 20
    np.testing.assert_array_equal(target_grid({"grid_x": [5, 6], "grid_y": [1]}), [[5, 1], [6, 1]])


def test_same_seed_same_numbers(tiny_runs):
    first, again, other = tiny_runs
    assert first["summary"] == again["summary"]
    for a, b in zip(first["_trials"], again["_trials"], strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    assert (
        other["summary"]["reps"]["final_reward_mean"]
        != first["summary"]["reps"]["final_reward_mean"]
    )


def test_summary_has_the_promised_keys(tiny_runs):
    first, _, _ = tiny_runs
    summary = first["summary"]
    for key in ("reps", "extra"):
        part = summary[key]
        for name in (
            "initial_reward",
            "final_reward_mean",
            "final_reward_std",
            "near_distance_mean_m",
            "near_distance_max_m",
            "far_distance_mean_m",
            "far_distance_max_m",
            "final_joint_penalty_mean",
            "failed_rollouts_during_learning",
            "conditioned_updates",
        ):
            assert np.isfinite(part[name]), name
        assert len(part["final_reward_per_trial"]) == 2
        assert part["near_distance_max_m"] >= part["near_distance_mean_m"] > 0
    assert summary["thesis"]["near_max_error_m"] == 0.1
    assert set(summary["learned"]) == set(summary["holds"]) == {"reps", "extra"}
    trial = first["_trials"][0]
    assert trial["rollouts"].tolist() == [0, 4, 8]
    assert trial["reps_mean_reward"].shape == trial["extra_mean_reward"].shape == (3,)
    assert trial["reps_distance"].shape == (2,)
    names = {s["name"] for s in first["series"]}
    assert names == {"REPS", "REPS + extra context"}


def test_saved_run_has_the_policy_history_the_viewer_plays_back(tmp_path):
    from skillkit.experiments.runner import reproduce
    from skillkit.viz.history import load_policy_history

    folder = reproduce("fig3.3", trials=1, seed=5, out=tmp_path, progress=False, html=False, **TINY)
    history = load_policy_history(folder, trial=0)
    assert len(history.policies) == TINY["n_updates"] + 1
    assert history.policies[0].dim == 41 and history.policies[0].context_dim == 2
    # The first entry is the initial policy, the others differ from it (REPS updated them).
    assert not np.allclose(history.policies[-1].mean, history.policies[0].mean)
