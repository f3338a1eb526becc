"""Chapter 3, robot hockey (Sec. 3.4.2, App. C.2): ``fig3.5``, contextual REPS (ε = 0.5) versus
CrKR (Eqs. 2.19–2.20) with k(s, s') = zᵀz' + 1 on z = (s − s̄) / h and D = diag(Σ₀) / (k(s̄, s̄)
+ λ), so that both first explore alike. Judged in ``skillkit/data/claims/ch3.toml``."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from skillkit._validation import check_array
from skillkit.experiments.curves import (
    EvaluationBlock,
    REPSBlock,
    curve_series,
    experiment,
    heldout_setup,
    run_curve,
)
from skillkit.experiments.registry import Series
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.kernels import Linear
from skillkit.tasks import make
from skillkit.trial import TrialContext


@dataclass(frozen=True)
class HockeySettings(Settings):
    """Settings of ``fig3.5`` (robot hockey, Sec. 3.4.2, App. C.2); see the module docstring."""

    task: Literal["hockey", "hockey-real"] = setting(
        "hockey", "C.2's simulated task or its real-robot variant."
    )
    reps: REPSBlock = setting(
        REPSBlock(n_updates=16, rollouts_per_update=50, epsilon=0.5, n_reuse_batches=4),
        "Contextual REPS (Sec. 3.4.2); CrKR learns with its K, N and reused batches.",
    )
    crkr_lam: float = setting(0.2, "CrKR's λ (Eqs 2.19–2.20).", above=0)
    crkr_beta_scale: float = setting(2.0, "CrKR's β = crkr_beta_scale / std(R).", above=0)
    evaluation: EvaluationBlock = setting(
        EvaluationBlock(n_eval_contexts=6, n_heldout=30, heldout_every=8),
        "Learning curve, and hit rate and error on held-out contexts.",
    )


SCALES = scales(
    HockeySettings(),
    # smoke: a gentle bound keeps the effective sample size of 25 samples above 16
    smoke={
        "reps": {"n_updates": 1, "rollouts_per_update": 25, "epsilon": 0.2},
        "evaluation": {"n_eval_contexts": 2, "n_heldout": 3, "heldout_every": 1},
    },
    # quick: 16 of 200 updates, 6 of 10 learning-curve contexts, 30 of 100 held-out, 1 trial
    paper={
        "reps": {"n_updates": 200},
        "evaluation": {"n_eval_contexts": 10, "n_heldout": 100, "heldout_every": 40},
    },
)
ALGORITHMS = ("reps", "crkr")
LABELS = {"reps": "contextual REPS (ε = 0.5)", "crkr": "CrKR (linear kernel)"}
THESIS = {"reps_hit_rate": 0.95, "reps_displacement_error_m": 0.20}
HOCKEY_SCORES = ("reward", "hit_rate", "displacement_error", "displacement_error_hits")
"""Held-out scores summarised per method: ``displacement_error`` counts a miss as an error of
d* (the target puck stays), ``displacement_error_hits`` is the placed puck's (hits only)."""


class NormalisedLinear(Linear):
    """Linear kernel on normalised inputs, k(s, s') = σ² zᵀz' + c with z = (s − centre) / scale.

    Parameters
    ----------
    centre, scale : array_like, shape (context_dim,)
        Input offset and (positive) scale.
    variance, bias : float
        σ² > 0 and c ≥ 0 of :class:`skillkit.models.kernels.Linear`.
    """

    def __init__(self, centre, scale, variance: float = 1.0, bias: float = 0.0):
        super().__init__(variance=variance, bias=bias)
        scale = check_array(scale, "scale", ndim=1)
        if np.any(scale <= 0):
            raise ValueError("scale: expected positive scales")
        centre = check_array(centre, "centre", shape=scale.shape)
        self.register_buffer("centre", torch.as_tensor(centre, dtype=torch.float64))
        self.register_buffer("scale", torch.as_tensor(scale, dtype=torch.float64))

    def forward(self, x1, x2, diag: bool = False, **params):
        z1 = (x1 - self.centre) / self.scale
        z2 = (x2 - self.centre) / self.scale
        return super().forward(z1, z2, diag=diag, **params)


def make_algorithm(name: str, task, settings: HockeySettings):
    """The search algorithm ``name`` ∈ {"reps", "crkr"} for ``task``, from its initial policy.

    Parameters
    ----------
    name : {"reps", "crkr"}
    task : skillkit.tasks.hockey.Hockey
    settings : HockeySettings
    """
    from skillkit.models.kernels import gram
    from skillkit.search import ContextualREPS, CrKR

    prior, b = task.initial_policy(), settings.reps
    if name == "reps":
        return ContextualREPS(prior, epsilon=b.epsilon, n_reuse_batches=b.n_reuse_batches)
    if name == "crkr":
        low, high = np.asarray(task.context_low), np.asarray(task.context_high)
        centre, half = 0.5 * (low + high), 0.5 * (high - low)
        kernel = NormalisedLinear(centre, np.where(half > 0, half, 1.0), bias=1.0)
        k_cc = float(gram(kernel, centre[None, :])[0, 0])
        lam = settings.crkr_lam
        scale = np.diag(prior.cov) / (k_cc + lam)
        return CrKR(
            prior,
            kernel,
            lam=lam,
            beta_scale=settings.crkr_beta_scale,
            n_reuse_batches=b.n_reuse_batches,
            variance_scale=scale,
        )
    raise ValueError(f"name: expected one of {ALGORITHMS}, got {name!r}")


def heldout_scores(task, policy, contexts, rng=None) -> dict[str, float]:
    """The policy mean's shots on ``contexts`` (n, 3), scored; ``rng``: the rollouts'
    randomness (observation noise of ``hockey-real``).

    Returns
    -------
    dict
        ``reward`` (mean R), ``hit_rate``, ``displacement_error`` (mean |d_T − d*|; a miss
        leaves d_T = 0), ``displacement_error_hits`` (over hits; NaN if none), ``blade_lowest``
        (lowest blade corner over all rollouts, m), ``failed`` (count).
    """
    from skillkit._validation import as_generator

    rng = as_generator(rng)
    means = np.atleast_2d(policy.mean_of(contexts))
    rewards, hits, errors, failed, lowest = [], [], [], 0, np.inf
    for w, s in zip(means, contexts, strict=True):
        r, traj = task.evaluate(w, s, rng)
        rewards.append(r)
        failed += int(traj.failed)
        lowest = min(lowest, float(traj.info.get("blade_lowest", np.inf)))
        hit = bool(traj.info.get("hit", False))
        hits.append(hit)
        errors.append(abs(float(traj.info.get("displacement", 0.0)) - float(s[2])))
    hits, errors = np.array(hits), np.array(errors)
    return {
        "reward": float(np.mean(rewards)),
        "hit_rate": float(hits.mean()),
        "displacement_error": float(errors.mean()),
        "displacement_error_hits": float(errors[hits].mean()) if hits.any() else float("nan"),
        "blade_lowest": lowest,
        "failed": failed,
    }


def _run_trial(settings: HockeySettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    """Both algorithms, same task, same evaluation and held-out contexts."""
    task = make(settings.task)
    K, N = settings.reps.n_updates, settings.reps.rollouts_per_update
    ev = settings.evaluation
    heldout, eval_contexts, score, seeds = heldout_setup(task, ev, rng, 2, heldout_scores)
    trial.reset(total=len(ALGORITHMS) * K)
    out: dict = {"heldout_contexts": heldout}
    for name, alg_rng in zip(ALGORITHMS, seeds, strict=True):
        t0 = time.perf_counter()
        algo = make_algorithm(name, task, settings)
        arrays, res = run_curve(
            task,
            algo,
            name,
            K,
            N,
            alg_rng,
            trial,
            eval_contexts,
            score=score,
            every=ev.heldout_every,
        )
        out.update(arrays)
        for key in ("explore_rollouts", "explore_reward", "n_failed"):
            out[f"{name}_{key}"] = res[key]
        out[f"{name}_wall_time_s"] = time.perf_counter() - t0  # this process's share
    return out


def _nan_stats(values: np.ndarray) -> tuple[float, float]:
    """Mean and standard deviation over trials ignoring NaN (no hits); NaN if all are NaN."""
    ok = values[np.isfinite(values)]
    return (float(ok.mean()), float(ok.std())) if ok.size else (float("nan"), float("nan"))


def _summarize(settings: HockeySettings, trials: list[dict]) -> tuple[list[Series], dict]:
    series: list[Series] = []
    summary: dict = {
        "n_trials": len(trials),
        "rollouts_per_algorithm": settings.reps.n_updates * settings.reps.rollouts_per_update,
    }
    panels = [
        ("mean_reward", "rollouts", "reward of the policy mean", "average reward"),
        ("heldout_hit_rate", "heldout_rollouts", "hit rate (held-out contexts)", "hit rate"),
        (
            "heldout_displacement_error",
            "heldout_rollouts",
            "displacement error |d_T − d*| (held-out)",
            "error [m]",
        ),
    ]
    for name in ALGORITHMS:
        series += [
            curve_series(
                trials,
                f"{name}_{xkey}",
                f"{name}_{key}",
                LABELS[name],
                panel,
                ylabel,
                log_x=False,
                xlabel="rollouts",
            )
            for key, xkey, panel, ylabel in panels
        ]
        stats = {}
        for key in ("mean_reward", *(f"heldout_{score}" for score in HOCKEY_SCORES)):
            vals = np.array([np.asarray(t[f"{name}_{key}"], dtype=float) for t in trials])
            stats[f"initial_{key}"] = _nan_stats(vals[:, 0])[0]
            stats[f"final_{key}"], stats[f"final_{key}_std"] = _nan_stats(vals[:, -1])
            stats[f"final_{key}_per_trial"] = vals[:, -1].tolist()
        stats["initial_mean_reward_per_trial"] = [
            float(t[f"{name}_mean_reward"][0]) for t in trials
        ]
        lowest = min(np.min(t[f"{name}_heldout_blade_lowest"]) for t in trials)
        stats["heldout_blade_lowest_m"] = float(lowest)
        stats["failed_rollouts"] = int(sum(int(np.sum(t[f"{name}_n_failed"])) for t in trials))
        stats["wall_time_s"] = float(np.mean([t[f"{name}_wall_time_s"] for t in trials]))
        summary[name] = stats
    summary["thesis_numbers"] = {
        "reps_hit_rate": THESIS["reps_hit_rate"],
        "reps_displacement_error_m": f"< {THESIS['reps_displacement_error_m']}",
        "crkr": "lower hit rate and larger displacement error than REPS",
    }
    return series, summary


experiment(
    "fig3.5",
    "Robot hockey: contextual REPS (ε = 0.5) vs CrKR with a linear kernel",
    SCALES,
    _run_trial,
    _summarize,
    (1, 1, 10),
)
