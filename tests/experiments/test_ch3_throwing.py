"""fig3.3 (throwing, contextual REPS vs REPS + extra context): a tiny run through the runner."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skillkit.experiments import get
from skillkit.experiments.ch3_throwing import target_grid, verdict
from skillkit.experiments.runner import run_trials
from skillkit.tasks.planar import Throwing


@pytest.fixture(scope="module")
def first():
    """Two smoke-scale trials (2 updates of 4 rollouts, targets [6, 2] and [14, 2] m)."""
    return run_trials("fig3.3", "smoke", seed=5, progress=False)


def test_registered_with_the_thesis_settings():
    exp = get("fig3.3")
    for scale in ("quick", "paper"):
        s = exp.settings[scale]
        assert s.epsilon == 0.6 and s.rollouts_per_update == 25
        assert s.rollouts_per_update * s.n_reuse_batches == 200
        # issue #17: exploration whose throws reach the farthest targets; Table 3.1's M-step
        assert s.initial_std_fraction == Throwing.covering_std_fraction
        assert s.m_step == "weighted_ml"
    assert exp.settings["paper"].n_updates * 25 >= 5000
    assert exp.trials["paper"] == 20
    grid = replace(exp.settings["quick"], grid_x=(5, 6), grid_y=(1,))
    np.testing.assert_array_equal(target_grid(grid), [[5, 1], [6, 1]])


def test_verdict_needs_extra_context_within_the_bounds_and_better(first):
    summary = first["summary"]
    settings = get("fig3.3").settings["smoke"]
    good = {**summary, "holds_per_method": {"reps": False, "extra": True}}
    assert verdict(settings, {**good, "extra_context_better": True}).holds is True
    assert verdict(settings, {**good, "extra_context_better": False}).holds is False
    bad = {**good, "holds_per_method": {"reps": True, "extra": False}}
    assert verdict(settings, {**bad, "extra_context_better": True}).holds is False


def test_summary_has_the_promised_keys(first):
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
    assert summary["thesis_numbers"]["near_max_error_m"] == 0.1
    assert set(summary["learned"]) == set(summary["holds_per_method"]) == {"reps", "extra"}
    assert summary["thesis_numbers"] == {
        "near_max_error_m": 0.1,
        "far_max_error_m": 0.5,
        "rollouts_to_converge": 5000,
    }
    trial = first["_trials"][0]
    assert trial["rollouts"].tolist() == [0, 4, 8]
    assert trial["reps_mean_reward"].shape == trial["extra_mean_reward"].shape == (3,)
    assert trial["reps_distance"].shape == (2,)
    names = {s["name"] for s in first["series"]}
    assert names == {"REPS", "REPS + extra context"}


def test_saved_run_has_the_policy_history_the_viewer_plays_back(tmp_path):
    from skillkit.experiments.runner import reproduce
    from skillkit.viz.history import load_policy_history

    folder = reproduce(
        "fig3.3", "smoke", trials=1, seed=5, out=tmp_path, progress=False, html=False
    )
    history = load_policy_history(folder, trial=0)
    assert len(history.policies) == get("fig3.3").settings["smoke"].n_updates + 1
    assert history.policies[0].dim == 41 and history.policies[0].context_dim == 2
    # The first entry is the initial policy, the others differ from it (REPS updated them).
    assert not np.allclose(history.policies[-1].mean, history.policies[0].mean)


def test_both_arms_start_from_the_covering_exploration(first):
    task = Throwing()
    start = task.initial_policy(Throwing.covering_std_fraction)
    for trial in first["_trials"]:
        np.testing.assert_array_equal(trial["policy_cov"][0], start.cov)  # the REPS arm
        np.testing.assert_array_equal(trial["policy_mean"][0], start.mean)
