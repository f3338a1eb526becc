"""The verdicts of fig4.6, fig4.7 and fig4.9 (skillkit.experiments.ch4_gpreps) on hand-made
summaries: each criterion of the docstring decides, at its boundary, on its own."""

from __future__ import annotations

import copy

import pytest

from skillkit.experiments import get
from skillkit.experiments.ch4_gpreps import _noise_ratios, verdict_46, verdict_47, verdict_49


def _method(reward: float, rollouts: int = 40) -> dict:
    return {
        "final_reward_mean": reward,
        "final_reward_std": 1.0,
        "final_distance_mean_m": 0.1,
        "prediction_relative_error_median": 0.05,
        "rollouts": rollouts,
    }


def _summary_46(gpreps: float, direct: float, reps: float) -> dict:
    return {
        "n_trials": 3,
        "gpreps": _method(gpreps, 39),
        "direct": _method(direct, 39),
        "reps": _method(reps, 5000),
    }


def test_verdict_46_needs_gpreps_at_least_reps_and_above_gp_direct():
    st = get("fig4.6").settings["smoke"]
    assert verdict_46(st, _summary_46(-10.0, -20.0, -10.0)).holds is True  # ties REPS
    assert verdict_46(st, _summary_46(-10.0, -20.0, -9.99)).holds is False  # below REPS
    assert verdict_46(st, _summary_46(-10.0, -10.0, -50.0)).holds is False  # ties GP direct
    v = verdict_46(st, _summary_46(-10.0, -20.0, -50.0))
    assert "After 39 real throws" in v.statement and "5000 rollouts" in v.statement


def _summary_47(finals: dict[int, float]) -> dict:
    return {"n_trials": 2, **{f"m{m}": _method(r, 40) for m, r in finals.items()}}


def test_verdict_47_needs_a_gain_to_500_and_little_above():
    st = get("fig4.7").settings["paper"]
    assert set(st.n_artificial_values) >= {50, 500, 1000}
    base = dict.fromkeys(st.n_artificial_values, -30.0)
    # gain 50 → 500 of 20; 500 → 1000 must gain less than a quarter of it (5)
    assert verdict_47(st, _summary_47({**base, 50: -30.0, 500: -10.0, 1000: -5.01})).holds
    assert not verdict_47(st, _summary_47({**base, 50: -30.0, 500: -10.0, 1000: -5.0})).holds
    assert not verdict_47(st, _summary_47({**base, 50: -10.0, 500: -10.0, 1000: -10.0})).holds
    # a sweep without M = 50, 500 and 1000 cannot decide and says so
    smoke = get("fig4.7").settings["smoke"]
    v = verdict_47(smoke, _summary_47(dict.fromkeys(smoke.n_artificial_values, -1.0)))
    assert v.holds is False and "lacks M = 50/500/1000" in v.statement


def _summary_49(reps: float, reps_noisy: float, gpreps: float, gpreps_noisy: float) -> dict:
    return {
        "n_trials": 2,
        "reps": _method(reps, 5000),
        "reps_noisy": _method(reps_noisy, 5000),
        "gpreps": _method(gpreps, 40),
        "gpreps_noisy": _method(gpreps_noisy, 40),
    }


def test_verdict_49_compares_noise_ratios():
    st = get("fig4.9").settings["smoke"]
    assert verdict_49(st, _summary_49(-715.0, -1086.0, -64.0, -68.0)).holds is True  # thesis
    # GPREPS may lose at most 20% to noise ...
    assert verdict_49(st, _summary_49(-100.0, -200.0, -50.0, -60.0)).holds is True
    assert verdict_49(st, _summary_49(-100.0, -200.0, -50.0, -60.5)).holds is False
    # ... and must lose less than REPS
    assert verdict_49(st, _summary_49(-100.0, -105.0, -50.0, -55.0)).holds is False
    s = _summary_49(-715.0, -1086.0, -64.0, -68.0)
    before = copy.deepcopy(s)
    verdict_49(st, s)
    assert s == before  # a stored summary can be judged again without changing it
    assert _noise_ratios(s)["reps"] == pytest.approx(1086 / 715)
    assert _noise_ratios(s)["gpreps"] == pytest.approx(68 / 64)
