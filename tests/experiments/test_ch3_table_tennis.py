"""fig3.7 (table tennis, contextual REPS): a tiny deterministic run and the summary's
arithmetic on hand-made trials."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import get, judge
from skillkit.experiments.ch3_table_tennis import OUTCOMES, SCALES, run_trial, summarize
from skillkit.experiments.run import stored_run
from skillkit.trial import NullBar, TrialContext
from tests._tolerances import fp_tol

TINY = SCALES["smoke"]  # 2 updates of 12 rollouts, 3 final contexts


class _Bar(NullBar):
    def __init__(self):
        self.total, self.n = None, 0

    def reset(self, total=None):
        self.total, self.n = total, 0

    def update(self, n=1):
        self.n += n


@pytest.fixture(scope="module")
def tiny_runs():
    bars = [_Bar(), _Bar()]
    runs = [run_trial(TINY, np.random.default_rng(7), TrialContext(bar)) for bar in bars]
    return runs, bars


def test_registered_with_thesis_settings():
    exp = get("fig3.7")
    for scale in ("quick", "paper"):
        s = exp.settings_for(scale).reps
        assert s.epsilon == 0.6
        assert s.rollouts_per_update * s.n_reuse_batches == 200  # reuse the last 200
    paper = exp.settings_for("paper").reps
    assert paper.n_updates * paper.rollouts_per_update >= 4000  # thesis: ~4000 rollouts
    assert exp.trials["paper"] >= 10  # enough runs to count those stuck at the net


def test_tiny_run_is_deterministic_and_well_formed(tiny_runs):
    (a, b), bars = tiny_runs
    assert bars[0].total == TINY.reps.n_updates and bars[0].n == TINY.reps.n_updates
    np.testing.assert_array_equal(a["mean_reward"], b["mean_reward"])
    np.testing.assert_array_equal(a["final_rewards"], b["final_rewards"])
    assert a["final_outcomes"] == b["final_outcomes"]
    assert a["rollouts"].tolist() == [0, 12, 24]
    assert a["mean_reward"].shape == (3,) and a["explore_reward"].shape == (2,)
    assert a["final_rewards"].shape == (3,)
    assert np.all(np.isfinite(a["mean_reward"])) and np.all(a["mean_reward"] < 0)
    assert set(a["final_outcomes"]) <= set(OUTCOMES)
    series, summary = summarize(TINY, [a, b])
    final = float(np.mean(a["final_rewards"]))
    assert summary["final_reward_per_trial"] == [pytest.approx(final)] * 2
    assert sum(summary["outcome_fractions_mean"].values()) == pytest.approx(1.0)
    assert {s.panel for s in series} == {"learning curve", "final policy outcomes"}


def _trial(final_rewards, outcomes, curve, errors):
    return {
        "rollouts": np.array([0, 25, 50]),
        "mean_reward": np.array(curve),
        "explore_reward": np.array(curve[1:]),
        "n_failed": 0,
        "n_skipped_updates": 0,
        "final_rewards": np.array(final_rewards),
        "final_outcomes": list(outcomes),
        "final_landing_error": np.array(errors),
    }


def test_summary_arithmetic_on_hand_made_trials():
    good = _trial(
        [-0.01, -0.015, -0.012, -0.013],
        ["returned"] * 4,
        [-0.2, -0.05, -0.01],
        [0.05, 0.1, 0.08, 0.12],
    )
    netty = _trial(
        [-0.03, -0.04, -0.012, -0.3],
        ["net", "net", "returned", "missed"],
        [-0.2, -0.1, -0.03],
        [0.3, 0.4, 0.1, 2.9],
    )
    _, summary = summarize(SCALES["quick"], [good, netty])
    assert summary["final_reward_per_trial"] == pytest.approx([-0.0125, -0.0955])
    assert summary["fraction_runs_above_-0.02"] == 0.5
    assert summary["net_fraction_per_trial"] == [0.0, 0.5]
    assert summary["net_fraction_mean"] == 0.25
    assert summary["fraction_runs_with_net_failures_above_10pct"] == 0.5
    assert summary["outcome_fractions_mean"] == {
        "returned": 0.625,
        "net": 0.25,
        "out": 0.0,
        "missed": 0.125,
    }
    # returns only: errors 0.05, 0.1, 0.08, 0.12 and 0.1 -> median 0.1
    assert summary["median_landing_error_of_returns_m"] == pytest.approx(0.1)
    # mean curve: -0.2, -0.075, -0.02 -> never strictly above -0.02
    assert summary["rollouts_to_mean_curve_above_-0.02"] is None
    assert summary["initial_reward"] == pytest.approx(-0.2)
    assert summary["net_shot_reward_mean"] == pytest.approx(-0.035)
    assert summary["net_shot_reward_range"] == pytest.approx([-0.04, -0.03])
    assert summary["n_trials"] == 2


def _runs(n_good, n_net, n=10):
    """A summary of ``n`` runs: ``n_good`` end above −0.02, ``n_net`` put 20% into the net."""
    return {
        "final_reward_per_trial": [-0.01] * n_good + [-0.03] * (n - n_good),
        "net_fraction_per_trial": [0.2] * n_net + [0.02] * (n - n_net),
    }


@pytest.mark.parametrize(
    "n_good, n_net, n, outcome",
    [
        (3, 1, 10, "undecided"),  # 3 of 10 [11%, 60%]: "most" not excluded by ten runs
        (1, 1, 30, "does not hold"),  # 1 of 30 [0.6%, 17%]
        (29, 1, 30, "holds"),  # 29 of 30 above −0.02 and one run at the net
        (29, 0, 30, "undecided"),  # no run at the net: "sometimes" not shown
    ],
)
def test_spec_decides_most_runs_and_sometimes_the_net(n_good, n_net, n, outcome):
    assert judge.judge("fig3.7", _runs(n_good, n_net, n), "paper").outcome == outcome


def test_stored_run_reads_a_wilson_interval_over_runs():
    """The engine's interval on the stored paper run's "most evaluations" equals Wilson's
    formula on the runs above −0.02 (10 runs; round-off of a few operations)."""
    run = stored_run("fig3.7")
    final = np.asarray(run.summary["final_reward_per_trial"])
    k, n = float(np.sum(final > -0.02)), final.size
    z = 1.959963984540054
    centre = (k / n + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(k / n * (1 - k / n) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    r = run.judgement.readings[0]
    assert (k, n) == (3, 10) and r.estimate == 0.3
    assert r.lower == pytest.approx(centre - half, abs=fp_tol(20))
    assert r.upper == pytest.approx(centre + half, abs=fp_tol(20))
    assert r.outcome == "undecided" and judge.card_lines_ok(run.card)


def test_smoke_run_is_not_judged():
    from skillkit.experiments.runner import run_trials

    s = run_trials("fig3.7", "smoke", seed=0, progress=False)["summary"]
    assert s["holds"] is None and s["verdict"] == "not judged"
    assert judge.card_lines_ok(s["judgement"]["card"])


# ---------------------------------------------------------------- the weighted ML fit
def test_thesis_fit_is_the_default_and_the_regularised_one_is_named():
    from dataclasses import replace

    from skillkit.experiments.ch3_table_tennis import REGULARISED, make_reps
    from skillkit.tasks import make

    exp = get("fig3.7")
    for scale in ("quick", "paper"):
        s = exp.settings_for(scale)
        assert s.cov_shrinkage == 0.0 and s.min_effective_samples is None
    task = make("table-tennis")
    fit = make_reps(task, exp.settings_for("paper"))._fit_kwargs
    assert fit["cov_shrinkage"] == 0.0 and fit["min_effective_samples"] is None
    reg = make_reps(task, replace(exp.settings_for("paper"), **REGULARISED))._fit_kwargs
    assert reg["cov_shrinkage"] == 0.2 and reg["min_effective_samples"] == 10.0


def test_fig412_reps_keeps_the_settings_of_its_stored_result(monkeypatch):
    from skillkit.experiments import ch4_table_tennis as ch4_events

    seen = []

    class Stop(Exception):
        pass

    def fake_make_reps(task, settings):
        seen.append(settings)
        raise Stop

    monkeypatch.setattr(ch4_events, "make_reps", fake_make_reps)
    monkeypatch.setattr(ch4_events, "gpreps_run", lambda *a, **k: {})
    exp = get("fig4.12")
    with pytest.raises(Stop):
        exp.run_trial(exp.settings_for("smoke"), np.random.default_rng(0), TrialContext(_Bar()))
    (tt,) = seen
    # the values fig4.12's stored run was made with (the REGULARISED fit)
    assert (tt.reps.epsilon, tt.reps.rollouts_per_update, tt.reps.n_reuse_batches) == (0.6, 50, 4)
    assert tt.baseline_features == "linear"
    assert (tt.min_effective_samples, tt.cov_shrinkage) == (10.0, 0.2)


def _toy_batch_and_ess():
    from skillkit.policies.gaussian import LinearGaussianPolicy
    from skillkit.search.loop import collect
    from skillkit.search.reps import ContextualREPS
    from skillkit.tasks.toy import LinearTarget

    task = LinearTarget()
    pol = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
    batch = collect(task, pol, 12, 3)
    plain = ContextualREPS(pol, 0.5, min_effective_samples=1.0)
    diag = plain.update(batch)
    return pol, batch, diag.fit.effective_samples, plain.policy


def test_keep_policy_reps_skips_an_update_below_the_ess_floor_and_counts_it():
    from skillkit.experiments.ch3_table_tennis import KeepPolicyREPS, SkippedUpdate

    pol, batch, ess, fitted = _toy_batch_and_ess()
    assert 1.0 < ess < 12.0
    keep = KeepPolicyREPS(pol, 0.5, min_effective_samples=ess + 0.5)
    out = keep.update(batch)
    assert isinstance(out, SkippedUpdate)
    assert out.ess == pytest.approx(ess, rel=1e-9) and out.needed == ess + 0.5
    assert out.n_samples == 12 and "effective sample size" in out.message
    assert keep.policy is pol and keep.n_skipped == 1 and len(keep._buffer) == 12
    # just above the floor: the ordinary update, the same policy as plain REPS
    ok = KeepPolicyREPS(pol, 0.5, min_effective_samples=ess - 0.5)
    diag = ok.update(batch)
    assert not isinstance(diag, SkippedUpdate) and ok.n_skipped == 0
    np.testing.assert_array_equal(ok.policy.mean, fitted.mean)
    np.testing.assert_array_equal(ok.policy.cov, fitted.cov)


def test_keep_policy_reps_raises_other_errors():
    from skillkit.experiments.ch3_table_tennis import KeepPolicyREPS
    from skillkit.search.base import Batch

    pol, batch, _, _ = _toy_batch_and_ess()
    keep = KeepPolicyREPS(pol, 0.5)
    bad = Batch(batch.contexts, batch.omegas[:, :1], batch.rewards)
    with pytest.raises(ValueError, match="omegas"):
        keep.update(bad)
    assert keep.n_skipped == 0


def test_summary_counts_updates_that_kept_the_policy():
    trial = _trial([-0.01] * 4, ["returned"] * 4, [-0.2, -0.05, -0.01], [0.1] * 4)
    _, quiet = summarize(TINY, [trial, trial])
    assert quiet["skipped_updates"] == 0
    _, noted = summarize(
        TINY, [{**trial, "n_skipped_updates": 2}, {**trial, "n_skipped_updates": 1}]
    )
    assert noted["skipped_updates"] == 3
