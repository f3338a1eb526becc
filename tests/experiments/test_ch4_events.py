"""Chapter 4, GPREPS with discrete-event models (fig4.10–4.13): verdicts on fixed criteria,
confidence intervals, the viewer's model stored in each trial, and the setup tables."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import ch4_events as ev
from skillkit.experiments import get, reproduce
from skillkit.viz.model_layers import load_gpreps_run, model_layers


def _hockey_summary(rollouts=120, error=0.049, reward=-0.2, reps_reward=-0.25):
    g = {"rollouts": rollouts, "final_hit_rate": 1.0, "final_displacement_error": error,
         "final_reward": reward}  # fmt: skip
    r = {"rollouts": 10000, "final_hit_rate": 0.99, "final_displacement_error": 0.07,
         "final_reward": reps_reward}  # fmt: skip
    return {"n_trials": 3, "gpreps": g, "reps": r}


def test_fig410_verdict_is_the_fixed_criterion():
    st = get("fig4.10").settings["paper"]
    assert ev.verdict_410(st, _hockey_summary()).holds is True
    assert ev.verdict_410(st, _hockey_summary(error=0.051)).holds is False
    assert ev.verdict_410(st, _hockey_summary(rollouts=121)).holds is False
    assert ev.verdict_410(st, _hockey_summary(reps_reward=-0.1)).holds is False


def test_fig411_verdict_needs_separated_confidence_intervals():
    st = get("fig4.11").settings["paper"]
    g = {"rollouts": 120, "initial_reward": -0.6, "final_reward": -0.2, "final_hit_rate": 0.95,
         "final_displacement_error": 0.05, "initial_reward_ci95": [-0.7, -0.5],
         "final_reward_ci95": [-0.3, -0.1]}  # fmt: skip
    assert ev.verdict_411(st, {"n_trials": 5, "gpreps": g}).holds is True
    g["final_reward_ci95"] = [-0.55, -0.1]
    assert ev.verdict_411(st, {"n_trials": 5, "gpreps": g}).holds is False


def test_ci95_is_students_t_interval():
    v = np.array([-0.3, -0.2, -0.25, -0.1, -0.22])
    lo, hi = ev._ci95(v)
    ref = stats.t.interval(0.95, v.size - 1, loc=v.mean(), scale=stats.sem(v))
    np.testing.assert_allclose([lo, hi], ref, rtol=1e-12)


def test_fig412_and_fig413_verdicts():
    st = get("fig4.12").settings["paper"]
    base = {"rollouts": 150, "final_returned": 0.9, "final_net": 0.05, "final_missed": 0.0,
            "final_landing_error": 0.29, "final_reward": -0.03}  # fmt: skip
    direct = dict(base, final_reward=-0.1)
    summary = {"n_trials": 3, "gpreps": base, "direct": direct, "reps": dict(base, rollouts=4000)}
    assert ev.verdict_412(st, summary).holds is True
    summary["gpreps"] = dict(base, final_net=0.06)
    assert ev.verdict_412(st, summary).holds is False
    st13 = get("fig4.13").settings["paper"]
    errors = {"bounce_position_error_m": 0.01, "racket_position_rmse_m": 0.02,
              "contact_accuracy": 0.95, "contact_majority_rate": 0.8,
              "return_landing_error_m": 0.2}  # fmt: skip
    assert ev.verdict_413(st13, {"errors": errors}).holds is True
    assert ev.verdict_413(st13, {"errors": dict(errors, contact_accuracy=0.85)}).holds is False


@pytest.mark.parametrize(("exp_id", "model"), [("fig4.10", "HockeyRewardModel"),
                                               ("fig4.12", "TableTennisRewardModel")])  # fmt: skip
def test_each_trial_keeps_its_policy_history_and_reward_model(tmp_path, exp_id, model):
    """What ``skillkit view TASK --gpreps RUN`` loads: the GPREPS run's K + 1 policies and its
    last fitted model, whose layers have shapes the viewer accepts."""
    run = reproduce(exp_id, scale="smoke", seed=0, out=tmp_path, html=False, progress=False)
    history, reward_model = load_gpreps_run(run.path, 0)
    assert type(reward_model).__name__ == model
    st = get(exp_id).settings["smoke"]
    assert len(history.policies) == st.n_updates + 1
    s = reward_model.task.sample_context(0)
    specs = model_layers(reward_model, s, history.policies[-1].mean_of(s), n_samples=3, rng=0)
    assert len(specs) >= 3 and all(spec["trajectories"].shape[2] == 3 for spec in specs)
    summary = run.result["summary"]
    assert {"thesis", "ours", "why"} <= set(summary["setup"][0])
    assert summary["gpreps"]["rollouts"] == st.n_initial + st.n_updates - 1


def test_bad_settings_are_refused_before_any_work():
    from dataclasses import replace

    with pytest.raises(ValueError, match="schedule"):
        replace(get("fig4.12").settings["paper"], schedule="sometimes")
    with pytest.raises(ValueError, match="task"):
        replace(get("fig4.10").settings["paper"], task="hockey-fast")
    with pytest.raises(ValueError, match="n_initial"):
        replace(get("fig4.11").settings["paper"], n_initial=1)
