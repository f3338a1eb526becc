"""The generic learning-curve experiment (:func:`skillkit.experiments.curves.learning_curves`)."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import curves, registry
from skillkit.experiments.runner import run_trials
from skillkit.models.gp import ExactGP
from skillkit.search.gpreps import DirectRewardModel


@pytest.fixture
def experiment(monkeypatch):
    monkeypatch.setattr(registry, "_EXPERIMENTS", dict(registry._EXPERIMENTS))
    return curves.learning_curves(
        "test.curves",
        "REPS and GPREPS on throwing",
        "throwing",
        reward_model=lambda task: DirectRewardModel(ExactGP(n_steps=5)),
        thresholds=(-100.0,),
        claim="a test of the generic learning curves",
    )


def test_learning_curves_run_both_methods_on_the_same_contexts(experiment):
    result = run_trials("test.curves", "smoke", trials=1, progress=False)
    (trial,) = result["_trials"]
    st = experiment.settings["smoke"]
    assert trial["reps_rollouts"][-1] == st.reps.n_updates * st.reps.rollouts_per_update
    assert trial["gpreps_rollouts"][-1] == st.gpreps.n_initial + st.gpreps.n_updates - 1
    assert trial["reps_mean_reward"][0] == trial["gpreps_mean_reward"][0]  # same π₀, contexts
    summary = result["summary"]
    for method in ("reps", "gpreps"):
        assert set(summary[method]["rollouts_to_reach"]) == {"-100"}
        assert np.isfinite(summary[method]["final_reward_mean"])


def test_nested_blocks_take_a_mapping_of_some_fields(experiment):
    st = experiment.settings_for("smoke", gpreps={"n_updates": 1}, reps={"epsilon": 0.3})
    assert (st.gpreps.n_updates, st.gpreps.n_initial) == (1, 5)
    assert (st.reps.epsilon, st.reps.n_updates) == (0.3, 2)
    with pytest.raises(ValueError, match="gpreps.n_updates"):
        experiment.settings_for("smoke", gpreps={"n_updates": -1})
    with pytest.raises(ValueError, match="reps.*not a setting"):
        experiment.settings_for("smoke", reps={"budget": 3})


def test_without_a_reward_model_only_reps_runs(monkeypatch):
    monkeypatch.setattr(registry, "_EXPERIMENTS", dict(registry._EXPERIMENTS))
    exp = curves.learning_curves("test.reps", "REPS on throwing", "throwing", claim="a test")
    assert all(st.gpreps.n_updates == 0 for st in exp.settings.values())
    result = run_trials("test.reps", "smoke", trials=1, progress=False)
    assert "gpreps_mean_reward" not in result["_trials"][0] and "gpreps" not in result["summary"]
