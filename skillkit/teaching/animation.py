"""Figs 3.2 and 3.8: a stored paper run's final policy rolled out at two contexts, animated."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_choice
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.viz.animation import (
    TABLE_TENNIS_CONTEXTS,
    THROWING_TARGETS,
    table_tennis_animation,
    throwing_animation,
)
from skillkit.viz.history import load_policy_history

_THESIS = {  # figure: (stored run, task, default contexts, animation)
    "fig3.2": ("fig3.3", "throwing", THROWING_TARGETS, throwing_animation),
    "fig3.8": ("fig3.7", "table-tennis", TABLE_TENNIS_CONTEXTS, table_tennis_animation),
}


def stored_final_policy(exp_id: str, trial: int = 0) -> LinearGaussianPolicy | None:
    """The last policy π_K (Eq. 3.13) of ``trial`` of the stored paper run of ``exp_id``, or
    None without a stored run or policy; ``ValueError`` for a bad ``trial``."""
    from skillkit.experiments import stored_run

    if isinstance(trial, bool) or not isinstance(trial, (int, np.integer)) or trial < 0:
        raise ValueError(f"trial: expected a trial number >= 0, got {trial!r}")
    try:
        folder = Path(stored_run(str(exp_id)).path)
    except FileNotFoundError:
        return None
    if not (folder / "trials.npz").exists():
        return None
    with np.load(folder / "trials.npz", allow_pickle=False) as data:
        if not any(k.endswith("__policy_mean") for k in data.files):
            return None
    return load_policy_history(folder, trial)[-1]


def thesis_animation(figure: str, contexts=None, *, trial: int = 0, n_frames: int = 40, **kwargs):
    """Fig. 3.2 or 3.8 (``figure``): the mean of :func:`stored_final_policy` (else the task's
    initial policy) rolled out at ``contexts`` (k, context_dim) (default the thesis's two)."""
    from skillkit.tasks import make

    exp_id, name, default, animate = _THESIS[check_choice(figure, "figure", sorted(_THESIS))]
    task = make(name)
    s = check_array(
        default if contexts is None else contexts, "contexts", shape=(None, task.context_dim)
    )
    policy = stored_final_policy(exp_id, trial)
    if policy is None:
        policy = task.initial_policy()
        source = f"policy: the task's initial policy (the stored {exp_id} run keeps no policy)"
    else:
        if (policy.dim, policy.context_dim) != (task.parameter_dim, task.context_dim):
            raise ValueError(f"figure: the stored {exp_id} policy does not fit task {name!r}")
        source = f"policy: final contextual REPS policy of the stored {exp_id} run (trial {trial})"
    trajs = [task.rollout(policy.mean_of(row), row, rng=0) for row in s]
    return animate(
        task, trajs, s, n_frames=n_frames, subtitle=source + ", its mean at each context", **kwargs
    )
