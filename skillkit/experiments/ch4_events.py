"""Chapter 4, GPREPS with discrete-event models: hockey (Sec. 4.3.3) and the GPREPS runs
shared with table tennis (Sec. 4.3.4, :mod:`skillkit.experiments.ch4_table_tennis`).

Every GPREPS run follows Table 4.1: N₀ = 20 real rollouts before the first update (Sec. 4.1:
"e.g. N = 20"), then one per update, M artificial (s, ω) pairs with L predicted trajectories
each, ε = 0.5, μ̂(s) the box of the observed contexts. All methods start from the task's
imitation policy and are scored by :mod:`skillkit.experiments.curves`: the reward of the policy
mean on fixed contexts after every update and, every few updates, the task's held-out scores
(hit rate and displacement error for hockey; outcome and landing error for table tennis).

* ``fig4.10`` — hockey: GPREPS with the decomposed model of 4.3.3
  (:class:`~skillkit.tasks.hockey.model.HockeyRewardModel`) against contextual REPS with
  ``fig3.5``'s settings.
* ``fig4.11`` — the real-robot setting (``hockey-real``: C.2's ranges, 30 Hz noisy puck
  tracking, Butterworth smoothing) with a displacement model in place of the contact model.
  GPREPS only, 5 runs, a 95% confidence band.

How each run is judged is the claims spec's (``skillkit/data/claims/ch4.toml``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Literal

import numpy as np
from scipy import stats

from skillkit.experiments.ch3_hockey import HockeySettings, heldout_scores
from skillkit.experiments.ch3_hockey import make_algorithm as hockey_algorithm
from skillkit.experiments.curves import (
    CurveTask,
    curve_series,
    gpreps_stats,
    heldout_stats,
    register_curve_task,
    rollouts_to_reach,
    run_curve,
    run_gpreps,
)
from skillkit.experiments.registry import Experiment, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ExactGP
from skillkit.search.loop import policy_history_arrays
from skillkit.tasks import make
from skillkit.trial import TrialContext
from skillkit.viz.model_layers import dumps_reward_model

__all__ = ["HockeyGPREPSSettings", "hockey_reward_model"]

THESIS_410 = {"gpreps_rollouts": 120, "gpreps_displacement_error_m": 0.05, "reps_rollouts": 10000}
"""The thesis's numbers on Fig. 4.10, kept in the summary as ``thesis_numbers``."""


@dataclass(frozen=True)
class EventGPREPSSettings(Settings):
    """GPREPS settings shared by the hockey and table-tennis experiments (Table 4.1)."""

    n_initial: int = setting(20, "N₀, real rollouts before the first update (Sec. 4.1).", minimum=2)
    n_updates: int = setting(100, "GPREPS updates, one real rollout each.", minimum=1)
    n_artificial: int = setting(500, "M, artificial (s, ω) pairs per update.", minimum=2)
    n_trajectories: int = setting(10, "L, predicted trajectories per pair (Eq. 4.1).", minimum=1)
    epsilon: float = setting(
        0.5,
        "KL bound ε of GPREPS: the thesis's REPS value on hockey "
        "(throwing's ε = 1 collapsed the search, data/notes/fig4.10.md).",
        above=0,
    )
    context_model: Literal["gaussian", "uniform", "prior"] = setting(
        "uniform", "μ̂(s): the box of the observed contexts."
    )
    gp_steps: int = setting(100, "L-BFGS iterations of every GP's hyper-parameter fit.", minimum=0)
    n_eval_contexts: int = setting(10, "Fixed contexts of the learning curve.", minimum=1)
    n_heldout: int = setting(50, "Held-out contexts of the shot scores.", minimum=1)
    heldout_every: int = setting(20, "Held-out scores every this many updates.", minimum=1)


@dataclass(frozen=True)
class HockeyGPREPSSettings(EventGPREPSSettings):
    """Settings of ``fig4.10`` and ``fig4.11`` (hockey; REPS with ``fig3.5``'s settings)."""

    task: Literal["hockey", "hockey-real"] = setting(
        "hockey", "Registered task: hockey (fig4.10) or hockey-real (fig4.11)."
    )
    slide_dt: float = setting(
        0.04, "Step of the sliding-puck model, s (hockey-real: its 30 Hz frame period).", above=0
    )
    max_sliding_points: int = setting(150, "Transitions the sliding GP is fitted on.", minimum=2)
    refit: Literal["best", "cold", "warm"] = setting(
        "best",
        "Start of each GP refit (Sec. 4.1): default initialisation (cold), previous "
        "values (warm), or both keeping the larger marginal likelihood (best).",
    )
    launch_targets: Literal["heading", "velocity"] = setting(
        "heading", "Launch GP outputs: [p_y, heading, speed, t_0] or [p_y, v_x, v_y, t_0]."
    )
    displacement: Literal["hit_gp", "gp"] = setting(
        "hit_gp",
        "hockey-real's displacement model: a hit/miss classifier and a GP on the hits, "
        "or one GP on all approaches.",
    )
    reps_updates: int = setting(200, "REPS updates (0: no REPS run).", minimum=0)
    reps_rollouts_per_update: int = setting(50, "REPS rollouts per update (fig3.5).", minimum=1)
    reps_epsilon: float = setting(0.5, "KL bound of REPS (fig3.5).", above=0)
    reps_reuse_batches: int = setting(4, "Batches REPS reuses (fig3.5).", minimum=1)


GPREPS_SMOKE = {
    "n_initial": 4,
    "n_updates": 2,
    "n_artificial": 20,
    "n_trajectories": 2,
    "gp_steps": 10,
    "n_eval_contexts": 1,
    "n_heldout": 2,
    "heldout_every": 1,
}
"""The smoke scale's changes of every GPREPS experiment here."""
GPREPS_QUICK = {
    "n_updates": 15,
    "n_artificial": 200,
    "n_trajectories": 5,
    "gp_steps": 60,
    "n_heldout": 20,
    "heldout_every": 5,
}
"""The quick scale's changes: updates 100→15 (fig4.11 61→15, table tennis 130→15), M 500→200,
L 10→5, L-BFGS iterations 100→60, held-out contexts 50→20 (scored every 5 updates)."""


def gpreps_scales(cls, smoke: dict, quick: dict, paper: dict | None = None) -> dict:
    """The three scales of ``cls``: the shared changes plus the experiment's own."""
    return scales(
        cls(), smoke={**GPREPS_SMOKE, **smoke}, quick={**GPREPS_QUICK, **quick}, paper=paper
    )


# --------------------------------------------------------------------------- models
def hockey_reward_model(task, st: HockeyGPREPSSettings):
    """The decomposed hockey reward model of GPREPS (Sec. 4.3.3) with ``st``'s GP fits
    (:class:`~skillkit.tasks.hockey.model.HockeyRewardModel`; the real-robot task slides at
    its observation frame rate)."""
    from skillkit.tasks.hockey.model import HockeyRewardModel

    gp = partial(ExactGP, n_steps=st.gp_steps)
    slide_dt = None if task.observation is not None else st.slide_dt  # real: the frame rate
    return HockeyRewardModel(
        task,
        make_launch_model=gp,
        make_launch_probability_model=gp,
        make_sliding_model=gp,
        make_contact_model=gp,
        make_displacement_model=gp,
        slide_dt=slide_dt,
        max_sliding_points=st.max_sliding_points,
        refit=st.refit,
        launch_targets=st.launch_targets,
        displacement=st.displacement,
    )


def gpreps_run(task, st, key, model, rng, trial, eval_contexts, score, keep_model=False):
    """GPREPS with ``model``; held-out ``score(policy)`` every ``heldout_every`` updates, the
    model's stage and refit starts per update, and with ``keep_model`` the model and the
    policy history."""
    out = run_gpreps(
        task,
        st,
        key,
        model,
        st.n_artificial,
        st.n_trajectories,
        rng,
        trial,
        eval_contexts,
        score=score,
    )
    diags = out.pop(f"{key}_diagnostics")
    algo = out.pop(f"{key}_algorithm")
    out[f"{key}_stage"] = np.array([str(d.model_fit.get("stage", "")) for d in diags])
    starts = [
        [v["start"] for v in d.model_fit.values() if isinstance(v, dict) and "start" in v]
        for d in diags
    ]
    if any(starts):  # models refitted by refit_gp: which start each update's GPs kept
        out[f"{key}_refit_gps"] = np.array([len(x) for x in starts])
        out[f"{key}_refit_warm_kept"] = np.array([x.count("warm") for x in starts])
    if keep_model:
        out["reward_model"] = np.frombuffer(dumps_reward_model(algo.reward_model), np.uint8)
        out.update(policy_history_arrays(out[f"{key}_policies"]))
    out.pop(f"{key}_policies", None)
    out.pop(f"{key}_policy")
    return out


# --------------------------------------------------------------------------- hockey
def run_trial_hockey(st: HockeyGPREPSSettings, rng: np.random.Generator, trial: TrialContext):
    """GPREPS (and, with ``reps_updates``, REPS) on ``st.task`` from the imitation policy."""
    task = make(st.task)
    heldout = task.sample_context(rng, n=st.n_heldout)
    eval_contexts = task.sample_context(rng, n=st.n_eval_contexts)
    heldout_seed = int(rng.integers(2**63))
    seeds = rng.spawn(2)
    trial.reset(total=st.n_updates + st.reps_updates)

    def score(policy) -> dict:
        return heldout_scores(task, policy, heldout, heldout_seed)

    out: dict = {"heldout_contexts": heldout}
    out.update(
        gpreps_run(
            task,
            st,
            "gpreps",
            hockey_reward_model(task, st),
            seeds[0],
            trial,
            eval_contexts,
            score,
            keep_model=True,
        )
    )
    if st.reps_updates:
        reps = _reps(task, st)
        every = max(1, st.reps_updates // 5)
        arrays, _ = run_curve(
            task,
            reps,
            "reps",
            st.reps_updates,
            st.reps_rollouts_per_update,
            seeds[1],
            trial,
            eval_contexts,
            score=score,
            every=every,
        )
        out.update(arrays)
    return out


def _reps(task, st: HockeyGPREPSSettings):
    """fig3.5's contextual REPS with ``st``'s ε and reuse."""
    hs = HockeySettings(epsilon=st.reps_epsilon, n_reuse_batches=st.reps_reuse_batches)
    return hockey_algorithm("reps", task, hs)


def gpreps_event_stats(trials, key) -> dict:
    """:func:`~skillkit.experiments.curves.gpreps_stats` with the median relative error per
    trial, the share of GP refits that kept the warm start and the update at which the reward
    schedule switched to returning (where recorded)."""
    out = gpreps_stats(trials, key)
    rel = [np.asarray(t[f"{key}_relative_error"][1:], dtype=float) for t in trials]
    out["prediction_relative_error_median_per_trial"] = [
        float(np.nanmedian(r)) if np.any(np.isfinite(r)) else None for r in rel
    ]
    if all(f"{key}_refit_gps" in t for t in trials):
        gps = sum(int(np.sum(t[f"{key}_refit_gps"])) for t in trials)
        warm = sum(int(np.sum(t[f"{key}_refit_warm_kept"])) for t in trials)
        out["refit_warm_kept_fraction"] = warm / gps if gps else None
    stages = [list(t[f"{key}_stage"]) for t in trials]
    if any(s and s[-1] for s in stages):
        out["switched_to_returning_at_update"] = [
            (s.index("returning") + 1) if "returning" in s else None for s in stages
        ]
    return out


HOCKEY_SCORES = ("reward", "hit_rate", "displacement_error", "displacement_error_hits")
"""Held-out shot scores summarised per method: ``displacement_error`` counts a miss as an
error of d* (the target puck stays), ``displacement_error_hits`` is the placed puck's error
(hits only)."""


def heldout_curves(trials, key, label, panels, heldout="displacement_error", **kw) -> list:
    """The learning curve and the held-out score ``heldout`` of run ``key`` on ``panels``
    ((panel, ylabel) of each)."""
    (p1, y1), (p2, y2) = panels
    return [
        curve_series(trials, f"{key}_rollouts", f"{key}_mean_reward", label, p1, y1, **kw),
        curve_series(
            trials, f"{key}_heldout_rollouts", f"{key}_heldout_{heldout}", label, p2, y2, **kw
        ),
    ]


def summarize_410(st: HockeyGPREPSSettings, trials: list[dict]):
    keys = ("gpreps", "reps") if st.reps_updates else ("gpreps",)
    labels = {"gpreps": "GPREPS", "reps": "REPS (ε = 0.5)"}
    panels = (
        ("learning curves", "reward of the policy mean"),
        ("held-out displacement error", "|d_T − d*| (m)"),
    )
    series = [s for key in keys for s in heldout_curves(trials, key, labels[key], panels)]
    summary: dict = {"n_trials": len(trials), "thesis_numbers": dict(THESIS_410)}
    for key in keys:
        summary[key] = heldout_stats(trials, key, HOCKEY_SCORES)
    summary["gpreps"].update(gpreps_event_stats(trials, "gpreps"))
    if st.reps_updates:
        summary["reps_rollouts_to_gpreps_final_reward"] = rollouts_to_reach(
            trials, "reps", summary["gpreps"]["final_reward"], "heldout_reward", "heldout_rollouts"
        )
    return series, summary


def summarize_411(st: HockeyGPREPSSettings, trials: list[dict]):
    panels = (
        ("learning curve", "reward of the policy mean (smoothed observations)"),
        ("held-out displacement error", "|d_T − d*| (m)"),
    )
    series = heldout_curves(trials, "gpreps", "GPREPS (mean, 95% CI)", panels, band="ci95")
    g = heldout_stats(trials, "gpreps", HOCKEY_SCORES)
    g.update(gpreps_event_stats(trials, "gpreps"))
    for when in ("initial", "final"):
        v = np.array([t["gpreps_heldout_reward"][0 if when == "initial" else -1] for t in trials])
        g[f"{when}_reward_ci95"] = list(_ci95(v))
    return series, {"n_trials": len(trials), "gpreps": g}


def _ci95(values: np.ndarray) -> tuple[float, float]:
    """Student-t 95% confidence interval of the mean of ``values``."""
    values = np.asarray(values, dtype=float)
    if values.size < 2:
        return float(values.mean()), float(values.mean())
    half = stats.t.ppf(0.975, values.size - 1) * values.std(ddof=1) / np.sqrt(values.size)
    return float(values.mean() - half), float(values.mean() + half)


# --------------------------------------------------------------------------- registry
register(
    Experiment(
        id="fig4.10",
        title="Robot hockey: GPREPS (decomposed event models) vs REPS",
        settings_class=HockeyGPREPSSettings,
        settings=gpreps_scales(
            HockeyGPREPSSettings,
            quick={"reps_updates": 20},
            smoke={"reps_updates": 1, "reps_rollouts_per_update": 25, "reps_epsilon": 0.2},
        ),
        run_trial=run_trial_hockey,
        summarize=summarize_410,
        trials={"smoke": 1, "quick": 1, "paper": 5},
    )
)
register(
    Experiment(
        id="fig4.11",
        title="Robot hockey, real-robot setting: GPREPS with a displacement model",
        settings_class=HockeyGPREPSSettings,
        settings=gpreps_scales(
            HockeyGPREPSSettings,
            smoke={"task": "hockey-real", "reps_updates": 0},
            quick={"task": "hockey-real", "reps_updates": 0},
            paper={"task": "hockey-real", "reps_updates": 0, "n_updates": 61, "n_trajectories": 5},
        ),
        run_trial=run_trial_hockey,
        summarize=summarize_411,
        trials={"smoke": 2, "quick": 3, "paper": 5},
    )
)
register_curve_task(
    "hockey",
    CurveTask(
        experiment="fig4.10",
        thresholds=(-0.2, -0.05),
        thresholds_source="Sec. 3.4.2: REPS's displacement error “remained below 20cm”; "
        "Sec. 4.3.3: GPREPS's “less than 5 cm” (a hit placing the puck d off its target "
        "scores R = −d)",
        reps=lambda task, st, policy: _reps(task, st),
        reward_model=hockey_reward_model,
    ),
)
