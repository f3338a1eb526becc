"""tab4.2 (Sec. 4.3.1): reading experience off the curves, the verdict's three criteria on
constructed summaries (the thesis's own numbers hold; each criterion can fail), settings."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from skillkit.experiments.ch4_balancing import (
    THESIS_42,
    BalancingComparisonSettings,
    experience_to_reach,
    initial_policy_42,
    median_reached,
    own_checks_42,
    random_experience,
    verdict_42,
)
from skillkit.models.linear import LinearGaussianModel
from skillkit.search import model_rollouts
from skillkit.search.gpreps import TrajectoryRewardModel
from skillkit.tasks import make
from tests._tolerances import mc_tol


def test_experience_to_reach_is_the_first_evaluation_at_or_above_the_limit():
    x = [6.0, 8.0, 10.0, 12.0]
    assert experience_to_reach(x, [-500.0, -120.0, -90.0, -200.0], -100.0) == 10.0
    assert experience_to_reach(x, [-500.0, -120.0, -90.0, -200.0], -10.0) is None
    assert experience_to_reach(x, [-100.0, -1e7, -1e7, -1e7], -100.0) == 6.0


def _summary(exp, compute, n=3, reps_budget=20000.0, start=-180.0):
    """A summary with the given experience / compute per method and limit: a number (every
    trial), None (no trial reaches it) or a list (per trial, None where a trial does not)."""
    st = BalancingComparisonSettings(linear_variant=False)
    out = {"n_trials": n, "table": ["…"], "start_reward_per_trial": [start] * n}

    def per_trial(v):
        return list(v) if isinstance(v, list) else [v] * n

    for key in ("pilco", "gpreps", "reps"):
        rows = {}
        for i, limit in enumerate(st.limits):
            e = per_trial(exp[key][i])
            reached = [x for x in e if x is not None]
            rows[f"{limit:g}"] = {
                "experience_s_per_trial": e,
                "experience_s_mean": float(np.mean(reached)) if reached else None,
                "n_reached": len(reached),
            }
            if key != "reps":
                c = per_trial(compute[key][i])
                c = [None if x is None else ci for x, ci in zip(e, c, strict=True)]
                rows[f"{limit:g}"]["compute_time_s_per_trial"] = c
        out[key] = {"limits": rows, "experience_budget_s": reps_budget,
                    "compute_time_s_total_mean": 1.0}  # fmt: skip
    return st, out


def test_the_thesis_numbers_satisfy_the_verdict_and_each_criterion_can_fail():
    thesis = THESIS_42["experience_s"]
    compute = {"pilco": [25.0, 40.0, 60.0], "gpreps": [10.0, 15.0, 25.0]}  # 2.4–2.7×
    st, s = _summary(thesis, compute)
    assert verdict_42(st, s).holds is True
    # REPS only 10× slower than GPREPS: not two orders of magnitude.
    st, s = _summary({**thesis, "reps": [100.0, 200.0, 385.0]}, compute)
    assert verdict_42(st, s).holds is False
    # REPS never reaching −1.5 within a large budget still counts as slower.
    st, s = _summary({**thesis, "reps": [1425.0, 2300.0, None]}, compute)
    assert verdict_42(st, s).holds is True
    # PILCO slower than GPREPS at one limit.
    st, s = _summary({**thesis, "pilco": [10.18, 30.0, 12.18]}, compute)
    assert verdict_42(st, s).holds is False
    # PILCO cheaper than GPREPS.
    st, s = _summary(thesis, {"pilco": [1.0, 1.0, 1.0], "gpreps": [10.0, 15.0, 25.0]})
    assert verdict_42(st, s).holds is False
    # A model-based method that never reaches a limit: not two orders of magnitude, but PILCO,
    # which does, is the more data-efficient one.
    st, s = _summary({**thesis, "gpreps": [10.68, 20.52, None]}, compute)
    v = verdict_42(st, s)
    assert v.holds is False
    assert "PILCO the most data-efficient (its median no larger at every limit): True" in (
        v.statement
    )
    assert "GPREPS two orders of magnitude below REPS at -1.5" in v.statement
    st, s = _summary({**thesis, "pilco": [10.18, 11.46, None]}, compute)
    assert "PILCO the most data-efficient (its median no larger at every limit): False" in (
        verdict_42(st, s).statement
    )


def test_the_verdict_judges_medians_with_a_trial_that_never_reaches_counted_as_slowest():
    """Five trials, one of which never reaches a limit: the median is that of the four
    plus +∞ (the thesis's numbers hold); with three of five missing the median is not
    finite and (1) fails. The strict reading (every trial reaches every limit), the
    criterion before 2026-12-03, is an own check that cannot change ``holds``."""
    thesis = THESIS_42["experience_s"]
    compute = {"pilco": [25.0, 40.0, 60.0], "gpreps": [10.0, 15.0, 25.0]}
    one_miss = [10.68, 10.68, None, 10.68, 10.68]
    gpreps = [one_miss, [20.52, 20.52, None, 20.52, 20.52], [20.0, 44.0, None, 28.0, 28.0]]
    st, s = _summary({**thesis, "gpreps": gpreps}, compute, n=5)
    v = verdict_42(st, s)
    assert v.holds is True and "-1.5: PILCO 12.18, GPREPS 28, REPS 4075" in v.statement
    assert own_checks_42(st, s)["gpreps_two_orders_below_reps"]["holds"] is False
    three_miss = [None, None, None, 28.0, 28.0]
    st, s = _summary({**thesis, "gpreps": [*gpreps[:2], three_miss]}, compute, n=5)
    v = verdict_42(st, s)
    assert v.holds is False and "GPREPS 28, REPS 4075" not in v.statement
    assert "(ratio undefined: GPREPS's median does not reach it)" in v.statement
    assert "n/a" not in v.statement and "None" not in v.statement
    # An even number of trials: the median of two middle values, +∞ if one of them misses.
    assert median_reached([1.0, 3.0]) == 2.0 and median_reached([1.0, None]) is None
    assert median_reached([None, 2.0, 4.0]) == 4.0


def test_pilco_needs_at_least_twice_gpreps_computation_time():
    """ "at least twice as much computation time": 1.5× fails (it held before issue #32),
    2.5× holds."""
    thesis = THESIS_42["experience_s"]
    gpreps = [10.0, 15.0, 25.0]
    for factor, holds in ((1.5, False), (2.5, True)):
        st, s = _summary(thesis, {"pilco": [factor * c for c in gpreps], "gpreps": gpreps})
        assert verdict_42(st, s).holds is holds


def test_pilco_against_reps_is_an_own_check():
    """The two orders of magnitude are the thesis's for GPREPS; PILCO's are our own check."""
    thesis = THESIS_42["experience_s"]
    compute = {"pilco": [25.0, 40.0, 60.0], "gpreps": [10.0, 15.0, 25.0]}
    st, s = _summary(thesis, compute)
    assert own_checks_42(st, s)["pilco_two_orders_below_reps"]["holds"] is True
    st, s = _summary({**thesis, "pilco": [10.18, 11.46, None], "gpreps": [10.68, 20.52, None]},
                     compute)  # fmt: skip
    assert own_checks_42(st, s)["pilco_two_orders_below_reps"]["holds"] is False


def test_the_start_below_minus_100_is_an_own_check():
    thesis = THESIS_42["experience_s"]
    compute = {"pilco": [25.0, 40.0, 60.0], "gpreps": [10.0, 15.0, 25.0]}
    st, s = _summary(thesis, compute)
    assert own_checks_42(st, s)["start_below_first_limit"]["holds"] is True
    st, s = _summary(thesis, compute, start=-90.0)
    assert own_checks_42(st, s)["start_below_first_limit"]["holds"] is False


def _rewards(task, gain, n, seed):
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.array([task.reward(task.rollout(np.ravel(gain), rng=rng)) for _ in range(n)])


def test_pi0_reproduces_the_thesis_start_far_below_minus_100():
    """The thesis's REPS needs 1425 s to reach −100, so π₀ starts below it: the expected
    reward of π₀'s mean controller (what every curve shows at 0 s) lies below −100 by more
    than 3 Monte Carlo standard errors (measured −183 ± 11 with 400 start states), and its
    exploration reaches the tight LQR gain (10 standard deviations; the old π₀: 1909)."""
    st = BalancingComparisonSettings()
    task = make("balancing", initial_std=st.initial_std)
    pi0 = initial_policy_42(st, task)
    r = _rewards(task, pi0.mean, 200, 0)
    assert r.mean() + mc_tol(r.std(ddof=1), r.size, 3.0) < st.limits[0]
    d = task.lqr_gain(control_weight=1e-4).ravel() - pi0.mean
    assert np.sqrt(d @ np.linalg.solve(pi0.cov, d)) < 15


def test_smallest_limit_is_reachable_with_margin():
    """The LQR gain (R = 1e-4) at the chosen start distribution scores above −1.5 by many
    standard errors (measured −0.55 ± 0.03; at the old σ = 0.1: −1.12)."""
    st = BalancingComparisonSettings()
    task = make("balancing", initial_std=st.initial_std)
    r = _rewards(task, task.lqr_gain(control_weight=1e-4), 200, 1)
    assert r.mean() - mc_tol(r.std(ddof=1), r.size, 5.0) > st.limits[-1]
    assert r.mean() > 0.5 * st.limits[-1]  # a factor 2 inside the limit, not at its edge


def test_artificial_samples_of_one_update_share_their_start_states(monkeypatch):
    """Every pair's L predicted trajectories start from the same L states (different among
    themselves); with common_start_states the experiment builds this model."""
    task = make("balancing", initial_std=0.07, excitation_std=30.0)
    gain = task.lqr_gain(control_weight=1.0).ravel()
    rng = np.random.default_rng(0)
    trajs = [task.rollout(gain, rng=rng) for _ in range(2)]
    model = TrajectoryRewardModel(
        make("balancing", initial_std=0.07), LinearGaussianModel, common_start_states=True
    )
    model.fit(None, None, None, trajs, rng=0)
    seen = []
    real = model_rollouts.predict_trajectories

    def spy(*args, **kwargs):
        seen.append(np.array(kwargs["x0"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(model_rollouts, "predict_trajectories", spy)
    omegas = gain + np.random.default_rng(1).normal(0, 1.0, (6, 32))
    r = model.expected_rewards(np.zeros((6, 0)), omegas, 4, rng=2)
    assert r.shape == (6,) and len(seen) == 1
    x0 = seen[0]
    assert x0.shape == (6, 4, 8)
    np.testing.assert_array_equal(x0, np.broadcast_to(x0[0], x0.shape))
    assert len({tuple(x) for x in x0[0]}) == 4


def test_settings_check():
    with pytest.raises(ValueError, match="model_mean"):
        BalancingComparisonSettings(model_mean="constant")
    with pytest.raises(ValueError, match="exploration"):
        BalancingComparisonSettings(exploration=0.0)
    with pytest.raises(ValueError, match="initial_std"):
        BalancingComparisonSettings(initial_std=0.0)
    with pytest.raises(ValueError, match="n_designs"):
        BalancingComparisonSettings(n_designs=1)
    st = replace(BalancingComparisonSettings(), start_gain_scale=0.5)
    with pytest.raises(ValueError, match="start_gain_scale"):
        initial_policy_42(st, make("balancing", initial_std=st.initial_std))
    with pytest.raises(ValueError, match="limits"):
        BalancingComparisonSettings(limits=(-1.5, -10.0))
    with pytest.raises(ValueError, match="limits"):
        BalancingComparisonSettings(limits=(-10.0, 1.0))
    with pytest.raises(ValueError, match="n_random"):
        BalancingComparisonSettings(n_random=0)


def test_random_experience_counts_control_steps_of_any_length():
    """12 rollouts of 10 steps at 50 ms are 6 s, as 3 of 40 (Sec. 4.3.1's 6 s); a
    trajectory without a control step is named."""
    task = make("balancing", initial_std=0.07)
    gain = task.lqr_gain(control_weight=1.0).ravel()
    short = make("balancing", initial_std=0.07, n_steps=10)
    trajs = [short.rollout(gain, rng=i) for i in range(12)]
    assert random_experience(task, trajs) == pytest.approx(6.0)
    assert random_experience(task, [task.rollout(gain, rng=0)] * 3) == pytest.approx(6.0)

    class Empty:
        controls = np.zeros((1, 4))

    with pytest.raises(ValueError, match="trajectories"):
        random_experience(task, [Empty()])


def test_short_random_rollouts_keep_the_learning_horizon(monkeypatch):
    """With random-policy rollouts shorter than the learning rollouts, GPREPS still predicts
    over the task's 40 steps (the reward model took its horizon from the first trajectory
    it learned, a 10-step prior one) and the curves start after the 6 s of random data."""
    from skillkit.experiments import ch4_balancing as mod
    from skillkit.trial import TrialContext

    st = replace(
        BalancingComparisonSettings(),
        **mod._SMOKE,
        linear_variant=False,
        random_steps=10,
        n_random=12,
        excitation_std=3.0,
    )
    horizons = []
    real = mod.GPREPS.update

    def spy(self, batch):
        out = real(self, batch)
        horizons.append(self.reward_model.horizon)
        return out

    monkeypatch.setattr(mod.GPREPS, "update", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = mod.run_trial_42(st, np.random.default_rng(0), TrialContext())
    assert horizons and set(horizons) == {40}
    for key in ("pilco", "gpreps"):
        assert out[f"{key}_experience"][0] == pytest.approx(6.0)
        np.testing.assert_allclose(np.diff(out[f"{key}_experience"]), 2.0)


def test_the_random_policy_gives_six_seconds_near_upright():
    """The default random policy (12 × 0.5 s of π₀'s gains with 3 N m excitation) gives the
    thesis's 6 s, with the links near upright where the learned controllers act (measured rms
    q̃ 0.18–0.30 rad on data seeds 0–2; the old 3 × 2 s at 30 N m: 0.82 rad on seed 0)."""
    from skillkit.tasks.balancing import X_UP, collect_balancing

    st = BalancingComparisonSettings()
    task = make("balancing", initial_std=st.initial_std)
    excited = make("balancing", initial_std=st.initial_std, excitation_std=st.excitation_std,
                   n_steps=st.random_steps)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = collect_balancing(excited, st.n_random, 0, 1.0, policy=initial_policy_42(st, task))
    assert random_experience(task, data["trajectories"]) == pytest.approx(6.0)
    q = data["x"][:, :4] - X_UP[:4]
    assert np.sqrt((q**2).mean()) < 0.4
