"""fig3.3 (throwing, contextual REPS vs REPS + extra context): a tiny run through the runner."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import get, judge
from skillkit.experiments.ch3_throwing import summarize, target_grid
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials
from skillkit.tasks.planar import Throwing
from tests._tolerances import fp_tol


@pytest.fixture(scope="module")
def first():
    """Two smoke-scale trials (2 updates of 4 rollouts, targets [6, 2] and [14, 2] m)."""
    return run_trials("fig3.3", "smoke", seed=5, progress=False)


def test_registered_with_the_thesis_settings():
    exp = get("fig3.3")
    for scale in ("quick", "paper"):
        s = exp.settings[scale]
        assert s.reps.epsilon == 0.6 and s.reps.rollouts_per_update == 25
        assert s.reps.rollouts_per_update * s.reps.n_reuse_batches == 200
        # exploration whose throws reach the farthest targets; Table 3.1's M-step
        assert s.initial_std_fraction == Throwing.covering_std_fraction
        assert s.m_step == "weighted_ml"
    assert exp.settings["paper"].reps.n_updates * 25 >= 5000
    assert exp.trials["paper"] == 20
    grid = replace(exp.settings["quick"], grid_x=(5, 6), grid_y=(1,))
    np.testing.assert_array_equal(target_grid(grid), [[5, 1], [6, 1]])


def _summary(first, near, far, gain, within=(True, True), extra_within=(True, True)):
    """The smoke summary with plain REPS's per-trial largest errors (near, far: two trials
    each), the extra arm's reward gain per trial and the per-trial "within bounds" flags."""
    s = first["summary"]
    reps = {
        **s["reps"],
        "near_distance_max_per_trial_m": list(near),
        "far_distance_max_per_trial_m": list(far),
        "final_reward_per_trial": [-10.0, -12.0],
        "within_bounds_per_trial": list(within),
    }
    extra = {
        **s["extra"],
        "final_reward_per_trial": [-10.0 + gain[0], -12.0 + gain[1]],
        "within_bounds_per_trial": list(extra_within),
    }
    return {**s, "reps": reps, "extra": extra}


@pytest.mark.parametrize(
    "near, far, gain, within, extra_within, outcome",
    [
        ((0.05, 0.06), (0.3, 0.31), (2.0, 2.1), (1, 1), (1, 1), "undecided"),  # "always": 2 of 2
        ((0.2, 0.21), (0.3, 0.31), (2.0, 2.1), (1, 1), (1, 1), "does not hold"),  # near > 10 cm
        ((0.05, 0.06), (0.8, 0.81), (2.0, 2.1), (1, 1), (1, 1), "does not hold"),  # far > 0.5 m
        ((0.05, 0.06), (0.3, 0.31), (-2.0, -2.1), (1, 1), (1, 1), "does not hold"),  # no gain
        ((0.05, 0.06), (0.3, 0.31), (2.0, 2.1), (1, 1), (1, 0), "does not hold"),  # not always
    ],
)
def test_spec_decides_the_thesis_sentences(first, near, far, gain, within, extra_within, outcome):
    summary = _summary(first, near, far, gain, within, extra_within)
    assert judge.judge("fig3.3", summary, "paper").outcome == outcome


def test_own_parts_do_not_change_the_verdict(first):
    summary = _summary(first, (0.05, 0.06), (0.3, 0.31), (2.0, 2.1), (1, 1), (1, 0))
    loose = {**summary["extra"], "near_distance_max_per_trial_m": [0.6, 0.61]}
    for extra in (summary["extra"], loose):
        j = judge.judge("fig3.3", {**summary, "extra": extra}, "paper")
        assert j.outcome == "does not hold"  # decided by the extra arm's 1 of 2 trials


def test_stored_run_reads_the_near_error_as_a_t_interval():
    """The engine's interval on the stored paper run equals scipy's Student-t interval on the
    stored per-trial largest near-target errors (20 numbers: ~80 operations of round-off)."""
    run = stored_run("fig3.3")
    x = np.asarray(run.summary["reps"]["near_distance_max_per_trial_m"])
    lo, hi = stats.t.interval(0.95, x.size - 1, loc=x.mean(), scale=stats.sem(x))
    r = next(r for r in run.judgement.readings if r.part.label == "REPS largest near-target error")
    tol = fp_tol(4 * x.size, scale=x.max())
    assert r.lower == pytest.approx(lo, abs=tol) and r.upper == pytest.approx(hi, abs=tol)
    assert r.outcome == "does not hold" and run.judgement.outcome == "does not hold"
    assert judge.card_lines_ok(run.card)


def test_smoke_run_is_not_judged(first):
    summary = first["summary"]
    assert summary["holds"] is None and summary["verdict"] == "not judged"
    assert judge.card_lines_ok(summary["judgement"]["card"])


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
    assert reps["within_bounds_per_trial"] == [True, False, False]


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
    own = {r["label"] for r in summary["judgement"]["readings"] if r["own"]}
    assert own == {"extra: largest near error", "extra: largest far error"}
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
    assert len(history.policies) == get("fig3.3").settings["smoke"].reps.n_updates + 1
    assert history.policies[0].dim == 41 and history.policies[0].context_dim == 2
    # The first entry is the initial policy, the others differ from it (REPS updated them).
    assert not np.allclose(history.policies[-1].mean, history.policies[0].mean)


def test_both_arms_start_from_the_covering_exploration(first):
    task = Throwing()
    start = task.initial_policy(Throwing.covering_std_fraction)
    for trial in first["_trials"]:
        np.testing.assert_array_equal(trial["policy_cov"][0], start.cov)  # the REPS arm
        np.testing.assert_array_equal(trial["policy_mean"][0], start.mean)
