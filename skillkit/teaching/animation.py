"""Figs 3.2 and 3.8: a stored paper run's final policy rolled out at two contexts, animated."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skillkit._validation import check_array
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.viz.animation import (
    TABLE_TENNIS_CONTEXTS,
    THROWING_TARGETS,
    table_tennis_animation,
    throwing_animation,
)

_THESIS = {  # figure: (stored run, task, default contexts, animation, title)
    "fig3.2": (
        "fig3.3",
        "throwing",
        THROWING_TARGETS,
        throwing_animation,
        "Throwing for two targets (Fig. 3.2)",
    ),
    "fig3.8": (
        "fig3.7",
        "table-tennis",
        TABLE_TENNIS_CONTEXTS,
        table_tennis_animation,
        "Two table-tennis shots (Fig. 3.8)",
    ),
}


def stored_final_policy(exp_id: str, trial: int = 0) -> LinearGaussianPolicy | None:
    """The last policy π_K (Eq. 3.13) of ``trial`` of the stored paper run of ``exp_id``, or
    None without a stored run or policy; ``ValueError`` for a bad ``trial``."""
    from skillkit.experiments import stored_run

    if isinstance(trial, bool) or not isinstance(trial, (int, np.integer)) or trial < 0:
        raise ValueError(f"trial: expected a trial number >= 0, got {trial!r}")
    try:
        file = Path(stored_run(str(exp_id)).path) / "trials.npz"
    except FileNotFoundError:
        return None
    if not file.exists():
        return None
    with np.load(file, allow_pickle=False) as data:
        keys = set(data.files)
        if not any(k.endswith("__policy_mean") for k in keys):
            return None
        prefix = f"trial{int(trial)}__"
        if prefix + "policy_mean" not in keys:
            raise ValueError(f"trial: the stored {exp_id} run has no policy for trial {trial}")
        return LinearGaussianPolicy(
            data[prefix + "policy_mean"][-1],
            data[prefix + "policy_cov"][-1],
            data[prefix + "policy_gain"][-1],
            context_dim=int(data[prefix + "policy_context_dim"]),
            features=str(data[prefix + "policy_features"]),
        )


def thesis_animation(figure: str, contexts=None, *, trial: int = 0, n_frames: int = 40, **kwargs):
    """Fig. 3.2 or 3.8 (``figure``): the mean of :func:`stored_final_policy` (else the task's
    initial policy) rolled out at ``contexts`` (k, context_dim) (default the thesis's two)."""
    from skillkit.tasks import make

    if figure not in _THESIS:
        raise ValueError(f"figure: expected one of {sorted(_THESIS)}, got {figure!r}")
    exp_id, name, default, animate, title = _THESIS[figure]
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
    kwargs.setdefault("title", title)
    return animate(
        task, trajs, s, n_frames=n_frames, subtitle=source + ", its mean at each context", **kwargs
    )
