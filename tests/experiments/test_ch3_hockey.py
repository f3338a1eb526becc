"""fig3.5 (hockey, contextual REPS vs CrKR): a tiny deterministic run and the summary logic."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import ch3_hockey as ch
from skillkit.experiments import judge
from skillkit.experiments.registry import get
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials
from skillkit.models.kernels import gram
from skillkit.tasks import make
from tests._tolerances import fp_tol


@pytest.fixture(scope="module")
def tiny_runs():
    """Two smoke-scale runs (one update of 25 rollouts, ε = 0.2, 3 held-out contexts)."""
    return [run_trials("fig3.5", "smoke", seed=3, progress=False) for _ in (0, 1)]


def test_registered_with_thesis_settings():
    exp = get("fig3.5")
    for scale in ("quick", "paper"):
        s = exp.settings_for(scale)
        assert s.reps.epsilon == 0.5 and s.task == "hockey"
    paper = exp.settings_for("paper").reps
    assert paper.n_updates * paper.rollouts_per_update >= 8000  # thesis: up to ~8000
    assert exp.trials["paper"] >= 3


def test_tiny_run_is_deterministic_and_complete(tiny_runs):
    a, b = tiny_runs
    tr_a, tr_b = a["_trials"][0], b["_trials"][0]
    assert tr_a.keys() == tr_b.keys()
    for key in tr_a:
        if not key.endswith("wall_time_s"):
            np.testing.assert_array_equal(np.asarray(tr_a[key]), np.asarray(tr_b[key]), err_msg=key)
    for name in ch.ALGORITHMS:
        np.testing.assert_array_equal(tr_a[f"{name}_rollouts"], [0, 25])
        np.testing.assert_array_equal(tr_a[f"{name}_heldout_rollouts"], [0, 25])
        assert tr_a[f"{name}_mean_reward"].shape == (2,)
        hit = tr_a[f"{name}_heldout_hit_rate"]
        assert np.all((hit >= 0) & (hit <= 1))
        assert np.all(np.isfinite(tr_a[f"{name}_heldout_displacement_error"]))
    # both algorithms start from the same initial policy on the same contexts
    np.testing.assert_array_equal(tr_a["reps_mean_reward"][0], tr_a["crkr_mean_reward"][0])
    for name in ch.ALGORITHMS:  # everything but the wall time is reproduced
        assert a["summary"][name].pop("wall_time_s") > 0
        b["summary"][name].pop("wall_time_s")
    assert a["summary"] == b["summary"]
    assert a["summary"]["verdict"] == "not judged"  # smoke scale
    assert judge.card_lines_ok(a["summary"]["judgement"]["card"])
    assert {r["label"] for r in a["summary"]["judgement"]["readings"] if r["own"]} == {
        "REPS error, misses as d*",
        "CrKR − REPS error, misses as d*",
        "REPS final minus initial reward",
    }
    panels = {s["panel"] for s in a["series"]}
    assert len(panels) == 3 and len(a["series"]) == 6


def _fake_trial(
    reps_final: tuple[float, float, float],
    crkr_final: tuple[float, float, float],
    placed: tuple[float, float] | None = None,
):
    """One trial's arrays; ``*_final`` = (reward, hit rate, error counting a miss as d*), and
    ``placed`` the placed puck's errors (REPS, CrKR; default: the same errors)."""
    trial = {}
    placed = placed or (reps_final[2], crkr_final[2])
    for (name, (reward, hit, err)), hits_err in zip(
        (("reps", reps_final), ("crkr", crkr_final)), placed, strict=True
    ):
        trial[f"{name}_rollouts"] = np.array([0, 50, 100])
        trial[f"{name}_mean_reward"] = np.array([-0.8, -0.6, reward])
        trial[f"{name}_explore_rollouts"] = np.array([50, 100])
        trial[f"{name}_explore_reward"] = np.array([-1.0, -0.9])
        trial[f"{name}_n_failed"] = np.array([0, 1])
        trial[f"{name}_heldout_rollouts"] = np.array([0, 100])
        trial[f"{name}_heldout_reward"] = np.array([-0.8, reward])
        trial[f"{name}_heldout_hit_rate"] = np.array([0.3, hit])
        trial[f"{name}_heldout_displacement_error"] = np.array([0.5, err])
        trial[f"{name}_heldout_displacement_error_hits"] = np.array([0.4, hits_err])
        trial[f"{name}_heldout_blade_lowest"] = np.array([0.001, -0.002])
        trial[f"{name}_wall_time_s"] = 1.0
    return trial


def test_summary_arithmetic_and_its_judgement():
    settings = get("fig3.5").settings_for("quick")
    good = [
        _fake_trial((-0.2, 0.96, 0.15), (-0.5, 0.5, 0.4)),
        _fake_trial((-0.3, 1.0, 0.17), (-0.6, 0.4, 0.5)),
    ]
    series, summary = ch._summarize(settings, good)
    reps, crkr = summary["reps"], summary["crkr"]
    assert reps["final_heldout_hit_rate"] == pytest.approx(0.98)
    assert reps["final_heldout_displacement_error"] == pytest.approx(0.16)
    assert reps["final_heldout_hit_rate_std"] == pytest.approx(0.02)
    assert reps["final_heldout_hit_rate_per_trial"] == pytest.approx([0.96, 1.0])
    assert reps["final_heldout_reward_per_trial"] == pytest.approx([-0.2, -0.3])
    assert reps["final_heldout_displacement_error_per_trial"] == pytest.approx([0.15, 0.17])
    assert reps["initial_mean_reward_per_trial"] == pytest.approx([-0.8, -0.8])
    assert reps["final_mean_reward_per_trial"] == pytest.approx([-0.2, -0.3])
    assert crkr["final_heldout_hit_rate_per_trial"] == pytest.approx([0.5, 0.4])
    assert crkr["failed_rollouts"] == 2
    assert reps["heldout_blade_lowest_m"] == -0.002
    band = next(s for s in series if s.name == ch.LABELS["reps"] and "hit rate" in s.panel)
    np.testing.assert_allclose(band.y, [0.3, 0.98])
    # 98% of 2 × 1000 held-out contexts: the pooled Wilson interval lies above 95%
    j = judge.judge("fig3.5", summary, "paper", {"evaluation": {"n_heldout": 1000}})
    assert j.readings[0].outcome == "holds"
    assert j.outcome == "undecided"  # two trials cannot decide the paired comparisons


def _summary_35(**kw) -> dict:
    """A fig3.5 summary of four trials that meets every part of the thesis's sentences;
    ``kw`` changes one per-trial array (REPS: ``hits``, ``placed``, ``miss_error``,
    ``curve``; CrKR: ``crkr_hit``, ``crkr_placed``, ``crkr_reward``)."""
    v = {
        "hits": [0.99, 1.0, 0.98, 0.99],
        "placed": [0.08, 0.12, 0.10, 0.09],
        "miss_error": [0.09, 0.12, 0.11, 0.10],
        "curve": [-0.2, -0.21, -0.19, -0.2],
        "crkr_hit": [0.8, 0.7, 0.75, 0.8],
        "crkr_placed": [0.30, 0.28, 0.33, 0.31],
        "crkr_reward": [-0.4, -0.45, -0.42, -0.41],
        **kw,
    }
    reps = {
        "initial_mean_reward_per_trial": [-0.7] * 4,
        "final_mean_reward_per_trial": v["curve"],
        "final_heldout_reward_per_trial": [-0.2, -0.21, -0.22, -0.2],
        "final_heldout_hit_rate_per_trial": v["hits"],
        "final_heldout_displacement_error_per_trial": v["miss_error"],
        "final_heldout_displacement_error_hits_per_trial": v["placed"],
    }
    crkr = {
        "final_heldout_reward_per_trial": v["crkr_reward"],
        "final_heldout_hit_rate_per_trial": v["crkr_hit"],
        "final_heldout_displacement_error_per_trial": [0.35, 0.36, 0.34, 0.37],
        "final_heldout_displacement_error_hits_per_trial": v["crkr_placed"],
    }
    return {"n_trials": 4, "rollouts_per_algorithm": 10000, "reps": reps, "crkr": crkr}


@pytest.mark.parametrize(
    ("change", "label"),
    [
        ({"hits": [0.85, 0.9, 0.88, 0.86]}, "REPS hit rate"),
        ({"placed": [0.28, 0.3, 0.26, 0.25]}, "REPS placed-puck error"),
        ({"hits": [0.96, 0.97, 0.96, 0.97], "crkr_hit": [1.0] * 4}, "CrKR minus REPS hit rate"),
        ({"crkr_placed": [0.05, 0.06, 0.04, 0.05]}, "CrKR minus REPS puck error"),
        ({"crkr_reward": [-0.1, -0.12, -0.11, -0.1]}, "CrKR minus REPS held-out reward"),
    ],
)
def test_spec_decides_each_part_of_the_sentence(change, label):
    settings = {"evaluation": {"n_heldout": 100}}
    assert judge.judge("fig3.5", _summary_35(), "paper", settings).outcome == "holds"
    j = judge.judge("fig3.5", _summary_35(**change), "paper", settings)
    assert j.outcome == "does not hold"
    assert [r.part.label for r in j.readings if r.outcome == "does not hold"] == [label]


def test_own_parts_do_not_change_the_verdict():
    """Counting a miss as an error of d* (30 cm) or a REPS curve that ends below its start
    fails our own parts, not the thesis's sentence."""
    for change in ({"miss_error": [0.3, 0.31, 0.32, 0.3]}, {"curve": [-0.8, -0.81, -0.79, -0.8]}):
        j = judge.judge(
            "fig3.5", _summary_35(**change), "paper", {"evaluation": {"n_heldout": 100}}
        )
        assert j.outcome == "holds"
        assert any(r.part.own and r.outcome == "does not hold" for r in j.readings)


def test_stored_run_reads_wilson_and_paired_t_intervals():
    """On the stored paper run the engine's REPS hit rate interval equals Wilson's formula on
    the pooled hits (5 × 100 held-out contexts), and its CrKR − REPS placed-puck error equals
    scipy's paired Student-t interval; float64 round-off of a few dozen operations."""
    run = stored_run("fig3.5")
    n = run.settings["evaluation"]["n_heldout"]
    rates = np.asarray(run.summary["reps"]["final_heldout_hit_rate_per_trial"])
    k, total = float(np.sum(rates * n)), n * rates.size
    p, z = k / total, stats.norm.ppf(0.975)
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * np.sqrt(p * (1 - p) / total + z * z / (4 * total**2)) / (1 + z * z / total)
    hit = run.judgement.readings[0]
    assert hit.n == total == 500
    assert hit.lower == pytest.approx(centre - half, abs=fp_tol(30))
    assert hit.upper == pytest.approx(centre + half, abs=fp_tol(30))
    assert hit.outcome == "undecided"  # 95.0% [92.7, 96.6]: the thesis's 95% inside
    key = "final_heldout_displacement_error_hits_per_trial"
    d = np.asarray(run.summary["crkr"][key]) - np.asarray(run.summary["reps"][key])
    lo, hi = stats.t.interval(0.95, d.size - 1, loc=d.mean(), scale=stats.sem(d))
    err = next(r for r in run.judgement.readings if r.part.label == "CrKR minus REPS puck error")
    assert err.lower == pytest.approx(lo, abs=fp_tol(20, scale=1.0))
    assert err.upper == pytest.approx(hi, abs=fp_tol(20, scale=1.0))
    assert err.outcome == "holds" and judge.card_lines_ok(run.card)


def test_crkr_starts_with_the_initial_diagonal_exploration():
    task = make("hockey")
    settings = get("fig3.5").settings_for("quick")
    crkr = ch.make_algorithm("crkr", task, settings)
    centre = 0.5 * (task.context_low + task.context_high)
    k_cc = float(gram(crkr.kernel, centre[None, :])[0, 0])
    assert k_cc == pytest.approx(1.0)  # z = 0 at the centre: only the intercept c = 1
    start = np.asarray(crkr.variance_scale) * (k_cc + crkr.lam)
    np.testing.assert_allclose(start, np.diag(task.initial_policy().cov))
    reps = ch.make_algorithm("reps", task, settings)
    assert reps.epsilon == 0.5
    with pytest.raises(ValueError, match="name"):
        ch.make_algorithm("pilco", task, settings)


def test_heldout_scores_closed_form_on_a_fixed_policy():
    """The demonstration mean hits the centre target; a context with the target behind the
    robot's line of fire is missed, so its displacement error is d*."""
    task = make("hockey")

    class Fixed:
        def mean_of(self, contexts):
            return np.tile(task.demo_omega, (len(contexts), 1))

    contexts = np.array([[2.0, 0.75, 0.5], [1.5, 1.0, 0.7]])
    scores = ch.heldout_scores(task, Fixed(), contexts, rng=0)
    trajs = [task.rollout(task.demo_omega, s, rng=0) for s in contexts]
    hits = [t.info["hit"] for t in trajs]
    assert hits == [True, False]
    assert scores["hit_rate"] == 0.5
    errors = [abs(t.info["displacement"] - s[2]) for t, s in zip(trajs, contexts, strict=True)]
    assert errors[1] == pytest.approx(0.7)
    assert scores["displacement_error"] == pytest.approx(np.mean(errors))
    assert scores["displacement_error_hits"] == pytest.approx(errors[0])
    assert scores["blade_lowest"] == min(t.info["blade_lowest"] for t in trajs)
    assert scores["reward"] == pytest.approx(
        np.mean([task.reward(t, s) for t, s in zip(trajs, contexts, strict=True)])
    )


def test_normalised_linear_kernel_closed_form():
    centre, scale = np.array([2.0, 0.75, 0.5]), np.array([0.5, 0.25, 0.5])
    kernel = ch.NormalisedLinear(centre, scale, variance=2.0, bias=0.5)
    rng = np.random.default_rng(0)
    a, b = rng.uniform(1.5, 2.5, (4, 3)), rng.uniform(1.5, 2.5, (3, 3))
    za, zb = (a - centre) / scale, (b - centre) / scale
    # z = (x − c) / s is off by ~2 ε |x| / s (x − c cancels), and σ² z·z' + c by (D + 2) ε
    # times the terms' size σ² ‖x_a / s‖ ‖x_b / s‖ + c (the entries can cancel): absolute
    na, nb = (np.linalg.norm(np.abs(x) / scale, axis=1).max() for x in (a, b))
    tol = fp_tol(3 + 2, scale=2.0 * na * nb + 0.5)
    np.testing.assert_allclose(gram(kernel, a, b), 2.0 * za @ zb.T + 0.5, rtol=0, atol=tol)
    with pytest.raises(ValueError, match="scale"):
        ch.NormalisedLinear(centre, np.array([0.5, 0.0, 1.0]))
    with pytest.raises(ValueError, match="centre"):
        ch.NormalisedLinear(centre[:2], scale)
