"""Fig. 3.7: contextual REPS learns table-tennis returns (Sec. 3.4.3).

Contextual REPS (ε = 0.6, Table 3.1) with π(ω|s) = N(a + A s, Σ) learns the 17 DMP parameters
ω = [g, ġ, τ] of :mod:`skillkit.tasks.table_tennis` from s = [v_x, v_y, v_z, b_x, b_y] and the
demonstrated forehand, through :mod:`skillkit.experiments.curves`. The final policy mean's
shots on fresh contexts are classified (returned / net / out / missed), which shows the
thesis's failure mode: balls into the net, reward in [−0.05, −0.02]. Judged in
``skillkit/data/claims/ch3.toml``; the variants tried: ``data/notes/fig3.7.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skillkit.experiments.curves import (
    EvaluationBlock,
    REPSBlock,
    curve_series,
    experiment,
    run_curve,
)
from skillkit.experiments.judge import quoted_numbers
from skillkit.experiments.registry import Series
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.policies.features import FeatureName
from skillkit.policies.gaussian import effective_sample_size
from skillkit.search.loop import policy_history_arrays
from skillkit.search.reps import ContextualREPS
from skillkit.trial import TrialContext

OUTCOMES = ("returned", "net", "out", "missed")


@dataclass(frozen=True)
class TableTennisSettings(Settings):
    """Settings of ``fig3.7`` (table tennis, Sec. 3.4.3); paper: 120 updates × 50 rollouts.

    The fit is unregularised as Eqs. 3.11–3.13 (an update whose Kish ESS is below d + 1 = 18
    keeps the policy, :class:`KeepPolicyREPS`); :data:`REGULARISED` is the fit of the stored
    variant run ``fig3.7-paper-s0-f82e2c5b`` and of fig4.12's REPS baseline.
    """

    reps: REPSBlock = setting(
        REPSBlock(n_updates=20, rollouts_per_update=50, epsilon=0.6, n_reuse_batches=4),
        "Contextual REPS (Table 3.1, Sec. 3.4.3).",
    )
    baseline_features: FeatureName = setting("linear", "Context features of V(s) (Eq. 3.8).")
    min_effective_samples: float | None = setting(
        None, "Least ESS the ML fit accepts (None: d + 1).", minimum=0
    )
    cov_shrinkage: float = setting(0.0, "Weight of the previous Σ in the new one.", minimum=0)
    evaluation: EvaluationBlock = setting(
        EvaluationBlock(n_eval_contexts=8, n_heldout=40),
        "Learning curve; held-out contexts the final shots are classified on.",
    )


REGULARISED = {"cov_shrinkage": 0.2, "min_effective_samples": 10.0}
"""A regularised weighted ML fit (not in the thesis), a named variant:
``dataclasses.replace(settings, **REGULARISED)``."""
SCALES = scales(
    TableTennisSettings(),
    smoke={
        "reps": {"n_updates": 2, "rollouts_per_update": 12, "n_reuse_batches": 2},
        "min_effective_samples": 3.0,
        "evaluation": {"n_eval_contexts": 2, "n_heldout": 3},
    },
    # quick: 20 of 120 updates, 8 of 12 learning-curve contexts, 40 of 200 final, 1 trial
    paper={"reps": {"n_updates": 120}, "evaluation": {"n_eval_contexts": 12, "n_heldout": 200}},
)


@dataclass(frozen=True)
class SkippedUpdate:
    """A :class:`KeepPolicyREPS` update whose weighted ML fit was refused: the weights' Kish
    effective sample size ``ess``, the least the fit accepts (``needed``), the samples they
    were computed on and the fit's error ``message``."""

    ess: float
    needed: float
    n_samples: int
    message: str


class KeepPolicyREPS(ContextualREPS):
    """Contextual REPS that keeps its policy when the weighted ML fit (Eqs. 3.11–3.13)
    refuses the weights (Kish ESS below ``min_effective_samples``, default d + 1): the update
    returns a :class:`SkippedUpdate`, counted in :attr:`n_skipped`, and the batch stays in the
    reuse buffer. Any other error is raised."""

    n_skipped: int = 0
    _last_ess: float | None = None

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray):
        weights, fields = super()._weigh(contexts, rewards)
        self._last_ess = float(effective_sample_size(weights / weights.sum()))
        return weights, fields

    def update(self, batch):
        """:meth:`ContextualREPS.update`, or :class:`SkippedUpdate` when the fit's ESS check
        refuses the weights (the policy is kept)."""
        self._last_ess = None
        try:
            return super().update(batch)
        except ValueError as err:
            need = self._fit_kwargs["min_effective_samples"]
            need = self.policy.dim + 1.0 if need is None else float(need)
            if self._last_ess is None or self._last_ess >= need:
                raise
            self.n_skipped += 1
            return SkippedUpdate(self._last_ess, need, len(self._buffer), str(err))


def run_trial(settings: TableTennisSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    """One contextual-REPS learning run, then the final policy mean's shots on fresh
    contexts (``final_rewards``, ``final_outcomes``, ``final_landing_error`` ‖b − p‖)."""
    from skillkit.tasks import make

    task = make("table-tennis")
    algorithm = make_reps(task, settings)
    b = settings.reps
    eval_contexts = task.sample_context(rng, n=settings.evaluation.n_eval_contexts)
    trial.reset(total=b.n_updates)
    _, curves = run_curve(
        task,
        algorithm,
        "learn",
        b.n_updates,
        b.rollouts_per_update,
        rng,
        trial,
        eval_contexts,
    )
    contexts = task.sample_context(rng, n=settings.evaluation.n_heldout)
    _, shots = shot_scores(task, curves["policy"], contexts, rng)
    return {
        "rollouts": curves["rollouts"],
        "mean_reward": curves["mean_reward"],
        "explore_reward": curves["explore_reward"],
        "n_failed": int(np.sum(curves["n_failed"])),
        "n_skipped_updates": int(algorithm.n_skipped),
        "final_rewards": shots["rewards"],
        "final_outcomes": shots["outcomes"],
        "final_landing_error": shots["landing_error"],
        **policy_history_arrays(curves["policies"]),  # Fig. 3.8 animates the last one
    }


def make_reps(task, settings: TableTennisSettings) -> KeepPolicyREPS:
    """Contextual REPS from ``task``'s imitation policy with ``settings``' ε, reuse, baseline
    and fit regularisation (the model-free learner of fig3.7, and fig4.12's baseline); an
    update whose weights are too few for the fit keeps the policy (:class:`KeepPolicyREPS`)."""
    return KeepPolicyREPS(
        task.initial_policy(),
        settings.reps.epsilon,
        n_reuse_batches=settings.reps.n_reuse_batches,
        baseline_features=settings.baseline_features,
        min_effective_samples=settings.min_effective_samples,
        cov_shrinkage=settings.cov_shrinkage,
    )


def shot_scores(task, policy, contexts, rng=None) -> tuple[dict[str, float], dict]:
    """Play the policy mean's shot on each of ``contexts`` (n, 5) and classify it.

    Returns
    -------
    scores : dict
        ``reward`` (mean R), the fractions ``returned``, ``net``, ``out``, ``missed`` and
        ``failed`` of the shots, ``landing_error`` (mean ‖b − p‖ over all shots, m).
    shots : dict
        Per shot: ``rewards`` (n,), ``outcomes`` (list of str), ``landing_error`` (n,).
    """
    from skillkit._validation import as_generator

    rng = as_generator(rng)
    omegas = np.atleast_2d(policy.mean_of(contexts))
    rewards, outcomes, errors = [], [], []
    for omega, s in zip(omegas, contexts, strict=True):
        r, traj = task.evaluate(omega, s, rng)
        rewards.append(r)
        outcomes.append("failed" if traj.failed else traj.info["outcome"])
        p = traj.info.get("landing_point", [np.nan, np.nan])
        errors.append(float(np.linalg.norm(s[3:5] - np.asarray(p))))
    shots = {"rewards": np.array(rewards), "outcomes": outcomes, "landing_error": np.array(errors)}
    scores = {"reward": float(np.mean(rewards))}
    for outcome in (*OUTCOMES, "failed"):
        scores[outcome] = float(np.mean([o == outcome for o in outcomes]))
    scores["landing_error"] = float(np.nanmean(errors))
    return scores, shots


def summarize(settings: TableTennisSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    """Learning curve (mean ± std and each trial), the final policies' outcome fractions and
    the headline numbers beside the thesis's."""
    thesis = quoted_numbers("fig3.7")  # rollouts, net band, good reward (Sec. 3.4.3)
    good = thesis[3]
    x = np.asarray(trials[0]["rollouts"], dtype=float).tolist()
    curves = np.array([t["mean_reward"] for t in trials], dtype=float)
    panel, ylabel = "learning curve", "reward of the policy mean"
    mean = curve_series(
        trials,
        "rollouts",
        "mean_reward",
        "contextual REPS (mean ± std)",
        panel,
        ylabel,
        log_x=False,
        xlabel="rollouts",
    )
    lines = [(f"trial {i + 1}", x, c.tolist()) for i, c in enumerate(curves)]
    lines.append(("thesis: good policy (−0.02)", [x[0], x[-1]], [good] * 2))
    series = [mean] + [
        Series(name, xs, ys, panel, "line", xlabel="rollouts", ylabel=ylabel)
        for name, xs, ys in lines
    ]
    final = np.array([float(np.mean(t["final_rewards"])) for t in trials])
    fractions = {
        o: [float(np.mean(np.asarray(t["final_outcomes"]) == o)) for t in trials] for o in OUTCOMES
    }
    shares = {o: float(np.mean(fractions[o])) for o in OUTCOMES}
    series.append(
        Series(
            "final policy: share of shots",
            list(OUTCOMES),
            list(shares.values()),
            "final policy outcomes",
            "bar",
            xlabel="outcome",
            ylabel="fraction of shots",
        )
    )
    reached = np.flatnonzero(np.asarray(mean.y) > good)
    returned_errors = _pooled(trials, "final_landing_error", "returned")
    net = _pooled(trials, "final_rewards", "net")
    summary = {
        "n_trials": len(trials),
        "initial_reward": float(curves[:, 0].mean()),
        "final_reward_per_trial": final.tolist(),
        "final_reward_mean": float(final.mean()),
        "final_curve_reward_per_trial": curves[:, -1].tolist(),
        "fraction_runs_above_-0.02": float(np.mean(final > good)),
        "net_fraction_per_trial": fractions["net"],
        "net_fraction_mean": shares["net"],
        "fraction_runs_with_net_failures_above_10pct": float(
            np.mean(np.array(fractions["net"]) > 0.1)
        ),
        "outcome_fractions_mean": shares,
        "net_shot_reward_mean": float(net.mean()) if net.size else None,
        "net_shot_reward_range": [float(net.min()), float(net.max())] if net.size else None,
        "median_landing_error_of_returns_m": float(np.median(returned_errors))
        if returned_errors.size
        else None,
        "rollouts_to_mean_curve_above_-0.02": float(x[reached[0]]) if reached.size else None,
        "total_rollouts_per_trial": float(x[-1]),
        "failed_rollouts": int(sum(t["n_failed"] for t in trials)),
        "skipped_updates": int(sum(t["n_skipped_updates"] for t in trials)),
        "thesis_numbers": {
            "good_reward": good,
            "net_band": thesis[1:3],
            "rollouts": int(thesis[0]),
        },
        "learned": bool(final.mean() > curves[:, 0].mean() + 0.05),
    }
    return series, summary


def _pooled(trials: list[dict], key: str, outcome: str) -> np.ndarray:
    """``key`` values of the final-policy shots with a given outcome, pooled over trials."""
    picked = [
        np.asarray(t[key], dtype=float)[np.asarray(t["final_outcomes"]) == outcome] for t in trials
    ]
    return np.concatenate(picked)


experiment(
    "fig3.7",
    "Table tennis: contextual REPS (ε = 0.6) learning returns to a target",
    SCALES,
    run_trial,
    summarize,
    (1, 1, 25),
)
