r"""``cmp.methods`` (not a thesis figure): REPS, GPREPS, CMA-ES, contextual CMA-ES and contextual
BO run the learning curve of :mod:`skillkit.experiments.curves` on throwing, hockey, table tennis
and balancing from the same initial policy and evaluation. REPS and GPREPS run as the task's
thesis experiment (its :class:`~skillkit.experiments.curves.CurveTask`); the evolution strategies
get REPS's real-rollout budget, contextual BO GPREPS's. See
``skillkit/data/claims/comparisons.toml``."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from skillkit.experiments import (  # noqa: F401  profiles
    ch4_balancing,
    ch4_events,
    ch4_gpreps,
    ch4_table_tennis,
)
from skillkit.experiments.curves import (
    CurveTask,
    curve_series,
    curve_stats,
    curve_task,
    experiment,
    kept_model,
    rollouts_to_reach,
    run_curve,
)
from skillkit.experiments.registry import SCALES, get
from skillkit.experiments.settings import Settings, apply_overrides, scales, setting
from skillkit.tasks import make
from skillkit.trial import TrialContext

TASKS = ("throwing", "hockey", "table-tennis", "balancing")
"""The registered tasks of the comparison."""
METHODS = ("reps", "gpreps", "cmaes", "ccmaes", "cbo")
"""The methods, in the order they run."""
LABELS = {
    "reps": "REPS",
    "gpreps": "GPREPS",
    "cmaes": "CMA-ES",
    "ccmaes": "C-CMA-ES",
    "cbo": "contextual BO",
}


@dataclass(frozen=True)
class MethodComparisonSettings(Settings):
    """Settings of ``cmp.methods``; REPS and GPREPS take theirs from the thesis experiments."""

    tasks: tuple[str, ...] = setting(TASKS, f"Tasks compared (a subset of {TASKS}).")
    methods: tuple[str, ...] = setting(METHODS, f"Methods compared (a subset of {METHODS}).")
    thesis_scale: str = setting(
        "quick", "Scale of the thesis experiments giving REPS's and GPREPS's settings."
    )
    gpreps_updates: int = setting(0, "GPREPS updates (0: the thesis experiment's).", minimum=0)
    n_artificial: int = setting(0, "GPREPS's M (0: the thesis experiment's).", minimum=0)
    n_trajectories: int = setting(0, "GPREPS's L (0: the thesis experiment's).", minimum=0)
    reps_updates: int = setting(0, "REPS updates (0: the thesis experiment's).", minimum=0)
    keep_gpreps_model: bool = setting(
        False, "Store GPREPS's policies and model on the first task (view)."
    )
    cmaes_budget: int = setting(0, "Real rollouts of each ES (0: REPS's).", minimum=0)
    cmaes_contexts: int = setting(
        4, "m, contexts each CMA-ES candidate is scored on (a task with contexts).", minimum=1
    )
    cbo_budget: int = setting(0, "Real rollouts of contextual BO (0: GPREPS's).", minimum=0)


SETTINGS = scales(
    MethodComparisonSettings(),
    smoke={"thesis_scale": "smoke", "cmaes_budget": 24, "cbo_budget": 6},
    paper={"thesis_scale": "paper"},
)
PAPER = SETTINGS["paper"]


def _check(st: MethodComparisonSettings) -> None:
    for name, values, known in (("tasks", st.tasks, TASKS), ("methods", st.methods, METHODS)):
        bad = [v for v in values if v not in known]
        if bad or not values or len(set(values)) != len(values):
            raise ValueError(f"{name}: expected distinct values from {known}, got {values!r}")
    if st.thesis_scale not in SCALES:
        raise ValueError(f"thesis_scale: expected one of {SCALES}, got {st.thesis_scale!r}")


@dataclass
class _Setup:
    """What every method of one task shares: the task, π₀, the thesis settings, evaluation."""

    task: object
    name: str
    profile: CurveTask
    thesis: Settings
    policy: object
    eval_contexts: np.ndarray
    eval_seed: int
    prior: list  # real trajectories the model-based methods start from (balancing)
    prior_rollouts: float  # those as rollout equivalents


def thesis_settings(name: str, st: MethodComparisonSettings) -> Settings:
    """The settings of task ``name``'s thesis experiment at ``st.thesis_scale``, with the
    GPREPS and REPS sizes that ``st`` sets (non-zero) in their place."""
    thesis = get(curve_task(name).experiment).settings[st.thesis_scale]
    sizes = {
        "gpreps": {
            "n_updates": st.gpreps_updates,
            "n_artificial": st.n_artificial,
            "n_trajectories": st.n_trajectories,
        },
        "reps": {"n_updates": st.reps_updates},
    }
    return apply_overrides(thesis, {b: {k: v for k, v in f.items() if v} for b, f in sizes.items()})


def _setup(name: str, st: MethodComparisonSettings, rng: np.random.Generator) -> _Setup:
    profile, thesis = curve_task(name), thesis_settings(name, st)
    if profile.setup is not None:
        task, policy, evals, prior, prior_rollouts = profile.setup(thesis, rng)
    else:
        task = make(name)
        policy = task.initial_policy()
        evals = task.sample_context(rng, n=thesis.evaluation.n_eval_contexts)
        prior, prior_rollouts = [], 0.0
    return _Setup(
        task, name, profile, thesis, policy, evals, int(rng.integers(2**63)), prior, prior_rollouts
    )


def _schedule(method: str, thesis: Settings) -> tuple[int, int, int]:
    """(updates K, rollouts per update N, first batch N₀) of REPS or GPREPS in ``thesis``."""
    if method == "reps":
        return thesis.reps.n_updates, *(thesis.reps.rollouts_per_update,) * 2
    return thesis.gpreps.n_updates, 1, thesis.gpreps.n_initial


def _algorithm(method: str, s: _Setup, st: MethodComparisonSettings, rng):
    """(algorithm, K, N, N₀) of ``method``; the evolution strategies get REPS's rollouts, BO
    GPREPS's, each in whole generations or batches."""
    reps, gpreps = _schedule("reps", s.thesis), _schedule("gpreps", s.thesis)
    if method == "reps":
        return (s.profile.reps(s.task, s.thesis, s.policy), *reps)
    if method == "gpreps":
        return (s.profile.make_gpreps(s.task, s.thesis, s.policy, s.prior, rng), *gpreps)
    es = method in ("cmaes", "ccmaes")
    k, n, n0 = reps if es else gpreps
    budget = (st.cmaes_budget if es else st.cbo_budget) or n0 + (k - 1) * n
    if es:
        from skillkit.search.ccmaes import CCMAES
        from skillkit.search.cmaes import CMAES  # here: the cma package imports pyplot

        m = st.cmaes_contexts if s.task.context_dim else None
        algo = (
            CMAES.for_task(s.task, policy=s.policy, rng=rng, contexts_per_candidate=m)
            if method == "cmaes"
            else CCMAES(s.policy)
        )
        n = algo.rollouts_per_update
        return algo, max(1, math.ceil(budget / n)), n, n
    from skillkit.search.cbo import CBOSettings, ContextualBO

    n = min(CBOSettings().rollouts_per_update, budget)  # its default batch, within the budget
    algo = ContextualBO.for_task(
        s.task, policy=s.policy, settings=CBOSettings(rollouts_per_update=n), rng=rng
    )
    return algo, max(1, math.ceil(budget / n)), n, n


def _run_method(method: str, s: _Setup, st, rng, trial: TrialContext) -> dict:
    algo, k, n, n0 = _algorithm(method, s, st, rng.spawn(1)[0])
    last = [time.perf_counter()]

    def clock(step: int, _alg) -> float:  # seconds since the last update in this process
        now = time.perf_counter()
        took, last[0] = now - last[0], now
        return took if step else 0.0

    key = f"{s.name}/{method}"
    _, c = run_curve(
        s.task,
        algo,
        key,
        k,
        n,
        rng,
        trial,
        s.eval_contexts,
        eval_seed=s.eval_seed,
        initial_rollouts=n0,
        callback=clock,
    )
    prior = s.prior_rollouts if method == "gpreps" and s.prior else 0.0
    out = {
        f"{key}_rollouts": c["rollouts"].astype(float) + prior,
        f"{key}_mean_reward": c["mean_reward"],
        f"{key}_eval_failure_rate": c["eval_failure_rate"],
        f"{key}_time_s": np.cumsum(np.asarray(c["callback"], dtype=float)),
        f"{key}_n_failed": int(np.sum(c["n_failed"])),
    }
    if method == "gpreps" and st.keep_gpreps_model and s.name == st.tasks[0]:
        out.update(kept_model(algo, c["policies"]))
    return out


def _updates(method: str, s: _Setup, st) -> int:
    """Updates of ``method`` on ``s`` (the progress bar's share); a peer is built (no fit)."""
    if method in ("reps", "gpreps"):
        return _schedule(method, s.thesis)[0]
    return _algorithm(method, s, st, np.random.default_rng(0))[1]


def run_trial(st: MethodComparisonSettings, rng: np.random.Generator, trial: TrialContext):
    """Every method on every task of ``st`` from the same π₀, evaluated the same way."""
    _check(st)
    setups = [
        _setup(name, st, r) for name, r in zip(st.tasks, rng.spawn(len(st.tasks)), strict=True)
    ]
    trial.reset(total=sum(_updates(m, s, st) for s in setups for m in st.methods))
    out: dict = {}
    for s, task_rng in zip(setups, rng.spawn(len(setups)), strict=True):
        for method, r in zip(st.methods, task_rng.spawn(len(st.methods)), strict=True):
            out.update(_run_method(method, s, st, r, trial))
    return out


def _method_row(trials: list[dict], key: str, thresholds) -> dict:
    reached = {}
    for level in thresholds:
        per_trial = [rollouts_to_reach([t], key, level) for t in trials]
        reached[f"{level:g}"] = {
            "rollouts_mean_curve": rollouts_to_reach(trials, key, level),
            "n_reached": sum(r is not None for r in per_trial),
            "rollouts_per_trial": per_trial,
        }
    return {
        "real_rollouts": float(trials[0][f"{key}_rollouts"][-1]),
        **curve_stats(trials, key),
        "time_s_mean": float(np.mean([t[f"{key}_time_s"][-1] for t in trials])),
        "failed_rollouts": int(sum(t[f"{key}_n_failed"] for t in trials)),
        "thresholds": reached,
    }


def _winners(row: dict, thresholds) -> dict:
    """The best final reward and, per threshold, the methods fastest to reach it (or "π₀")."""
    finals = {m: r["final_reward_mean"] for m, r in row.items()}
    finals = {m: f for m, f in finals.items() if f is not None and math.isfinite(f)}
    best_final = max(finals, key=finals.get) if finals else None
    first = {}
    for level in thresholds:
        got = {m: row[m]["thresholds"][f"{level:g}"]["rollouts_mean_curve"] for m in row}
        got = {m: r for m, r in got.items() if r is not None}
        if not got:
            first[f"{level:g}"] = None
        elif min(got.values()) == 0:
            first[f"{level:g}"] = ["π₀"]
        else:
            first[f"{level:g}"] = [m for m, r in got.items() if r == min(got.values())]
    return {"best_final_reward": best_final, "fewest_rollouts": first}


def summarize(st: MethodComparisonSettings, trials: list[dict]):
    """Learning curves per task (reward vs real rollouts, log x) and the comparison table."""
    series, table = [], {}
    for name in st.tasks:
        profile = curve_task(name)
        levels = profile.thresholds
        row = {m: _method_row(trials, f"{name}/{m}", levels) for m in st.methods}
        series += [
            curve_series(
                trials,
                f"{name}/{m}_rollouts",
                f"{name}/{m}_mean_reward",
                LABELS[m],
                name,
                "reward of the policy mean",
                drop_first=True,
            )
            for m in st.methods
        ]
        if any(np.any(t[f"{name}/{m}_eval_failure_rate"] > 0) for t in trials for m in st.methods):
            series += [
                curve_series(
                    trials,
                    f"{name}/{m}_rollouts",
                    f"{name}/{m}_eval_failure_rate",
                    LABELS[m],
                    f"{name}: failed evaluations",
                    "share of evaluation rollouts that failed",
                    drop_first=True,
                )
                for m in st.methods
            ]
        table[name] = {
            "thresholds": list(levels),
            "thresholds_source": profile.thresholds_source,
            "thesis_settings": profile.experiment,
            "methods": row,
            "winners": _winners(row, levels),
        }
    return series, {"n_trials": len(trials), "tasks": table}


experiment(
    "cmp.methods",
    "REPS, GPREPS, CMA-ES, C-CMA-ES and contextual BO on the thesis's tasks (not a thesis figure)",
    SETTINGS,
    run_trial,
    summarize,
    (1, 2, 5),
)
