"""fig4.12 / fig4.13's table-tennis parts (issue #31): settings, setup table, own checks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skillkit.experiments import ch4_table_tennis as tt
from skillkit.experiments.registry import get


def _gpreps(switched, returned) -> dict:
    g = {"switched_to_returning_at_update": switched, "final_returned_per_trial": returned}
    return {"gpreps": g}


def test_fig412_has_at_least_five_paper_trials_and_own_checks():
    exp = get("fig4.12")
    assert exp.trials["paper"] >= 5
    checks = exp.own_checks(exp.settings["paper"], _gpreps([3, 7], [0.95, 0.92]))
    assert {k: v["holds"] for k, v in checks.items()} == {
        "gpreps_switched_every_trial": True,
        "gpreps_returns_90pct_every_trial": True,
    }
    checks = tt.own_checks_412(_gpreps([3, None], [0.95, 0.85]))
    assert not checks["gpreps_switched_every_trial"]["holds"]
    assert not checks["gpreps_returns_90pct_every_trial"]["holds"]
    assert tt.own_checks_412(_gpreps(None, None))["gpreps_switched_every_trial"]["holds"] is None


def test_switch_update_is_the_first_returning_stage():
    from skillkit.experiments.ch4_events import _gpreps_stats

    def trial(stages):
        one = np.ones(len(stages))
        arrays = {f"gpreps_time_{p}": one for p in ("training", "prediction", "policy")}
        return {**arrays, "gpreps_relative_error": one, "gpreps_kl": one,
                "gpreps_stage": np.array(stages)}  # fmt: skip

    trials = [trial(["hitting", "hitting", "returning"]), trial(["hitting", "hitting"])]
    stats = _gpreps_stats(trials, "gpreps")
    assert stats["switched_to_returning_at_update"] == [3, None]


def test_setup_table_names_every_choice_with_the_thesis_sentence():
    st = get("fig4.12").settings["paper"]
    rows = tt._tt_setup(st)
    items = {r["item"] for r in rows}
    assert {"contact event", "contact inputs", "contact score", "refit", "reward schedule",
            "M, L, ε, data"} <= items  # fmt: skip
    assert all({"thesis", "ours", "why"} <= set(r) for r in rows)
    assert f"contact_score={st.contact_score!r}" in rows[-1]["ours"]
    # every variant tried is listed with its numbers
    names = {v["variant"] for v in tt.TT_VARIANTS}
    for features in ("thesis", "extended"):
        for score in ("decision", "probability", "margin"):
            assert f"event=face, features={features}, score={score}" in names
            assert f"event=closest, features={features}, score={score}" in names


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
