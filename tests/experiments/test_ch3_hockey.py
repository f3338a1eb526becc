"""fig3.5 (hockey, contextual REPS vs CrKR): a tiny deterministic run and the summary logic."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import ch3_hockey as ch
from skillkit.experiments.registry import get
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
        assert s.epsilon == 0.5 and s.task == "hockey"
    paper = exp.settings_for("paper")
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
    assert set(a["summary"]["claim_parts"]) == {
        "reps_always_95pct_below_20cm",
        "crkr_lower_hit_rate",
        "crkr_larger_displacement_error",
        "crkr_could_not_compete",
    }
    assert set(a["summary"]["own_checks"]) == {
        "reps_learns",
        "reps_error_counting_misses_below_20cm",
        "crkr_larger_error_counting_misses",
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


def test_summary_judges_the_thesis_sentences():
    settings = get("fig3.5").settings_for("quick")
    good = [
        _fake_trial((-0.2, 0.96, 0.15), (-0.5, 0.5, 0.4)),
        _fake_trial((-0.3, 1.0, 0.17), (-0.6, 0.4, 0.5)),
    ]
    series, summary = ch._summarize(settings, good)
    assert summary["reps"]["final_heldout_hit_rate"] == pytest.approx(0.98)
    assert summary["reps"]["final_heldout_displacement_error"] == pytest.approx(0.16)
    assert summary["reps"]["final_heldout_hit_rate_std"] == pytest.approx(0.02)
    assert summary["reps"]["final_heldout_hit_rate_per_trial"] == pytest.approx([0.96, 1.0])
    assert summary["crkr"]["failed_rollouts"] == 2
    assert summary["reps"]["heldout_blade_lowest_m"] == -0.002
    assert all(summary["claim_parts"].values()) and summary["holds"] is True
    assert all(c["holds"] for c in summary["own_checks"].values())
    assert "hits 98.0%" in summary["statement"] and "16.0 cm" in summary["statement"]
    assert "per trial: 96.0, 100.0%" in summary["statement"]
    band = next(s for s in series if s.name == ch.LABELS["reps"] and "hit rate" in s.panel)
    np.testing.assert_allclose(band.y, [0.3, 0.98])
    bad = [_fake_trial((-0.5, 0.9, 0.25), (-0.4, 0.95, 0.2))]
    _, summary = ch._summarize(settings, bad)
    assert not any(summary["claim_parts"].values()) and summary["holds"] is False
    assert summary["own_checks"]["reps_learns"]["holds"] is True
    tie = [_fake_trial((-0.2, 1.0, 0.05), (-0.3, 1.0, 0.2))]  # paper scale: both always hit
    parts = ch._summarize(settings, tie)[1]["claim_parts"]
    assert parts["crkr_could_not_compete"] and parts["crkr_larger_displacement_error"]
    assert not parts["crkr_lower_hit_rate"]


def test_a_trial_below_95pct_fails_the_always_of_the_thesis():
    """The mean hit rate is above 95%, but one trial's is not: "always" fails."""
    settings = get("fig3.5").settings_for("quick")
    trials = [
        _fake_trial((-0.2, 0.90, 0.15), (-0.5, 0.5, 0.4)),
        _fake_trial((-0.3, 1.0, 0.17), (-0.6, 0.4, 0.5)),
        _fake_trial((-0.3, 1.0, 0.17), (-0.6, 0.4, 0.5)),
    ]
    summary = ch._summarize(settings, trials)[1]
    assert summary["reps"]["final_heldout_hit_rate"] > 0.95
    assert summary["claim_parts"]["reps_always_95pct_below_20cm"] is False
    assert (
        summary["holds"] is False
        and "Not met: reps_always_95pct_below_20cm" in (summary["statement"])
    )


def _summary_35(**kw) -> dict:
    """A fig3.5 summary that meets every part of the thesis's sentences; ``kw`` changes one
    number (REPS per trial: ``hits``, ``placed``; ``miss_error``; CrKR: ``crkr_hit``,
    ``crkr_placed``, ``crkr_reward``; REPS's learning curve ``reps_final_curve``)."""
    v = {"hits": [0.97, 0.99], "placed": [0.08, 0.12], "miss_error": 0.10, "crkr_hit": 0.8,
         "crkr_placed": 0.30, "crkr_reward": -0.4, "reps_final_curve": -0.2, **kw}  # fmt: skip
    reps = {
        "initial_mean_reward": -0.7,
        "final_mean_reward": v["reps_final_curve"],
        "final_heldout_reward": -0.2,
        "final_heldout_hit_rate": float(np.mean(v["hits"])),
        "final_heldout_hit_rate_per_trial": v["hits"],
        "final_heldout_displacement_error": v["miss_error"],
        "final_heldout_displacement_error_hits": float(np.mean(v["placed"])),
        "final_heldout_displacement_error_hits_per_trial": v["placed"],
    }
    crkr = {
        "initial_mean_reward": -0.7,
        "final_mean_reward": -0.4,
        "final_heldout_reward": v["crkr_reward"],
        "final_heldout_hit_rate": v["crkr_hit"],
        "final_heldout_displacement_error": 0.35,
        "final_heldout_displacement_error_hits": v["crkr_placed"],
    }
    return {"n_trials": 2, "rollouts_per_algorithm": 10000, "reps": reps, "crkr": crkr}


@pytest.mark.parametrize(
    ("change", "part"),
    [
        ({"hits": [0.93, 0.99]}, "reps_always_95pct_below_20cm"),
        ({"placed": [0.08, 0.24]}, "reps_always_95pct_below_20cm"),
        ({"crkr_hit": 0.99}, "crkr_lower_hit_rate"),
        ({"crkr_placed": 0.05}, "crkr_larger_displacement_error"),
        ({"crkr_reward": -0.1}, "crkr_could_not_compete"),
    ],
)
def test_verdict_decides_each_part_of_the_sentence(change, part):
    settings = get("fig3.5").settings_for("paper")
    assert ch.verdict(settings, _summary_35()).holds is True
    assert ch.claim_parts(_summary_35(**change))[part] is False
    assert ch.verdict(settings, _summary_35(**change)).holds is False


def test_own_checks_do_not_change_holds():
    """Counting a miss as an error of d* (30 cm) or a REPS curve that ends below its start
    fails our own checks, not the thesis's sentence."""
    settings = get("fig3.5").settings_for("paper")
    for change, name in (
        ({"miss_error": 0.30}, "reps_error_counting_misses_below_20cm"),
        ({"miss_error": 0.40}, "crkr_larger_error_counting_misses"),
        ({"reps_final_curve": -0.8}, "reps_learns"),
    ):
        summary = _summary_35(**change)
        assert ch.own_checks(summary)[name]["holds"] is False
        assert ch.own_checks(_summary_35())[name]["holds"] is True
        assert ch.verdict(settings, summary).holds is True


def test_a_stored_summary_without_per_trial_values_is_undecided():
    """Runs before issue #32 recorded no per-trial values: "always" cannot be decided, unless
    another part fails."""
    settings = get("fig3.5").settings_for("paper")
    summary = _summary_35()
    for key in (
        "final_heldout_hit_rate_per_trial",
        "final_heldout_displacement_error_hits_per_trial",
    ):
        del summary["reps"][key]
    v = ch.verdict(settings, summary)
    assert v.holds is None and "not recorded in this run" in v.statement
    summary["crkr"]["final_heldout_reward"] = -0.1
    assert ch.verdict(settings, summary).holds is False


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
