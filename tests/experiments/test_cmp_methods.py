"""``cmp.methods``: REPS, GPREPS, CMA-ES, C-CMA-ES and contextual BO on the thesis's tasks."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from skillkit.experiments import cmp_methods
from skillkit.experiments.curves import curve_task
from skillkit.experiments.registry import get
from skillkit.experiments.runner import run_trials
from skillkit.tasks import make
from tests._tolerances import fp_tol

TASKS = ("hockey", "balancing")  # the cheapest two at smoke scale (seconds)


@pytest.fixture(scope="module")
def result():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # diverging balancing gains
        return run_trials("cmp.methods", "smoke", trials=1, progress=False, tasks=TASKS)


def test_every_method_starts_from_the_same_policy_evaluated_the_same_way(result):
    (trial,) = result["_trials"]
    for task in TASKS:
        first = [trial[f"{task}/{m}_mean_reward"][0] for m in cmp_methods.METHODS]
        assert len(set(first)) == 1, (task, first)  # same π₀, contexts and evaluation seed


def test_budgets_follow_the_thesis_methods(result):
    (trial,) = result["_trials"]
    st = get("cmp.methods").settings["smoke"]
    for task in TASKS:
        thesis = cmp_methods.thesis_settings(task, st)
        rollouts = {m: trial[f"{task}/{m}_rollouts"] for m in cmp_methods.METHODS}
        assert rollouts["reps"][-1] == thesis.reps.n_updates * thesis.reps.rollouts_per_update
        if task == "balancing":  # Table 4.2's random-policy experience, counted as rollouts
            prior = thesis.n_random * thesis.random_steps / make("balancing").n_steps
            assert rollouts["gpreps"][0] == pytest.approx(prior, rel=fp_tol(4))
            assert rollouts["gpreps"][-1] == pytest.approx(prior + thesis.gpreps.n_updates)
        else:  # N₀, then one per update after the first batch (the thesis experiments' loop)
            assert rollouts["gpreps"][-1] == thesis.gpreps.n_initial + thesis.gpreps.n_updates - 1
        # CMA-ES: whole generations of λ m rollouts, the fewest that cover its budget
        per = np.diff(rollouts["cmaes"])[0]
        assert rollouts["cmaes"][-1] == per * math.ceil(st.cmaes_budget / per)
        assert rollouts["cbo"][-1] >= st.cbo_budget and np.all(np.diff(rollouts["cbo"]) > 0)
        # compute time is recorded per update and never decreases
        for m in cmp_methods.METHODS:
            t = trial[f"{task}/{m}_time_s"]
            assert t[0] == 0.0 and np.all(np.diff(t) >= 0)


def test_summary_names_winners_and_is_not_a_thesis_verdict(result):
    s = result["summary"]
    assert s["holds"] is None and s["thesis"] == [] and s["verdict"] == "not judged"
    assert "setup" not in s  # the setup table is the spec's (comparisons.toml)
    for task in TASKS:
        row = s["tasks"][task]
        assert row["thresholds"] == list(curve_task(task).thresholds)
        best = row["winners"]["best_final_reward"]
        finals = {m: v["final_reward_mean"] for m, v in row["methods"].items()}
        assert finals[best] == max(finals.values())


def test_winners_on_ties_at_pi0_and_when_no_method_reaches():
    def row(**at):
        return {
            m: {"final_reward_mean": -float(i), "thresholds": {"-1": {"rollouts_mean_curve": r}}}
            for i, (m, r) in enumerate(at.items())
        }

    assert cmp_methods._winners(row(a=10.0, b=10.0, c=30.0), [-1.0])["fewest_rollouts"] == {
        "-1": ["a", "b"]
    }
    assert cmp_methods._winners(row(a=0.0, b=5.0), [-1.0])["fewest_rollouts"] == {"-1": ["π₀"]}
    assert cmp_methods._winners(row(a=None, b=None), [-1.0])["fewest_rollouts"] == {"-1": None}
    assert cmp_methods._winners(row(a=None, b=3.0), [-1.0])["best_final_reward"] == "a"


def test_settings_overrides_reach_the_thesis_experiments_settings():
    st = get("cmp.methods").settings_for("smoke", gpreps_updates=7, n_artificial=33, reps_updates=3)
    throwing = cmp_methods.thesis_settings("throwing", st)
    g = throwing.gpreps
    assert (g.n_updates, g.n_artificial, throwing.reps.n_updates) == (7, 33, 3)
    balancing = cmp_methods.thesis_settings("balancing", st)
    assert (balancing.gpreps.n_updates, balancing.gpreps.n_artificial) == (7, 33)
    unchanged = cmp_methods.thesis_settings("hockey", get("cmp.methods").settings["smoke"])
    assert unchanged == get("fig4.10").settings["smoke"]


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("tasks", ("throwing", "juggling"), "tasks: expected distinct values"),
        ("tasks", ("throwing", "throwing"), "tasks: expected distinct values"),
        ("methods", ("reps", "ppo"), "methods: expected distinct values"),
        ("thesis_scale", "huge", "thesis_scale: expected one of"),
    ],
)
def test_bad_settings_are_named(name, value, match):
    st = get("cmp.methods").settings_for("smoke", **{name: value})
    with pytest.raises(ValueError, match=match):
        cmp_methods.run_trial(st, np.random.default_rng(0), None)  # checked before any work


def test_comparison_rows_and_tables_show_the_summary(result):
    from types import SimpleNamespace

    from skillkit.experiments.run import comparison_markdown, comparison_rows
    from skillkit.teaching.tables import method_comparison_table

    s = result["summary"]
    rows = comparison_rows(s)
    assert [(r["task"], r["method"]) for r in rows] == [
        (t, cmp_methods.LABELS[m]) for t in TASKS for m in cmp_methods.METHODS
    ]
    for r in rows:
        m = next(k for k, v in cmp_methods.LABELS.items() if v == r["method"])
        row = s["tasks"][r["task"]]["methods"][m]
        assert float(r["real rollouts"]) == row["real_rollouts"]  # printed in full, not .4g
        for level in s["tasks"][r["task"]]["thresholds"]:
            n = row["thresholds"][f"{level:g}"]["n_reached"]
            assert r[f"to R ≥ {level:g}"].endswith(f"({n}/1)")
    text = comparison_markdown(s)
    assert text.count("| method |") == len(TASKS) and text.count("Thresholds: ") == len(TASKS)
    table = method_comparison_table(SimpleNamespace(id="cmp.methods", summary=s))
    assert table.shape[0] == len(rows) and table.index.names == ["task", "method"]
    with pytest.raises(ValueError, match="run: expected a cmp.methods run"):
        method_comparison_table(SimpleNamespace(id="fig3.3", summary=s))


def test_rollout_counts_are_printed_in_full():
    from skillkit.experiments.run import _count

    assert _count(10048.0) == "10048" and _count(10_000) == "10000" and _count(27.5) == "27.5"


def test_the_thesis_scoreboard_leaves_comparisons_out(tmp_path):
    import json
    import shutil

    from skillkit.experiments.run import results_root, scoreboard

    shutil.copytree(results_root() / "fig2.10-paper-s0", tmp_path / "fig2.10-paper-s0")
    (tmp_path / "cmp.methods-quick-s0").mkdir()
    stored = json.loads((tmp_path / "fig2.10-paper-s0" / "result.json").read_text())
    (tmp_path / "cmp.methods-quick-s0" / "result.json").write_text(
        json.dumps({**stored, "id": "cmp.methods"})
    )
    board = scoreboard(tmp_path)
    assert "| fig2.10 |" in board and "cmp.methods" not in board


def test_readme_comparison_is_made_from_the_stored_result():
    """README.md's comparison tables are exactly comparison_section() of the stored run, which
    says whether today's code would still make it."""
    from pathlib import Path

    from skillkit.experiments.run import comparison_section, stored_run

    run = stored_run("cmp.methods")  # the paper-scale run
    readme = (Path(__file__).parents[2] / "README.md").read_text()
    table = readme.split("<!-- comparison:start -->\n")[1].split("<!-- comparison:end -->")[0]
    assert table == comparison_section(run)
    assert ("**stale**" in table) == (run.stale is not None)


@pytest.mark.parametrize("scale", ["smoke", "paper"])
def test_the_comparison_is_never_judged_and_its_card_is_short(result, scale):
    """Smoke runs are not judged, and the stored paper run neither: the thesis makes no such
    claim (the spec's no_result); the card says what is compared in three short lines."""
    from skillkit.experiments import judge
    from skillkit.experiments.run import stored_run

    s = result["summary"] if scale == "smoke" else stored_run("cmp.methods").summary
    why = "smoke scale" if scale == "smoke" else judge.spec("cmp.methods").no_result
    assert s["verdict"] == "not judged" and s["holds"] is None and s["not_judged"] == why
    card = s["judgement"]["card"]
    assert judge.card_lines_ok(card) and card.split("\n")[0] == (
        "cmp.methods: " + judge.spec("cmp.methods").plain
    )
    assert s["judgement"]["readings"] == []


def test_every_compared_task_has_a_learning_curve_profile():
    from skillkit.experiments.curves import register_curve_task

    for task in cmp_methods.TASKS:
        profile = curve_task(task)
        assert get(profile.experiment).settings_class is not None and profile.thresholds
    with pytest.raises(ValueError, match="has no learning-curve profile"):
        curve_task("pendulum")
    with pytest.raises(ValueError, match="unknown task"):
        register_curve_task("juggling", curve_task("hockey"))
