"""The learning-curve experiment shared by Chapters 3 and 4 and ``cmp.methods``: a run learns
with :func:`~skillkit.search.loop.learn` (Tables 3.1, 4.1) from the task's imitation policy and
records the policy mean's reward on fixed contexts after every update (arrays
``f"{key}_<name>"``). A task's :class:`CurveTask` (:func:`register_curve_task`) says how REPS
and GPREPS run on it; :func:`learning_curves` builds the experiment for a new task."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from skillkit.experiments.registry import SCALES, Experiment, Series, register
from skillkit.experiments.settings import Settings, apply_overrides, scales, setting
from skillkit.policies.features import FeatureName
from skillkit.search import ContextualREPS, learn
from skillkit.search.gpreps import GPREPS, GPREPSSettings
from skillkit.search.loop import policy_history_arrays
from skillkit.tasks import make, names
from skillkit.trial import TrialContext
from skillkit.viz.model_layers import dumps_reward_model
from skillkit.viz.series import trial_band

COV_FLOOR = 0.1
"""The weighted ML fit of GPREPS and the Chapter 4 REPS baselines keeps each direction of Σ
above this fraction of its previous variance per update (M = 50 or N = 25 samples are fewer
than a full 41 × 41 covariance needs)."""
MIN_EFFECTIVE_SAMPLES = 2.0
"""The least effective sample size the regularised fit accepts (as fig3.3)."""


@dataclass(frozen=True)
class CurveTask:
    """What a registered task supplies to the learning-curve experiments.

    ``experiment``: the thesis experiment whose settings ``st`` (at a scale; its ``reps``,
    ``gpreps`` and ``evaluation`` blocks) REPS and GPREPS use; ``thresholds``: the reward levels
    whose real-rollout cost is compared. The callables take ``st``: ``reps(task, st, policy)``
    builds REPS; ``reward_model(task, st)`` is GPREPS's unless ``gpreps(task, st, policy, prior,
    rng)`` builds GPREPS itself; ``setup(st, rng)`` returns ``(task, policy, eval_contexts,
    prior, prior_rollouts)`` where the default (the task's imitation policy,
    ``evaluation.n_eval_contexts`` contexts, no prior data) does not fit.
    """

    experiment: str
    thresholds: tuple[float, ...]
    thresholds_source: str
    reps: Callable[..., Any]
    reward_model: Callable[..., Any] | None = None
    gpreps: Callable[..., Any] | None = None
    setup: Callable[..., tuple] | None = None

    def make_gpreps(self, task, settings: Settings, policy, prior, rng) -> GPREPS:
        """GPREPS on ``task`` with ``settings`` (:attr:`gpreps`, or the default)."""
        if self.gpreps is not None:
            return self.gpreps(task, settings, policy, prior, rng)
        return gpreps_algorithm(task, settings.gpreps, self.reward_model(task, settings), rng)


_PROFILES: dict[str, CurveTask] = {}


def register_curve_task(name: str, profile: CurveTask) -> None:
    """Attach ``profile`` to the registered task ``name`` (done by the module that owns the
    task's reward model)."""
    if name not in names():
        raise ValueError(f"name: unknown task {name!r}; registered tasks: {', '.join(names())}")
    _PROFILES[name] = profile


def curve_task(name: str) -> CurveTask:
    """The :class:`CurveTask` profile of the registered task ``name``."""
    if name not in _PROFILES:
        known = ", ".join(sorted(_PROFILES)) or "none"
        raise ValueError(f"task: {name!r} has no learning-curve profile; tasks with one: {known}")
    return _PROFILES[name]


def run_curve(
    task,
    algorithm,
    key: str,
    n_updates: int,
    rollouts_per_update: int,
    rng,
    trial: TrialContext | None,
    eval_contexts,
    *,
    score: Callable[[Any], dict] | None = None,
    every: int = 1,
    rollouts_after: Callable[[int], float] | None = None,
    **learn_kwargs,
) -> tuple[dict, dict]:
    """One :func:`~skillkit.search.loop.learn` run (``key`` its checkpoint key and array
    prefix): ``(arrays, curves)``, ``arrays`` holding ``f"{key}_rollouts"`` and
    ``f"{key}_mean_reward"`` (K+1,) and, with ``score``, ``f"{key}_heldout_<score>"`` of
    ``score(policy)`` before the first update, every ``every`` updates and after the last,
    against ``f"{key}_heldout_rollouts"`` (``rollouts_after(k)`` real rollouts after update k,
    default k × N); ``curves`` is :func:`learn`'s result. Other keywords go to :func:`learn`."""
    if score is not None:

        def record(k: int, alg):
            return score(alg.policy) if k % every == 0 or k == n_updates else None

        learn_kwargs["callback"] = record
    curves = learn(
        task,
        algorithm,
        n_updates,
        rollouts_per_update,
        rng,
        trial=trial,
        eval_contexts=eval_contexts,
        checkpoint_key=key,
        **learn_kwargs,
    )
    out = {f"{key}_rollouts": curves["rollouts"], f"{key}_mean_reward": curves["mean_reward"]}
    out[f"{key}_eval_failure_rate"] = curves["eval_failure_rate"]
    if score is not None:
        after = rollouts_after or (lambda k: k * rollouts_per_update)
        points = [(k, v) for k, v in enumerate(curves["callback"]) if v is not None]
        x = [0 if k == 0 else after(k) for k, _ in points]
        out[f"{key}_heldout_rollouts"] = np.array(x, dtype=float)
        for name in points[0][1]:
            out[f"{key}_heldout_{name}"] = np.array([v[name] for _, v in points], dtype=float)
    return out, curves


def heldout_setup(task, ev: EvaluationBlock, rng, n_runs: int, scorer) -> tuple:
    """Held-out and evaluation contexts, the held-out ``score(policy)`` (``scorer(task,
    policy, heldout, seed)``, one seed for all) and ``n_runs`` seeds."""
    if ev.n_heldout < 1:
        raise ValueError(f"evaluation.n_heldout: expected at least 1, got {ev.n_heldout}")
    heldout = task.sample_context(rng, n=ev.n_heldout)
    eval_contexts = task.sample_context(rng, n=ev.n_eval_contexts)
    heldout_seed = int(rng.integers(2**63))

    def score(policy) -> dict:
        return scorer(task, policy, heldout, heldout_seed)

    return heldout, eval_contexts, score, rng.spawn(n_runs)


def regularised_reps(
    policy, epsilon: float, n_reuse_batches: int, baseline_features: FeatureName = "quadratic"
) -> ContextualREPS:
    """Contextual REPS (Table 3.1) with the fit regularised as GPREPS's (:data:`COV_FLOOR`,
    :data:`MIN_EFFECTIVE_SAMPLES`)."""
    return ContextualREPS(
        policy,
        epsilon,
        n_reuse_batches,
        baseline_features,
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )


def kept_model(algo: GPREPS, policies) -> dict:
    """GPREPS's policy history (``skillkit view TASK --policy RUN``) and, where it draws
    prediction layers (hockey, table tennis), its reward model (``--gpreps RUN``)."""
    out = policy_history_arrays(policies)
    if callable(getattr(algo.reward_model, "prediction_layers", None)):
        out["reward_model"] = np.frombuffer(dumps_reward_model(algo.reward_model), np.uint8)
    return out


def gpreps_algorithm(
    task, g: GPREPSBlock, reward_model, rng, n_artificial: int | None = None
) -> GPREPS:
    """GPREPS (Table 4.1) from the task's π₀ with ``reward_model``: ε, μ̂, M (unless
    ``n_artificial`` is given) and L from ``g``, the fit regularised by :data:`COV_FLOOR` and
    :data:`MIN_EFFECTIVE_SAMPLES`."""
    settings = GPREPSSettings(
        epsilon=g.epsilon,
        n_artificial=n_artificial or g.n_artificial,
        n_trajectories=g.n_trajectories,
        context_model=g.context_model,
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )
    return GPREPS(task.initial_policy(), reward_model, settings, rng=rng, task=task)


def run_gpreps(
    task, st, key, reward_model, rng, trial, eval_contexts, score=None, n_artificial=None
) -> tuple[dict, dict, GPREPS]:
    """One GPREPS run of ``st.gpreps`` (N₀ real rollouts, then one per update):
    ``(arrays, curves, algorithm)``, the arrays of :func:`run_curve` (held-out scores every
    ``st.evaluation.heldout_every`` updates) with the per-update model error, times and KL."""
    g = st.gpreps
    algo_rng, loop_rng = rng.spawn(2)
    algo = gpreps_algorithm(task, g, reward_model, algo_rng, n_artificial)
    out, curves = run_curve(
        task,
        algo,
        key,
        g.n_updates,
        1,
        loop_rng,
        trial,
        eval_contexts,
        score=score,
        every=st.evaluation.heldout_every,
        rollouts_after=lambda k: g.n_initial + k - 1,
        initial_rollouts=g.n_initial,
    )
    diags = curves["diagnostics"]
    rel = [
        np.nan if d.prediction_bias is None else abs(d.prediction_bias) / abs(d.real_reward)
        for d in diags
    ]
    out[f"{key}_relative_error"] = np.array(rel)
    for part in ("training", "prediction", "policy"):
        out[f"{key}_time_{part}"] = np.array([getattr(d, f"time_{part}") for d in diags])
    out[f"{key}_kl"] = np.array([d.reps.kl for d in diags])
    return out, curves, algo


def curve_series(
    trials,
    x_key: str,
    y_key: str,
    label: str,
    panel: str,
    ylabel: str,
    *,
    band: str = "std",
    log_x: bool = True,
    xlabel: str | None = None,
    drop_first: bool = False,
) -> Series:
    """Mean ± ``band`` over trials of ``y_key`` against ``x_key`` (the first trial's); on a
    log axis only the points with x > 0, or with ``drop_first`` those after the first."""
    x = np.asarray(trials[0][x_key], dtype=float)
    ys = np.array([t[y_key] for t in trials], dtype=float)
    keep = np.ones_like(x, dtype=bool)
    if drop_first:
        keep[0] = False
    elif log_x:
        keep = x > 0
    m, spread = trial_band(ys[:, keep], kind=band)
    if xlabel is None:
        xlabel = "real rollouts (log scale)" if log_x else "real rollouts"
    return Series(
        label, x[keep].tolist(), m, panel=panel, **spread, xlabel=xlabel, ylabel=ylabel, log_x=log_x
    )


def curve_stats(trials, key: str) -> dict:
    """Start and final reward of the curves ``f"{key}_mean_reward"`` (the mean over the
    evaluation rollouts that did not fail; NaN where all failed): mean over the trials with a
    number, the final values' std (ddof 1; 0 for one) and per trial; and the final share of
    failed evaluation rollouts (mean over trials) where the run records it."""
    curves = np.array([t[f"{key}_mean_reward"] for t in trials], dtype=float)
    final = curves[:, -1]
    ok = final[np.isfinite(final)]
    out = {
        "initial_reward": nan_mean(curves[:, 0]),
        "final_reward_mean": nan_mean(final),
        "final_reward_std": float(ok.std(ddof=1)) if ok.size > 1 else 0.0,
        "final_reward_per_trial": final.tolist(),
    }
    if f"{key}_eval_failure_rate" in trials[0]:
        rates = [float(t[f"{key}_eval_failure_rate"][-1]) for t in trials]
        out["final_eval_failure_rate"] = float(np.mean(rates))
    return out


def nan_mean(values) -> float:
    """Mean of the finite entries of ``values``; NaN if there are none (no warning)."""
    values = np.asarray(values, dtype=float)
    ok = values[np.isfinite(values)]
    return float(ok.mean()) if ok.size else float("nan")


def finite_or_none(value) -> float | None:
    """``value`` as a float; None for None or a non-finite number (``result.json``'s NaN)."""
    if value is None:
        return None
    value = float(value)
    return value if np.isfinite(value) else None


def heldout_stats(trials, key: str, names) -> dict:
    """Per held-out score ``name``: its first and last value (mean over trials, NaN ignored)
    and the last per trial; the reward's first per trial; the curve's final mean reward."""
    out: dict = {"rollouts": int(trials[0][f"{key}_rollouts"][-1])}
    for name in names:
        v = np.array([t[f"{key}_heldout_{name}"] for t in trials], dtype=float)
        out[f"initial_{name}"] = nan_mean(v[:, 0])
        out[f"final_{name}"] = nan_mean(v[:, -1])
        out[f"final_{name}_per_trial"] = v[:, -1].tolist()
        if name == "reward":  # a paired reading of start against end needs both per trial
            out["initial_reward_per_trial"] = v[:, 0].tolist()
    curves = np.array([t[f"{key}_mean_reward"] for t in trials], dtype=float)
    out["final_mean_reward"] = nan_mean(curves[:, -1])
    return out


def gpreps_stats(trials, key) -> dict:
    """A GPREPS run's model error on the next real rollout (median, share below 10%), mean
    seconds per update in training, prediction and the policy update, and largest KL."""
    rel = np.concatenate([t[f"{key}_relative_error"][1:] for t in trials])
    return {
        "prediction_relative_error_median": float(np.nanmedian(rel)) if rel.size else None,
        "prediction_relative_error_below_10pct": float(np.nanmean(rel < 0.1)) if rel.size else None,
        "time_per_update_s": {
            part: float(np.mean(np.concatenate([t[f"{key}_time_{part}"] for t in trials])))
            for part in ("training", "prediction", "policy")
        },
        "max_kl": float(max(np.max(t[f"{key}_kl"]) for t in trials)),
    }


def rollouts_to_reach(
    trials, key, level: float, curve: str = "mean_reward", x: str = "rollouts"
) -> float | None:
    """Rollouts after which run ``key``'s curve ``f"{key}_{curve}"`` (mean over trials, NaN
    ignored; an evaluation with failed rollouts counts as not reaching it) first reaches
    ``level``, read off ``f"{key}_{x}"``; None if it never does."""
    at = np.asarray(trials[0][f"{key}_{x}"], dtype=float)
    ys = np.array([t[f"{key}_{curve}"] for t in trials], dtype=float)
    if curve == "mean_reward" and f"{key}_eval_failure_rate" in trials[0]:
        failed = np.array([t[f"{key}_eval_failure_rate"] for t in trials]) > 0
        ys = np.where(failed, -np.inf, ys)
    m = np.nanmean(ys, axis=0)
    hit = np.flatnonzero(m >= level)
    return float(at[hit[0]]) if hit.size else None


def experiment(
    exp_id: str,
    title: str,
    settings: dict[str, Settings],
    run_trial: Callable[..., dict],
    summarize: Callable[..., tuple],
    trials: tuple[int, int, int] = (1, 1, 5),
    claim: str = "",
) -> Experiment:
    """Register the experiment ``exp_id`` (:class:`~skillkit.experiments.registry.Experiment`,
    its settings class that of ``settings``) with ``trials`` per scale (smoke, quick, paper)."""
    cls = type(settings["paper"])
    runs = dict(zip(SCALES, trials, strict=True))
    return register(Experiment(exp_id, title, cls, settings, run_trial, summarize, runs, claim))


@dataclass(frozen=True)
class REPSBlock(Settings):
    """Model-free contextual REPS (Table 3.1), its fit regularised as GPREPS's
    (:data:`COV_FLOOR`, :data:`MIN_EFFECTIVE_SAMPLES`)."""

    n_updates: int = setting(20, "Policy updates K (0: REPS does not run).", minimum=0)
    rollouts_per_update: int = setting(25, "Rollouts N between updates.", minimum=1)
    epsilon: float = setting(0.6, "KL bound ε (Eq. 3.4).", above=0)
    n_reuse_batches: int = setting(8, "Batches L each update reuses (the last L × N).", minimum=1)


@dataclass(frozen=True)
class GPREPSBlock(Settings):
    """GPREPS (Table 4.1)."""

    n_updates: int = setting(10, "Updates K (0: GPREPS does not run).", minimum=0)
    n_initial: int = setting(10, "N₀, real rollouts before the first update.", minimum=1)
    n_artificial: int = setting(200, "M, artificial (s, ω) pairs per update.", minimum=2)
    n_trajectories: int = setting(5, "L, predicted trajectories per pair (Eq. 4.1).", minimum=1)
    epsilon: float = setting(1.0, "KL bound ε (Sec. 4.3.2).", above=0)
    context_model: Literal["gaussian", "uniform", "prior"] = setting(
        "uniform", "μ̂(s) of the artificial samples."
    )


@dataclass(frozen=True)
class EvaluationBlock(Settings):
    """The learning curve's evaluation and the held-out scores."""

    n_eval_contexts: int = setting(10, "Fixed contexts the policy mean is scored on.", minimum=1)
    n_heldout: int = setting(0, "Held-out contexts of the held-out scores (0: none).", minimum=0)
    heldout_every: int = setting(1, "Held-out scores every this many updates.", minimum=1)


@dataclass(frozen=True)
class CurveSettings(Settings):
    """Settings of a :func:`learning_curves` experiment."""

    task: str = setting("throwing", "Registered task the methods learn.")
    reps: REPSBlock = setting(REPSBlock(), "Model-free REPS.")
    gpreps: GPREPSBlock = setting(GPREPSBlock(), "GPREPS with the experiment's reward model.")
    evaluation: EvaluationBlock = setting(EvaluationBlock(), "The learning curve's evaluation.")


_SMOKE = {
    "reps": {"n_updates": 2, "rollouts_per_update": 5, "n_reuse_batches": 2},
    "gpreps": {"n_updates": 2, "n_initial": 5, "n_artificial": 20, "n_trajectories": 2},
    "evaluation": {"n_eval_contexts": 2},
}


def learning_curves(
    exp_id: str,
    title: str,
    task: str,
    *,
    reward_model: Callable[[Any], Any] | None = None,
    thresholds: tuple[float, ...] = (),
    claim: str = "",
    smoke: dict | None = None,
    quick: dict | None = None,
    paper: dict | None = None,
) -> Experiment:
    """Register and return the experiment ``exp_id``: REPS and GPREPS on the registered
    ``task`` from its imitation policy, scored on the same fixed contexts against real
    rollouts (``reproduce(exp_id, scale="smoke")`` runs it). ``reward_model(task)`` is
    GPREPS's (without one GPREPS does not run); the summary gives the real rollouts each
    method's mean curve needs to reach each of ``thresholds``; ``claim`` says what the run
    shows (an id outside the claims spec needs one); ``smoke``, ``quick``, ``paper``: each
    scale's changes of :class:`CurveSettings` (a block as a mapping of some of its fields)."""

    def run_trial(st: CurveSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
        made = make(st.task)
        eval_contexts = made.sample_context(rng, n=st.evaluation.n_eval_contexts)
        runs = [m for m, block in (("reps", st.reps), ("gpreps", st.gpreps)) if block.n_updates]
        trial.reset(total=sum(getattr(st, m).n_updates for m in runs))
        out: dict = {}
        for method, r in zip(runs, rng.spawn(len(runs)), strict=True):
            if method == "reps":
                b = st.reps
                algo = regularised_reps(made.initial_policy(), b.epsilon, b.n_reuse_batches)
                arrays, _ = run_curve(
                    made, algo, "reps", b.n_updates, b.rollouts_per_update, r, trial, eval_contexts
                )
                out.update(arrays)
            else:
                model = reward_model(made)
                out.update(run_gpreps(made, st, "gpreps", model, r, trial, eval_contexts)[0])
        return out

    def summarize(st: CurveSettings, trials: list[dict]):
        runs = [m for m in ("reps", "gpreps") if f"{m}_mean_reward" in trials[0]]
        series = [
            curve_series(
                trials,
                f"{m}_rollouts",
                f"{m}_mean_reward",
                m.upper(),
                "learning curves",
                "reward of the policy mean",
                drop_first=True,
            )
            for m in runs
        ]
        summary: dict = {"n_trials": len(trials)}
        for m in runs:
            summary[m] = {
                "real_rollouts": float(trials[0][f"{m}_rollouts"][-1]),
                **curve_stats(trials, m),
                "rollouts_to_reach": {
                    f"{level:g}": rollouts_to_reach(trials, m, level) for level in thresholds
                },
            }
            if m == "gpreps":
                summary[m].update(gpreps_stats(trials, m))
        return series, summary

    settings = scales(
        CurveSettings(task=task), shared={"smoke": _SMOKE}, smoke=smoke, quick=quick, paper=paper
    )
    if reward_model is None:  # GPREPS does not run
        off = {"gpreps": {"n_updates": 0}}
        settings = {scale: apply_overrides(st, off) for scale, st in settings.items()}
    return experiment(exp_id, title, settings, run_trial, summarize, (1, 1, 1), claim)
