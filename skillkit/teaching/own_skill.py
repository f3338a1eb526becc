"""Notebook 06, your own skill: a task the reader wrote
(:class:`~skillkit.tasks.functional.TrajectoryTask`) learned by contextual REPS, GPREPS and
CMA-ES through :func:`~skillkit.search.loop.learn`. This module sizes the runs, picks the
evaluation contexts, draws the learned context → ω mapping and tabulates the results.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from skillkit._validation import check_array, check_count
from skillkit.experiments.ch4_balancing import experience_to_reach
from skillkit.tasks.base import Task
from skillkit.teaching._common import draw, index_pair
from skillkit.trajectory import Trajectory
from skillkit.viz.series import Series

__all__ = ["SCALES", "RunSizes", "comparison_table", "context_grid", "mapping_figure", "run_sizes"]


# --------------------------------------------------------------------------- sizes
@dataclass(frozen=True)
class RunSizes:
    """How long each method of the notebook runs at one scale.

    REPS: K updates of N real rollouts; CMA-ES: generations (λ candidates × m contexts
    rollouts each); GPREPS: N₀ initial rollouts (Table 4.1), K updates, N rollouts per later
    update (N₀ + (K − 1) N in all), M artificial pairs and L trajectories per pair (Eq. 4.1),
    and the L-BFGS steps of each model fit (2.28; the thesis uses 150).
    """

    reps_updates: int
    reps_rollouts: int
    cmaes_generations: int
    gpreps_initial: int
    gpreps_updates: int
    gpreps_rollouts: int
    n_artificial: int
    n_trajectories: int
    gp_steps: int


#: The notebook's sizes per ``SKILLKIT_SCALE``; "paper" has the thesis's GPREPS setting
#: (N₀ = 10, then one real rollout per update, M = 500, L = 25).
SCALES: dict[str, RunSizes] = {
    "smoke": RunSizes(
        reps_updates=15,
        reps_rollouts=20,
        cmaes_generations=10,
        gpreps_initial=10,
        gpreps_updates=6,
        gpreps_rollouts=2,
        n_artificial=100,
        n_trajectories=5,
        gp_steps=50,
    ),
    "quick": RunSizes(
        reps_updates=40,
        reps_rollouts=20,
        cmaes_generations=30,
        gpreps_initial=10,
        gpreps_updates=16,
        gpreps_rollouts=2,
        n_artificial=500,
        n_trajectories=10,
        gp_steps=150,
    ),
    "paper": RunSizes(
        reps_updates=100,
        reps_rollouts=20,
        cmaes_generations=80,
        gpreps_initial=10,
        gpreps_updates=41,
        gpreps_rollouts=1,
        n_artificial=500,
        n_trajectories=25,
        gp_steps=150,
    ),
}


def run_sizes(scale: str) -> RunSizes:
    """The notebook's sizes at ``scale`` (a key of :data:`SCALES`)."""
    if scale not in SCALES:
        raise ValueError(f"scale: expected one of {tuple(SCALES)}, got {scale!r}")
    return SCALES[scale]


# --------------------------------------------------------------------------- contexts
def context_grid(task: Task, n_per_dim: int) -> np.ndarray:
    """An even grid of ``n_per_dim`` ≥ 1 points per dimension (one: the centre) over a
    contextual task's [context_low, context_high], shape (n_per_dim ** context_dim,
    context_dim), the last dimension varying fastest."""
    _check_task(task)
    n = check_count(n_per_dim, "n_per_dim")
    low = np.asarray(task.context_low, dtype=np.float64)
    high = np.asarray(task.context_high, dtype=np.float64)
    if n == 1:
        axes = [np.array([(lo + hi) / 2]) for lo, hi in zip(low, high, strict=True)]
    else:
        axes = [np.linspace(lo, hi, n) for lo, hi in zip(low, high, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, task.context_dim)


def _check_task(task) -> None:
    if not isinstance(task, Task):
        raise ValueError(f"task: expected a Task, got {type(task).__name__}")
    if task.context_dim == 0:
        raise ValueError(f"task: {task.name!r} has no context (context_dim = 0)")


# --------------------------------------------------------------------------- figures
def mapping_figure(
    task: Task,
    policies: Mapping,
    outcome: Callable[[Trajectory], ArrayLike],
    contexts: ArrayLike,
    *,
    omega_dims: tuple[int, int] = (0, 1),
    omega_label: str = "ω",
    outcome_label: str = "",
    seed: int = 0,
    title: str = "the learned mapping s → ω and where it leads",
    backend: str = "plotly",
):
    """What several policies do across the contexts: ω(s) and where the rollout ends up.

    Each policy's mean ω(s) is rolled out once per context, every policy with the same random
    stream from ``seed`` (common random numbers). Left: the coordinates ``omega_dims`` of ω(s)
    (axes ``omega_label`` 1, 2, …). Right: per policy, a segment from each context to
    ``outcome(trajectory)`` (2,) of its rollout (gaps for failed rollouts).
    The task's context is a point in the outcome's plane; ``policies`` maps labels to anything
    with ``mean_of(contexts)``; ``contexts`` (n, 2); ``outcome_label`` the right axes' unit.
    """
    _check_task(task)
    if task.context_dim != 2:
        raise ValueError(
            f"task: the outcome panel draws contexts in the plane; {task.name!r} has "
            f"context_dim = {task.context_dim}"
        )
    if not isinstance(policies, Mapping) or not policies:
        raise ValueError("policies: expected a non-empty mapping of label to policy")
    if not callable(outcome):
        raise ValueError(f"outcome: expected a callable, got {type(outcome).__name__}")
    s = check_array(contexts, "contexts", shape=(None, 2))
    d = task.parameter_dim
    i, j = index_pair(omega_dims, "omega_dims", d, "coordinates of ω")
    left = {
        "panel": "policy mean ω(s) at the contexts",
        "kind": "markers",
        "xlabel": f"{omega_label}{i + 1}",
        "ylabel": f"{omega_label}{j + 1}",
    }
    unit = f" {outcome_label}" if outcome_label else ""
    right = {
        "panel": "context s → outcome of the policy mean's rollout",
        "xlabel": f"x{unit}",
        "ylabel": f"y{unit}",
    }
    mapped, reached_paths = [], []
    for label, policy in policies.items():
        if not callable(getattr(policy, "mean_of", None)):
            raise ValueError(
                f"policies[{label!r}]: expected a policy with mean_of(contexts), "
                f"got {type(policy).__name__}"
            )
        omegas = np.atleast_2d(policy.mean_of(s))
        if omegas.shape != (s.shape[0], d):
            raise ValueError(
                f"policies[{label!r}]: mean_of gave shape {omegas.shape}, "
                f"expected ({s.shape[0]}, {d})"
            )
        rng = np.random.default_rng(seed)
        reached = np.full_like(s, np.nan)
        for k, (w, c) in enumerate(zip(omegas, s, strict=True)):
            trajectory = task.rollout(w, c, rng)
            if not trajectory.failed:
                reached[k] = check_array(outcome(trajectory), "outcome", shape=(2,))
        path = np.stack([s, reached, np.full_like(s, np.nan)], axis=1).reshape(-1, 2)
        name = str(label)
        mapped.append(Series(name, omegas[:, i].tolist(), omegas[:, j].tolist(), **left))
        reached_paths.append(
            Series(name, path[:, 0].tolist(), path[:, 1].tolist(), kind="lines+markers", **right)
        )
    # the contexts last: drawn over the segments that start at them
    targets = Series("contexts s", s[:, 0].tolist(), s[:, 1].tolist(), kind="markers", **right)
    series = [*mapped, *reached_paths, targets]
    return draw(title, series, backend)


# --------------------------------------------------------------------------- tables
def comparison_table(runs: Mapping, levels: Sequence[float] = ()) -> pd.DataFrame:
    """Several :func:`~skillkit.search.loop.learn` results (label → result) side by side.

    Compare runs evaluated on the same contexts with the same seed. One row per method: real
    rollouts (evaluations not counted), updates, the policy mean's reward before the first
    update, after the last and at its best, for each of ``levels`` the real rollouts after
    which it first reached it (NaN: not within the run), and the failed rollouts.
    """
    if not isinstance(runs, Mapping) or not runs:
        raise ValueError("runs: expected a non-empty mapping of label to learn() result")
    levels = [float(v) for v in check_array(list(levels), "levels", ndim=1)]
    rows, index = [], []
    for label, run in runs.items():
        if not isinstance(run, Mapping):
            raise ValueError(
                f"runs[{label!r}]: expected a learn() result, got {type(run).__name__}"
            )
        missing = [k for k in ("rollouts", "mean_reward", "n_failed") if k not in run]
        if missing:
            raise ValueError(f"runs[{label!r}]: not a learn() result, missing {missing}")
        x = check_array(run["rollouts"], f"runs[{label!r}]['rollouts']", ndim=1)
        r = check_array(
            run["mean_reward"], f"runs[{label!r}]['mean_reward']", shape=x.shape, finite=False
        )
        if x.size == 0:
            raise ValueError(f"runs[{label!r}]: empty learning curve")
        row = {
            "real rollouts": int(x[-1]),
            "updates": x.size - 1,
            "reward before": r[0],
            "final reward": r[-1],
            "best reward": np.nanmax(r),
        }
        for level in levels:
            reached = experience_to_reach(x, r, level)
            row[f"rollouts to R ≥ {level:g}"] = np.nan if reached is None else reached
        row["failed rollouts"] = int(np.sum(run["n_failed"]))
        rows.append(row)
        index.append(str(label))
    return pd.DataFrame(rows, index=pd.Index(index, name="method"))
