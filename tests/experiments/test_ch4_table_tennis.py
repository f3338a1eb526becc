"""fig4.12 / fig4.13's table-tennis parts: the claims spec's readings on the stored runs against
independent computations, the smoke run of fig4.13, settings, setup table and notes."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import ch4_table_tennis as tt
from skillkit.experiments import reproduce
from skillkit.experiments.judge import card_lines_ok, read, spec
from skillkit.experiments.registry import get
from tests._claims import part as _part
from tests._claims import stored as _stored
from tests._claims import wilson as _wilson
from tests._tolerances import fp_tol

REPO = Path(__file__).resolve().parents[2]


def test_fig412_net_share_is_a_wilson_interval_over_all_held_out_shots():
    """Not "≤ 5% in every trial" on 50 shots each (a policy at the pooled rate fails that most
    of the time), but the pooled share of every trial's held-out shots."""
    run = _stored("fig4.12")
    n_heldout = run.settings["evaluation"]["n_heldout"]
    net = np.asarray(run.summary["gpreps"]["final_net_per_trial"], dtype=float)
    k, n = float(np.round(np.sum(net * n_heldout))), net.size * n_heldout
    r = read(_part("fig4.12", "shots into the net"), run.summary, run.settings)
    # the pooled count (n flops, each share a multiple of 1/50 up to round-off), the bounds'
    # ~20 flops, on the scale of a rate (≤ 1)
    np.testing.assert_allclose([r.lower, r.upper], _wilson(k, n), rtol=0, atol=fp_tol(n + 20))
    assert r.n == n == run.summary["n_trials"] * n_heldout


def test_fig412_landing_error_is_students_t_over_the_stored_trials():
    run = _stored("fig4.12")
    x = np.asarray(run.summary["gpreps"]["final_landing_error_per_trial"], dtype=float)
    r = read(_part("fig4.12", "landing error"), run.summary)
    ref = stats.t.interval(0.95, x.size - 1, loc=x.mean(), scale=stats.sem(x))
    tol = fp_tol(3 * x.size + 16, scale=float(np.abs(ref).max()))
    np.testing.assert_allclose([r.lower, r.upper], ref, rtol=0, atol=tol)


def test_fig413_contact_accuracy_is_a_wilson_interval_over_the_held_out_pairs():
    """One trial: the interval is over its held-out (s, ω) pairs, against the majority class."""
    run = _stored("fig4.13")
    e = run.summary["errors"]
    k, n = e["contact_accuracy"] * e["n_pairs"], e["n_pairs"]
    part = _part("fig4.13", "contact accuracy")
    r = read(part, run.summary, run.settings)
    np.testing.assert_allclose([r.lower, r.upper], _wilson(k, n), rtol=0, atol=fp_tol(n + 20))
    assert part.threshold == ("errors", "contact_majority_rate") and r.n == n


def test_fig413_smoke_is_not_judged_and_records_per_trial_errors(tmp_path):
    run = reproduce("fig4.13", scale="smoke", seed=0, out=tmp_path, html=False, progress=False)
    s = run.summary
    assert s["verdict"] == "not judged" and s["holds"] is None
    assert card_lines_ok(s["judgement"]["card"])
    per_trial, errors = s["errors_per_trial"], s["errors"]
    assert set(per_trial) == set(errors)
    for name, values in per_trial.items():
        assert len(values) == s["n_trials"]
        assert (values[0] is None and errors[name] is None) or values[0] == errors[name]


def test_fig412_landing_error_upper_is_the_t_bound_over_the_shots():
    """The per-evaluation bound against scipy's Student-t interval over the same shots (one
    seed: the same simulator draws), and its use as fig4.12's per-trial reading."""
    from skillkit.experiments.ch3_table_tennis import shot_scores
    from skillkit.tasks import make

    task = make("table-tennis")
    contexts = task.sample_context(np.random.default_rng(3), n=12)
    policy = task.initial_policy()
    got = tt._shot_scores(task, policy, contexts, 7)
    e = shot_scores(task, policy, contexts, 7)[1]["landing_error"]
    e = e[np.isfinite(e)]
    ref = stats.t.interval(0.95, e.size - 1, loc=e.mean(), scale=stats.sem(e))[1]
    # as test_ci95_is_students_t_interval: ~3n + 16 flops on the bound's scale
    assert abs(got["landing_error_upper"] - ref) <= fp_tol(3 * e.size + 16, scale=abs(ref))
    assert got["landing_error_upper"] > got["landing_error"]
    part = _part("fig4.12", "trials under 30 cm")
    upper = [0.2, 0.25, 0.35]
    r = read(part, {"gpreps": {"final_landing_error_upper_per_trial": upper}})
    assert r.estimate == 2 / 3 and r.n == 3


def test_fig412_and_fig413_paper_counts():
    """fig4.12: ≥ 10 trials, ≥ 200 held-out contexts; fig4.13: ≥ 20 trials × ≥ 100 held-out."""
    assert get("fig4.12").trials["paper"] >= 10
    assert get("fig4.12").settings["paper"].evaluation.n_heldout >= 200
    assert get("fig4.13").trials["paper"] >= 20
    assert get("fig4.13").settings["paper"].n_heldout >= 100


def test_fig412_has_at_least_five_paper_trials_and_own_checks():
    assert get("fig4.12").trials["paper"] >= 5
    own = {p.label for p in spec("fig4.12").parts if p.own}
    assert own == {"trials switched to c₁ = c₂", "balls returned"}


def test_switch_update_is_the_first_returning_stage():
    from skillkit.experiments.ch4_events import gpreps_event_stats

    def trial(stages):
        one = np.ones(len(stages))
        arrays = {f"gpreps_time_{p}": one for p in ("training", "prediction", "policy")}
        return {
            **arrays,
            "gpreps_relative_error": one,
            "gpreps_kl": one,
            "gpreps_stage": np.array(stages),
        }

    trials = [trial(["hitting", "hitting", "returning"]), trial(["hitting", "hitting"])]
    stats_ = gpreps_event_stats(trials, "gpreps")
    assert stats_["switched_to_returning_at_update"] == [3, None]
    assert stats_["prediction_relative_error_median_per_trial"] == [1.0, 1.0]


def test_setup_table_names_every_choice_with_the_thesis_sentence():
    rows = {r.what: r for r in spec("fig4.12").setup}
    assert {
        "contact event",
        "contact inputs",
        "contact score",
        "refit",
        "reward schedule",
        "M, L, ε, data",
    } <= set(rows)
    assert all(r.thesis and r.ours and r.why for r in rows.values())
    # every variant tried is listed with its numbers
    notes = (REPO / "data" / "notes" / "fig4.12.md").read_text()
    for features in ("thesis", "extended"):
        for score in ("decision", "probability", "margin"):
            for event in ("face", "closest"):
                assert f"| event={event}, features={features}, score={score} |" in notes


def test_models_of_both_figures_use_the_settings_options():
    from skillkit.tasks import make

    task = make("table-tennis")
    for exp_id in ("fig4.12", "fig4.13"):
        st = replace(get(exp_id).settings["smoke"], contact_features="thesis", refit="cold")
        model = tt.table_tennis_reward_model(task, st)
        assert model.contact.features == "thesis" and model.refit == "cold"
        assert model.contact.score == st.contact_score


@pytest.mark.parametrize(
    ("field", "value"),
    [("contact_features", "all"), ("contact_score", "vote"), ("refit", "sometimes")],
)
def test_bad_model_options_are_refused_by_name(field, value):
    for exp_id in ("fig4.12", "fig4.13"):
        with pytest.raises(ValueError, match=field):
            replace(get(exp_id).settings["paper"], **{field: value})
