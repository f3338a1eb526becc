"""Policy histories: the upper-level policies of a learning run, for the viewer's playback.

:class:`PolicyHistory` holds π_0 (initial) … π_K (after the K-th update); :class:`PolicyRecorder`
collects them as the ``callback`` of :func:`skillkit.search.loop.learn`;
:func:`save_policy_history` and :func:`load_policy_history` write and read the file that
``skillkit view TASK --policy FILE`` plays back.

File format
-----------
A NumPy ``.npz`` archive (``np.savez_compressed``; read with ``allow_pickle=False``). K is the
number of updates, d = dim ω, F the number of context features; each policy is
π_k(ω|s) = N(a_k + A_k φ(s), Σ_k) (Eq. 3.13):

==========================  ==============  =======  ==========================================
key                         shape           dtype    meaning
==========================  ==============  =======  ==========================================
``format``                  ()              str      ``"skillkit-policy-history-v1"``
``policy_mean``             (K+1, d)        float64  offsets a_k
``policy_cov``              (K+1, d, d)     float64  covariances Σ_k (symmetric positive definite)
``policy_gain``             (K+1, d, F)     float64  gains A_k
``policy_context_dim``      ()              int      context dimension
``policy_features``         ()              str      ``"linear"`` or ``"quadratic"``
``task``                    ()              str      task name ("" if unknown)
``rollouts``                (K+1,)          float64  optional: rollouts used before each policy
``mean_reward``             (K+1,)          float64  optional: reward of each policy's mean
==========================  ==============  =======  ==========================================

A file without ``format`` (the ``policy_*`` arrays alone) is accepted, another version refused.
``skillkit reproduce`` stores the same arrays per trial in a run folder's ``trials.npz``,
prefixed ``trial<i>__``, when ``run_trial`` returned :meth:`PolicyRecorder.arrays`.
"""

from __future__ import annotations

import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skillkit._validation import check_array
from skillkit.policies.gaussian import LinearGaussianPolicy

__all__ = [
    "HISTORY_FORMAT",
    "PolicyHistory",
    "PolicyRecorder",
    "load_policy_history",
    "save_policy_history",
]

HISTORY_FORMAT = "skillkit-policy-history-v1"
"""The ``format`` entry of a policy-history file (see the module docstring)."""


@dataclass(frozen=True)
class PolicyHistory:
    """The upper-level policies π_0 … π_K of a learning run (same ``dim`` and ``context_dim``),
    with optional ``rollouts`` used before each and ``mean_reward`` of each policy's mean
    (K+1,), and the ``task`` name ("" if unknown). ``ValueError``: no policies, another policy
    class, mismatched dimensions or shapes."""

    policies: tuple
    rollouts: np.ndarray | None = None
    mean_reward: np.ndarray | None = None
    task: str = ""

    def __post_init__(self) -> None:
        if not self.policies:
            raise ValueError("policies: expected at least one policy")
        for i, p in enumerate(self.policies):
            if not isinstance(p, LinearGaussianPolicy):
                msg = f"policies: entry {i} is a {type(p).__name__}, not a LinearGaussianPolicy"
                raise ValueError(msg)
        first = self.policies[0]
        if any((p.dim, p.context_dim) != (first.dim, first.context_dim) for p in self.policies):
            raise ValueError("policies: expected the same dim and context_dim for every update")
        n = len(self.policies)
        for name in ("rollouts", "mean_reward"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, check_array(value, name, shape=(n,), finite=False))

    def __len__(self) -> int:
        return len(self.policies)

    def __getitem__(self, k: int) -> LinearGaussianPolicy:
        return self.policies[k]

    def __repr__(self) -> str:
        first = self.policies[0]
        parts = [f"K={len(self) - 1}", f"dim={first.dim}", f"context_dim={first.context_dim}"]
        if self.task:
            parts.append(f"task={self.task!r}")
        if self.rollouts is not None:
            parts.append(f"rollouts={self.rollouts[0]:g}…{self.rollouts[-1]:g}")
        if self.mean_reward is not None:
            parts.append(f"mean_reward={self.mean_reward[0]:.4g}…{self.mean_reward[-1]:.4g}")
        return f"PolicyHistory({', '.join(parts)})"


def read_npz(path: str | Path, name: str, key: str, version: str) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file, read without pickles; ``ValueError`` naming ``name``
    when it is not a readable archive or its entry ``key`` names another format ``version``."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{name}: {path} is not a readable .npz file ({exc})") from None
    if key in arrays and str(arrays[key]) != version:
        raise ValueError(f"{name}: {path} has format {str(arrays[key])!r}, expected {version!r}")
    return arrays


class PolicyRecorder:
    """The ``callback`` of :func:`skillkit.search.loop.learn` recording ``algorithm.policy`` after
    every update k = 0 … K into :attr:`policies`, for :meth:`save` or :meth:`arrays`."""

    def __init__(self) -> None:
        self.policies: list[LinearGaussianPolicy] = []

    def __call__(self, k: int, algorithm) -> None:
        if k != len(self.policies):
            raise ValueError(f"k: expected update {len(self.policies)}, got {k}")
        self.policies.append(algorithm.policy)

    def __repr__(self) -> str:
        return f"PolicyRecorder({len(self.policies)} policies)"

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``policy_*`` arrays of the file format (see the module docstring)."""
        from skillkit.search.loop import policy_history_arrays

        return policy_history_arrays(PolicyHistory(tuple(self.policies)).policies)

    def save(self, path, *, result: Mapping | None = None, task: str = "") -> Path:
        """Write the history; ``result`` (the dict ``learn`` returns) adds rollouts and rewards."""
        curve = {k: (result or {}).get(k) for k in ("rollouts", "mean_reward")}
        return save_policy_history(path, self.policies, task=task, **curve)


def save_policy_history(
    path,
    policies: Sequence[LinearGaussianPolicy],
    *,
    rollouts=None,
    mean_reward=None,
    task: str = "",
) -> Path:
    """Write policies π_0 … π_K (same dimensions) with optional ``rollouts``, ``mean_reward``
    (K+1,) and the task name to ``path`` (``.npz`` appended if missing); returns the file."""
    from skillkit.search.loop import policy_history_arrays

    history = PolicyHistory(tuple(policies), rollouts, mean_reward, str(task))  # validates
    arrays = policy_history_arrays(history.policies)
    arrays.update(format=np.asarray(HISTORY_FORMAT), task=np.asarray(history.task))
    for key in ("rollouts", "mean_reward"):
        if getattr(history, key) is not None:
            arrays[key] = getattr(history, key)
    np.savez_compressed(path, **arrays)
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


def load_policy_history(path, trial: int = 0) -> PolicyHistory:
    """Read a policy history: a file of :func:`save_policy_history`, or trial ``trial`` of a run
    folder whose ``trials.npz`` holds ``trial<i>__policy_*``.

    Raises
    ------
    ValueError
        Missing, unreadable or malformed file (argument ``policy``), another version, no trial.
    """
    path = Path(path)
    file, prefix = (path / "trials.npz", f"trial{int(trial)}__") if path.is_dir() else (path, "")
    if not file.exists():
        raise ValueError(f"policy: no such file {file}")
    arrays = read_npz(file, "policy", "format", HISTORY_FORMAT)
    if prefix and not any(k.startswith(prefix) for k in arrays):
        n = len({k.split("__")[0] for k in arrays if k.startswith("trial")})
        raise ValueError(f"trial: {file} has no trial {trial} (it has {n} trials)")
    keys = ("policy_mean", "policy_cov", "policy_gain", "policy_context_dim", "policy_features")
    for key in keys:
        if prefix + key not in arrays:
            msg = f"policy: {file} has no {prefix + key!r} array (not a skillkit policy history)"
            raise ValueError(msg)
    mean, cov, gain, context_dim, features = (np.asarray(arrays[prefix + k]) for k in keys)
    try:
        policies = tuple(
            LinearGaussianPolicy(m, c, g, context_dim=int(context_dim), features=str(features))
            for m, c, g in zip(mean, cov, gain, strict=True)
        )
    except (ValueError, TypeError) as exc:
        raise ValueError(f"policy: {file} holds an invalid policy ({exc})") from None
    extra = {}
    for key in ("rollouts", "mean_reward"):
        value = arrays.get(prefix + key)
        if value is not None and np.shape(value) == (len(policies),):
            extra[key] = np.asarray(value, dtype=np.float64)
    return PolicyHistory(policies, task=str(arrays.get(prefix + "task", "")), **extra)
