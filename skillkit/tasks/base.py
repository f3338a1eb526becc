"""The Task contract (DESIGN.md): context distribution, parameter space, rollout, reward.

A task is a small class in the style of dm_control's suite: it knows its context
distribution μ(s) (:meth:`Task.sample_context`), the dimension of the lower-level policy
parameters ω, a sensible initial upper-level policy, how to run one episode
(:meth:`Task.rollout`) and how to score a trajectory in a context (:meth:`Task.reward`).
Rewards are pure functions of the trajectory and the context, so a trajectory can be
re-scored in other contexts (the *extra context* trick of Sec. 3.4) whenever the trajectory
does not depend on the context (``trajectory_depends_on_context`` is False).
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod

import numpy as np

from skillkit._validation import as_generator, check_array
from skillkit.trajectory import Trajectory


class SimulationFailure(RuntimeError):
    """Raised inside a simulator when the physics produced non-finite or unstable values."""


class Task(ABC):
    """Base class of every task.

    Subclasses set the class attributes and implement :meth:`_simulate` and :meth:`_reward`.

    Attributes
    ----------
    name : str
        Registry name.
    context_dim : int
        Dimension of the context s (0 for context-free tasks).
    parameter_dim : int
        Dimension of the lower-level policy parameters ω.
    context_low, context_high : ndarray, shape (context_dim,)
        Bounds of the context distribution μ(s) (uniform unless :meth:`sample_context` is
        overridden). Contexts outside them are rejected by :meth:`check_context`.
    worst_reward : float
        Reward given to a failed (NaN, unstable) rollout: lower than any reward a working
        rollout can get in practice.
    trajectory_depends_on_context : bool
        Whether the rollout itself depends on s (False for throwing: the target only enters
        the reward; True for hockey: the target puck is part of the scene).
    """

    name: str = "task"
    context_dim: int = 0
    parameter_dim: int = 0
    context_low: np.ndarray = np.zeros(0)
    context_high: np.ndarray = np.zeros(0)
    context_names: tuple[str, ...] = ()
    worst_reward: float = -1e6
    trajectory_depends_on_context: bool = True

    # ----------------------------------------------------------------- contexts
    def sample_context(self, rng=None, n: int | None = None) -> np.ndarray:
        """Draw contexts s ~ μ(s).

        Parameters
        ----------
        rng : Generator, int or None
            Randomness.
        n : int, optional
            Number of contexts. ``None`` returns one context of shape (context_dim,),
            otherwise shape (n, context_dim).
        """
        rng = as_generator(rng)
        size = (self.context_dim,) if n is None else (int(n), self.context_dim)
        low, high = np.asarray(self.context_low), np.asarray(self.context_high)
        return low + (high - low) * rng.random(size)

    def check_context(self, context, name: str = "context") -> np.ndarray:
        """Validate one context: shape (context_dim,), finite, inside the task's range."""
        if context is None:
            if self.context_dim == 0:
                return np.zeros(0)
            raise ValueError(
                f"{name}: task {self.name!r} needs a context of shape ({self.context_dim},), "
                "got None"
            )
        s = check_array(context, name, shape=(self.context_dim,))
        low, high = np.asarray(self.context_low), np.asarray(self.context_high)
        tol = 1e-9 * (1.0 + np.abs(high - low))
        outside = (s < low - tol) | (s > high + tol)
        if np.any(outside):
            i = int(np.flatnonzero(outside)[0])
            label = self.context_names[i] if i < len(self.context_names) else f"[{i}]"
            raise ValueError(
                f"{name}: {label}={s[i]:g} is outside task {self.name!r}'s range "
                f"[{low[i]:g}, {high[i]:g}]"
            )
        return s

    def check_omega(self, omega, name: str = "omega") -> np.ndarray:
        """Validate lower-level parameters: shape (parameter_dim,), finite."""
        return check_array(omega, name, shape=(self.parameter_dim,))

    # ----------------------------------------------------------------- episodes
    def rollout(self, omega, context=None, rng=None) -> Trajectory:
        """Run one episode with lower-level parameters ω in context s.

        Parameters
        ----------
        omega : array_like, shape (parameter_dim,)
            Lower-level policy parameters.
        context : array_like, shape (context_dim,), optional
            The context (omit for context-free tasks).
        rng : Generator, int or None
            Randomness of the episode (initial state, noise). Same seed ⇒ same trajectory.

        Returns
        -------
        Trajectory
            With ``failed=True`` and a message if the physics produced non-finite values;
            the failure is reported through a ``RuntimeWarning``, never raised.
        """
        omega = self.check_omega(omega)
        s = self.check_context(context)
        rng = as_generator(rng)
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            try:
                traj = self._simulate(omega, s, rng)
            except (SimulationFailure, FloatingPointError, OverflowError) as exc:
                return self._failed(omega, s, f"{type(exc).__name__}: {exc}")
        if not (np.all(np.isfinite(traj.states)) and np.all(np.isfinite(traj.controls))) or not all(
            np.all(np.isfinite(v)) for v in traj.signals.values()
        ):
            return self._failed(omega, s, "non-finite values in the simulated trajectory")
        return traj

    def _failed(self, omega: np.ndarray, context: np.ndarray, message: str) -> Trajectory:
        warnings.warn(
            f"{self.name}: rollout failed ({message}); reward set to {self.worst_reward:g}",
            RuntimeWarning,
            stacklevel=3,
        )
        return Trajectory(
            np.zeros(1),
            np.zeros((1, 1)),
            np.zeros((1, 1)),
            info={"omega": omega.tolist(), "context": context.tolist()},
            failed=True,
            message=message,
        )

    def reward(self, trajectory: Trajectory, context=None) -> float:
        """Reward R(τ, s) of a trajectory in a context (a pure function of both).

        A failed trajectory gets :attr:`worst_reward`.
        """
        s = self.check_context(context)
        if trajectory.failed:
            return float(self.worst_reward)
        r = float(self._reward(trajectory, s))
        if not np.isfinite(r):
            warnings.warn(
                f"{self.name}: non-finite reward; set to {self.worst_reward:g}",
                RuntimeWarning,
                stacklevel=2,
            )
            return float(self.worst_reward)
        return r

    def evaluate(self, omega, context=None, rng=None) -> tuple[float, Trajectory]:
        """Roll out and score in one call: returns (R(τ, s), τ)."""
        traj = self.rollout(omega, context, rng)
        return self.reward(traj, context), traj

    # ----------------------------------------------------------------- subclass hooks
    @abstractmethod
    def _simulate(
        self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator
    ) -> Trajectory:
        """Simulate one episode (inputs already validated)."""

    @abstractmethod
    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        """Score a (non-failed) trajectory in a (validated) context."""

    @abstractmethod
    def initial_policy(self):
        """The thesis's initial upper-level policy π(ω|s) (imitation / thesis setting)."""

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, context_dim={self.context_dim}, "
            f"parameter_dim={self.parameter_dim})"
        )
