"""fig4.8 (Sec. 4.3.2.2): the stochastic pendulum's reward distribution and the L-averages."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.experiments.ch4_stochastic import (
    SCALES,
    block_rmse,
    commanded_transitions,
)
from skillkit.experiments.judge import card_lines_ok, judge, read, spec
from skillkit.experiments.registry import get
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials
from skillkit.tasks import make
from skillkit.tasks.pendulum import THESIS_GAINS, feedback_torque
from skillkit.trial import TrialContext

_CACHE: dict = {}


def _smoke() -> dict:
    if "r" not in _CACHE:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            _CACHE["r"] = run_trials("fig4.8", "smoke", seed=0, progress=False)
    return _CACHE["r"]


def test_mc_expected_reward_is_the_mean_of_independently_rescored_rollouts():
    """R_MC, its standard error and the single-rollout std are the plain statistics of the
    trial's rewards, and the first reward is that of a fresh simulation with the trial's
    generator, scored by hand."""
    r = _smoke()
    trial, summary = r["_trials"][0], r["summary"]
    rewards = np.asarray(trial["real_rewards"])
    assert summary["expected_reward_mc"] == pytest.approx(np.sum(rewards) / rewards.size)
    sd = np.sqrt(np.sum((rewards - rewards.mean()) ** 2) / (rewards.size - 1))
    assert summary["single_rollout_std"] == pytest.approx(sd)
    assert summary["expected_reward_mc_se"] == pytest.approx(sd / np.sqrt(rewards.size))
    assert summary["single_rollout_std_over_abs_expected"] == pytest.approx(
        sd / abs(rewards.mean())
    )
    # The rewards are the task's reward of real rollouts of the pair: re-simulate the first
    # one with the trial's generator and score it by hand, −Σ_{t≥1} (α_t² + 0.1 α̇_t²).
    s = SCALES["smoke"]
    task = make("pendulum-stochastic", horizon=s.horizon, control_noise=s.control_noise)
    rng = np.random.default_rng(np.random.SeedSequence(r["seed"]).spawn(1)[0])  # trial 0
    traj = task.rollout(np.array(s.gains), np.array(s.context), rng)
    x = traj.states[1:]
    assert rewards[0] == pytest.approx(-(x[:, 0] ** 2 + 0.1 * x[:, 1] ** 2).sum())
    assert np.allclose(trial["real_alpha"][0], traj.states[:, 0])
    # The rewards really vary: the experiment is about a noisy reward.
    assert np.unique(rewards).size == rewards.size


def test_block_rmse_closed_form_and_shrinks_with_L():
    assert block_rmse(np.array([1.0, 3.0, 5.0, 7.0]), 1, 4.0) == pytest.approx(np.sqrt(5.0))
    assert block_rmse(np.array([1.0, 3.0, 5.0, 7.0]), 2, 4.0) == pytest.approx(2.0)
    assert block_rmse(np.array([1.0, 3.0, 5.0, 7.0, 100.0]), 4, 4.0) == 0.0  # remainder unused
    # i.i.d. noise: the RMSE of the L-average is σ/√L (up to sampling error).
    x = np.random.default_rng(0).normal(2.0, 3.0, 200_000)
    for L in (1, 4, 25, 100):
        assert block_rmse(x, L, 2.0) == pytest.approx(3.0 / np.sqrt(L), rel=0.1)


def test_l_average_error_shrinks_with_L():
    """On average over trials the error of the model's L-average decreases with L, and so
    does that of the real rollouts' average."""
    summary = _smoke()["summary"]
    sizes = [str(L) for L in summary["sample_sizes"]]
    for key in ("rmse_model_L", "rmse_real_L"):
        errors = [summary[key][L] for L in sizes]
        assert errors[-1] < errors[0], (key, errors)
    # The single real rollout's RMSE is its (population) std: the estimate REPS uses.
    rewards = np.asarray(_smoke()["_trials"][0]["real_rewards"])
    assert summary["rmse_real_L"]["1"] == pytest.approx(rewards.std())


def test_model_is_trained_on_commanded_torques():
    """The applied torque carries the noise; the model input is the controller's output."""
    task = make("pendulum-stochastic", horizon=8)
    omega = THESIS_GAINS + np.array([0.2, -0.1])
    traj = task.rollout(omega, np.array([1.0, 0.5]), 3)
    x, u, x_next = commanded_transitions(task, traj, omega)
    _, applied, _ = task.transitions(traj)
    assert np.allclose(u[:, 0], feedback_torque(x, omega))
    assert not np.allclose(u, applied)
    assert np.array_equal(x_next, traj.states[1:]) and np.array_equal(x, traj.states[:-1])


def test_smoke_run_is_not_judged_and_its_card_is_short():
    summary = _smoke()["summary"]
    j = judge("fig4.8", summary, "smoke")
    assert j.outcome == "not judged" and card_lines_ok(j.card())
    assert summary["holds"] is None


def test_own_parts_read_the_stored_spread_and_l_average():
    """The thesis reports no result (not judged); the own parts read the stored numbers: the
    single-rollout spread recomputed from the stored std and R_MC, and the 100-trajectory model
    average's RMSE against one real rollout's."""
    run = stored_run("fig4.8")
    s = run.summary
    assert run.outcome == "not judged"
    spread, average = (p for p in spec("fig4.8").parts if p.own)
    r = read(spread, s)
    ratio = s["single_rollout_std"] / abs(s["expected_reward_mc"])
    assert r.estimate == r.lower == r.upper and abs(r.estimate - ratio) <= fp_tol(2, scale=ratio)
    assert r.outcome == "does not hold"  # 9.6% against our 10%
    r = read(average, s)
    assert r.estimate == s["rmse_model_L"]["100"] < s["rmse_real_L"]["1"]
    assert r.outcome == "holds"


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"sample_sizes": (5, 1)}, "sample_sizes: expected increasing"),
        ({"sample_sizes": (0, 5)}, "sample_sizes: expected increasing"),
        ({"n_model": 30}, "n_model: need at least two blocks"),
        ({"n_real": 30}, "n_real: need at least two blocks"),
        ({"control_noise": 0.0}, "control_noise: the experiment needs stochastic"),
        ({"train_gain_std": (-0.1, 0.2)}, "train_gain_std: expected ≥ 0"),
        ({"context": (5.0, 0.0)}, "context: alpha0=5 is outside"),
        ({"n_train": 0}, "n_train: expected ≥ 1"),
    ],
)
def test_bad_settings_are_rejected(overrides, match):
    run_trial = get("fig4.8").run_trial
    with pytest.raises(ValueError, match=match):  # at construction, or for the context in the trial
        settings = dataclasses.replace(SCALES["smoke"], **overrides)
        run_trial(settings, np.random.default_rng(0), TrialContext())
    with pytest.raises(ValueError, match="sample_sizes: expected list of int"):
        get("fig4.8").settings_for("smoke", sample_sizes=[1.5])
