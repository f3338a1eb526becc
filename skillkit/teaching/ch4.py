"""Chapter 4 step by step: one GPREPS iteration (Sec. 4.1, Table 4.1) in the order
:meth:`~skillkit.search.gpreps.GPREPS.update` runs it (model fit, μ̂(s), Eq. 4.1, weights 3.10,
ML fit 3.11–3.13), the M, L widget's reward estimates and stored runs (Table 4.2, Fig. 4.4,
fig4.10–4.12). Figures take ``backend`` in {"plotly", "matplotlib"}."""

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

from skillkit._validation import as_generator, check_array, check_count, check_type
from skillkit.experiments.ch4_balancing import LABELS, median_reached, thesis_42
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
from skillkit.teaching._common import at_scale, draw, per_scale, xy
from skillkit.viz.figures import polyline
from skillkit.viz.series import Series


@dataclass(frozen=True)
class IterationSizes:
    """The step-through's sizes at one scale: N₀, M, L (Eq. 4.1), later updates; FITC
    pseudo-inputs and L-BFGS steps (2.28) of the flight and robot models, at most
    ``max_points`` transitions each; the reward pool of :func:`reward_pool`."""

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
SCALES: dict[str, IterationSizes] = per_scale(
    IterationSizes,
    n_initial=(8, 10, 10),
    n_artificial=(30, 200, 500),
    n_trajectories=(3, 5, 25),
    n_updates=(1, 5, 10),
    n_inducing=(15, 50, 50),
    gp_steps=(20, 60, 150),
    robot_inducing=(20, 50, 50),
    robot_steps=(150, 150, 150),
    max_points=(300, 1000, 1000),
    pool_pairs=(30, 100, 200),
    pool_repeats=(6, 10, 20),
    max_trajectories=(10, 20, 25),
)


def iteration_sizes(scale: str) -> IterationSizes:
    """The step-through's sizes at ``scale`` (a key of :data:`SCALES`)."""
    return at_scale(SCALES, scale)


def _fitc_model(n_inducing: int, n_steps: int) -> ForwardModel:
    return ForwardModel(FITC(n_inducing=n_inducing, n_steps=n_steps), target="delta")


def throwing_model(task: Throwing, sizes: IterationSizes) -> ThrowingRewardModel:
    """The decomposed throwing model of Fig. 4.2 at ``sizes``: FITC robot and flight models,
    an exact release GP (at most 300 points)."""
    check_type(sizes, IterationSizes, "sizes")
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
    """GPREPS's settings: M, L of ``sizes``, ε, μ̂(s) = the task's μ(s) and fig4.6's ML fit."""
    check_type(sizes, IterationSizes, "sizes")
    return GPREPSSettings(
        epsilon=epsilon,
        n_artificial=sizes.n_artificial,
        n_trajectories=sizes.n_trajectories,
        context_model="prior",
        cov_floor=COV_FLOOR,
        min_effective_samples=MIN_EFFECTIVE_SAMPLES,
    )


def batch_table(batch: Batch) -> pd.DataFrame:
    """A batch's real throws: target s, release time, landing x (NaN: failed) and reward."""
    n = check_type(batch, Batch, "batch", "a Batch").n_rollouts
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
    """``RewardModel.fit``'s statistics, a row per GP: points, iterations, log ML (2.28), the
    largest noise variance and the handled events."""
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
    """What the weighted ML fit (3.11–3.13) did, in one row: KL(π_new ‖ π_old) over the M
    ``contexts`` (M, context_dim), ε, KL(p ‖ uniform), ESS, entropies, Σ R̂/M and Σ p R̂ of
    ``rewards`` R̂ (M,)."""
    if not isinstance(old, LinearGaussianPolicy) or not isinstance(new, LinearGaussianPolicy):
        raise ValueError("old, new: expected LinearGaussianPolicy objects")
    p = check_type(weights, REPSWeights, "weights").weights
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
    """A row per :class:`~skillkit.search.gpreps.GPREPSDiagnostics`: real samples, η, KL, ε,
    ESS, predicted (NaN before a model) and real reward of the new batch, mean R̂, the policy
    mean's ``policy_rewards`` (n_updates,) if given, and the seconds of each phase."""
    diags = list(diagnostics) if isinstance(diagnostics, Sequence) else []
    if not diags or not all(hasattr(d, "reps") and hasattr(d, "n_real") for d in diags):
        raise ValueError("diagnostics: expected a non-empty sequence of GPREPSDiagnostics")
    evaluated = np.full(len(diags), np.nan)
    if policy_rewards is not None:
        evaluated = check_array(policy_rewards, "policy_rewards", shape=(len(diags),))
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
    """The step-through's η, KL, ESS, max |a| and log det Σ beside one ``GPREPS.update`` on
    the same draws, and whether they are exactly equal."""
    check_type(weights, REPSWeights, "weights")
    if not hasattr(diagnostics, "reps"):
        raise ValueError("diagnostics: expected GPREPSDiagnostics")
    for name, pol in (("policy", policy), ("update_policy", update_policy)):
        check_type(pol, LinearGaussianPolicy, name, "a LinearGaussianPolicy")

    def row(w, pol: LinearGaussianPolicy) -> list:
        return [w.eta, w.kl, w.ess, np.abs(pol.mean).max(), pol.log_det_cov()]

    ours, theirs = row(weights, policy), row(diagnostics.reps, update_policy)
    equal = [a == b for a, b in zip(ours, theirs, strict=True)]
    equal[3] = bool(np.array_equal(policy.mean, update_policy.mean))
    equal[4] = bool(np.array_equal(policy.cov, update_policy.cov))
    return pd.DataFrame(
        {"cells above": ours, "GPREPS.update": theirs, "equal": equal},
        index=["η", "KL(p ‖ uniform)", "ESS", "max |a| (policy mean)", "log det Σ"],
    )


def gflops_table(run: Any) -> pd.DataFrame:
    """Fig. 4.4 per thread count (a ``fig4.4`` run or its summary): trajectories sampled in
    one moment-matching time and both GFLOP/s."""
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


#: Table 4.2 of the thesis (its claims spec): seconds of real experience to reach each limit.
THESIS_TABLE_4_2: dict[str, tuple[float, float, float]] = {
    LABELS[m]: tuple(v) for m, v in thesis_42()["experience_s"].items()
}


def table_4_2(run: Any) -> pd.DataFrame:
    """Table 4.2 of a ``tab4.2`` run (or its summary) beside :data:`THESIS_TABLE_4_2`: per
    method and limit the mean seconds of the trials that reached it, the median with misses
    slowest (:func:`~skillkit.experiments.ch4_balancing.median_reached`), the count reached and
    the thesis's seconds."""
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
    for key, label in LABELS.items():
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
                THESIS_TABLE_4_2[LABELS[key.split("_")[0]]][i],
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
    epsilon = settings.get("gpreps", {}).get("epsilon")
    if epsilon is None:
        raise ValueError(f"run: {run.id} has no KL bound 'gpreps.epsilon' in its settings")
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
    return scales, kls, float(epsilon)


def exploration_table(run: Any, method: str = "gpreps") -> pd.DataFrame:
    r"""A row per trial of a run (fig4.10–4.12, ``trial<i>__policy_cov`` (K + 1, D, D) and
    ``trial<i>__<method>_kl`` (K,)) and a median: √tr Σ_k / √tr Σ_0 after ¼, ½, ¾ and all
    updates, the last KL and the share of updates at KL ≥ 0.99 ε (3.5)."""
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
    """√tr Σ_k / √tr Σ_0 over updates k, a line per trial (see :func:`exploration_table`)."""
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


def contexts_figure(real: ArrayLike, artificial: ArrayLike, backend: str = "plotly"):
    """Targets of the real throws (N, 2) and of the artificial ones from μ̂(s) (M, 2)."""
    s_real = check_array(real, "real", shape=(None, 2))
    s_art = check_array(artificial, "artificial", shape=(None, 2))
    common = {"kind": "markers", "xlabel": "target x [m]", "ylabel": "target y [m]"}
    series = [
        Series(f"artificial s ~ μ̂(s) (M = {len(s_art)})", *xy(s_art), **common),
        Series(f"real throws (N = {len(s_real)})", *xy(s_real), **common),
    ]
    return draw("contexts of the real and the artificial samples", series, backend)


def predicted_throws_figure(
    prediction: ThrowingPrediction, real: Batch, n_pairs: int = 3, backend: str = "plotly"
):
    """The L predicted flights of the first ``n_pairs`` artificial pairs over the real ones."""
    if not isinstance(prediction, ThrowingPrediction):
        raise ValueError(f"prediction: expected a ThrowingPrediction, got {prediction!r:.60}")
    if not isinstance(real, Batch) or real.trajectories is None:
        raise ValueError("real: expected a Batch with trajectories")
    n_pairs = check_count(n_pairs, "n_pairs")
    common = {"xlabel": "x [m]", "ylabel": "height y [m]"}
    balls = [t.signals["ball"] for t in real.trajectories[: real.n_rollouts] if not t.failed]
    series = [Series(f"real flights ({len(balls)})", *polyline(balls), dash="dash", **common)]
    B, L = prediction.rewards.shape
    for j in range(min(n_pairs, B)):
        series.append(
            Series(f"pair {j + 1}: {L} predicted flights", *polyline(prediction.ball[j]), **common)
        )
    return draw("predicted ball flights over the real ones", series, backend)


def weights_figure(
    weights: REPSWeights, rewards: ArrayLike, features: ArrayLike, backend: str = "plotly"
):
    """The REPS weights p_j ∝ exp((R̂_j − γᵀφ(s_j))/η) (Eq. 3.10) against the advantage, with
    the closed form and 1/M; ``rewards`` R̂ (M,), ``features`` φ(s_j) (M, F)."""
    p = check_type(weights, REPSWeights, "weights").weights
    r = check_array(rewards, "rewards", shape=p.shape)
    phi = check_array(features, "features", shape=(p.shape[0], weights.gamma.shape[0]))
    adv = r - phi @ weights.gamma
    grid = np.linspace(adv.min(), adv.max(), 50)
    shift = adv.max() / weights.eta
    log_z = shift + np.log(np.sum(np.exp(adv / weights.eta - shift)))
    curve = np.exp(grid / weights.eta - log_z).tolist()
    common = {"xlabel": "advantage R̂ − V(s) (Eq. 3.10)", "ylabel": "weight p", "log_y": True}
    series = [
        Series(
            f"artificial samples (M = {p.size})", adv.tolist(), p.tolist(), kind="markers", **common
        ),
        Series(f"exp(A/η)/Z, η = {weights.eta:.3g}", grid.tolist(), curve, **common),
        Series("uniform 1/M", [grid[0], grid[-1]], [1.0 / p.size] * 2, dash="dash", **common),
    ]
    title = (
        f"REPS weights: KL = {weights.kl:.3g} (ε = {weights.epsilon:.3g}), "
        f"ESS = {weights.ess:.3g} of {p.size}"
    )
    return draw(title, series, backend)


@dataclass(frozen=True)
class RewardPool:
    """Predicted rewards of the M, L widget: ``fixed`` (K, P) at K pairs (s_k, policy mean)
    and ``pairs`` (Q, L_max) at Q pairs s ~ μ(s), ω ~ π(ω|s)."""

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
    """The rewards :func:`reward_estimate_figure` resamples, from ``model.predict``:
    ``pool_repeats × max_trajectories`` at each fixed context (K, context_dim) and
    ``max_trajectories`` at each of ``pool_pairs`` pairs drawn from the task and ``policy``."""
    check_type(sizes, IterationSizes, "sizes")
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
    check_type(pool, RewardPool, "pool", "a RewardPool")
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
    r""":func:`reward_estimates` drawn: R̂_sω = (1/L) Σ_l R(τ^[l], s) (Eq. 4.1) per fixed pair,
    and the policy's estimate from M pairs; y ranges are the pool's."""
    fixed, policy = reward_estimates(pool, n_artificial, n_trajectories, n_repeats, seed)
    L = n_trajectories
    left = {"panel": f"R̂ of {fixed.shape[0]} fixed pairs (L = {L}), {n_repeats} estimates each"}
    left |= {"xlabel": "target x of the pair [m]", "ylabel": "R̂ (Eq. 4.1)"}
    right = {"panel": f"policy's mean R̂ from M = {n_artificial} pairs × L = {L}"}
    right |= {"xlabel": "estimate", "ylabel": "mean R̂ of M pairs"}
    xs = pool.contexts[:, 0]
    repeats = np.arange(1, n_repeats + 1, dtype=float)
    mean_fixed, sd_fixed = fixed.mean(axis=1), fixed.std(axis=1, ddof=1)
    ref = pool.pairs.mean()
    pool_mean = [1.0, float(n_repeats)], [ref, ref]
    estimates = np.repeat(xs, n_repeats).tolist(), fixed.reshape(-1).tolist()
    series = [
        Series("estimates", *estimates, kind="markers", **left),
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
        Series(f"pool mean ({pool.pairs.size} predicted throws)", *pool_mean, dash="dash", **right),
    ]
    title = (
        f"std of R̂ per pair {', '.join(f'{v:.3g}' for v in sd_fixed)}; "
        f"std of the policy's estimate {policy.std(ddof=1):.3g}"
    )
    fig = draw(title, series, backend)
    if backend == "plotly":
        for axis, values in (("yaxis", pool.fixed), ("yaxis2", pool.pairs.mean(axis=1))):
            lo, hi = float(values.min()), float(values.max())
            pad = 0.05 * (hi - lo) if hi > lo else 1.0
            if axis in fig.layout:
                fig.layout[axis].range = (lo - pad, hi + pad)
                fig.layout[axis].autorange = False
    return fig


#: Warnings the chapter's cells cause by design, with the reason each is expected.
EXPECTED_WARNINGS: dict[str, str] = {
    r"rollout failed": "an exploring policy drove the simulated robot unstable; the rollout "
    "is reported as failed and scored with the task's worst reward (Task.rollout), as the "
    "method being reproduced would have to cope with"
}


@dataclass
class HandledEvents:
    """What :func:`handled_events` caught: GP events (``numerical``) and expected warnings."""

    numerical: Any
    warnings: list[str] = field(default_factory=list)

    def table(self) -> pd.DataFrame:
        """One row per kind that occurred: count, what it means, an example message."""
        counts = self.numerical.counts.items()
        rows = [{"event": k, "count": n, "meaning": EVENT_KINDS[k]} for k, n in counts if n]
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
    """Count a block's handled GP events and :data:`EXPECTED_WARNINGS` instead of printing
    them; other warnings are re-issued on leaving."""
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


@dataclass
class ModelView:
    """The viewer with model layers, or the same layers drawn as a static ``figure``
    (:func:`gpreps_model_view`, :func:`prediction_overlay`), which ``drawn`` names."""

    shown: Any
    figure: Any = None
    drawn: str = "the model layers drawn from above"

    def _ipython_display_(self) -> None:
        from IPython.display import HTML, display

        if self.figure is None:
            display(self.shown)
            return
        display(self.figure)
        why = f"no live viewer ({self.shown.reason}): {self.drawn} instead"
        display(HTML(f"<small>{why}</small>"))

    def stop(self) -> None:
        """Stop the viewer's server (idempotent)."""
        self.shown.stop()


def gpreps_model_view(
    run_dir: str | Path, *, live: bool, trial: int = 0, n_samples: int = 5
) -> ModelView:
    """A stored GPREPS run's last reward model over its final policy: with ``live`` the viewer
    with a layer per learned model, else the layers drawn from above. It unpickles the model:
    load only runs you trust."""
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


def prediction_overlay(task, predicted, real, *, live: bool, n_shown: int = 20) -> ModelView:
    """The balancing robot's sampled trajectories (4.3) of the first controller over its real
    rollout: with ``live`` the viewer with a prediction layer, else the robot's plane with the
    hand's real and ``n_shown`` sampled paths. ``predicted`` is
    :func:`~skillkit.search.model_rollouts.predict_trajectories`' output (states (B, L, T + 1,
    8), q first), ``real`` the simulator's rollouts of the same controllers."""
    import plotly.graph_objects as go

    from skillkit.viz.animation import planar_link_points
    from skillkit.viz.notebook import show_viewer

    n_shown = check_count(n_shown, "n_shown")
    samples = np.asarray(predicted.states[0], dtype=float)  # (L, T + 1, 8)
    shown = show_viewer(task.name, live=bool(live))
    if shown.live:
        shown.viewer.add_prediction_layer("gp", samples, label="GP samples")
        return ModelView(shown)
    L, T1, _ = samples.shape
    hands = planar_link_points(task, samples[:n_shown, :, :4].reshape(-1, 4))[:, -1]
    hands = hands.reshape(min(L, n_shown), T1, 2)
    links = planar_link_points(task, np.asarray(real[0].states)[:, :4])
    fig = go.Figure()
    for k, path in enumerate(hands):
        fig.add_scatter(
            x=path[:, 0],
            y=path[:, 1],
            mode="lines",
            line=dict(color="#1f77b4", width=1),
            opacity=0.35,
            name="hand, GP samples",
            legendgroup="gp",
            showlegend=k == 0,
        )
    fig.add_scatter(
        x=links[:, -1, 0],
        y=links[:, -1, 1],
        mode="lines",
        line=dict(color="black", width=3),
        name="hand, real rollout",
    )
    fig.add_scatter(
        x=links[0, :, 0],
        y=links[0, :, 1],
        mode="lines+markers",
        name="robot at t = 0",
        line=dict(color="grey", width=6),
        marker=dict(size=8),
    )
    fig.update_layout(
        title="Balancing: sampled hand paths over the real rollout (robot plane)",
        xaxis_title="x (m)",
        yaxis_title="z (m)",
        height=480,
        yaxis=dict(scaleanchor="x", scaleratio=1),
    )
    return ModelView(shown, fig, "the sampled paths drawn in the robot's plane")
