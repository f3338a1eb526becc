"""Chapter 4, Table 4.2 (Sec. 4.3.1): the real experience PILCO, GPREPS and REPS need to find
gains G of u = G x̃ that balance the planar 4-link robot, all from the same π₀
(:func:`initial_policy_42`), scored by R = −Σ_t x̃_tᵀ x̃_t on common start states. The
model-based methods start from 6 s of random-policy experience and make one real rollout per
update, REPS 25; departures from the thesis: ``skillkit/data/claims/ch4.toml``."""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from skillkit.experiments.curves import (
    COV_FLOOR,
    MIN_EFFECTIVE_SAMPLES,
    CurveTask,
    EvaluationBlock,
    GPREPSBlock,
    REPSBlock,
    experiment,
    nan_mean,
    register_curve_task,
    regularised_reps,
)
from skillkit.experiments.judge import quoted_numbers
from skillkit.experiments.registry import Series
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ForwardModel
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sparse import FITC
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.search import ContextualREPS, learn
from skillkit.search.gpreps import GPREPS, GPREPSSettings, TrajectoryRewardModel
from skillkit.search.pilco import PILCO, PILCOSettings
from skillkit.tasks import make
from skillkit.tasks.balancing import Balancing, collect_balancing, design_policy
from skillkit.trial import TrialContext
from skillkit.viz.series import trial_band

METHODS = ("pilco", "gpreps", "reps")
LINEAR_METHODS = ("pilco_linear", "gpreps_linear")
LABELS = {"pilco": "PILCO", "gpreps": "GPREPS", "reps": "REPS"}
LABELS |= {f"{m}_linear": f"{LABELS[m]} (linear model)" for m in ("pilco", "gpreps")}


def thesis_42() -> dict:
    """Table 4.2's numbers as the claims spec records them: the limits and, per method, the
    experience (s) to reach each."""
    x = quoted_numbers("tab4.2")  # PILCO ×3, GPREPS ×3, REPS ×3, then the limits
    return {
        "limits": x[9:12],
        "experience_s": {m: x[3 * i : 3 * i + 3] for i, m in enumerate(METHODS)},
    }


@dataclass(frozen=True)
class BalancingComparisonSettings(Settings):
    """Settings of ``tab4.2`` (PILCO, GPREPS and REPS on balancing, Sec. 4.3.1)."""

    initial_std: float = setting(0.07, "σ of x₀ ~ N(x_up, σ² I) (rad, rad/s).", above=0)
    limits: tuple[float, ...] = setting((-100.0, -10.0, -1.5), "Reward limits of Table 4.2.")
    start_control_weight: float = setting(
        1.0, "R of the LQR design scaled into π₀'s mean.", above=0
    )
    start_gain_scale: float = setting(
        0.68, "κ: π₀'s mean is κ G_lqr(start_control_weight).", above=0
    )
    exploration: float = setting(0.7, "c: π₀'s covariance is c² that of the designs.", above=0)
    n_designs: int = setting(300, "Designs whose covariance shapes π₀'s.", minimum=2)
    design_spread: float = setting(2.0, "Log-scale spread of the designs' cost weights.", minimum=0)
    design_control_weight: float = setting(1e-2, "Base R of the designs.", above=0)
    gain_scale_std: float = setting(0.15, "σ of the designs' log gain level.", minimum=0)
    design_seed: int = setting(0, "Seed of the designs: the same π₀ everywhere.", minimum=0)
    common_start_states: bool = setting(True, "One set of L start states per update (Eq. 4.1).")
    excitation_std: float = setting(3.0, "σ_ξ (N m) of the random policy's torques.", minimum=0)
    n_random: int = setting(12, "Random-policy rollouts (6 s in all, Sec. 4.3.1).", minimum=1)
    random_steps: int = setting(10, "Control steps of each random-policy rollout.", minimum=1)
    evaluation: EvaluationBlock = setting(
        EvaluationBlock(n_eval_contexts=50), "Evaluation start states, common to the methods."
    )
    n_inducing: int = setting(100, "Pseudo-inputs of the FITC dynamics model.", minimum=1)
    model_mean: str = setting("linear", "FITC prior mean: 'linear' or 'zero' (PILCO's).")
    linear_variant: bool = setting(True, "Also run PILCO and GPREPS with a linear model.")
    gp_steps: int = setting(100, "L-BFGS iterations of each FITC hyper-parameter fit.", minimum=0)
    pilco_updates: int = setting(10, "PILCO updates (one real rollout each).", minimum=1)
    policy_iterations: int = setting(50, "L-BFGS iterations of each PILCO update.", minimum=1)
    gpreps: GPREPSBlock = setting(
        GPREPSBlock(n_updates=20, n_initial=1, n_artificial=500, n_trajectories=10, epsilon=1.0),
        "GPREPS, one real rollout per update after the random policy's (no contexts: μ̂ unused).",
    )
    reps: REPSBlock = setting(
        REPSBlock(n_updates=100, rollouts_per_update=25, epsilon=0.5, n_reuse_batches=8),
        "Model-free REPS, no initial data.",
    )

    def check(self) -> None:
        """Limits negative and rising (harder ones later); a known model mean."""
        lim = np.asarray(self.limits, dtype=float)
        if lim.size == 0 or np.any(np.diff(lim) <= 0) or np.any(lim >= 0):
            raise ValueError(f"limits: expected rising negative rewards, got {self.limits}")
        if self.model_mean not in ("linear", "zero"):
            raise ValueError(f"model_mean: expected 'linear' or 'zero', got {self.model_mean!r}")


def initial_policy_42(st: BalancingComparisonSettings, task: Balancing) -> GaussianPolicy:
    """π₀ of every method: N(κ vec G_lqr(R), c² Σ_d) (:func:`design_policy`), the same in
    every trial (``design_seed``). Raises ValueError when its mean does not balance (closed
    loop of the linearisation at upright not stable): no method could start there."""
    mean = st.start_gain_scale * task.lqr_gain(control_weight=st.start_control_weight)
    a, b = task.linearization()
    radius = float(np.abs(np.linalg.eigvals(a + b @ mean)).max())
    if radius >= 1.0:
        raise ValueError(
            f"start_gain_scale: π₀'s mean {st.start_gain_scale:g} G_lqr does not balance "
            f"(spectral radius {radius:.3f} of the closed loop at upright)"
        )
    return design_policy(
        task,
        mean,
        st.exploration,
        st.n_designs,
        st.design_spread,
        st.design_control_weight,
        st.gain_scale_std,
        st.design_seed,
    )


def _fitc(n_inducing: int, n_steps: int, mean: str) -> ForwardModel:
    # Δx targets (ForwardModel's default target is x′).
    return ForwardModel(FITC(n_inducing=n_inducing, n_steps=n_steps), target="delta", mean=mean)


def random_experience(task: Balancing, trajectories) -> float:
    """Seconds of real experience in ``trajectories``: their control steps × ``control_dt``
    (the random-policy rollouts may be shorter than the learning rollouts)."""
    steps = [len(t.controls) - 1 for t in trajectories]
    if any(n < 1 for n in steps):
        raise ValueError("trajectories: expected rollouts with at least one control step")
    return float(sum(steps) * task.control_dt)


def _run_model_based(task, st, pi0, prior, key, make_model, rng, trial, evals, eval_seed) -> dict:
    """PILCO (``key`` "pilco...") or GPREPS from ``prior``: experience, reward, compute."""
    alg_rng, loop_rng = rng.spawn(2)
    if key.startswith("pilco"):
        settings = PILCOSettings(policy_iterations=st.policy_iterations)
        algo = PILCO(task, pi0, make_model, settings, rng=alg_rng, prior_trajectories=prior)
        updates, parts = st.pilco_updates, ("training", "policy")
    else:
        algo = gpreps_algorithm(task, st, pi0, prior, make_model, alg_rng)
        updates, parts = st.gpreps.n_updates, ("training", "prediction", "policy")
    c = learn(
        task,
        algo,
        updates,
        1,
        loop_rng,
        initial_rollouts=1 if key.startswith("pilco") else st.gpreps.n_initial,
        trial=trial,
        checkpoint_key=key,
        eval_contexts=evals,
        eval_seed=eval_seed,
    )
    d = c["diagnostics"]
    per = [sum(getattr(x, f"time_{p}") for p in parts) for x in d]
    rollout_s = task.n_steps * task.control_dt
    return {  # with the model's prediction of each real rollout's reward and the real one
        f"{key}_experience": random_experience(task, prior) + rollout_s * c["rollouts"],
        f"{key}_mean_reward": c["mean_reward"],
        f"{key}_eval_failure_rate": c["eval_failure_rate"],
        f"{key}_time_cumulative": np.concatenate([[0.0], np.cumsum(per)]),
        f"{key}_predicted": np.array(
            [np.nan if x.predicted_real_reward is None else x.predicted_real_reward for x in d]
        ),
        f"{key}_real": np.array([x.real_reward for x in d]),
    }


def random_prior(st: BalancingComparisonSettings, pi0: GaussianPolicy, rng) -> dict:
    """The random policy's experience the model-based methods start from: gains drawn from π₀
    with white torque excitation (:func:`~skillkit.tasks.balancing.collect_balancing`)."""
    excited = make(
        "balancing",
        initial_std=st.initial_std,
        excitation_std=st.excitation_std,
        n_steps=st.random_steps,
    )
    return collect_balancing(excited, st.n_random, rng, 1.0, policy=pi0)


def gpreps_algorithm(task, st: BalancingComparisonSettings, pi0, prior, make_model, rng) -> GPREPS:
    """Table 4.2's GPREPS: ε, M, L of ``st``, the FITC (or ``make_model``) dynamics model
    started from the ``prior`` trajectories, common start states if ``st`` says so."""
    settings = GPREPSSettings(
        epsilon=st.gpreps.epsilon,
        n_artificial=st.gpreps.n_artificial,
        n_trajectories=st.gpreps.n_trajectories,
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )
    # The horizon is the learning rollouts' (the random-policy ones may be shorter).
    model = TrajectoryRewardModel(
        task,
        make_model,
        horizon=task.n_steps,
        prior_trajectories=prior,
        common_start_states=st.common_start_states,
    )
    return GPREPS(pi0, model, settings, rng=rng, task=task)


def reps_algorithm(st: BalancingComparisonSettings, pi0) -> ContextualREPS:
    """Table 4.2's model-free REPS (no initial data)."""
    return regularised_reps(pi0, st.reps.epsilon, st.reps.n_reuse_batches, "linear")


def fitc_model(st: BalancingComparisonSettings):
    """``make_model`` of Table 4.2's FITC dynamics model (pseudo-inputs, fit iterations and
    prior mean of ``st``; Δx targets)."""
    return partial(_fitc, st.n_inducing, st.gp_steps, st.model_mean)


def methods(st: BalancingComparisonSettings) -> tuple[str, ...]:
    """The runs of a trial: the thesis's three, then the linear-model variants if asked."""
    return METHODS + (LINEAR_METHODS if st.linear_variant else ())


def run_trial_42(st: BalancingComparisonSettings, rng: np.random.Generator, trial: TrialContext):
    """PILCO, GPREPS and REPS from the same π₀; the model-based ones from the same 6 s."""
    task = make("balancing", initial_std=st.initial_std)
    pi0 = initial_policy_42(st, task)
    random_rng, pilco_rng, gpreps_rng, reps_rng, lin_p_rng, lin_g_rng = rng.spawn(6)
    eval_seed = int(rng.integers(2**63))  # every method is evaluated on the same start states
    evals = np.zeros((st.evaluation.n_eval_contexts, 0))
    # The random policy: gains drawn from π₀ that balance at upright, with torque excitation.
    random = random_prior(st, pi0, random_rng)
    prior = random["trajectories"]
    gp = fitc_model(st)
    n_model_runs = 2 if st.linear_variant else 1
    trial.reset(total=n_model_runs * (st.pilco_updates + st.gpreps.n_updates) + st.reps.n_updates)
    out: dict = {
        "random_policy_rewards": np.array([task.reward(t) for t in prior]),
        "random_policy_failed": random["n_failed"],
    }
    for key, r in (("pilco", pilco_rng), ("gpreps", gpreps_rng)):
        out.update(_run_model_based(task, st, pi0, prior, key, gp, r, trial, evals, eval_seed))

    # REPS (model-free: no initial data).
    reps = reps_algorithm(st, pi0)
    t0 = time.perf_counter()
    c = learn(
        task,
        reps,
        st.reps.n_updates,
        st.reps.rollouts_per_update,
        reps_rng,
        trial=trial,
        checkpoint_key="reps",
        eval_contexts=evals,
        eval_seed=eval_seed,
    )
    out["reps_experience"] = task.n_steps * task.control_dt * c["rollouts"].astype(float)
    out["reps_mean_reward"] = c["mean_reward"]
    out["reps_eval_failure_rate"] = c["eval_failure_rate"]
    out["reps_time_total"] = time.perf_counter() - t0

    if st.linear_variant:  # the same searches with a model that can predict the closed loop
        lin = LinearGaussianModel
        for key, r in (("pilco_linear", lin_p_rng), ("gpreps_linear", lin_g_rng)):
            out.update(_run_model_based(task, st, pi0, prior, key, lin, r, trial, evals, eval_seed))
    return out


def experience_to_reach(experience, rewards, limit: float, failure_rate=None) -> float | None:
    """Experience (s) at the first evaluation whose reward is ≥ ``limit`` and none of whose
    rollouts failed; None if never.

    Parameters
    ----------
    experience : array_like, shape (K + 1,)
        Seconds of real experience at each evaluation.
    rewards : array_like, shape (K + 1,)
        The evaluated reward at each (over the rollouts that did not fail).
    limit : float
    failure_rate : array_like, shape (K + 1,), optional
        The share of each evaluation's rollouts that failed (default: none failed).
    """
    i = _first_index(rewards, limit, failure_rate)
    return None if i is None else float(np.asarray(experience, float)[i])


def _first_index(rewards, limit, failure_rate=None) -> int | None:
    """Index of the first evaluation at or above ``limit`` without a failed rollout."""
    ok = np.asarray(rewards, float) >= limit
    if failure_rate is not None:
        ok &= np.asarray(failure_rate, float) == 0
    hit = np.flatnonzero(ok)
    return int(hit[0]) if hit.size else None


def _method_table(st, trials, key) -> dict:
    cols = {"experience_s": "experience"}
    if key != "reps":
        cols["compute_time_s"] = "time_cumulative"
    rows = {}
    for limit in st.limits:
        idx = [
            _first_index(t[f"{key}_mean_reward"], limit, t.get(f"{key}_eval_failure_rate"))
            for t in trials
        ]
        row: dict = {"n_reached": sum(i is not None for i in idx)}
        for name, col in cols.items():
            per = [
                None if i is None else float(t[f"{key}_{col}"][i])
                for t, i in zip(trials, idx, strict=True)
            ]
            done = [x for x in per if x is not None]
            row[f"{name}_per_trial"] = per
            row[f"{name}_mean"] = float(np.mean(done)) if done else None
            row[f"{name}_median"] = median_reached(per)
            # A trial that never reaches the limit counts its whole run (a lower bound).
            row[f"{name}_censored_per_trial"] = [
                float(t[f"{key}_{col}"][-1]) if x is None else x
                for t, x in zip(trials, per, strict=True)
            ]
        rows[f"{limit:g}"] = row
    final = [float(t[f"{key}_mean_reward"][-1]) for t in trials]
    rates = [float(t.get(f"{key}_eval_failure_rate", [np.nan])[-1]) for t in trials]
    out = {
        "limits": rows,
        "final_reward_mean": nan_mean(final),
        "final_reward_per_trial": final,
        "final_eval_failure_rate": nan_mean(rates),
        "experience_budget_s": float(trials[0][f"{key}_experience"][-1]),
    }
    if key != "reps":
        pred = np.concatenate([t[f"{key}_predicted"][1:] for t in trials])
        real = np.concatenate([t[f"{key}_real"][1:] for t in trials])
        ok = np.isfinite(pred) & (real > -1e6)
        rel = np.abs(pred[ok] - real[ok]) / np.abs(real[ok])
        out["prediction_relative_error_median"] = float(np.median(rel)) if rel.size else None
    times = [
        t["reps_time_total"] if key == "reps" else t[f"{key}_time_cumulative"][-1] for t in trials
    ]
    out["compute_time_s_total_mean"] = float(np.mean(times))
    return out


def summarize_42(st: BalancingComparisonSettings, trials: list[dict]):
    """Every method's cost curve and, per limit, the experience (and computation time) to reach
    it: per trial (None: never), mean over the trials that did, median and censored."""
    series, panel = [], "cost of the current controller"
    for key in methods(st):
        costs = [np.maximum(-np.asarray(t[f"{key}_mean_reward"], float), 1e-12) for t in trials]
        mean, band = trial_band(costs, kind="gstd")
        series.append(
            Series(
                LABELS[key],
                list(map(float, trials[0][f"{key}_experience"])),
                mean,
                panel=panel,
                xlabel="real experience (s)",
                ylabel="−reward (50 common start states)",
                log_x=True,
                log_y=True,
                **band,
            )
        )
    x_all = np.concatenate([t[f"{k}_experience"] for t in trials for k in methods(st)])
    lo, hi = float(np.min(x_all[x_all > 0])), float(np.max(x_all))
    series += [Series(f"limit {v:g}", [lo, hi], [-v, -v], panel, "line") for v in st.limits]
    summary: dict = {"n_trials": len(trials), "thesis_numbers": thesis_42()}
    for key in methods(st):
        summary[key] = _method_table(st, trials, key)
    summary["random_policy_reward_mean"] = float(
        np.mean([t["random_policy_rewards"] for t in trials])
    )
    # Every method's curve starts at π₀'s mean on the trial's common evaluation states.
    summary["start_reward_per_trial"] = [float(t["reps_mean_reward"][0]) for t in trials]
    return series, summary


def median_reached(per_trial) -> float | None:
    """Median over trials of the experience (or computation time) to reach a limit, a trial
    that never reached it counting as +∞; None when at most half the trials reached it."""
    x = np.median([np.inf if v is None else float(v) for v in per_trial])
    return float(x) if np.isfinite(x) else None


experiment(
    "tab4.2",
    "Balancing: real experience PILCO, GPREPS and REPS need to reach −100, −10, −1.5",
    scales(
        BalancingComparisonSettings(),
        smoke={
            "n_inducing": 15,
            "gp_steps": 5,
            "pilco_updates": 2,
            "policy_iterations": 2,
            "gpreps": {"n_updates": 2, "n_artificial": 20, "n_trajectories": 2},
            "reps": {"n_updates": 2, "rollouts_per_update": 6},
            "evaluation": {"n_eval_contexts": 5},
        },
        quick={
            "pilco_updates": 6,
            "policy_iterations": 30,
            "gp_steps": 50,
            "gpreps": {"n_updates": 10, "n_artificial": 200, "n_trajectories": 5},
            "reps": {"n_updates": 50},
        },
        paper={"pilco_updates": 12, "gpreps": {"n_updates": 30}, "reps": {"n_updates": 400}},
    ),
    run_trial_42,
    summarize_42,
    (1, 1, 23),
)


def _balancing_setup(th, rng) -> tuple:
    """Table 4.2's task, π₀, 50 common start states and 6 s of random-policy experience."""
    task = make("balancing", initial_std=th.initial_std)
    policy = initial_policy_42(th, task)
    prior = random_prior(th, policy, rng)["trajectories"]
    rollouts = random_experience(task, prior) / (task.n_steps * task.control_dt)
    return task, policy, np.zeros((th.evaluation.n_eval_contexts, 0)), prior, rollouts


register_curve_task(
    "balancing",
    CurveTask(
        experiment="tab4.2",
        thresholds=(-100.0, -10.0, -1.5),
        thresholds_source="Table 4.2's reward limits",
        reps=lambda task, th, policy: reps_algorithm(th, policy),
        gpreps=lambda task, th, policy, prior, rng: gpreps_algorithm(
            task, th, policy, prior, fitc_model(th), rng
        ),
        setup=_balancing_setup,
    ),
)
