"""The verdicts of fig4.6, fig4.7 and fig4.9 (skillkit.experiments.ch4_gpreps) on hand-made
summaries: each part of the thesis's sentences decides on its own, on both sides of its
bound; our own checks never change ``holds``."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from skillkit.experiments import get
from skillkit.experiments.ch4_gpreps import (
    _noise_ratios,
    claim_parts_46,
    claim_parts_47,
    claim_parts_49,
    own_checks_49,
    verdict_46,
    verdict_47,
    verdict_49,
)


def _method(reward: float, rollouts: int = 40, std: float = 1.0, n: int = 3,
            initial: float = -600.0) -> dict:  # fmt: skip
    return {
        "initial_reward": initial,
        "final_reward_mean": reward,
        "final_reward_std": std,
        "final_reward_per_trial": [reward] * n,
        "final_distance_mean_m": 0.1,
        "prediction_relative_error_median": 0.05,
        "rollouts": rollouts,
    }


def _summary_46(**kw) -> dict:
    """A fig4.6 summary meeting every part of the thesis's sentences; ``kw`` changes one."""
    v = {"g": -20.0, "g_std": 5.0, "g_rollouts": 39, "d": -100.0, "d_std": 50.0, "r": -60.0,
         "r_std": 20.0, "r_rollouts": 5000, "reached": None, "n": 3, **kw}  # fmt: skip
    return {
        "n_trials": v["n"],
        "gpreps": _method(v["g"], v["g_rollouts"], v["g_std"], v["n"]),
        "direct": _method(v["d"], v["g_rollouts"], v["d_std"], v["n"]),
        "reps": _method(v["r"], v["r_rollouts"], v["r_std"], v["n"]),
        "reps_rollouts_to_gpreps_final": v["reached"],
    }


@pytest.mark.parametrize(
    ("change", "part"),
    [
        ({"d": -700.0}, "gp_direct_learns"),  # ends below its start (−600)
        ({"d": -50.0}, "gp_direct_below_reps_and_gpreps"),  # above REPS (−60)
        ({"d_std": 10.0}, "gp_direct_higher_variance"),  # below REPS's 20
        ({"g_rollouts": 45}, "gpreps_within_40"),
        ({"g": -70.0}, "gpreps_highest_quality"),  # below REPS (−60)
        ({"g_std": 40.0}, "gpreps_negligible_variance"),  # 7% of the gain of 580
        ({"reached": 3000.0}, "two_orders_fewer_than_reps"),  # < 100 × 39 throws
    ],
)
def test_verdict_46_decides_each_part_of_the_sentences(change, part):
    st = get("fig4.6").settings["paper"]
    assert verdict_46(st, _summary_46()).holds is True
    assert verdict_46(st, _summary_46(reached=4500.0)).holds is True  # > 100 × 39
    assert claim_parts_46(_summary_46(**change))[part] is False
    v = verdict_46(st, _summary_46(**change))
    assert v.holds is False and part in v.statement


def test_verdict_46_undecided_parts():
    st = get("fig4.6").settings["paper"]
    # one trial: no spread to compare
    v = verdict_46(st, _summary_46(n=1))
    assert v.holds is None and "gpreps_negligible_variance" in v.statement
    # REPS's run shorter than 100 × GPREPS's throws and never reaching: not decided
    assert verdict_46(st, _summary_46(r_rollouts=1000)).holds is None
    s = _summary_46()
    assert "After 39 real throws" in verdict_46(st, s).statement
    assert "5000 rollouts" in verdict_46(st, s).statement


def _summary_47(finals: dict[int, float], stds: dict[int, float] | None = None, n=2) -> dict:
    stds = stds or {m: (50.0 if m < 500 else 5.0) for m in finals}
    return {"n_trials": n, **{f"m{m}": _method(r, 30, stds[m], n) for m, r in finals.items()}}


FINALS_47 = {50: -350.0, 100: -300.0, 200: -220.0, 500: -30.0, 1000: -20.0}


def test_verdict_47_judges_the_sentences():
    st = get("fig4.7").settings["paper"]
    assert set(st.n_artificial_values) >= {50, 500, 1000}
    assert verdict_47(st, _summary_47(FINALS_47)).holds is True
    # "always has a positive influence": M = 100 below M = 50
    s = _summary_47({**FINALS_47, 100: -360.0})
    assert claim_parts_47(st, s)["more_samples_always_better"] is False
    assert verdict_47(st, s).holds is False
    # "not much difference above 500": 500 → 1000 gains 100 of the 320 from 50 to 500 (> 1/4)
    s = _summary_47({**FINALS_47, 1000: 70.0})
    assert claim_parts_47(st, s)["little_gain_above_500"] is False
    assert verdict_47(st, s).holds is False
    # "highly varying" with fewer samples: M = 200 varies less than M = 1000
    stds = {50: 50.0, 100: 50.0, 200: 3.0, 500: 5.0, 1000: 5.0}
    s = _summary_47(FINALS_47, stds)
    assert claim_parts_47(st, s)["fewer_samples_vary_more"] is False
    assert verdict_47(st, s).holds is False
    # one trial: the spread is not measurable
    assert verdict_47(st, _summary_47(FINALS_47, n=1)).holds is None


def test_verdict_47_a_sweep_without_the_ms_of_the_claim_is_not_decided():
    smoke = get("fig4.7").settings["smoke"]
    v = verdict_47(smoke, _summary_47(dict.fromkeys(smoke.n_artificial_values, -1.0)))
    assert v.holds is None and "lacks M = 50/500/1000" in v.statement


def _summary_49(curves: tuple[float, float, float, float],
                noise: tuple[float, float, float, float] | None) -> dict:  # fmt: skip
    """REPS, REPS noisy, GPREPS, GPREPS noisy: final learning-curve rewards and (``noise``)
    the expected rewards of their final policies under the same release noise."""
    keys = ("reps", "reps_noisy", "gpreps", "gpreps_noisy")
    out: dict = {"n_trials": 2}
    for i, key in enumerate(keys):
        out[key] = _method(curves[i], 5000 if key.startswith("reps") else 30)
        if noise is not None:
            out[key]["noisy_expected_reward"] = noise[i]
    return out


CURVES_49 = (-77.6, -191.8, -32.0, -49.4)  # the stored run's learning curves (own check fails)


def test_verdict_49_compares_the_policies_under_the_same_noise():
    st = get("fig4.9").settings["paper"]
    # the stored run's numbers: REPS 2.02, GPREPS 0.915 under noise
    s = _summary_49(CURVES_49, (-93.7, -188.8, -52.0, -47.6))
    assert verdict_49(st, s).holds is True
    assert own_checks_49(s)["learning_curve_ratios"]["holds"] is False  # 1.55 > 1.2
    # GPREPS trained with noise 1.35× worse under noise: not of similar quality
    s = _summary_49(CURVES_49, (-93.7, -188.8, -52.0, -70.0))
    assert claim_parts_49(s)["gpreps_similar_quality"] is False
    assert verdict_49(st, s).holds is False
    # REPS trained with noise only 1.1× worse: of similar quality, against the thesis
    s = _summary_49(CURVES_49, (-93.7, -103.0, -52.0, -47.6))
    assert claim_parts_49(s)["reps_not_similar_quality"] is False
    assert verdict_49(st, s).holds is False


def test_verdict_49_learning_curves_are_an_own_check():
    st = get("fig4.9").settings["paper"]
    noise = (-93.7, -188.8, -52.0, -47.6)
    for curves, own in (((-715.0, -1086.0, -64.0, -68.0), True), (CURVES_49, False)):
        s = _summary_49(curves, noise)
        assert own_checks_49(s)["learning_curve_ratios"]["holds"] is own
        assert verdict_49(st, s).holds is True


def test_verdict_49_without_the_noisy_evaluation_is_not_decided():
    st = get("fig4.9").settings["paper"]
    s = _summary_49((-715.0, -1086.0, -64.0, -68.0), None)
    before = copy.deepcopy(s)
    v = verdict_49(st, s)
    assert v.holds is None and "not recorded in this run" in v.statement
    assert s == before  # a stored summary can be judged again without changing it
    assert _noise_ratios(s)["reps"] == pytest.approx(1086 / 715)
    assert _noise_ratios(s)["gpreps"] == pytest.approx(68 / 64)
    assert np.isfinite(_noise_ratios(s)["thesis_reps"])
