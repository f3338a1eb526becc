"""fig3.3 (throwing, contextual REPS vs REPS + extra context): a tiny run through the runner."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skillkit.experiments import get
from skillkit.experiments.ch3_throwing import own_checks, summarize, target_grid, verdict
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


def _judged_summary(first, reps_near, reps_far, better, extra_max=(0.05, 0.3)):
    """The smoke summary with plain REPS's median-trial largest errors (near, far), the
    reward comparison, and the extra arm's largest errors over all trials set by hand."""
    summary = first["summary"]
    reps = {
        **summary["reps"],
        "near_distance_trial_max_median_m": reps_near,
        "far_distance_trial_max_median_m": reps_far,
    }
    extra = {
        **summary["extra"],
        "near_distance_max_m": extra_max[0],
        "far_distance_max_m": extra_max[1],
        "failed_final_rollouts": 0,
    }
    return {**summary, "reps": reps, "extra": extra, "extra_context_better": better}


@pytest.mark.parametrize(
    "near, far, better, holds",
    [
        (0.05, 0.3, True, True),
        (0.15, 0.3, True, False),  # the median trial misses a near target by more than 10 cm
        (0.05, 0.7, True, False),  # ... a far one by more than 0.5 m
        (0.05, 0.3, False, False),  # extra context does not improve REPS
    ],
)
def test_verdict_decides_the_thesis_sentences(first, near, far, better, holds):
    settings = get("fig3.3").settings["smoke"]
    assert verdict(settings, _judged_summary(first, near, far, better)).holds is holds


def test_own_checks_do_not_change_holds(first):
    settings = get("fig3.3").settings["smoke"]
    # an extra-context trial 0.6 m off a near target: our every-trial check fails, holds not
    loose = _judged_summary(first, 0.05, 0.3, True, extra_max=(0.6, 0.3))
    assert own_checks(loose)["extra_every_trial_within_bounds"]["holds"] is False
    assert verdict(settings, loose).holds is True
    # every extra trial within the bounds, but the median REPS trial is not: holds is False
    tight = _judged_summary(first, 0.15, 0.3, True, extra_max=(0.05, 0.3))
    assert own_checks(tight)["extra_every_trial_within_bounds"]["holds"] is True
    assert verdict(settings, tight).holds is False


def test_summary_without_the_median_trial_is_undecided(first):
    """Summaries stored before issue #32 lack the median trial's errors: holds is None (or
    False when the reward comparison fails), and the statement says the number is missing."""
    settings = get("fig3.3").settings["smoke"]
    summary = _judged_summary(first, 0.05, 0.3, True)
    for key in ("near_distance_trial_max_median_m", "far_distance_trial_max_median_m"):
        del summary["reps"][key]
    old = verdict(settings, summary)
    assert old.holds is None and "not recorded in this run" in old.statement
    assert verdict(settings, {**summary, "extra_context_better": False}).holds is False
    del summary["reps"]["trials_within_bounds"]
    assert own_checks(summary)["reps_most_trials_within_bounds"]["holds"] is None


def test_summary_counts_the_median_trial_and_the_trials_within_bounds(first):
    targets = np.array([[6.0, 2.0], [7.0, 2.0], [14.0, 2.0]])
    trials = [
        {
            **first["_trials"][0],
            "targets": targets,
            "reps_distance": np.array(d),
            "extra_distance": np.array(d),
            "reps_penalty": np.zeros(3),
            "extra_penalty": np.zeros(3),
        }
        for d in ([0.02, 0.05, 0.3], [0.02, 0.2, 0.3], [0.01, np.nan, 0.4])
    ]
    settings = replace(get("fig3.3").settings["smoke"], grid_x=(6.0, 7.0, 14.0))
    _, summary = summarize(settings, trials)
    reps = summary["reps"]
    assert reps["near_distance_max_per_trial_m"] == pytest.approx([0.05, 0.2, 0.01])
    assert reps["far_distance_max_per_trial_m"] == pytest.approx([0.3, 0.3, 0.4])
    assert reps["near_distance_trial_max_median_m"] == pytest.approx(0.05)
    assert reps["far_distance_trial_max_median_m"] == pytest.approx(0.3)
    # the second trial misses a near target by 0.2 m, the third has a failed throw
    assert reps["trials_within_bounds"] == 1 and reps["failed_final_rollouts"] == 1
    assert summary["own_checks"]["reps_most_trials_within_bounds"]["holds"] is False
    assert summary["own_checks"]["extra_every_trial_within_bounds"]["holds"] is False


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
    assert set(summary["learned"]) == {"reps", "extra"}
    for key in ("reps", "extra"):
        assert len(summary[key]["near_distance_max_per_trial_m"]) == 2
        assert 0 <= summary[key]["trials_within_bounds"] <= 2
    assert set(summary["own_checks"]) == {
        "extra_every_trial_within_bounds",
        "reps_most_trials_within_bounds",
        "extra_typical_trial_within_bounds",
    }
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
