"""Notebook 06, your own skill: a reader's task learned by contextual REPS, GPREPS and CMA-ES
(:func:`~skillkit.search.loop.learn`), sized, evaluated on a context grid, drawn and tabulated."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from skillkit._validation import check_array, check_count, check_type
from skillkit.experiments.ch4_balancing import experience_to_reach
from skillkit.tasks.base import Task
from skillkit.teaching._common import at_scale, draw, index_pair, per_scale, xy
from skillkit.trajectory import Trajectory
from skillkit.viz.series import Series


@dataclass(frozen=True)
class RunSizes:
    """How long each method runs at one scale: REPS updates × rollouts, CMA-ES generations,
    GPREPS N₀, updates, rollouts per later update, M, L (Eq. 4.1) and L-BFGS steps (2.28)."""

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
SCALES: dict[str, RunSizes] = per_scale(
    RunSizes,
    reps_updates=(15, 40, 100),
    reps_rollouts=(20, 20, 20),
    cmaes_generations=(10, 30, 80),
    gpreps_initial=(10, 10, 10),
    gpreps_updates=(6, 16, 41),
    gpreps_rollouts=(2, 2, 1),
    n_artificial=(100, 500, 500),
    n_trajectories=(5, 10, 25),
    gp_steps=(50, 150, 150),
)


def run_sizes(scale: str) -> RunSizes:
    """The notebook's sizes at ``scale`` (a key of :data:`SCALES`)."""
    return at_scale(SCALES, scale)


def context_grid(task: Task, n_per_dim: int) -> np.ndarray:
    """An even grid of ``n_per_dim`` points per dimension (one: the centre) over the task's
    context box, shape (n_per_dim ** context_dim, context_dim), the last varying fastest."""
    _check_task(task)
    n = check_count(n_per_dim, "n_per_dim")
    low = np.asarray(task.context_low, dtype=np.float64)
    high = np.asarray(task.context_high, dtype=np.float64)
    axes = [
        np.linspace(lo, hi, n) if n > 1 else np.array([(lo + hi) / 2])
        for lo, hi in zip(low, high, strict=True)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, task.context_dim)


def _check_task(task) -> None:
    if check_type(task, Task, "task", "a Task").context_dim == 0:
        raise ValueError(f"task: {task.name!r} has no context (context_dim = 0)")


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
    """What policies (label → anything with ``mean_of``) do across ``contexts`` (n, 2): ω(s)
    on ``omega_dims``, and a segment from each context to ``outcome(trajectory)`` (2,)."""
    _check_task(task)
    if task.context_dim != 2:
        raise ValueError(f"task: expected planar contexts, got context_dim = {task.context_dim}")
    if not isinstance(policies, Mapping) or not policies:
        raise ValueError("policies: expected a non-empty mapping of label to policy")
    if not callable(outcome):
        raise ValueError(f"outcome: expected a callable, got {type(outcome).__name__}")
    s = check_array(contexts, "contexts", shape=(None, 2))
    d = task.parameter_dim
    i, j = index_pair(omega_dims, "omega_dims", d, "coordinates of ω")
    left = {"panel": "policy mean ω(s) at the contexts", "kind": "markers"}
    left |= {"xlabel": f"{omega_label}{i + 1}", "ylabel": f"{omega_label}{j + 1}"}
    unit = f" {outcome_label}" if outcome_label else ""
    right = {"panel": "context s → outcome of the policy mean's rollout"}
    right |= {"xlabel": f"x{unit}", "ylabel": f"y{unit}"}
    mapped, reached_paths = [], []
    for label, policy in policies.items():
        if not callable(getattr(policy, "mean_of", None)):
            raise ValueError(f"policies[{label!r}]: expected a policy with mean_of(contexts)")
        omegas = np.atleast_2d(policy.mean_of(s))
        check_array(omegas, f"policies[{label!r}].mean_of", shape=(len(s), d), finite=False)
        rng = np.random.default_rng(seed)
        reached = np.full_like(s, np.nan)
        for k, (w, c) in enumerate(zip(omegas, s, strict=True)):
            trajectory = task.rollout(w, c, rng)
            if not trajectory.failed:
                reached[k] = check_array(outcome(trajectory), "outcome", shape=(2,))
        path = np.stack([s, reached, np.full_like(s, np.nan)], axis=1).reshape(-1, 2)
        name = str(label)
        mapped.append(Series(name, *xy(omegas[:, [i, j]]), **left))
        reached_paths.append(Series(name, *xy(path), kind="lines+markers", **right))
    # the contexts last: drawn over the segments that start at them
    targets = Series("contexts s", *xy(s), kind="markers", **right)
    return draw(title, [*mapped, *reached_paths, targets], backend)


def comparison_table(runs: Mapping, levels: Sequence[float] = ()) -> pd.DataFrame:
    """:func:`~skillkit.search.loop.learn` results (label → result), a row each: rollouts,
    updates, rewards before, final and best, rollouts to reach each of ``levels`` without a
    failed evaluation rollout (NaN: never) and failed rollouts."""
    if not isinstance(runs, Mapping) or not runs:
        raise ValueError("runs: expected a non-empty mapping of label to learn() result")
    levels = [float(v) for v in check_array(list(levels), "levels", ndim=1)]
    rows = {}
    for label, run in runs.items():
        check_type(run, Mapping, f"runs[{label!r}]", "a learn() result")
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
            reached = experience_to_reach(x, r, level, run.get("eval_failure_rate"))
            row[f"rollouts to R ≥ {level:g}"] = np.nan if reached is None else reached
        row["failed rollouts"] = int(np.sum(run["n_failed"]))
        rows[str(label)] = row
    return pd.DataFrame(list(rows.values()), index=pd.Index(list(rows), name="method"))
