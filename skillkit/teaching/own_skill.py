r"""Notebook 06, your own skill: run sizes per scale, and the figures and tables that compare
the methods learning a task the reader wrote.

The notebook wraps a few numpy functions as a :class:`~skillkit.tasks.functional.TrajectoryTask`
and learns it with contextual REPS, GPREPS and CMA-ES through
:func:`~skillkit.search.loop.learn`; this module sizes the runs (:func:`run_sizes`), picks the
evaluation contexts (:func:`context_grid`), draws the learned context → ω mapping
(:func:`mapping_figure`) and tabulates the results (:func:`comparison_table`). Learning curves
are :func:`skillkit.viz.figures.plot_learning`'s.
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
from skillkit.trajectory import Trajectory
from skillkit.viz.plots import draw_figure
from skillkit.viz.series import Series

__all__ = [
    "SCALES",
    "RunSizes",
    "comparison_table",
    "context_grid",
    "mapping_figure",
    "run_sizes",
]


# --------------------------------------------------------------------------- sizes
@dataclass(frozen=True)
class RunSizes:
    """How long each method of the notebook runs at one scale.

    Attributes
    ----------
    reps_updates : int
        Updates K of contextual REPS.
    reps_rollouts : int
        Real rollouts N per REPS update.
    cmaes_generations : int
        Generations of CMA-ES (each λ candidates × m contexts real rollouts).
    gpreps_initial : int
        N₀, real rollouts before GPREPS's first update (Table 4.1: "a higher N in the first
        iteration").
    gpreps_updates : int
        GPREPS updates K, the first on the N₀ initial rollouts: N₀ + (K − 1) N real rollouts
        in all.
    gpreps_rollouts : int
        Real rollouts N per later GPREPS update.
    n_artificial : int
        M, artificial (s, ω) pairs per GPREPS update.
    n_trajectories : int
        L, trajectories predicted per pair (Eq. 4.1).
    gp_steps : int
        L-BFGS iterations of each forward-model fit (2.28); 150 is the thesis's setting.
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


#: The notebook's sizes per ``SKILLKIT_SCALE``: "smoke" runs in seconds (what CI executes),
#: "quick" in a few minutes, "paper" uses the thesis's GPREPS setting (N₀ = 10, then one real
#: rollout per update, M = 500, L = 25) and runs the model-free methods for thousands of
#: rollouts.
SCALES: dict[str, RunSizes] = {
    "smoke": RunSizes(
        reps_updates=15, reps_rollouts=20, cmaes_generations=10, gpreps_initial=10,
        gpreps_updates=6, gpreps_rollouts=2, n_artificial=100, n_trajectories=5, gp_steps=50,
    ),
    "quick": RunSizes(
        reps_updates=40, reps_rollouts=20, cmaes_generations=30, gpreps_initial=10,
        gpreps_updates=16, gpreps_rollouts=2, n_artificial=500, n_trajectories=10,
        gp_steps=150,
    ),
    "paper": RunSizes(
        reps_updates=100, reps_rollouts=20, cmaes_generations=80, gpreps_initial=10,
        gpreps_updates=41, gpreps_rollouts=1, n_artificial=500, n_trajectories=25,
        gp_steps=150,
    ),
}  # fmt: skip


def run_sizes(scale: str) -> RunSizes:
    """The notebook's sizes at ``scale`` (a key of :data:`SCALES`)."""
    if scale not in SCALES:
        raise ValueError(f"scale: expected one of {tuple(SCALES)}, got {scale!r}")
    return SCALES[scale]


# --------------------------------------------------------------------------- contexts
def context_grid(task: Task, n_per_dim: int) -> np.ndarray:
    """An even grid over the task's context range [context_low, context_high].

    Parameters
    ----------
    task : Task
        A contextual task (context_dim ≥ 1).
    n_per_dim : int
        Points per context dimension (≥ 1; one point is the range's centre).

    Returns
    -------
    ndarray, shape (n_per_dim ** context_dim, context_dim)
        The grid, the last context dimension varying fastest.
    """
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

    Each policy's mean ω(s) = E[π(ω|s)] is rolled out once per context, with one random stream for
    every policy (common random numbers, as :class:`~skillkit.search.loop.Evaluator`). Left: two
    coordinates of ω(s). Right: per policy, a segment from each context to ``outcome(trajectory)``
    of its rollout: the shorter, the better the skill generalises.

    Parameters
    ----------
    task : Task
        A contextual task whose context is a point in the plane of the outcome
        (context_dim = 2).
    policies : mapping of str to policy
        Label → anything with ``mean_of(contexts)`` (a
        :class:`~skillkit.policies.gaussian.LinearGaussianPolicy`, a CMA-ES policy, a
        ``learn`` result's ``"policy"``).
    outcome : callable
        ``outcome(trajectory) -> (2,)``: the point a rollout reached, in the context's
        coordinates. Not called for failed rollouts (drawn as gaps).
    contexts : array_like, shape (n, 2)
        Where to evaluate (e.g. :func:`context_grid`).
    omega_dims : pair of int
        The coordinates of ω drawn on the left.
    omega_label : str
        Name of ω's coordinates on the left axes (``"ω"`` gives ω1, ω2, …).
    outcome_label : str
        Unit or name of the right panel's axes (e.g. ``"[m]"``).
    seed : int
        Seed of the rollouts' stream (the same for every policy).
    title : str
    backend : {"plotly", "matplotlib"}

    Returns
    -------
    plotly.graph_objects.Figure or NotebookFigure
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
    if (
        not isinstance(omega_dims, (tuple, list))
        or len(omega_dims) != 2
        or any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) for i in omega_dims)
        or not all(0 <= i < d for i in omega_dims)
        or omega_dims[0] == omega_dims[1]
    ):
        raise ValueError(
            f"omega_dims: expected two different coordinates of ω in [0, {d}), got {omega_dims!r}"
        )
    i, j = (int(k) for k in omega_dims)
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
    return draw_figure({"title": title, "series": [x.to_dict() for x in series]}, backend)


# --------------------------------------------------------------------------- tables
def comparison_table(runs: Mapping, levels: Sequence[float] = ()) -> pd.DataFrame:
    """Several :func:`~skillkit.search.loop.learn` results side by side.

    Parameters
    ----------
    runs : mapping of str to dict
        Method label → its ``learn`` result. Compare runs evaluated on the same contexts with
        the same seed (``eval_contexts``, ``eval_seed``), or the rewards are not comparable.
    levels : sequence of float
        Rewards of the policy mean to reach; one column each.

    Returns
    -------
    DataFrame
        One row per method: real rollouts executed (``learn``'s count; evaluation rollouts of
        the policy mean are not counted), updates, the policy mean's reward before the first
        update, after the last and at its best, for each level the real rollouts after which
        the policy mean first reached it (NaN: not within the run; read off the evaluations,
        one per update), and the failed rollouts.
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
