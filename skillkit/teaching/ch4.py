"""Chapter 4 step by step: one GPREPS iteration (Sec. 4.1, Table 4.1) taken apart.

The notebook calls the library's pieces in the order
:meth:`GPREPS.update <skillkit.search.gpreps.GPREPS.update>` does (model fit, μ̂(s), policy
samples, Eq. 4.1, weights 3.10, ML fit 3.11–3.13), so from one generator it gets its numbers.
This module sizes, tabulates and draws those cells, resamples the reward estimates of the
M, L widget and reads stored runs (Table 4.2, Fig. 4.4, fig4.10–4.12). Figures take
``backend`` in {"plotly", "matplotlib"}.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from skillkit._validation import as_generator, check_array, check_count
from skillkit.experiments.ch4_balancing import median_reached
from skillkit.experiments.ch4_gpreps import COV_FLOOR, MIN_EFFECTIVE_SAMPLES
from skillkit.models.gp import EVENT_KINDS, ExactGP, ForwardModel, record_numerical_events
from skillkit.models.sparse import FITC
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.gpreps import GPREPSDiagnostics, GPREPSSettings
from skillkit.search.reps import REPSWeights
from skillkit.tasks.base import Task
from skillkit.tasks.planar import Throwing
from skillkit.tasks.throwing_model import ThrowingPrediction, ThrowingRewardModel
from skillkit.teaching._common import draw
from skillkit.viz.series import Series

__all__ = [
    "EXPECTED_WARNINGS",
    "HandledEvents",
    "IterationSizes",
    "ModelView",
    "RewardPool",
    "SCALES",
    "THESIS_TABLE_4_2",
    "batch_table",
    "contexts_figure",
    "diagnostics_table",
    "exploration_figure",
    "exploration_table",
    "fit_table",
    "gflops_table",
    "gpreps_model_view",
    "handled_events",
    "iteration_sizes",
    "policy_change_table",
    "predicted_throws_figure",
    "reward_estimate_figure",
    "reward_estimates",
    "reward_pool",
    "step_settings",
    "table_4_2",
    "throwing_model",
    "update_comparison",
    "weights_figure",
]


# --------------------------------------------------------------------------- sizes
@dataclass(frozen=True)
class IterationSizes:
    """How big the notebook's GPREPS step-through is at one scale.

    N₀ real throws before the first update, M artificial pairs per update, L predicted
    throws per pair (Eq. 4.1), updates after the first (one real throw each); pseudo-inputs
    of the FITC flight and robot models and L-BFGS steps of the GP fits (2.28; 150 for the
    robot at every scale, as fig4.6), at most ``max_points`` transitions each; the reward
    pool of the M, L widget (:func:`reward_pool`).
    """

    n_initial: int
    n_artificial: int
    n_trajectories: int
    n_updates: int
    n_inducing: int
    gp_steps: int
    robot_inducing: int
    robot_steps: int
    max_points: int
    pool_pairs: int
    pool_repeats: int
    max_trajectories: int


#: The step-through's sizes per ``SKILLKIT_SCALE``; "paper" has the thesis's N₀ = 10, M = 500,
#: L = 25 and fig4.6's model sizes.
SCALES: dict[str, IterationSizes] = {
    "smoke": IterationSizes(
        n_initial=8,
        n_artificial=30,
        n_trajectories=3,
        n_updates=1,
        n_inducing=15,
        gp_steps=20,
        robot_inducing=20,
        robot_steps=150,
        max_points=300,
        pool_pairs=30,
        pool_repeats=6,
        max_trajectories=10,
    ),
    "quick": IterationSizes(
        n_initial=10,
        n_artificial=200,
        n_trajectories=5,
        n_updates=5,
        n_inducing=50,
        gp_steps=60,
        robot_inducing=50,
        robot_steps=150,
        max_points=1000,
        pool_pairs=100,
        pool_repeats=10,
        max_trajectories=20,
    ),
    "paper": IterationSizes(
        n_initial=10,
        n_artificial=500,
        n_trajectories=25,
        n_updates=10,
        n_inducing=50,
        gp_steps=150,
        robot_inducing=50,
        robot_steps=150,
        max_points=1000,
        pool_pairs=200,
        pool_repeats=20,
        max_trajectories=25,
    ),
}


def iteration_sizes(scale: str) -> IterationSizes:
    """The step-through's sizes at ``scale`` (a key of :data:`SCALES`)."""
    if scale not in SCALES:
        raise ValueError(f"scale: expected one of {tuple(SCALES)}, got {scale!r}")
    return SCALES[scale]


def _sizes(sizes) -> IterationSizes:
    if not isinstance(sizes, IterationSizes):
        raise ValueError(f"sizes: expected IterationSizes, got {type(sizes).__name__}")
    return sizes


def _reps(weights) -> REPSWeights:
    if not isinstance(weights, REPSWeights):
        raise ValueError(f"weights: expected REPSWeights, got {type(weights).__name__}")
    return weights


def _fitc_model(n_inducing: int, n_steps: int) -> ForwardModel:
    """A FITC forward model of Δx."""
    return ForwardModel(FITC(n_inducing=n_inducing, n_steps=n_steps), target="delta")


def throwing_model(task: Throwing, sizes: IterationSizes) -> ThrowingRewardModel:
    """The decomposed throwing model of Fig. 4.2 at the step-through's ``sizes``: FITC robot
    and flight models and an exact release GP (at most 300 points), the library's defaults
    otherwise."""
    _sizes(sizes)
    return ThrowingRewardModel(
        task,
        make_robot_model=partial(_fitc_model, sizes.robot_inducing, sizes.robot_steps),
        make_release_model=partial(ExactGP, n_steps=sizes.gp_steps),
        make_flight_model=partial(_fitc_model, sizes.n_inducing, sizes.gp_steps),
        max_robot_points=sizes.max_points,
        max_release_points=min(sizes.max_points, 300),
        max_flight_points=sizes.max_points,
    )


def step_settings(sizes: IterationSizes, epsilon: float = 1.0) -> GPREPSSettings:
    """GPREPS's settings of the step-through: M, L of ``sizes``, ε, ``context_model="prior"``
    (μ̂(s) = the task's μ(s), usable before any update) and fig4.6's regularised ML fit."""
    _sizes(sizes)
    return GPREPSSettings(
        epsilon=epsilon,
        n_artificial=sizes.n_artificial,
        n_trajectories=sizes.n_trajectories,
        context_model="prior",
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )


# --------------------------------------------------------------------------- tables
def batch_table(batch: Batch) -> pd.DataFrame:
    """The real throws of a batch: target s = [x, y], release time, landing x (NaN for a
    failed rollout) and reward R(τ, s)."""
    if not isinstance(batch, Batch):
        raise ValueError(f"batch: expected a Batch, got {type(batch).__name__}")
    n = batch.n_rollouts
    trajs = list(batch.trajectories or [])[:n]
    info = [(t.info or {}) if t is not None and not t.failed else {} for t in trajs]
    info += [{}] * (n - len(info))
    return pd.DataFrame(
        {
            "target x [m]": batch.contexts[:n, 0],
            "target y [m]": batch.contexts[:n, 1],
            "release time [s]": [i.get("release_time", np.nan) for i in info],
            "landing x [m]": [i.get("landing_x", np.nan) for i in info],
            "reward": batch.rewards[:n],
        },
        index=pd.RangeIndex(1, n + 1, name="throw"),
    )


def fit_table(stats: Mapping) -> pd.DataFrame:
    """A reward model's fit statistics (``RewardModel.fit``), one row per learned GP: points,
    iterations, log ML (2.28), the largest noise variance and the handled events."""
    if not isinstance(stats, Mapping):
        raise ValueError(f"stats: expected the dict a reward model's fit returns, got {stats!r}")
    rows = {}
    for key, value in stats.items():
        if isinstance(value, Mapping) and "n_data" in value:
            events = value.get("numerical_events") or {}
            seen = [f"{k} ×{n}" for k, n in events.items() if k in EVENT_KINDS and n]
            rows[key] = {
                "points": value["n_data"],
                "iterations": value.get("iterations"),
                "log ML": value.get("log_ml"),
                "largest noise variance": value.get("noise_var_max"),
                "handled events": ", ".join(seen) or "none",
            }
    if not rows:
        raise ValueError("stats: no per-model statistics (entries with 'n_data') found")
    return pd.DataFrame.from_dict(rows, orient="index").rename_axis("model")


def policy_change_table(
    old: LinearGaussianPolicy,
    new: LinearGaussianPolicy,
    contexts: ArrayLike,
    weights: REPSWeights,
    rewards: ArrayLike,
) -> pd.DataFrame:
    """What the weighted ML fit (3.11–3.13) did to the policy, in one row.

    With the M artificial ``contexts`` (M, context_dim), the dual's ``weights`` and the
    predicted ``rewards`` R̂ (M,): KL(π_new ‖ π_old) averaged over the contexts (it can exceed
    ε), ε, KL(p ‖ uniform), the ESS, both entropies, Σ R̂/M and Σ p R̂.
    """
    if not isinstance(old, LinearGaussianPolicy) or not isinstance(new, LinearGaussianPolicy):
        raise ValueError("old, new: expected LinearGaussianPolicy objects")
    p = _reps(weights).weights
    s = check_array(contexts, "contexts", shape=(p.shape[0], old.context_dim))
    r = check_array(rewards, "rewards", shape=p.shape)
    return pd.DataFrame(
        {
            "KL(π_new ‖ π_old)": [new.kl(old, s)],
            "ε": [weights.epsilon],
            "KL(p ‖ uniform)": [weights.kl],
            "ESS": [weights.ess],
            "M": [p.shape[0]],
            "entropy old": [old.entropy()],
            "entropy new": [new.entropy()],
            "mean R̂": [float(r.mean())],
            "Σ p R̂": [float(p @ r)],
        },
        index=pd.Index(["update"]),
    )


def diagnostics_table(
    diagnostics: Sequence, policy_rewards: ArrayLike | None = None
) -> pd.DataFrame:
    """One row per :class:`~skillkit.search.gpreps.GPREPSDiagnostics` of ``GPREPS.update``.

    Columns: real samples, η, KL, ε, ESS of the M artificial samples, the model's prediction
    of the new real batch (NaN before the first model) against its real reward, the mean R̂,
    the policy mean's reward (``policy_rewards`` (n_updates,), if given) and the seconds spent
    training, predicting and updating the policy.
    """
    diags = list(diagnostics) if isinstance(diagnostics, Sequence) else []
    if not diags or not all(hasattr(d, "reps") and hasattr(d, "n_real") for d in diags):
        raise ValueError("diagnostics: expected a non-empty sequence of GPREPSDiagnostics")
    evaluated = (
        np.full(len(diags), np.nan)
        if policy_rewards is None
        else check_array(policy_rewards, "policy_rewards", shape=(len(diags),))
    )
    rows = []
    for d, policy_reward in zip(diags, evaluated, strict=True):
        predicted = d.predicted_real_reward
        rows.append(
            {
                "real samples": d.n_real,
                "η": d.reps.eta,
                "KL": d.reps.kl,
                "ε": d.reps.epsilon,
                "ESS": d.reps.ess,
                "M": d.reps.n_samples,
                "predicted R (new batch)": np.nan if predicted is None else predicted,
                "real R (new batch)": d.real_reward,
                "mean R̂ (artificial)": d.artificial_reward_mean,
                "policy mean's R": policy_reward,
                "train [s]": d.time_training,
                "predict [s]": d.time_prediction,
                "policy [s]": d.time_policy,
            }
        )
    return pd.DataFrame(rows, index=pd.RangeIndex(1, len(rows) + 1, name="update"))


def update_comparison(
    weights: REPSWeights,
    policy: LinearGaussianPolicy,
    diagnostics: GPREPSDiagnostics,
    update_policy: LinearGaussianPolicy,
) -> pd.DataFrame:
    """The step-through's dual solution and new policy beside one ``GPREPS.update`` on the
    same data (its diagnostics and policy): η, KL, ESS, max |a| and log det Σ, and whether
    they are exactly equal (the same draws in the same order give the same numbers)."""
    _reps(weights)
    if not hasattr(diagnostics, "reps"):
        raise ValueError("diagnostics: expected GPREPSDiagnostics")
    for name, pol in (("policy", policy), ("update_policy", update_policy)):
        if not isinstance(pol, LinearGaussianPolicy):
            raise ValueError(f"{name}: expected a LinearGaussianPolicy")
    ours = [weights.eta, weights.kl, weights.ess, np.abs(policy.mean).max(), policy.log_det_cov()]
    theirs = [
        diagnostics.reps.eta,
        diagnostics.reps.kl,
        diagnostics.reps.ess,
        np.abs(update_policy.mean).max(),
        update_policy.log_det_cov(),
    ]
    equal = [a == b for a, b in zip(ours, theirs, strict=True)]
    equal[3] = bool(np.array_equal(policy.mean, update_policy.mean))
    equal[4] = bool(np.array_equal(policy.cov, update_policy.cov))
    return pd.DataFrame(
        {"cells above": ours, "GPREPS.update": theirs, "equal": equal},
        index=["η", "KL(p ‖ uniform)", "ESS", "max |a| (policy mean)", "log det Σ"],
    )


def gflops_table(run: Any) -> pd.DataFrame:
    """Fig. 4.4's speed numbers per thread count, from a ``fig4.4`` run or its summary:
    trajectories sampled in one moment-matching time, and the GFLOP/s of both."""
    summary = getattr(run, "summary", run)
    keys = ("trajectories_in_mm_time", "mm_gflops", "sampling_gflops")
    if not isinstance(summary, Mapping) or any(k not in summary for k in keys):
        raise ValueError(f"run: expected a fig4.4 run or its summary (with {keys})")
    rows = {}
    for threads, n in summary["trajectories_in_mm_time"].items():
        row = {"trajectories in one MM time": n, "MM GFLOP/s": summary["mm_gflops"][threads]}
        for n_traj, value in summary["sampling_gflops"].get(threads, {}).items():
            row[f"sampling GFLOP/s, N = {n_traj}"] = value
        rows[threads] = row
    return pd.DataFrame.from_dict(rows, orient="index").rename_axis("threads")


#: Table 4.2 of the thesis: seconds of real experience to reach each reward limit.
THESIS_TABLE_4_2: dict[str, tuple[float, float, float]] = {
    "PILCO": (10.18, 11.46, 12.18),
    "GPREPS": (10.68, 20.52, 38.50),
    "REPS": (1425.0, 2300.0, 4075.0),
}
_TAB42_METHODS = {
    "pilco": ("PILCO", "PILCO"),
    "gpreps": ("GPREPS", "GPREPS"),
    "reps": ("REPS", "REPS"),
    "pilco_linear": ("PILCO (linear model)", "PILCO"),
    "gpreps_linear": ("GPREPS (linear model)", "GPREPS"),
}


def table_4_2(run: Any) -> pd.DataFrame:
    """Table 4.2 (experience to reach each reward limit) beside :data:`THESIS_TABLE_4_2`.

    ``run`` is a ``tab4.2`` run or its summary. Per method and limit −100, −10, −1.5: the mean
    seconds over the trials that reached it, the median over all trials with a trial that
    never reached it counted as slowest (:func:`~skillkit.experiments.ch4_balancing.median_reached`,
    what the verdict judges), the trials that reached it, and the thesis's seconds (a
    linear-model variant beside its method's).
    """
    summary = getattr(run, "summary", run)
    if not isinstance(summary, Mapping) or "pilco" not in summary:
        raise ValueError("run: expected a tab4.2 run or its summary (with a 'pilco' entry)")
    n_trials = summary.get("n_trials")
    limits = ("-100", "-10", "-1.5")
    columns = pd.MultiIndex.from_product(
        [
            [f"R ≥ {lim.replace('-', '−')}" for lim in limits],
            ["ours [s]", "median [s]", "reached", "thesis [s]"],
        ],
        names=["reward limit", ""],
    )
    rows, index = [], []
    for key, (label, thesis_key) in _TAB42_METHODS.items():
        entry = summary.get(key)
        if not isinstance(entry, Mapping) or "limits" not in entry:
            continue
        row = []
        for i, lim in enumerate(limits):
            cell = entry["limits"].get(lim, {})
            mean = cell.get("experience_s_mean")
            per_trial = cell.get("experience_s_per_trial")
            median = None if per_trial is None else median_reached(per_trial)
            reached = cell.get("n_reached")
            row += [
                np.nan if mean is None else round(float(mean), 2),
                np.nan if median is None else round(float(median), 2),
                f"{reached}/{n_trials}" if reached is not None else "",
                THESIS_TABLE_4_2[thesis_key][i],
            ]
        rows.append(row)
        index.append(label)
    return pd.DataFrame(rows, index=pd.Index(index, name="method"), columns=columns)


def _exploration(run: Any, method: str) -> tuple[list[np.ndarray], list[np.ndarray], float]:
    """Per trial √tr Σ_k / √tr Σ_0 (k = 0 … K) and the KL of each update, and the run's ε."""
    path = getattr(run, "path", None)
    settings = getattr(run, "settings", None)
    if path is None or not isinstance(settings, Mapping):
        raise ValueError(f"run: expected a Run (stored_run or reproduce), got {type(run).__name__}")
    file = Path(path) / "trials.npz"
    if not file.exists():
        raise ValueError(f"run: {path} has no trials.npz (its policy history is not stored)")
    if "epsilon" not in settings:
        raise ValueError(f"run: {run.id} has no KL bound 'epsilon' in its settings")
    scales, kls = [], []
    with np.load(file, allow_pickle=False) as arrays:
        t = 0
        while f"trial{t}__policy_cov" in arrays.files:
            if f"trial{t}__{method}_kl" not in arrays.files:
                raise ValueError(f"method: {run.id} stores no KL per update for {method!r}")
            cov = arrays[f"trial{t}__policy_cov"]
            scale = np.sqrt(np.trace(cov, axis1=1, axis2=2))
            scales.append(scale / scale[0])
            kls.append(np.asarray(arrays[f"trial{t}__{method}_kl"], dtype=float))
            t += 1
    if not scales:
        raise ValueError(f"run: {file} holds no policy history (trial<i>__policy_cov)")
    return scales, kls, float(settings["epsilon"])


def exploration_table(run: Any, method: str = "gpreps") -> pd.DataFrame:
    r"""How much a GPREPS run still explores, and how much of its KL bound each update spends.

    REPS bounds KL(p ‖ q) ≤ ε per update (3.5) and the weighted ML fit (3.11–3.13) shrinks Σ;
    when every update spends its whole bound, Σ shrinks at a rate set by ε. ``run`` (fig4.10,
    fig4.11, fig4.12) stores ``trial<i>__policy_cov`` (K + 1, D, D) and ``trial<i>__<method>_kl``
    (K,) in its ``trials.npz``. One row per trial and a median row: √tr Σ_k / √tr Σ_0 after a
    quarter, half, three quarters and all of the updates, the last update's KL and the share of
    updates with KL ≥ 0.99 ε.
    """
    scales, kls, epsilon = _exploration(run, method)
    rows = []
    for scale, kl in zip(scales, kls, strict=True):
        k = len(scale) - 1
        at = np.linspace(0, k, 5).round().astype(int)[1:]
        rows.append([*scale[at].tolist(), float(kl[-1]), float(np.mean(kl >= 0.99 * epsilon))])
    quarters = ["¼", "½", "¾", "all"]
    columns = [f"√tr Σ / start after {q} of the updates" for q in quarters]
    columns += [f"KL of the last update (ε = {epsilon:g})", "updates at KL ≥ 0.99 ε"]
    table = pd.DataFrame(rows, columns=columns, index=pd.Index(range(len(rows)), name="trial"))
    table.loc["median"] = table.median()
    return table.round(3)


def exploration_figure(run: Any, method: str = "gpreps", backend: str = "plotly"):
    """√tr Σ_k / √tr Σ_0 after each update k (log axis), one line per trial, of the run of
    :func:`exploration_table`."""
    scales, kls, epsilon = _exploration(run, method)
    series = [
        Series(
            f"trial {t}",
            list(range(len(scale))),
            scale.tolist(),
            xlabel="update k",
            ylabel="√tr Σ_k / √tr Σ_0 (search width against the start)",
            log_y=True,
        )
        for t, scale in enumerate(scales)
    ]
    at_bound = np.mean(np.concatenate([kl >= 0.99 * epsilon for kl in kls]))
    title = (
        f"{run.id}: the search distribution's width; ε = {epsilon:g}, "
        f"{100 * at_bound:.0f}% of the updates at KL ≥ 0.99 ε"
    )
    return draw(title, series, backend)


# --------------------------------------------------------------------------- figures
def _xy(points: np.ndarray) -> tuple[list, list]:
    return points[:, 0].tolist(), points[:, 1].tolist()


def _joined(paths) -> tuple[list, list]:
    """Paths (each (K, 2)) as one polyline broken by NaN gaps."""
    pieces = []
    for p in paths:
        pieces += [np.asarray(p, dtype=float), np.full((1, 2), np.nan)]
    return _xy(np.concatenate(pieces))


def contexts_figure(real: ArrayLike, artificial: ArrayLike, backend: str = "plotly"):
    """The targets (N, 2) of the real throws and the M artificial ones (M, 2) from μ̂(s)."""
    s_real = check_array(real, "real", shape=(None, 2))
    s_art = check_array(artificial, "artificial", shape=(None, 2))
    common = {"kind": "markers", "xlabel": "target x [m]", "ylabel": "target y [m]"}
    series = [
        Series(f"artificial s ~ μ̂(s) (M = {len(s_art)})", *_xy(s_art), **common),
        Series(f"real throws (N = {len(s_real)})", *_xy(s_real), **common),
    ]
    return draw("contexts of the real and the artificial samples", series, backend)


def predicted_throws_figure(
    prediction: ThrowingPrediction, real: Batch, n_pairs: int = 3, backend: str = "plotly"
):
    """The L predicted ball flights of the first ``n_pairs`` artificial pairs
    (``ThrowingRewardModel.predict``) over the flights of the real throws."""
    if not isinstance(prediction, ThrowingPrediction):
        raise ValueError(f"prediction: expected a ThrowingPrediction, got {prediction!r:.60}")
    if not isinstance(real, Batch) or real.trajectories is None:
        raise ValueError("real: expected a Batch with trajectories")
    n_pairs = check_count(n_pairs, "n_pairs")
    common = {"xlabel": "x [m]", "ylabel": "height y [m]"}
    balls = [t.signals["ball"] for t in real.trajectories[: real.n_rollouts] if not t.failed]
    series = [Series(f"real flights ({len(balls)})", *_joined(balls), dash="dash", **common)]
    B, L = prediction.rewards.shape
    for j in range(min(n_pairs, B)):
        series.append(
            Series(f"pair {j + 1}: {L} predicted flights", *_joined(prediction.ball[j]), **common)
        )
    return draw("predicted ball flights over the real ones", series, backend)


def weights_figure(
    weights: REPSWeights, rewards: ArrayLike, features: ArrayLike, backend: str = "plotly"
):
    """The REPS weights p_j ∝ exp((R̂_j − γᵀφ(s_j))/η) (Eq. 3.10) of the M artificial samples
    against their advantage, with the closed form (a line of slope 1/η on the log axis) and
    1/M; ``rewards`` R̂ (M,) and ``features`` φ(s_j) (M, F) as the dual used them."""
    p = _reps(weights).weights
    r = check_array(rewards, "rewards", shape=p.shape)
    phi = check_array(features, "features", shape=(p.shape[0], weights.gamma.shape[0]))
    adv = r - phi @ weights.gamma
    grid = np.linspace(adv.min(), adv.max(), 50)
    shift = adv.max() / weights.eta
    log_z = shift + np.log(np.sum(np.exp(adv / weights.eta - shift)))
    common = {"xlabel": "advantage R̂ − V(s) (Eq. 3.10)", "ylabel": "weight p", "log_y": True}
    series = [
        Series(
            f"artificial samples (M = {p.size})", adv.tolist(), p.tolist(), kind="markers", **common
        ),
        Series(
            f"exp(A/η)/Z, η = {weights.eta:.3g}",
            grid.tolist(),
            np.exp(grid / weights.eta - log_z).tolist(),
            **common,
        ),
        Series("uniform 1/M", [grid[0], grid[-1]], [1.0 / p.size] * 2, dash="dash", **common),
    ]
    title = (
        f"REPS weights: KL = {weights.kl:.3g} (ε = {weights.epsilon:.3g}), "
        f"ESS = {weights.ess:.3g} of {p.size}"
    )
    return draw(title, series, backend)


# --------------------------------------------------------------------------- M, L widget
@dataclass(frozen=True)
class RewardPool:
    """Predicted rewards the M, L widget resamples: K fixed pairs (s_k, ω_k), ω_k the policy
    mean, with P rewards each (``fixed`` (K, P)), and Q pairs s ~ μ(s), ω ~ π(ω|s) with L_max
    rewards each (``pairs`` (Q, L_max))."""

    contexts: np.ndarray
    omegas: np.ndarray
    fixed: np.ndarray
    pairs: np.ndarray


def reward_pool(
    model: Any,
    policy: LinearGaussianPolicy,
    task: Task,
    sizes: IterationSizes,
    contexts: ArrayLike,
    rng: np.random.Generator | int | None = None,
) -> RewardPool:
    """Predict once the rewards :func:`reward_estimate_figure` resamples.

    ``model.predict(contexts, omegas, L, rng).rewards`` (B, L) gives ``pool_repeats ×
    max_trajectories`` rewards of the policy mean at each fixed context (K, context_dim), and
    ``max_trajectories`` of each of ``pool_pairs`` pairs drawn from ``task.sample_context``
    and ``policy``.
    """
    _sizes(sizes)
    rng = as_generator(rng)
    s = check_array(contexts, "contexts", shape=(None, policy.context_dim))
    w = np.atleast_2d(policy.mean_of(s))
    n_fixed = sizes.pool_repeats * sizes.max_trajectories
    fixed = model.predict(s, w, n_fixed, rng).rewards
    s_pool = np.asarray(task.sample_context(rng, n=sizes.pool_pairs), dtype=float)
    w_pool = np.atleast_2d(policy.sample(s_pool, rng))
    pairs = model.predict(s_pool, w_pool, sizes.max_trajectories, rng).rewards
    return RewardPool(s, w, np.asarray(fixed, dtype=float), np.asarray(pairs, dtype=float))


def reward_estimates(
    pool: RewardPool, n_artificial: int, n_trajectories: int, n_repeats: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``n_repeats`` ≥ 2 reward estimates of GPREPS for M and L, resampled from ``pool``.

    Returns
    -------
    fixed : ndarray, shape (K, n_repeats)
        R̂ of each fixed pair: the mean of L of its P rewards, drawn without replacement.
    policy : ndarray, shape (n_repeats,)
        (1/M) Σ_j R̂_j over M pool pairs drawn with replacement, each R̂_j the mean of L of its
        L_max rewards; 1 ≤ L ≤ min(P, L_max).
    """
    if not isinstance(pool, RewardPool):
        raise ValueError(f"pool: expected a RewardPool, got {type(pool).__name__}")
    n_artificial = check_count(n_artificial, "n_artificial")
    n_trajectories = check_count(n_trajectories, "n_trajectories")
    if n_trajectories > min(pool.pairs.shape[1], pool.fixed.shape[1]):
        raise ValueError(
            f"n_trajectories: the pool holds at most "
            f"{min(pool.pairs.shape[1], pool.fixed.shape[1])} trajectories per pair, "
            f"got {n_trajectories}"
        )
    n_repeats = check_count(n_repeats, "n_repeats", 2)
    rng = np.random.default_rng(seed)
    K, P = pool.fixed.shape
    Q, L_max = pool.pairs.shape
    L = n_trajectories
    fixed = np.array(
        [
            [pool.fixed[k, rng.choice(P, L, replace=False)].mean() for _ in range(n_repeats)]
            for k in range(K)
        ]
    )
    policy = np.empty(n_repeats)
    for r in range(n_repeats):
        rows = rng.choice(Q, n_artificial, replace=True)
        cols = np.argsort(rng.random((n_artificial, L_max)), axis=1)[:, :L]
        policy[r] = pool.pairs[rows[:, None], cols].mean()
    return fixed, policy


def reward_estimate_figure(
    pool: RewardPool,
    n_artificial: int = 30,
    n_trajectories: int = 3,
    n_repeats: int = 20,
    seed: int = 0,
    backend: str = "plotly",
):
    r""":func:`reward_estimates` drawn: left, R̂_sω = (1/L) Σ_l R(τ^[l], s) (Eq. 4.1) of each
    fixed pair (spread σ_k/√L); right, the policy's estimate from M pairs (spread falling with
    M and L). Each panel's y range is the pool's, so moving M or L changes only the spread."""
    fixed, policy = reward_estimates(pool, n_artificial, n_trajectories, n_repeats, seed)
    L = n_trajectories
    left = {
        "panel": f"R̂ of {fixed.shape[0]} fixed pairs (L = {L}), {n_repeats} estimates each",
        "xlabel": "target x of the pair [m]",
        "ylabel": "R̂ (Eq. 4.1)",
    }
    right = {
        "panel": f"policy's mean R̂ from M = {n_artificial} pairs × L = {L}",
        "xlabel": "estimate",
        "ylabel": "mean R̂ of M pairs",
    }
    xs = pool.contexts[:, 0]
    repeats = np.arange(1, n_repeats + 1, dtype=float)
    mean_fixed, sd_fixed = fixed.mean(axis=1), fixed.std(axis=1, ddof=1)
    ref = pool.pairs.mean()
    series = [
        Series(
            "estimates",
            np.repeat(xs, n_repeats).tolist(),
            fixed.reshape(-1).tolist(),
            kind="markers",
            **left,
        ),
        Series(
            "mean ± std of the estimates",
            xs.tolist(),
            mean_fixed.tolist(),
            kind="lines+markers",
            lower=(mean_fixed - sd_fixed).tolist(),
            upper=(mean_fixed + sd_fixed).tolist(),
            band=f"± std over {n_repeats}",
            **left,
        ),
        Series("policy estimates", repeats.tolist(), policy.tolist(), kind="markers", **right),
        Series(
            f"pool mean ({pool.pairs.size} predicted throws)",
            [1.0, float(n_repeats)],
            [ref, ref],
            dash="dash",
            **right,
        ),
    ]
    title = (
        f"std of R̂ per pair {', '.join(f'{v:.3g}' for v in sd_fixed)}; "
        f"std of the policy's estimate {policy.std(ddof=1):.3g}"
    )
    fig = draw(title, series, backend)
    if backend == "plotly":
        means = pool.pairs.mean(axis=1)
        ranges = {
            "yaxis": (float(pool.fixed.min()), float(pool.fixed.max())),
            "yaxis2": (float(means.min()), float(means.max())),
        }
        for axis, (lo, hi) in ranges.items():
            pad = 0.05 * (hi - lo) if hi > lo else 1.0
            if axis in fig.layout:
                fig.layout[axis].range = (lo - pad, hi + pad)
                fig.layout[axis].autorange = False
    return fig


# --------------------------------------------------------------------------- warnings
#: Warnings the chapter's cells cause by design, with the reason each is expected.
EXPECTED_WARNINGS: dict[str, str] = {
    r"rollout failed": "an exploring policy drove the simulated robot unstable; the rollout "
    "is reported as failed and scored with the task's worst reward (Task.rollout), as the "
    "method being reproduced would have to cope with"
}


@dataclass
class HandledEvents:
    """What :func:`handled_events` caught: the counted handled GP events (``numerical``,
    :data:`~skillkit.models.gp.EVENT_KINDS`) and the messages of expected warnings."""

    numerical: Any
    warnings: list[str] = field(default_factory=list)

    def table(self) -> pd.DataFrame:
        """One row per kind that occurred: count, what it means, an example message."""
        rows = []
        for kind, n in self.numerical.counts.items():
            if n:
                rows.append({"event": kind, "count": n, "meaning": EVENT_KINDS[kind]})
        for pattern, reason in EXPECTED_WARNINGS.items():
            hits = [m for m in self.warnings if re.search(pattern, m)]
            if hits:
                rows.append(
                    {"event": pattern, "count": len(hits), "meaning": reason, "example": hits[0]}
                )
        columns = ["event", "count", "meaning", "example"]
        return pd.DataFrame(rows, columns=columns).fillna("")

    def _repr_html_(self) -> str:
        table = self.table()
        if table.empty:
            return "<small>no numerical events, no failed rollouts</small>"
        return table.to_html(index=False)

    def __repr__(self) -> str:
        return f"HandledEvents({self.numerical!r}, {len(self.warnings)} expected warnings)"


@contextmanager
def handled_events() -> Iterator[HandledEvents]:
    """Count a block's handled GP events (:func:`~skillkit.models.gp.record_numerical_events`)
    and warnings matching :data:`EXPECTED_WARNINGS` instead of printing them; any other
    warning is re-issued on leaving."""
    with record_numerical_events() as events, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        shown = HandledEvents(events)
        try:
            yield shown
        finally:
            others = []
            for w in caught:
                message = str(w.message)
                if any(re.search(p, message) for p in EXPECTED_WARNINGS):
                    shown.warnings.append(message)
                else:
                    others.append(w)
    for w in others:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


# --------------------------------------------------------------------------- viewer
@dataclass
class ModelView:
    """What :func:`gpreps_model_view` returns: the viewer with the model layers, or the
    static top view of the same layers with the viewer's screenshot reason."""

    shown: Any
    figure: Any = None

    def _ipython_display_(self) -> None:
        from IPython.display import HTML, display

        if self.figure is None:
            display(self.shown)
            return
        display(self.figure)
        display(
            HTML(
                f"<small>no live viewer ({self.shown.reason}): the model layers drawn "
                "from above instead</small>"
            )
        )

    def stop(self) -> None:
        """Stop the viewer's server (idempotent)."""
        self.shown.stop()


def gpreps_model_view(
    run_dir: str | Path, *, live: bool, trial: int = 0, n_samples: int = 5
) -> ModelView:
    """A stored GPREPS run's last reward model over its final policy, with model layers.

    With ``live`` and a server that starts: :func:`~skillkit.viz.notebook.show_viewer` with
    the run's policy history and one switchable layer per learned model; otherwise the same
    layers drawn from above (:func:`~skillkit.viz.figures.gpreps_run_paths_figure`).

    .. warning:: This unpickles the run's reward model: load only runs you trust.
    """
    from skillkit.viz.figures import gpreps_run_paths_figure
    from skillkit.viz.model_layers import load_gpreps_run
    from skillkit.viz.notebook import show_viewer

    n_samples = check_count(n_samples, "n_samples")
    history, model = load_gpreps_run(run_dir, trial)
    shown = show_viewer(model.task.name, live=bool(live), history=history)
    if shown.live:
        shown.viewer.add_model_layers(model, n_samples=n_samples)
        return ModelView(shown)
    return ModelView(shown, gpreps_run_paths_figure(run_dir, trial, n_samples=n_samples))
