"""fig4.6, fig4.7 and fig4.9 (skillkit.experiments.ch4_gpreps): the claims engine's readings of
the stored paper runs against independent computations, the measurements the readings need
(rebuilt from the stored per-trial arrays), and the smoke runs (never judged, short cards)."""

from __future__ import annotations

import numpy as np
import pytest
from _tolerances import fp_tol
from scipy import stats

from skillkit.experiments.ch4_gpreps import _noise_ratios
from skillkit.experiments.judge import card_lines_ok, judge, read, spec
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials
from tests._claims import resummarised


def _part(exp_id: str, label: str):
    (p,) = [p for p in spec(exp_id).parts if p.label == label]
    return p


def _resummarised(exp_id: str):
    return resummarised(exp_id)


def _t_interval(x) -> tuple[float, float]:
    x = np.asarray(x, dtype=float)
    return stats.t.interval(0.95, x.size - 1, loc=x.mean(), scale=stats.sem(x))


def test_fig4_6_paired_reading_is_the_t_interval_of_per_trial_differences():
    """GPREPS minus GP direct's final reward: the engine's interval is Student's t on the
    five per-trial differences of the stored run."""
    run = stored_run("fig4.6")
    s = run.summary
    diff = np.subtract(s["gpreps"]["final_reward_per_trial"], s["direct"]["final_reward_per_trial"])
    r = read(_part("fig4.6", "GPREPS − GP direct final"), s)
    lo, hi = _t_interval(diff)
    tol = fp_tol(50, scale=float(np.abs(diff).max()))
    assert r.n == 5 and abs(r.estimate - diff.mean()) <= tol
    assert abs(r.lower - lo) <= tol and abs(r.upper - hi) <= tol
    assert r.outcome == "holds"  # 522 [367, 676]


def test_fig4_6_gp_direct_learns_is_paired_on_its_start_per_trial():
    """Rebuilt from the stored curves, the per-trial changes (−51, −9, −11, +108, +88) leave
    "GP direct learns" undecided, the summary's other numbers are the stored ones, and the
    stored (remeasured) run reads the same."""
    run, s = _resummarised("fig4.6")
    label = "GP direct: final − start"
    for key in ("gpreps", "direct", "reps"):
        assert s[key]["final_reward_per_trial"] == run.summary[key]["final_reward_per_trial"]
    d = s["direct"]
    change = np.subtract(d["final_reward_per_trial"], d["initial_reward_per_trial"])
    r = read(_part("fig4.6", label), s)
    lo, hi = _t_interval(change)
    tol = fp_tol(50, scale=float(np.abs(change).max()))
    assert abs(r.lower - lo) <= tol and abs(r.upper - hi) <= tol
    assert r.outcome == "undecided"
    assert read(_part("fig4.6", label), run.summary).estimate == r.estimate
    err = read(_part("fig4.6", "model reward error"), s)
    assert err.outcome == "undecided" and err.n == 5  # per-trial medians 7–21%


def test_fig4_7_always_better_steps_are_paired_t_intervals():
    run = stored_run("fig4.7")
    s = run.summary
    diff = np.subtract(s["m100"]["final_reward_per_trial"], s["m50"]["final_reward_per_trial"])
    r = read(_part("fig4.7", "M 100 − M 50 final reward"), s)
    lo, hi = _t_interval(diff)
    tol = fp_tol(50, scale=float(np.abs(diff).max()))
    assert abs(r.lower - lo) <= tol and abs(r.upper - hi) <= tol
    assert r.outcome == "holds"
    assert read(_part("fig4.7", "M 200 − M 100 final reward"), s).outcome == "undecided"


def test_fig4_7_little_gain_above_500_is_a_ratio_of_paired_changes():
    """The change 500 → 1000 over the gain 50 → 500, built per trial from the stored final
    rewards: its estimate is the ratio of the mean final rewards' differences."""
    run, s = _resummarised("fig4.7")
    m = {k: np.asarray(run.summary[k]["final_reward_per_trial"]) for k in ("m50", "m500", "m1000")}
    r = read(_part("fig4.7", "change 500→1000 / gain 50→500"), s)
    want = (m["m1000"] - m["m500"]).mean() / (m["m500"] - m["m50"]).mean()
    assert abs(r.estimate - want) <= fp_tol(50, scale=abs(want))
    assert r.outcome == "holds"


def test_fig4_9_ratio_reading_is_the_bootstrap_of_the_stored_final_rewards():
    """GPREPS noisy / noise-free final reward: the estimate is the summary's learning-curve
    ratio (2.11 against the thesis's 1.06), the interval the paired percentile bootstrap."""
    run = stored_run("fig4.9")
    s = run.summary
    x = np.asarray(s["gpreps_noisy"]["final_reward_per_trial"])
    y = np.asarray(s["gpreps"]["final_reward_per_trial"])
    r = read(_part("fig4.9", "GPREPS noisy / noise-free"), s)
    assert abs(r.estimate - s["noise_ratio"]["gpreps"]) <= fp_tol(20, scale=r.estimate)
    ci = stats.bootstrap(
        (x, y),
        lambda a, b, axis=-1: a.mean(axis=axis) / b.mean(axis=axis),
        paired=True,
        vectorized=True,
        n_resamples=9999,
        method="percentile",
        rng=np.random.default_rng(0),
    ).confidence_interval
    assert abs(r.lower - ci.low) <= fp_tol(50, scale=ci.high)
    assert abs(r.upper - ci.high) <= fp_tol(50, scale=ci.high)
    assert r.outcome == "does not hold" and run.outcome == "does not hold"


def test_fig4_9_same_noise_evaluation_is_an_own_check_per_trial():
    run, s = _resummarised("fig4.9")
    for key in ("gpreps", "gpreps_noisy", "reps", "reps_noisy"):
        per = s[key]["noisy_expected_reward_per_trial"]
        assert len(per) == 5
        mean = run.summary[key]["noisy_expected_reward"]
        assert abs(np.mean(per) - mean) <= fp_tol(10, scale=abs(mean))
    r = read(_part("fig4.9", "GPREPS same-noise ratio"), s)
    assert r.part.own and r.outcome == "holds"  # 1.02
    assert judge("fig4.9", s, "paper").outcome == "does not hold"


def test_noise_ratios_are_the_final_rewards_ratios():
    finals = {"reps": -715.0, "reps_noisy": -1086.0, "gpreps": -64.0, "gpreps_noisy": -68.0}
    s = {k: {"final_reward_mean": v} for k, v in finals.items()}
    assert _noise_ratios(s)["reps"] == pytest.approx(1086 / 715)
    assert _noise_ratios(s)["gpreps"] == pytest.approx(68 / 64)
    assert np.isfinite(_noise_ratios(s)["thesis_reps"])


@pytest.mark.parametrize("exp_id", ["fig4.6", "fig4.7", "fig4.9"])
def test_smoke_runs_are_not_judged_and_cards_are_short(exp_id):
    summary = run_trials(exp_id, "smoke", seed=0, progress=False)["summary"]
    j = judge(exp_id, summary, "smoke")
    assert j.outcome == "not judged" and card_lines_ok(j.card())
    assert summary["holds"] is None


def test_fig4_6_gp_direct_runs_to_the_thesis_curve_end_with_its_own_update_count():
    """GP direct's N₀ + K − 1 real throws reach the thesis's 100 at paper scale; a smoke run
    with its own K records that many throws beside GPREPS's unchanged curve."""
    from skillkit.experiments.registry import get

    paper = get("fig4.6").settings["paper"]
    assert paper.gpreps.n_initial + paper.direct_updates - 1 == 100
    r = run_trials("fig4.6", "smoke", seed=0, progress=False, direct_updates=4)
    t, g = r["_trials"][0], r["settings"]["gpreps"]
    assert t["direct_rollouts"][-1] == g["n_initial"] + 4 - 1
    assert t["direct_mean_reward"].shape == (4 + 1,)
    assert t["gpreps_rollouts"][-1] == g["n_initial"] + g["n_updates"] - 1
    assert r["summary"]["direct"]["rollouts"] == g["n_initial"] + 4 - 1
