"""Chapter 4, GPREPS on ball throwing (Sec. 4.3.2, Figs 4.6, 4.7 and 4.9).

Every run starts from the task's imitation policy and is scored by the learning-curve
evaluator of :mod:`skillkit.experiments.curves` (reward of the policy mean on fixed targets
against real rollouts):

* **GPREPS** (Table 4.1): N₀ = 10 real throws, then one per update; the decomposed model of
  Fig. 4.2 (:class:`~skillkit.tasks.throwing_model.ThrowingRewardModel`) refitted on all throws
  at every update, M artificial pairs × L predicted throws, ε = 1.
* **GP direct** (Sec. 4.3.2): the same loop with a GP from [s, ω] to R.
* **REPS**: contextual REPS with the settings of ``fig3.3``, up to 5000 rollouts.

``fig4.6`` compares the three, ``fig4.7`` runs GPREPS with M = 50 … 1000 and ``fig4.9`` runs
REPS and GPREPS on ``throwing`` and ``throwing-noisy`` (release noise 7.5 cm and 0.3 m/s).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from skillkit.experiments.ch3_throwing import final_errors, target_grid
from skillkit.experiments.curves import (
    COV_FLOOR,
    MIN_EFFECTIVE_SAMPLES,
    CurveTask,
    curve_series,
    curve_stats,
    finite_or_none,
    gpreps_algorithm,
    gpreps_stats,
    register_curve_task,
    rollouts_to_reach,
    run_curve,
    run_gpreps,
)
from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ExactGP, ForwardModel
from skillkit.models.sparse import FITC
from skillkit.search import ContextualREPS
from skillkit.search.gpreps import DirectRewardModel
from skillkit.tasks import make
from skillkit.tasks.throwing_model import ThrowingRewardModel
from skillkit.trial import TrialContext

__all__ = [
    "COV_FLOOR",
    "MIN_EFFECTIVE_SAMPLES",
    "GPREPSThrowingSettings",
    "SampleSizeSettings",
    "StochasticThrowingSettings",
    "gpreps_algorithm",
    "reps_algorithm",
    "throwing_reward_model",
]

THESIS_46 = {"gpreps_rollouts_to_converge": (30, 40), "reps_rollouts_to_converge": 5000}
"""fig4.6: the thesis's numbers (Sec. 4.3.2), stored beside ours in the summary."""
THESIS_49 = {"reps_noisy": -1086.0, "reps": -715.0, "gpreps_noisy": -68.0, "gpreps": -64.0}
"""fig4.9: the final rewards of the Fig. 4.9 captions, stored beside ours in the summary."""


@dataclass(frozen=True)
class GPREPSThrowingSettings(Settings):
    """Settings of ``fig4.6`` (GPREPS, GP direct and REPS on throwing, Sec. 4.3.2)."""

    n_initial: int = setting(10, "N₀, real throws before the first GPREPS update.", minimum=2)
    n_updates: int = setting(
        30,
        "GPREPS / GP-direct updates, one new throw each after the "
        "first (real throws = N₀ + n_updates − 1).",
        minimum=1,
    )
    n_artificial: int = setting(500, "M, artificial (s, ω) pairs per update.", minimum=2)
    n_trajectories: int = setting(25, "L, predicted throws per pair (Eq. 4.1).", minimum=1)
    epsilon: float = setting(1.0, "KL bound ε of GPREPS and GP direct (Sec. 4.3.2).", above=0)
    context_model: str = setting("uniform", "μ̂(s): the box of the observed targets.")
    gp_steps: int = setting(
        150,
        "L-BFGS iterations of the release, flight and GP-direct hyper-parameter fits.",
        minimum=0,
    )
    robot_steps: int = setting(150, "L-BFGS iterations of the robot GP's fit.", minimum=0)
    robot_inducing: int = setting(50, "Pseudo-inputs of the FITC robot-dynamics GP.", minimum=1)
    flight_inducing: int = setting(50, "Pseudo-inputs of the FITC ball-flight GP.", minimum=1)
    max_robot_points: int = setting(
        1000, "Robot transitions the FITC GP is fitted on, drawn from all throws.", minimum=2
    )
    reps_updates: int = setting(200, "REPS updates (× 25 = 5000 rollouts).", minimum=1)
    reps_rollouts_per_update: int = setting(25, "REPS rollouts per update (fig3.3).", minimum=1)
    reps_epsilon: float = setting(0.6, "KL bound of REPS (fig3.3).", above=0)
    reps_reuse_batches: int = setting(8, "Batches REPS reuses (fig3.3).", minimum=1)
    n_eval_contexts: int = setting(8, "Fixed targets of the learning curves.", minimum=1)
    grid_x: tuple[float, ...] = setting(
        (5.0, 7.5, 10.0, 12.5, 15.0), "Target x (m) of the final ball-to-target distances."
    )
    grid_y: tuple[float, ...] = setting((1.0, 3.0), "Target y (m) of the final distances.")


@dataclass(frozen=True)
class SampleSizeSettings(GPREPSThrowingSettings):
    """Settings of ``fig4.7`` (GPREPS with different numbers of artificial samples)."""

    n_artificial_values: tuple[int, ...] = setting(
        (50, 100, 200, 500, 1000), "The M compared (Sec. 4.3.2.1, Fig. 4.7).", minimum=2
    )


@dataclass(frozen=True)
class StochasticThrowingSettings(GPREPSThrowingSettings):
    """Settings of ``fig4.9`` (REPS and GPREPS on deterministic and noisy throwing)."""

    release_noise: tuple[float, float] = setting(
        (0.075, 0.3),
        "Std of the release position (m) and velocity (m/s) (Sec. 4.3.2.2).",
        minimum=0,
    )
    n_final_rollouts: int = setting(
        10,
        "Noisy rollouts per target that estimate each final policy's expected reward.",
        minimum=1,
    )


SMOKE = {
    "n_initial": 3,
    "n_updates": 2,
    "n_artificial": 20,
    "n_trajectories": 2,
    "gp_steps": 10,
    "robot_inducing": 10,
    "flight_inducing": 10,
    "max_robot_points": 200,
    "reps_updates": 2,
    "reps_rollouts_per_update": 4,
    "reps_reuse_batches": 2,
    "n_eval_contexts": 1,
    "grid_x": (8.0,),
    "grid_y": (2.0,),
}
"""The smoke scale's changes, shared by the three experiments."""
QUICK = {
    "n_updates": 8,
    "n_artificial": 200,
    "n_trajectories": 5,
    "gp_steps": 60,
    "reps_updates": 40,
}
"""The quick scale's changes, shared by the three experiments: GPREPS / GP-direct updates
30→8 (fig4.7 and fig4.9: 20→8), M 500→200, L 25→5, release / flight L-BFGS iterations
150→60 (the robot GP keeps its 150), REPS updates 200→40, learning-curve targets 20→8."""


def _scales(cls, smoke: dict | None = None, quick: dict | None = None, paper=None) -> dict:
    """The three scales of a settings class: the shared changes plus the experiment's own."""
    return scales(
        cls(),
        smoke={**SMOKE, **(smoke or {})},
        quick={**QUICK, **(quick or {})},
        paper={"n_eval_contexts": 20, **(paper or {})},
    )


# --------------------------------------------------------------------------- one run
def _fitc(n_inducing: int, n_steps: int) -> ForwardModel:
    # Δx targets, as in the stored paper results (ForwardModel's default target is x′).
    return ForwardModel(FITC(n_inducing=n_inducing, n_steps=n_steps), target="delta")


def throwing_reward_model(task, st: GPREPSThrowingSettings, model: str = "decomposed"):
    """The reward model of GPREPS on throwing (Sec. 4.3.2) with ``st``'s GP sizes:
    ``model="decomposed"``, the robot, release and flight GPs of Fig. 4.2
    (:class:`~skillkit.tasks.throwing_model.ThrowingRewardModel`), or ``"direct"``, one GP from
    (s, ω) to the reward."""
    if model == "decomposed":  # the full 2.5 s flight of every ball, as the results were made
        return ThrowingRewardModel(
            task,
            make_robot_model=partial(_fitc, st.robot_inducing, st.robot_steps),
            make_release_model=partial(ExactGP, n_steps=st.gp_steps),
            make_flight_model=partial(_fitc, st.flight_inducing, st.gp_steps),
            max_robot_points=st.max_robot_points,
            stop_flight_at_ground=False,
        )
    return DirectRewardModel(ExactGP(n_steps=st.gp_steps))


def reps_algorithm(task, st) -> ContextualREPS:
    """Model-free contextual REPS on throwing with fig3.3's settings (ε, reused batches and
    the quadratic baseline from ``st``), from the task's π₀."""
    return ContextualREPS(
        task.initial_policy(),
        st.reps_epsilon,
        n_reuse_batches=st.reps_reuse_batches,
        baseline_features="quadratic",
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )


def _gpreps(task, st, key, model, m, rng, trial, eval_contexts) -> dict:
    return run_gpreps(
        task,
        st,
        key,
        throwing_reward_model(task, st, model),
        m,
        st.n_trajectories,
        rng,
        trial,
        eval_contexts,
    )


def _run_reps(task, st, key, rng, trial, eval_contexts) -> dict:
    """Model-free contextual REPS with fig3.3's settings (:func:`reps_algorithm`)."""
    out, curves = run_curve(
        task,
        reps_algorithm(task, st),
        key,
        st.reps_updates,
        st.reps_rollouts_per_update,
        rng,
        trial,
        eval_contexts,
    )
    out[f"{key}_policy"] = curves["policy"]
    return out


def _finish(task, st, out: dict, keys) -> dict:
    """Final ball-to-target distances of each run's policy mean; drop the policy objects."""
    targets = target_grid(st)
    out["targets"] = targets
    for key in keys:
        dist, _ = final_errors(task, out.pop(f"{key}_policy"), targets)
        out[f"{key}_distance"] = dist
        for extra in ("policies", "diagnostics", "algorithm"):
            out.pop(f"{key}_{extra}", None)
    return out


def _learning_series(trials, keys, labels) -> list[Series]:
    return [
        curve_series(
            trials,
            f"{k}_rollouts",
            f"{k}_mean_reward",
            label,
            "learning curves",
            "average reward of the policy mean",
            xlabel="real rollouts (log scale; after the first batch)",
            drop_first=True,
        )
        for k, label in zip(keys, labels, strict=True)
    ]


def _method_summary(trials, key) -> dict:
    dist = np.array([t[f"{key}_distance"] for t in trials], dtype=float)
    out = {
        "rollouts": int(trials[0][f"{key}_rollouts"][-1]),
        **curve_stats(trials, key),
        "final_distance_mean_m": float(np.nanmean(dist)),
        "final_distance_max_m": float(np.nanmax(dist)) if np.isfinite(dist).any() else None,
    }
    if f"{key}_relative_error" in trials[0]:
        out.update(gpreps_stats(trials, key))
    return out


# --------------------------------------------------------------------------- fig4.6
def run_trial_46(st: GPREPSThrowingSettings, rng: np.random.Generator, trial: TrialContext):
    """GPREPS, GP direct and REPS on ``throwing`` from the same policy and targets."""
    task = make("throwing")
    eval_contexts = task.sample_context(rng, n=st.n_eval_contexts)
    seeds = rng.spawn(3)
    trial.reset(total=2 * st.n_updates + st.reps_updates)
    out: dict = {}
    for key, model, seed in (("gpreps", "decomposed", seeds[0]), ("direct", "direct", seeds[1])):
        out.update(_gpreps(task, st, key, model, st.n_artificial, seed, trial, eval_contexts))
    out.update(_run_reps(task, st, "reps", seeds[2], trial, eval_contexts))
    return _finish(task, st, out, ("gpreps", "direct", "reps"))


def summarize_46(st: GPREPSThrowingSettings, trials: list[dict]):
    """Learning curves of GPREPS, GP direct and REPS and what the claims spec reads of them
    (per-trial start and final rewards, GPREPS's gain and prediction error, REPS's rollouts
    to reach GPREPS's final reward)."""
    keys, labels = ("gpreps", "direct", "reps"), ("GPREPS", "GP direct", "REPS")
    series = _learning_series(trials, keys, labels)
    summary: dict = {"n_trials": len(trials), "thesis_numbers": dict(THESIS_46)}
    for key in keys:
        summary[key] = _method_summary(trials, key)
    summary["reps_rollouts_to_gpreps_final"] = rollouts_to_reach(
        trials, "reps", summary["gpreps"]["final_reward_mean"]
    )
    for key in keys:
        summary[key].update(_per_trial(trials, key))
    g = summary["gpreps"]
    g["gain_per_trial"] = _difference(g["final_reward_per_trial"], g["initial_reward_per_trial"])
    converge = min(THESIS_46["gpreps_rollouts_to_converge"])
    at = np.flatnonzero(np.asarray(trials[0]["gpreps_rollouts"]) == converge)
    if at.size:
        g[f"gain_after_{converge}_per_trial"] = [
            float(t["gpreps_mean_reward"][-1] - t["gpreps_mean_reward"][at[0]]) for t in trials
        ]
    g["prediction_relative_error_median_per_trial"] = [
        finite_or_none(np.nanmedian(t["gpreps_relative_error"][1:]))
        if np.isfinite(t["gpreps_relative_error"][1:]).any()
        else None
        for t in trials
    ]
    summary["reps_over_gpreps_rollouts_per_trial"] = _reps_over_gpreps(trials)
    return series, summary


def _per_trial(trials, key) -> dict:
    """A method's start reward per trial and each trial's absolute deviation from the mean
    final reward over trials."""
    curves = np.array([t[f"{key}_mean_reward"] for t in trials], dtype=float)
    final = curves[:, -1]
    return {
        "initial_reward_per_trial": curves[:, 0].tolist(),
        "final_reward_abs_deviation_per_trial": np.abs(final - final.mean()).tolist(),
    }


def _difference(a, b) -> list[float]:
    return (np.asarray(a, dtype=float) - np.asarray(b, dtype=float)).tolist()


def _reps_over_gpreps(trials) -> list[float]:
    """Per trial: REPS's rollouts until its curve reaches the trial's GPREPS final reward,
    over GPREPS's throws (REPS's whole run, a lower bound, where it never does)."""
    out = []
    for t in trials:
        g_throws = float(t["gpreps_rollouts"][-1])
        hit = np.flatnonzero(np.asarray(t["reps_mean_reward"]) >= t["gpreps_mean_reward"][-1])
        reps = float(t["reps_rollouts"][hit[0] if hit.size else -1])
        out.append(reps / g_throws)
    return out


# --------------------------------------------------------------------------- fig4.7
def run_trial_47(st: SampleSizeSettings, rng: np.random.Generator, trial: TrialContext):
    """GPREPS with each M of ``n_artificial_values`` from the same policy and targets."""
    task = make("throwing")
    eval_contexts = task.sample_context(rng, n=st.n_eval_contexts)
    seeds = rng.spawn(len(st.n_artificial_values))
    trial.reset(total=st.n_updates * len(st.n_artificial_values))
    out: dict = {}
    keys = []
    for m, seed in zip(st.n_artificial_values, seeds, strict=True):
        key = f"m{m}"
        keys.append(key)
        out.update(_gpreps(task, st, key, "decomposed", m, seed, trial, eval_contexts))
    return _finish(task, st, out, keys)


def summarize_47(st: SampleSizeSettings, trials: list[dict]):
    """Learning curves for each M, the final reward against M, and its change between every
    two M per trial (the arms of a trial share π₀ and the evaluation targets)."""
    keys = [f"m{m}" for m in st.n_artificial_values]
    series = _learning_series(trials, keys, [f"M = {m}" for m in st.n_artificial_values])
    summary: dict = {"n_trials": len(trials), "n_artificial_values": list(st.n_artificial_values)}
    for key in keys:
        summary[key] = _method_summary(trials, key)
    finals = [summary[k]["final_reward_mean"] for k in keys]
    series.append(
        Series(
            "final reward",
            list(st.n_artificial_values),
            finals,
            panel="final reward against M",
            kind="lines+markers",
            xlabel="artificial samples M (log scale)",
            ylabel="final average reward of the policy mean",
            log_x=True,
        )
    )
    for key in keys:
        summary[key].update(_per_trial(trials, key))
    values = sorted(st.n_artificial_values)
    summary["final_reward_change_per_trial"] = {
        f"m{a}_to_m{b}": _difference(
            summary[f"m{b}"]["final_reward_per_trial"], summary[f"m{a}"]["final_reward_per_trial"]
        )
        for i, a in enumerate(values)
        for b in values[i + 1 :]
    }
    return series, summary


# --------------------------------------------------------------------------- fig4.9
def run_trial_49(st: StochasticThrowingSettings, rng: np.random.Generator, trial: TrialContext):
    """REPS and GPREPS on deterministic and noisy throwing from the same policy and targets."""
    tasks = {"": make("throwing"), "_noisy": make("throwing", release_noise=st.release_noise)}
    eval_contexts = tasks[""].sample_context(rng, n=st.n_eval_contexts)
    seeds = rng.spawn(4)
    trial.reset(total=2 * (st.n_updates + st.reps_updates))
    out: dict = {}
    policies = {}
    for i, (suffix, task) in enumerate(tasks.items()):
        g = _gpreps(
            task,
            st,
            f"gpreps{suffix}",
            "decomposed",
            st.n_artificial,
            seeds[2 * i],
            trial,
            eval_contexts,
        )
        r = _run_reps(task, st, f"reps{suffix}", seeds[2 * i + 1], trial, eval_contexts)
        out.update(g)
        out.update(r)
        policies[f"gpreps{suffix}"] = g[f"gpreps{suffix}_policy"]
        policies[f"reps{suffix}"] = r[f"reps{suffix}_policy"]
    # Expected reward of each final policy mean under noise: n_final_rollouts per target.
    noisy = tasks["_noisy"]
    final_rng = rng.spawn(1)[0]
    for key, pol in policies.items():
        means = np.atleast_2d(pol.mean_of(eval_contexts))
        rewards = [
            noisy.evaluate(w, s, final_rng)[0]
            for w, s in zip(means, eval_contexts, strict=True)
            for _ in range(st.n_final_rollouts)
        ]
        out[f"{key}_noisy_expected_reward"] = float(np.mean(rewards))
    return _finish(tasks[""], st, out, list(policies))


def summarize_49(st: StochasticThrowingSettings, trials: list[dict]):
    """The learning curves of REPS and GPREPS with and without release noise, and each final
    policy mean's expected reward under the noise (per trial and mean over trials)."""
    keys = ("reps", "reps_noisy", "gpreps", "gpreps_noisy")
    labels = ("REPS", "REPS, noisy", "GPREPS", "GPREPS, noisy")
    series = _learning_series(trials, keys, labels)
    summary: dict = {"n_trials": len(trials), "thesis_numbers": dict(THESIS_49)}
    for key in keys:
        summary[key] = _method_summary(trials, key)
        summary[key]["noisy_expected_reward"] = float(
            np.mean([t[f"{key}_noisy_expected_reward"] for t in trials])
        )
    summary["noise_ratio"] = {**_noise_ratios(summary), **_same_noise_ratios(summary)}
    for key in keys:
        summary[key]["noisy_expected_reward_per_trial"] = [
            float(t[f"{key}_noisy_expected_reward"]) for t in trials
        ]
    return series, summary


def _noise_ratios(summary: dict) -> dict[str, float]:
    """|noisy| / |deterministic| final learning-curve reward of REPS and GPREPS, beside the
    thesis's (REPS 1086 / 715, GPREPS 68 / 64)."""

    def ratio(key: str) -> float:
        return abs(summary[f"{key}_noisy"]["final_reward_mean"]) / max(
            abs(summary[key]["final_reward_mean"]), 1e-12
        )

    return {
        "reps": ratio("reps"),
        "gpreps": ratio("gpreps"),
        "thesis_reps": 1086 / 715,
        "thesis_gpreps": 68 / 64,
    }


def _same_noise_ratios(summary: dict) -> dict[str, float | None]:
    """|noisy-trained| / |deterministic-trained| expected reward under the same release noise
    of REPS's and GPREPS's final policy means; None where one is not finite."""

    def ratio(key: str) -> float | None:
        noisy = finite_or_none(summary[f"{key}_noisy"]["noisy_expected_reward"])
        det = finite_or_none(summary[key]["noisy_expected_reward"])
        if noisy is None or det is None:
            return None
        return abs(noisy) / max(abs(det), 1e-12)

    return {"reps_same_noise": ratio("reps"), "gpreps_same_noise": ratio("gpreps")}


register(
    Experiment(
        id="fig4.6",
        title="Ball throwing: GPREPS (decomposed GP models) vs GP direct vs REPS",
        settings_class=GPREPSThrowingSettings,
        settings=_scales(GPREPSThrowingSettings),
        run_trial=run_trial_46,
        summarize=summarize_46,
        trials={"smoke": 1, "quick": 2, "paper": 5},
    )
)
register(
    Experiment(
        id="fig4.7",
        title="Ball throwing: GPREPS with 50 to 1000 artificial samples",
        settings_class=SampleSizeSettings,
        settings=_scales(
            SampleSizeSettings,
            smoke={"n_artificial_values": (10, 20)},
            quick={"n_artificial_values": (50, 200)},
            paper={"n_trajectories": 5, "n_updates": 20},
        ),
        run_trial=run_trial_47,
        summarize=summarize_47,
        trials={"smoke": 1, "quick": 1, "paper": 5},
    )
)
register(
    Experiment(
        id="fig4.9",
        title="Stochastic ball throwing: REPS and GPREPS with and without release noise",
        settings_class=StochasticThrowingSettings,
        settings=_scales(
            StochasticThrowingSettings, smoke={"n_final_rollouts": 2}, paper={"n_updates": 20}
        ),
        run_trial=run_trial_49,
        summarize=summarize_49,
        trials={"smoke": 1, "quick": 1, "paper": 5},
    )
)
register_curve_task(
    "throwing",
    CurveTask(
        experiment="fig4.6",
        thresholds=(-100.0, -50.0),
        thresholds_source="R ≈ −c₁ × the ball's distance to the target with c₁ = 100 per metre "
        "(Appendix C.1): −100 is 1 m off on average, −50 the 0.5 m bound of Sec. 3.4.1 (Fig. 3.3); "
        "the thesis's final rewards are −715 (REPS) and −64 (GPREPS) in Fig. 4.9's caption",
        reps=lambda task, st, policy: reps_algorithm(task, st),
        reward_model=throwing_reward_model,
    ),
)
