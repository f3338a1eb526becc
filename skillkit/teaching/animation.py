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

_THESIS = {
    "fig3.2": {
        "exp_id": "fig3.3",
        "task": "throwing",
        "contexts": THROWING_TARGETS,
        "animate": throwing_animation,
        "title": "Throwing for two targets (Fig. 3.2)",
    },
    "fig3.8": {
        "exp_id": "fig3.7",
        "task": "table-tennis",
        "contexts": TABLE_TENNIS_CONTEXTS,
        "animate": table_tennis_animation,
        "title": "Two table-tennis shots (Fig. 3.8)",
    },
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
    file = folder / "trials.npz"
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
    """Fig. 3.2 or 3.8 (``figure``): the policy mean's rollouts at ``contexts`` (k,
    context_dim) (default the thesis's two) in ``n_frames`` frames, the policy
    :func:`stored_final_policy` or else the task's initial one; ``kwargs`` go to the animation.
    """
    from skillkit.tasks import make

    if figure not in _THESIS:
        raise ValueError(f"figure: expected one of {sorted(_THESIS)}, got {figure!r}")
    spec = _THESIS[figure]
    task = make(spec["task"])
    s = spec["contexts"] if contexts is None else contexts
    s = check_array(s, "contexts", shape=(None, task.context_dim))
    policy = stored_final_policy(spec["exp_id"], trial)
    if policy is None:
        policy = task.initial_policy()
        source = (
            f"policy: the task's initial policy (the stored {spec['exp_id']} run keeps no "
            "policy), its mean at each context"
        )
    else:
        if (policy.dim, policy.context_dim) != (task.parameter_dim, task.context_dim):
            raise ValueError(
                f"figure: the stored {spec['exp_id']} policy has dim {policy.dim}, context_dim "
                f"{policy.context_dim}; task {spec['task']!r} needs {task.parameter_dim}, "
                f"{task.context_dim}"
            )
        source = (
            f"policy: final contextual REPS policy of the stored {spec['exp_id']} run "
            f"(trial {trial}), its mean at each context"
        )
    trajs = [task.rollout(policy.mean_of(row), row, rng=0) for row in s]
    kwargs.setdefault("title", spec["title"])
    return spec["animate"](task, trajs, s, n_frames=n_frames, subtitle=source, **kwargs)
