"""Chapter 4, GPREPS with discrete-event models on hockey (fig4.10, fig4.11): the claims spec's
readings on the stored runs against independent computations, the smoke runs (not judged,
short cards, the per-trial numbers the readings need), the viewer's model stored in each trial,
and the settings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import ch4_events as ev
from skillkit.experiments import get, reproduce
from skillkit.experiments.judge import card_lines_ok, judge, read, spec
from skillkit.viz.model_layers import load_gpreps_run, model_layers
from tests._claims import part as _part
from tests._claims import stored as _stored
from tests._claims import wilson as _wilson
from tests._tolerances import fp_tol

REPO = Path(__file__).resolve().parents[2]


def test_fig410_placed_puck_interval_is_students_t_over_the_stored_trials():
    run = _stored("fig4.10")
    part = _part("fig4.10", "placed-puck error")
    x = np.asarray(run.summary["gpreps"]["final_displacement_error_hits_per_trial"], dtype=float)
    r = read(part, run.summary, run.result["settings"])
    ref = stats.t.interval(0.95, x.size - 1, loc=x.mean(), scale=stats.sem(x))
    # mean and std (~3n flops), the t quantile (a few ulp), product and sum: ~3n + 16 flops
    # on the scale of the bounds
    tol = fp_tol(3 * x.size + 16, scale=float(np.abs(ref).max()))
    np.testing.assert_allclose([r.lower, r.upper], ref, rtol=0, atol=tol)
    assert r.n == x.size == run.summary["n_trials"]
    assert (r.lower < part.threshold < r.upper) is (r.outcome == "undecided")


def test_fig410_reps_comparison_is_paired_by_trial():
    run = _stored("fig4.10")
    g = np.asarray(run.summary["gpreps"]["final_reward_per_trial"], dtype=float)
    d = g - np.asarray(run.summary["reps"]["final_reward_per_trial"], dtype=float)
    r = read(_part("fig4.10", "GPREPS minus REPS reward"), run.summary)
    ref = stats.t.interval(0.95, d.size - 1, loc=d.mean(), scale=stats.sem(d))
    tol = fp_tol(4 * d.size + 16, scale=float(np.abs(g).max()))
    np.testing.assert_allclose([r.estimate, r.lower, r.upper], [d.mean(), *ref], rtol=0, atol=tol)


def test_fig411_hit_rate_is_a_wilson_interval_over_the_held_out_shots():
    run = _stored("fig4.11")
    settings = run.result["settings"]
    rates = np.asarray(run.summary["gpreps"]["final_hit_rate_per_trial"], dtype=float)
    k, n = (
        float(np.sum(rates * settings["evaluation"]["n_heldout"])),
        rates.size * settings["evaluation"]["n_heldout"],
    )
    r = read(_part("fig4.11", "hit rate"), run.summary, settings)
    # the pooled count (n flops), the bounds' ~20 flops, on the scale of a rate (≤ 1)
    np.testing.assert_allclose([r.lower, r.upper], _wilson(k, n), rtol=0, atol=fp_tol(n + 20))
    assert r.n == n


def test_fig411_start_against_end_is_paired_by_run():
    """The per-run start the paired reading needs; its interval is Student's t on the
    differences."""
    summary = {
        "gpreps": {
            "final_reward_per_trial": [-0.3, -0.4, -0.6],
            "initial_reward_per_trial": [-0.5, -0.6, -0.5],
        }
    }
    r = read(_part("fig4.11", "reward gain, end minus start"), summary)
    d = np.array([0.2, 0.2, -0.1])
    ref = stats.t.interval(0.95, 2, loc=d.mean(), scale=stats.sem(d))
    np.testing.assert_allclose([r.lower, r.upper], ref, rtol=0, atol=fp_tol(30, scale=1.0))
    assert r.outcome == "undecided" and "trials would decide it" in r.needed


def test_smoke_hockey_real_is_not_judged_and_records_the_per_run_numbers(tmp_path):
    run = reproduce("fig4.11", scale="smoke", seed=0, out=tmp_path, html=False, progress=False)
    s = run.summary
    assert s["verdict"] == "not judged" and s["holds"] is None
    assert card_lines_ok(s["judgement"]["card"]) and len(s["judgement"]["card"].split("\n")) == 3
    g = s["gpreps"]
    assert len(g["initial_reward_per_trial"]) == s["n_trials"] == 2
    x0 = g["initial_reward_per_trial"]  # a mean of n numbers, summed in another order
    assert abs(np.mean(x0) - g["initial_reward"]) <= fp_tol(len(x0), scale=np.abs(x0).max())
    assert len(g["prediction_relative_error_median_per_trial"]) == 2
    assert judge("fig4.11", s, "paper").readings[1].outcome != "not measured"


@pytest.mark.parametrize(
    ("exp_id", "model"), [("fig4.10", "HockeyRewardModel"), ("fig4.12", "TableTennisRewardModel")]
)
def test_each_trial_keeps_its_policy_history_and_reward_model(tmp_path, exp_id, model):
    """What ``skillkit view TASK --gpreps RUN`` loads: the GPREPS run's K + 1 policies and its
    last fitted model, whose layers have shapes the viewer accepts; the smoke run is not
    judged and its card is short."""
    run = reproduce(exp_id, scale="smoke", seed=0, out=tmp_path, html=False, progress=False)
    history, reward_model = load_gpreps_run(run.path, 0)
    assert type(reward_model).__name__ == model
    st = get(exp_id).settings["smoke"]
    assert len(history.policies) == st.gpreps.n_updates + 1
    s = reward_model.task.sample_context(0)
    specs = model_layers(reward_model, s, history.policies[-1].mean_of(s), n_samples=3, rng=0)
    assert len(specs) >= 3 and all(spec["trajectories"].shape[2] == 3 for spec in specs)
    summary = run.summary
    assert summary["gpreps"]["rollouts"] == st.gpreps.n_initial + st.gpreps.n_updates - 1
    assert summary["verdict"] == "not judged" and summary["not_judged"] == "smoke scale"
    assert card_lines_ok(summary["judgement"]["card"])
    assert not {"setup", "variants", "claim_parts"} & set(summary)
    if exp_id == "fig4.12":  # the per-trial number GP direct's "net, or even miss" reads
        for key in ("gpreps", "direct", "reps"):
            m = summary[key]
            both = np.add(m["final_net_per_trial"], m["final_missed_per_trial"])
            np.testing.assert_allclose(
                m["final_net_or_missed_per_trial"], both, rtol=0, atol=fp_tol(1)
            )


def test_bad_settings_are_refused_before_any_work():
    from dataclasses import replace

    with pytest.raises(ValueError, match="schedule"):
        replace(get("fig4.12").settings["paper"], schedule="sometimes")
    with pytest.raises(ValueError, match="task"):
        replace(get("fig4.10").settings["paper"], task="hockey-fast")
    with pytest.raises(ValueError, match="n_initial"):
        replace(get("fig4.11").settings["paper"], gpreps={"n_initial": 0})


def test_hockey_setup_names_the_refit_launch_targets_and_displacement_model():
    """Each model choice in the spec's setup table with the thesis sentence it follows; the
    variants tried, with their numbers, in the notes; ≥ 5 paper runs of fig4.10 and fig4.11."""
    rows = {row.what: row for row in spec("fig4.10").setup}
    for what in ("hyper-parameter refit", "launch targets"):
        assert "'" in rows[what].thesis and rows[what].why
    assert "After each data collection step" in rows["hyper-parameter refit"].thesis
    rows_411 = {row.what: row for row in spec("fig4.11").setup}
    assert "displacement of the second puck" in rows_411["displacement model"].thesis
    for exp_id in ("fig4.10", "fig4.11"):
        assert get(exp_id).trials["paper"] >= 5
        st = get(exp_id).settings["paper"]
        assert (st.refit, st.launch_targets, st.displacement) == ("best", "heading", "hit_gp")
        notes = (REPO / "data" / "notes" / f"{exp_id}.md").read_text()
        assert f"data/notes/{exp_id}.md" in spec(exp_id).notes[0]
        assert "| no |" in notes and "| yes |" in notes  # the worse variants too


def test_ci95_is_students_t_interval():
    v = np.array([-0.3, -0.2, -0.25, -0.1, -0.22])
    lo, hi = ev.ci95(v)
    ref = stats.t.interval(0.95, v.size - 1, loc=v.mean(), scale=stats.sem(v))
    # mean (n flops), standard deviation (2n + 3), the t quantile at 0.975 vs at
    # (1 − 0.95) / 2 (a few ulp each, and p off by an ulp: condition p / (q f(q)) < 1), the
    # product and the sum: ~3n + 16 flops on the mean's and the half-width's size
    scale = np.abs(ref).max() + abs(ref[1] - ref[0])
    np.testing.assert_allclose([lo, hi], ref, rtol=0, atol=fp_tol(3 * v.size + 16, scale=scale))


def test_bad_hockey_model_settings_name_the_setting():
    from dataclasses import replace

    st = get("fig4.10").settings["paper"]
    for name, bad in (("refit", "sometimes"), ("launch_targets", "polar"), ("displacement", "svm")):
        with pytest.raises(ValueError, match=name):
            replace(st, **{name: bad})
