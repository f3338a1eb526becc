"""The reward-model interface of GPREPS (Sec. 4.1, Eq. 4.1) and helpers task models share.

Task-specific models (``skillkit.tasks.hockey.model``, ``skillkit.tasks.table_tennis.model``,
``skillkit.tasks.throwing_model``) derive from :class:`RewardModel`."""

from __future__ import annotations

import abc
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np

from skillkit.models.gp import GPRegression, check_dtype
from skillkit.trajectory import Trajectory

__all__ = [
    "REFIT_STARTS",
    "Prediction",
    "RewardModel",
    "check_refit",
    "check_sample_dtype",
    "gp_stats",
    "refit_gp",
    "subsample",
    "warm_start_hypers",
    "worst_if_failed",
    "worst_if_nonfinite",
]


class Prediction:
    """Base of a reward model's prediction: ``rewards`` (B, L), one per predicted trajectory."""

    rewards: np.ndarray

    @property
    def expected_rewards(self) -> np.ndarray:
        """R̂ = mean of the L rewards of each pair (Eq. 4.1), shape (B,)."""
        return self.rewards.mean(axis=1)


class RewardModel(abc.ABC):
    """What GPREPS needs from a model: fit on real data, predict expected rewards (Eq. 4.1)."""

    @abc.abstractmethod
    def fit(
        self,
        contexts: np.ndarray,
        omegas: np.ndarray,
        rewards: np.ndarray,
        trajectories: Sequence[Trajectory] | None,
        rng: np.random.Generator,
    ) -> dict[str, Any]:
        """Fit on all real samples so far.

        Parameters
        ----------
        contexts : ndarray, shape (N, context_dim)
        omegas : ndarray, shape (N, d)
            Policy parameters ω.
        rewards : ndarray, shape (N,)
        trajectories : sequence of Trajectory, length N, or None
        rng : Generator

        Returns
        -------
        dict
            Fit statistics.
        """
        ...

    @abc.abstractmethod
    def expected_rewards(
        self,
        contexts: np.ndarray,
        omegas: np.ndarray,
        n_trajectories: int,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Predicted expected rewards R̂_sω (Eq. 4.1).

        Parameters
        ----------
        contexts : ndarray, shape (M, context_dim)
        omegas : ndarray, shape (M, d)
        n_trajectories : int
            L, sampled trajectories per pair (where the model samples).
        rng : Generator

        Returns
        -------
        ndarray, shape (M,)
        """
        ...


#: Warm-started ARD length-scales are capped at this many standard deviations of their input.
WARM_LENGTHSCALE_CAP = 100.0


def warm_start_hypers(
    gp: GPRegression, hypers: dict[str, np.ndarray] | None, inputs: np.ndarray
) -> None:
    """Start ``gp``'s next optimisation at ``hypers`` (raw units), length-scales capped at
    :data:`WARM_LENGTHSCALE_CAP` std of ``inputs`` (a switched-off input would stay off)."""
    if hypers is None:
        return
    sd = inputs.std(axis=0)
    cap = WARM_LENGTHSCALE_CAP * np.where(sd > 0, sd, 1.0)
    gp.init_lengthscale = np.minimum(np.asarray(hypers["lengthscale"], dtype=np.float64), cap)
    gp.init_outputscale = np.asarray(hypers["outputscale"], dtype=np.float64)
    gp.init_noise = np.asarray(hypers["noise"], dtype=np.float64)


#: How a model's GP hyper-parameters are refitted after each data collection step (Sec. 4.1):
#: "cold" restarts the optimisation (2.28) at the default initialisation (PILCO's rule),
#: "warm" at the previous fit's values, "best" runs both and keeps the larger marginal
#: likelihood.
RefitStart = Literal["cold", "warm", "best"]
REFIT_STARTS: tuple[str, ...] = ("cold", "warm", "best")


def check_refit(refit: str) -> str:
    """``refit`` if it is one of :data:`REFIT_STARTS`, else a ValueError."""
    if refit not in REFIT_STARTS:
        raise ValueError(f"refit: expected one of {REFIT_STARTS}, got {refit!r}")
    return refit


def refit_gp(
    make_gp: Callable[[], Any],
    x: np.ndarray,
    y: np.ndarray,
    rng: np.random.Generator,
    previous: dict[str, np.ndarray] | None,
    refit: str = "best",
) -> tuple[Any, dict[str, Any]]:
    """Refit a GP's hyper-parameters on all data so far (Sec. 4.1).

    Parameters
    ----------
    make_gp : callable
        ``make_gp() -> gp``, a fresh unfitted model.
    x : ndarray, shape (N, d)
    y : ndarray, shape (N, E) or (N,)
    rng : Generator
        One seed is drawn and shared by both starts.
    previous : dict or None
        The previous fit's ``gp.hyperparameters`` (None: cold start only).
    refit : {"cold", "warm", "best"}
        "cold" starts at the default initialisation, "warm" at ``previous``, "best" runs both
        and keeps the larger log marginal likelihood (2.28).

    Returns
    -------
    gp
        The fitted model kept.
    record : dict
        ``start``, ``log_ml_cold``, ``log_ml_warm``.

    Raises
    ------
    ValueError
        On an unknown ``refit``.
    """
    check_refit(refit)
    seed = int(rng.integers(2**63))
    record: dict[str, Any] = {"start": "cold", "log_ml_cold": None, "log_ml_warm": None}
    starts = {"cold": ("cold",), "warm": ("warm",), "best": ("cold", "warm")}[refit]
    if previous is None:
        starts = ("cold",)
    best = None
    for start in starts:
        gp = make_gp()
        if not isinstance(gp, GPRegression):
            gp.fit(x, y, np.random.default_rng(seed))
            return gp, record
        if start == "warm":
            warm_start_hypers(gp, previous, x)
        gp.fit(x, y, np.random.default_rng(seed))
        lml = gp.diagnostics.get("log_marginal_likelihood")
        value = -np.inf if lml is None else float(np.sum(lml))
        value = value if np.isfinite(value) else -np.inf
        record[f"log_ml_{start}"] = value
        if best is None or value > best[0]:
            best = (value, gp, start)
    record["start"] = best[2]
    return best[1], record


def gp_stats(gp: GPRegression, n_data: int) -> dict[str, Any]:
    """One fit's report: data size, log ML, iterations, largest noise variance, events."""
    lml = gp.diagnostics.get("log_marginal_likelihood")
    return {
        "n_data": int(n_data),
        "log_ml": None if lml is None else float(np.sum(lml)),
        "iterations": gp.diagnostics.get("n_iterations"),
        "noise_var_max": float(np.max(gp.hyperparameters["noise"])),
        "numerical_events": gp.diagnostics.get("numerical_events"),
    }


#: ``dtype`` of a reward model's sampled trajectories: float64 or float32.
check_sample_dtype = check_dtype


def subsample(rng: np.random.Generator, n_max: int, *arrays: np.ndarray) -> tuple:
    """The same ``n_max`` random rows of each array (all rows, in order, if there are fewer)."""
    n = arrays[0].shape[0]
    if n <= n_max:
        return arrays
    pick = rng.choice(n, n_max, replace=False)
    return tuple(a[pick] for a in arrays)


def worst_if_failed(
    rewards: np.ndarray, states: np.ndarray, task: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Rewards (B,) with predicted paths the simulator would stop as failed set to
    ``task.worst_reward``, and the failed mask."""
    failed = np.asarray(task.failed_batch(states), dtype=bool)
    return np.where(failed, task.worst_reward, rewards), failed


def worst_if_nonfinite(rewards: np.ndarray, task: Any, where: str) -> np.ndarray:
    """Non-finite predicted rewards set to ``task.worst_reward`` (a counting ``RuntimeWarning``)."""
    bad = ~np.isfinite(rewards)
    if bad.any():
        warnings.warn(
            f"{where}: {int(bad.sum())} of {bad.size} predicted trajectories have a "
            f"non-finite reward (the model diverged); set to {task.worst_reward:g}",
            RuntimeWarning,
            stacklevel=3,
        )
        rewards = np.where(bad, task.worst_reward, rewards)
    return rewards
