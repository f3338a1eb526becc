r"""``cmp.methods``: REPS, GPREPS, CMA-ES and contextual BO on the thesis's tasks.

Not a figure of the thesis: the comparison a researcher would make before choosing a method,
on the same tasks, from the same initial policy, evaluated the same way. Each method runs
through :func:`~skillkit.search.loop.learn` on

* **throwing** (Appendix C.1), **hockey** (C.3), **table tennis** (C.4) and **balancing**
  (Sec. 4.3.1);
* **REPS** and **GPREPS** exactly as the thesis experiments run them — the settings of
  ``fig4.6`` (throwing), ``fig4.10`` (hockey), ``fig4.12`` (table tennis) and ``tab4.2``
  (balancing) at the same scale, their reward models and their REPS baselines (built by the
  same functions);
* **CMA-ES** (:class:`~skillkit.search.cmaes.CMAES`, cma's defaults: λ = 4 + ⌊3 ln n⌋; a linear
  context mapping with m = 4 contexts per candidate) with REPS's real-rollout budget;
* **contextual BO** (:class:`~skillkit.search.cbo.ContextualBO`, BoTorch's defaults) with
  GPREPS's real-rollout budget (its cost grows with the cube of the data).

Every method of a trial starts from the task's initial policy (balancing: Table 4.2's π₀) and is
evaluated after every update on the same contexts with the same evaluation seed (the policy
mean; balancing: 50 common start states). The model-based methods on balancing start from
Table 4.2's 6 s of random-policy experience, counted as real rollouts (6 s = 1.2 rollouts of
5 s).

What is measured per task and method: the real rollouts after which the mean learning curve
first reaches each of the task's reward thresholds (:data:`THRESHOLDS`, from the thesis), the
final reward (mean ± std over trials), and the compute time (wall-clock seconds of the learning
run — rollouts, updates and evaluations — on the machine of the run). The thesis makes no claim
about CMA-ES or Bayesian optimisation: the claims spec (``skillkit/data/claims/comparisons.toml``)
says so and holds the setup table. The summary names, per task, the method with the best final
reward and those that reached each threshold with the fewest real rollouts (``winners``).

``import skillkit.experiments`` registers this experiment, as every other (the package
``__init__``'s registration imports are not part of any experiment's code fingerprint).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from skillkit.experiments import ch4_balancing as balancing42
from skillkit.experiments.ch3_hockey import HockeySettings
from skillkit.experiments.ch3_hockey import make_algorithm as hockey_algorithm
from skillkit.experiments.ch3_table_tennis import REGULARISED, TableTennisSettings, make_reps
from skillkit.experiments.ch4_events import hockey_reward_model
from skillkit.experiments.ch4_gpreps import (
    gpreps_algorithm,
    reps_algorithm,
    rollouts_to_reach,
    throwing_reward_model,
)
from skillkit.experiments.ch4_table_tennis import table_tennis_reward_model
from skillkit.experiments.registry import SCALES, Experiment, Series, get, register
from skillkit.experiments.settings import Settings, setting
from skillkit.search.loop import learn, policy_history_arrays
from skillkit.tasks import make
from skillkit.trial import TrialContext
from skillkit.viz.model_layers import dumps_reward_model
from skillkit.viz.series import trial_band

__all__ = ["METHODS", "TASKS", "THRESHOLDS", "MethodComparisonSettings", "thesis_settings"]

TASKS = ("throwing", "hockey", "table-tennis", "balancing")
"""The registered tasks of the comparison."""
METHODS = ("reps", "gpreps", "cmaes", "cbo")
"""The methods, in the order they run."""
LABELS = {"reps": "REPS", "gpreps": "GPREPS", "cmaes": "CMA-ES", "cbo": "contextual BO"}
THESIS_SETUP = {"throwing": "fig4.6", "hockey": "fig4.10", "table-tennis": "fig4.12",
                "balancing": "tab4.2"}  # fmt: skip
"""The thesis experiment whose settings (at the same scale) REPS and GPREPS use per task."""
THRESHOLDS: dict[str, tuple[tuple[float, ...], str]] = {
    "throwing": (
        (-100.0, -50.0),
        "R ≈ −c₁ × the ball's distance to the target with c₁ = 100 per metre (Appendix C.1): "
        "−100 is 1 m off on average, −50 the 0.5 m bound of Sec. 3.4.1 (Fig. 3.3); the "
        "thesis's final rewards are −715 (REPS) and −64 (GPREPS) in Fig. 4.9's caption",
    ),
    "hockey": (
        (-0.2, -0.05),
        "Sec. 3.4.2: REPS's displacement error “remained below 20cm”; Sec. 4.3.3: GPREPS's "
        "“less than 5 cm” (a hit placing the puck d off its target scores R = −d)",
    ),
    "table-tennis": (
        (-0.05, -0.02),
        "Sec. 3.4.3: high-quality policies have “a reward above -0.02”; balls in the net score "
        "“in interval [−0.05, −0.02]”",
    ),
    "balancing": ((-100.0, -10.0, -1.5), "Table 4.2's reward limits"),
}
"""Per task: the reward levels whose real-rollout cost is compared, and where they come from."""


@dataclass(frozen=True)
class MethodComparisonSettings(Settings):
    """Settings of ``cmp.methods``; REPS and GPREPS take theirs from the thesis experiments."""

    tasks: tuple[str, ...] = setting(TASKS, f"Tasks compared (a subset of {TASKS}).")
    methods: tuple[str, ...] = setting(METHODS, f"Methods compared (a subset of {METHODS}).")
    thesis_scale: str = setting(
        "quick",
        "Scale of the thesis experiments (fig4.6, fig4.10, fig4.12, tab4.2) whose REPS and "
        "GPREPS settings are used.",
    )
    gpreps_updates: int = setting(
        0, "GPREPS updates, one real rollout each (0: the thesis experiment's).", minimum=0
    )
    n_artificial: int = setting(
        0, "GPREPS's M, artificial samples per update (0: the thesis experiment's).", minimum=0
    )
    n_trajectories: int = setting(
        0, "GPREPS's L, predicted trajectories per sample (0: the thesis experiment's).", minimum=0
    )
    reps_updates: int = setting(0, "REPS updates (0: the thesis experiment's).", minimum=0)
    keep_gpreps_model: bool = setting(
        False,
        "Store GPREPS's policy history on the first task (`skillkit view TASK --policy RUN_DIR` "
        "plays it back) and, where the reward model draws prediction layers (hockey, table "
        "tennis), the model (`--gpreps RUN_DIR` overlays its predictions).",
    )
    cmaes_budget: int = setting(
        0, "Real rollouts of CMA-ES (0: REPS's budget on the task).", minimum=0
    )
    cbo_budget: int = setting(
        0, "Real rollouts of contextual BO (0: GPREPS's budget on the task).", minimum=0
    )


SMOKE = MethodComparisonSettings(thesis_scale="smoke", cmaes_budget=24, cbo_budget=6)
QUICK = MethodComparisonSettings()
PAPER = MethodComparisonSettings(thesis_scale="paper")
SETTINGS = {"smoke": SMOKE, "quick": QUICK, "paper": PAPER}


def _check(st: MethodComparisonSettings) -> None:
    for name, values, known in (("tasks", st.tasks, TASKS), ("methods", st.methods, METHODS)):
        bad = [v for v in values if v not in known]
        if bad or not values or len(set(values)) != len(values):
            raise ValueError(f"{name}: expected distinct values from {known}, got {values!r}")
    if st.thesis_scale not in SCALES:
        raise ValueError(f"thesis_scale: expected one of {SCALES}, got {st.thesis_scale!r}")


# --------------------------------------------------------------------------- one task
@dataclass
class _Setup:
    """What every method of one task shares: the task, π₀, the thesis settings, evaluation."""

    task: object
    name: str
    thesis: Settings
    policy: object
    eval_contexts: np.ndarray
    eval_seed: int
    prior: list  # real trajectories the model-based methods start from (balancing)
    prior_rollouts: float  # those as rollout equivalents


def thesis_settings(name: str, st: MethodComparisonSettings) -> Settings:
    """The settings of task ``name``'s thesis experiment at ``st.thesis_scale``, with the
    GPREPS and REPS sizes that ``st`` sets (non-zero) in their place."""
    thesis = get(THESIS_SETUP[name]).settings[st.thesis_scale]
    updates = "gpreps_updates" if name == "balancing" else "n_updates"
    sizes = {updates: st.gpreps_updates, "n_artificial": st.n_artificial,
             "n_trajectories": st.n_trajectories, "reps_updates": st.reps_updates}  # fmt: skip
    return replace(thesis, **{k: v for k, v in sizes.items() if v})


def _setup(name: str, st: MethodComparisonSettings, rng: np.random.Generator) -> _Setup:
    thesis = thesis_settings(name, st)
    prior, prior_rollouts = [], 0.0
    if name == "balancing":
        task = make("balancing", initial_std=thesis.initial_std)
        policy = balancing42.initial_policy_42(thesis, task)
        evals = np.zeros((thesis.n_eval, 0))
        prior = balancing42.random_prior(thesis, policy, rng)["trajectories"]
        prior_rollouts = balancing42.random_experience(task, prior) / (
            task.n_steps * task.control_dt
        )
    else:
        task = make(name)
        policy = task.initial_policy()
        evals = task.sample_context(rng, n=thesis.n_eval_contexts)
    return _Setup(task, name, thesis, policy, evals, int(rng.integers(2**63)), prior,
                  prior_rollouts)  # fmt: skip


def _schedule(method: str, s: _Setup) -> tuple[int, int, int]:
    """(updates K, rollouts per update N, initial rollouts N₀) of the thesis experiment's
    REPS or GPREPS on ``s``, read from its settings."""
    th = s.thesis
    if method == "gpreps":
        if s.name == "balancing":  # tab4.2: one rollout per update after the random prior
            return th.gpreps_updates, 1, 1
        return th.n_updates, 1, th.n_initial
    if s.name == "table-tennis":  # fig3.7's batch size
        n = replace(TableTennisSettings(), **REGULARISED).rollouts_per_update
        return th.reps_updates, n, n
    return th.reps_updates, th.reps_rollouts_per_update, th.reps_rollouts_per_update


def _real_rollouts(k: int, n: int, n0: int) -> int:
    """Real rollouts of a :func:`learn` run of k updates: N₀ first, then N per update."""
    return n0 + (k - 1) * n


def _reps(s: _Setup):
    """The thesis experiment's REPS baseline on ``s``."""
    th = s.thesis
    if s.name == "throwing":  # fig4.6's REPS (fig3.3's settings)
        return reps_algorithm(s.task, th)
    if s.name == "hockey":  # fig4.10's REPS (fig3.5's settings)
        hs = HockeySettings(epsilon=th.reps_epsilon, n_reuse_batches=th.reps_reuse_batches)
        return hockey_algorithm("reps", s.task, hs)
    if s.name == "table-tennis":  # fig4.12's REPS (fig3.7's, with the stored regularisation)
        return make_reps(s.task, replace(TableTennisSettings(), **REGULARISED))
    return balancing42.reps_algorithm(th, s.policy)


def _gpreps(s: _Setup, rng):
    """The thesis experiment's GPREPS on ``s``."""
    th = s.thesis
    if s.name == "balancing":
        return balancing42.gpreps_algorithm(s.task, th, s.policy, s.prior,
                                            balancing42.fitc_model(th), rng)  # fmt: skip
    if s.name == "throwing":
        model = throwing_reward_model(s.task, th, "decomposed")
    elif s.name == "hockey":
        model = hockey_reward_model(s.task, th)
    else:
        model = table_tennis_reward_model(s.task, th, th.schedule)
    return gpreps_algorithm(s.task, th, model, th.n_artificial, th.n_trajectories, rng)


def _peer_budget(method: str, s: _Setup, st: MethodComparisonSettings) -> int:
    """Real rollouts of CMA-ES (default: REPS's on the task) or BO (default: GPREPS's)."""
    if method == "cmaes":
        return st.cmaes_budget or _real_rollouts(*_schedule("reps", s))
    return st.cbo_budget or _real_rollouts(*_schedule("gpreps", s))


def _algorithm(method: str, s: _Setup, st: MethodComparisonSettings, rng):
    """(algorithm, updates, rollouts per update, initial rollouts) of ``method`` on ``s``."""
    if method == "reps":
        return (_reps(s), *_schedule("reps", s))
    if method == "gpreps":
        return (_gpreps(s, rng), *_schedule("gpreps", s))
    budget = _peer_budget(method, s, st)
    if method == "cmaes":
        from skillkit.search.cmaes import CMAES  # here: the cma package imports pyplot

        algo = CMAES.for_task(s.task, policy=s.policy, rng=rng)
        n = algo.rollouts_per_update
        return algo, max(1, math.ceil(budget / n)), n, n
    from skillkit.search.cbo import CBOSettings, ContextualBO

    n = min(CBOSettings().rollouts_per_update, budget)  # its default batch, within the budget
    algo = ContextualBO.for_task(s.task, policy=s.policy, settings=CBOSettings(
        rollouts_per_update=n), rng=rng)  # fmt: skip
    return algo, max(1, math.ceil(budget / n)), n, n


def _run_method(method: str, s: _Setup, st, rng, trial: TrialContext) -> dict:
    algo, k, n, n0 = _algorithm(method, s, st, rng.spawn(1)[0])
    last = [time.perf_counter()]

    def clock(step: int, _alg) -> float:  # seconds since the last update in this process
        now = time.perf_counter()
        took, last[0] = now - last[0], now
        return took if step else 0.0

    key = f"{s.name}/{method}"
    c = learn(s.task, algo, k, n, rng, trial=trial, eval_contexts=s.eval_contexts,
              eval_seed=s.eval_seed, checkpoint_key=key, initial_rollouts=n0,
              callback=clock)  # fmt: skip
    prior = s.prior_rollouts if method == "gpreps" and s.prior else 0.0
    out = {
        f"{key}_rollouts": c["rollouts"].astype(float) + prior,
        f"{key}_mean_reward": c["mean_reward"],
        f"{key}_time_s": np.cumsum(np.asarray(c["callback"], dtype=float)),
        f"{key}_n_failed": int(np.sum(c["n_failed"])),
    }
    if method == "gpreps" and st.keep_gpreps_model and s.name == st.tasks[0]:
        out.update(policy_history_arrays(c["policies"]))  # `skillkit view TASK --policy RUN`
        if callable(getattr(algo.reward_model, "prediction_layers", None)):  # hockey, tt
            model = dumps_reward_model(algo.reward_model)  # `skillkit view TASK --gpreps RUN`
            out["reward_model"] = np.frombuffer(model, np.uint8)
    return out


def _updates(method: str, s: _Setup, st) -> int:
    """The number of updates ``method`` runs on ``s`` (the progress bar's share): REPS's and
    GPREPS's from their settings; a peer's from its population, so it is built (no fit)."""
    if method in ("reps", "gpreps"):
        return _schedule(method, s)[0]
    return _algorithm(method, s, st, np.random.default_rng(0))[1]


def run_trial(st: MethodComparisonSettings, rng: np.random.Generator, trial: TrialContext):
    """Every method on every task of ``st`` from the same π₀, evaluated the same way."""
    _check(st)
    setups = [_setup(name, st, r) for name, r in zip(st.tasks, rng.spawn(len(st.tasks)),
                                                     strict=True)]  # fmt: skip
    trial.reset(total=sum(_updates(m, s, st) for s in setups for m in st.methods))
    out: dict = {}
    for s, task_rng in zip(setups, rng.spawn(len(setups)), strict=True):
        for method, r in zip(st.methods, task_rng.spawn(len(st.methods)), strict=True):
            out.update(_run_method(method, s, st, r, trial))
    return out


# --------------------------------------------------------------------------- summary
def _method_row(trials: list[dict], key: str, thresholds) -> dict:
    final = np.array([t[f"{key}_mean_reward"][-1] for t in trials], dtype=float)
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
        "initial_reward": float(np.mean([t[f"{key}_mean_reward"][0] for t in trials])),
        "final_reward_mean": float(final.mean()),
        "final_reward_std": float(final.std(ddof=1)) if len(trials) > 1 else 0.0,
        "final_reward_per_trial": final.tolist(),
        "time_s_mean": float(np.mean([t[f"{key}_time_s"][-1] for t in trials])),
        "failed_rollouts": int(sum(t[f"{key}_n_failed"] for t in trials)),
        "thresholds": reached,
    }


def _winners(row: dict, thresholds) -> dict:
    """Per task: the method with the best final reward, and per threshold the methods that
    reached it (on the mean curve) with the fewest real rollouts — all of them on a tie, "π₀"
    when the initial policy is already there, None when no method reached it."""
    best_final = max(row, key=lambda m: row[m]["final_reward_mean"])
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
        levels, source = THRESHOLDS[name]
        row = {m: _method_row(trials, f"{name}/{m}", levels) for m in st.methods}
        for m in st.methods:
            key = f"{name}/{m}"
            x = np.asarray(trials[0][f"{key}_rollouts"], dtype=float)
            m_curve, band = trial_band(np.array([t[f"{key}_mean_reward"] for t in trials]))
            series.append(Series(LABELS[m], x[1:].tolist(), m_curve[1:], panel=name,
                                 **{k: v[1:] if isinstance(v, list) else v
                                    for k, v in band.items()},
                                 xlabel="real rollouts (log scale)",
                                 ylabel="reward of the policy mean", log_x=True))  # fmt: skip
        table[name] = {
            "thresholds": list(levels),
            "thresholds_source": source,
            "thesis_settings": THESIS_SETUP[name],
            "methods": row,
            "winners": _winners(row, levels),
        }
    return series, {"n_trials": len(trials), "tasks": table}


register(
    Experiment(
        id="cmp.methods",
        title="REPS, GPREPS, CMA-ES and contextual BO on the thesis's tasks (not a thesis figure)",
        settings_class=MethodComparisonSettings,
        settings=SETTINGS,
        run_trial=run_trial,
        summarize=summarize,
        trials={"smoke": 1, "quick": 2, "paper": 5},
    )
)
