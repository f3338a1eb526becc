"""fig3.5 (hockey, contextual REPS vs CrKR): a tiny deterministic run and the summary logic."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import ch3_hockey as ch
from skillkit.experiments.registry import get
from skillkit.experiments.runner import run_trials
from skillkit.models.kernels import gram
from skillkit.tasks import make


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
    assert set(a["summary"]["checks"]) == {
        "reps_learns",
        "reps_hit_rate_at_least_95pct",
        "reps_displacement_error_below_20cm",
        "crkr_lower_reward",
        "crkr_lower_hit_rate",
        "crkr_larger_displacement_error",
    }
    panels = {s["panel"] for s in a["series"]}
    assert len(panels) == 3 and len(a["series"]) == 6


def _fake_trial(reps_final: tuple[float, float, float], crkr_final: tuple[float, float, float]):
    trial = {}
    for name, (reward, hit, err) in (("reps", reps_final), ("crkr", crkr_final)):
        trial[f"{name}_rollouts"] = np.array([0, 50, 100])
        trial[f"{name}_mean_reward"] = np.array([-0.8, -0.6, reward])
        trial[f"{name}_explore_rollouts"] = np.array([50, 100])
        trial[f"{name}_explore_reward"] = np.array([-1.0, -0.9])
        trial[f"{name}_n_failed"] = np.array([0, 1])
        trial[f"{name}_heldout_rollouts"] = np.array([0, 100])
        trial[f"{name}_heldout_reward"] = np.array([-0.8, reward])
        trial[f"{name}_heldout_hit_rate"] = np.array([0.3, hit])
        trial[f"{name}_heldout_displacement_error"] = np.array([0.5, err])
        trial[f"{name}_heldout_displacement_error_hits"] = np.array([0.4, err])
        trial[f"{name}_heldout_blade_lowest"] = np.array([0.001, -0.002])
        trial[f"{name}_wall_time_s"] = 1.0
    return trial


def test_summary_checks_against_thesis_claims():
    settings = get("fig3.5").settings_for("quick")
    good = [
        _fake_trial((-0.2, 0.96, 0.15), (-0.5, 0.5, 0.4)),
        _fake_trial((-0.3, 1.0, 0.17), (-0.6, 0.4, 0.5)),
    ]
    series, summary = ch._summarize(settings, good)
    assert summary["reps"]["final_heldout_hit_rate"] == pytest.approx(0.98)
    assert summary["reps"]["final_heldout_displacement_error"] == pytest.approx(0.16)
    assert summary["reps"]["final_heldout_hit_rate_std"] == pytest.approx(0.02)
    assert summary["crkr"]["failed_rollouts"] == 2
    assert summary["reps"]["heldout_blade_lowest_m"] == -0.002
    assert all(summary["checks"].values()) and summary["holds"] is True
    assert "hits 98.0%" in summary["statement"] and "16.0 cm" in summary["statement"]
    band = next(s for s in series if s.name == ch.LABELS["reps"] and "hit rate" in s.panel)
    np.testing.assert_allclose(band.y, [0.3, 0.98])
    bad = [_fake_trial((-0.5, 0.9, 0.25), (-0.4, 0.95, 0.2))]
    _, summary = ch._summarize(settings, bad)
    checks = summary["checks"]
    assert checks["reps_learns"]
    assert not checks["reps_hit_rate_at_least_95pct"]
    assert not checks["reps_displacement_error_below_20cm"]
    assert not checks["crkr_lower_reward"]
    assert not checks["crkr_lower_hit_rate"]
    assert not checks["crkr_larger_displacement_error"]
    assert summary["holds"] is False
    tie = [_fake_trial((-0.2, 1.0, 0.05), (-0.3, 1.0, 0.2))]  # paper scale: both always hit
    checks = ch._summarize(settings, tie)[1]["checks"]
    assert checks["crkr_lower_reward"] and checks["crkr_larger_displacement_error"]
    assert not checks["crkr_lower_hit_rate"]


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
    np.testing.assert_allclose(gram(kernel, a, b), 2.0 * za @ zb.T + 0.5, rtol=1e-12)
    with pytest.raises(ValueError, match="scale"):
        ch.NormalisedLinear(centre, np.array([0.5, 0.0, 1.0]))
    with pytest.raises(ValueError, match="centre"):
        ch.NormalisedLinear(centre[:2], scale)
