"""The reward-model interface of GPREPS (Sec. 4.1, Eq. 4.1) and what the task models
(``skillkit.tasks.*model``) share: validation, GP refitting and failure handling."""

from __future__ import annotations

import abc
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skillkit._validation import as_generator, check_array, check_choice, check_count
from skillkit.models.gp import GPRegression
from skillkit.trajectory import Trajectory

__all__ = [
    "Prediction",
    "RewardModel",
    "check_refit",
    "gp_stats",
    "refit_gp",
    "set_factories",
    "subsample",
    "usable_trajectories",
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
    """What GPREPS needs from a model: fit on real data, predict expected rewards (Eq. 4.1).

    Task models set ``task``, ``refit`` and ``_hypers`` (previous GP hyper-parameters by key)
    and implement ``predict`` returning a :class:`Prediction`."""

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

    def expected_rewards(
        self,
        contexts: np.ndarray,
        omegas: np.ndarray,
        n_trajectories: int,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Predicted expected rewards R̂_sω (Eq. 4.1), by default of ``self.predict``.

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
        return self.predict(contexts, omegas, n_trajectories, rng).expected_rewards

    def _pairs(self, fitted: bool, contexts, omegas, n_trajectories, rng) -> tuple:
        """Validated (ω (B, d), s (B, context_dim), L, generator) of a fitted task model."""
        if not fitted:
            raise RuntimeError(f"{type(self).__name__}: call fit() before predicting")
        w = check_array(omegas, "omegas", shape=(None, self.task.parameter_dim))
        s = check_array(contexts, "contexts", shape=(w.shape[0], self.task.context_dim))
        return w, s, check_count(n_trajectories, "n_trajectories"), as_generator(rng)

    def _refit(self, key: str, make_gp: Callable[[], Any], x, y, rng) -> tuple[Any, dict]:
        """Refit GP ``key`` from its previous hyper-parameters (:func:`refit_gp`); the GP and
        the refit record."""
        gp, record = refit_gp(make_gp, x, y, rng, self._hypers[key], self.refit)
        if isinstance(gp, GPRegression):
            self._hypers[key] = gp.hyperparameters
        return gp, record


def set_factories(model: Any, **factories: tuple[Any, Callable[[], Any]]) -> None:
    """Set ``model.<name>`` to each ``(factory, default)``'s factory, or its default for None;
    ValueError naming a factory that is neither."""
    for name, (f, default) in factories.items():
        if f is not None and not callable(f):
            raise ValueError(f"{name}: expected a callable, got {type(f).__name__}")
        setattr(model, name, f or default)


def usable_trajectories(trajectories, what: str) -> list:
    """The distinct non-failed trajectories; ValueError for None or none left."""
    if trajectories is None:
        raise ValueError(f"trajectories: the {what} model learns from trajectories")
    ok = list({id(t): t for t in trajectories if not t.failed}.values())
    if not ok:
        raise ValueError("trajectories: every trajectory failed; nothing to learn from")
    return ok


WARM_LENGTHSCALE_CAP = 100.0


def warm_start_hypers(
    gp: GPRegression, hypers: dict[str, np.ndarray] | None, inputs: np.ndarray
) -> None:
    """Start ``gp``'s next optimisation at ``hypers`` (raw units), length-scales capped at
    :data:`WARM_LENGTHSCALE_CAP` std of ``inputs``; the fit refits from the cold start if the warm
    one ends above the cold start's objective (``diagnostics["start"]``)."""
    if hypers is None:
        return
    if gp.cold_start is None:
        gp.cold_start = (gp.init_lengthscale, gp.init_outputscale, gp.init_noise)
    sd = inputs.std(axis=0)
    cap = WARM_LENGTHSCALE_CAP * np.where(sd > 0, sd, 1.0)
    gp.init_lengthscale = np.minimum(np.asarray(hypers["lengthscale"], dtype=np.float64), cap)
    gp.init_outputscale = np.asarray(hypers["outputscale"], dtype=np.float64)
    gp.init_noise = np.asarray(hypers["noise"], dtype=np.float64)


def check_refit(refit: str) -> str:
    """``refit`` if it is "cold", "warm" or "best", else a ValueError."""
    return check_choice(refit, "refit", ("cold", "warm", "best"))


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
    x, y : ndarray, shape (N, d) and (N, E) or (N,)
    rng : Generator
        One seed is drawn and shared by both starts.
    previous : dict or None
        The previous fit's ``gp.hyperparameters`` (None: cold start only).
    refit : {"cold", "warm", "best"}
        Start at the default initialisation (PILCO's rule), at ``previous``, or both keeping
        the larger log marginal likelihood (2.28); ValueError otherwise.

    Returns
    -------
    gp, record
        The fitted model kept; ``{start, log_ml_cold, log_ml_warm}``.
    """
    starts = ("cold", "warm") if check_refit(refit) == "best" else (refit,)
    seed = int(rng.integers(2**63))
    record: dict[str, Any] = {"start": "cold", "log_ml_cold": None, "log_ml_warm": None}
    best = None
    for start in starts if previous is not None else ("cold",):
        gp = make_gp()
        if start == "warm" and isinstance(gp, GPRegression):
            warm_start_hypers(gp, previous, x)
        gp.fit(x, y, np.random.default_rng(seed))
        if not isinstance(gp, GPRegression):
            return gp, record
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
