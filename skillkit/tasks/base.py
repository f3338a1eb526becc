"""The Task contract (DESIGN.md): context distribution, parameter space, rollout, reward.

A task is a small class in the style of dm_control's suite: it knows its context
distribution μ(s) (:meth:`Task.sample_context`), the dimension of the lower-level policy
parameters ω, a sensible initial upper-level policy, how to run one episode
(:meth:`Task.rollout`) and how to score a trajectory in a context (:meth:`Task.reward`).
Rewards are pure functions of the trajectory and the context, so a trajectory can be
re-scored in other contexts (the *extra context* trick of Sec. 3.4) whenever the trajectory
does not depend on the context (``trajectory_depends_on_context`` is False).

For model-based search (Ch. 4–5) a task also states what a forward model learns
(:meth:`Task.model_signals`, :meth:`Task.transitions`), where model rollouts start
(:meth:`Task.initial_states`), the very lower-level policy the simulator runs as a batched
torch callable for :func:`~skillkit.models.sampling.sample_trajectories`
(:meth:`Task.controller`), and the batched reward on (predicted) trajectories
(:meth:`Task.reward_batch`), which is the single definition :meth:`Task.reward` goes through.
A task that cannot support a part says so: :attr:`Task.supports_model_rollout` is False and
the method raises ``NotImplementedError`` with the reason.
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from skillkit._validation import as_generator, check_array, check_count  # noqa: F401  (re-exported for the task modules)
from skillkit.trajectory import Trajectory


class SimulationFailure(RuntimeError):
    """Raised inside a simulator when the physics produced non-finite or unstable values.

    Parameters
    ----------
    message : str
        What failed, and when.
    partial : Trajectory, optional
        The episode up to the last state before the failure (at least two time stamps, so at
        least one transition). :meth:`Task.rollout` keeps it in the failed trajectory: the
        transitions before a robot falls are real experience, which model learners such as
        PILCO and GPREPS learn (Sec. 4.3.1), while the rollout's reward stays the task's
        worst.
    """

    def __init__(self, message: str, partial: Trajectory | None = None):
        super().__init__(message)
        if partial is not None and (not isinstance(partial, Trajectory) or partial.n_steps < 2):
            raise ValueError(
                f"partial: expected a Trajectory with at least two time stamps, got {partial!r}"
            )
        self.partial = partial


def state_transitions(
    trajectory: Trajectory, state_dim: int, control_dim: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x_t, u_t, x_{t+1}) of a trajectory: states[:−1], controls[:−1], states[1:].

    A failed trajectory gives the transitions simulated before its failure when it kept them
    (:attr:`~skillkit.trajectory.Trajectory.has_transitions`). Raises a ValueError for a
    failed trajectory that kept none or states/controls not of shapes (T, state_dim) and
    (T, control_dim).
    """
    if not trajectory.has_transitions:
        raise ValueError(
            "trajectory: a failed trajectory that kept no states has no transitions "
            f"({trajectory.message})"
        )
    states = check_array(trajectory.states, "trajectory.states", shape=(None, state_dim))
    controls = check_array(
        trajectory.controls, "trajectory.controls", shape=(states.shape[0], control_dim)
    )
    return states[:-1], controls[:-1], states[1:]


@dataclass(frozen=True)
class ModelSignals:
    """What a forward model of a task learns (names, in array-column order).

    Attributes
    ----------
    state : tuple of str
        Names of the model state x (the columns of :meth:`Task.transitions`'s X and of
        :meth:`Task.initial_states`).
    control : tuple of str
        Names of the control u (the columns of U; empty when the model has no control input).
    signals : tuple of str
        Named trajectory signals :meth:`Task.reward_batch` reads besides states and controls.
    """

    state: tuple[str, ...]
    control: tuple[str, ...] = ()
    signals: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("state", "control", "signals"):
            value = getattr(self, name)
            if not isinstance(value, tuple) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{name}: expected a tuple of str, got {value!r}")
            if len(set(value)) != len(value):
                raise ValueError(f"{name}: names must be unique, got {value!r}")
        if not self.state:
            raise ValueError("state: expected at least one state name")

    @property
    def state_dim(self) -> int:
        """Dimension of x."""
        return len(self.state)

    @property
    def control_dim(self) -> int:
        """Dimension of u."""
        return len(self.control)


class Task(ABC):
    """Base class of every task.

    Subclasses set the class attributes and implement :meth:`_simulate` and
    :meth:`reward_batch` (with :meth:`reward_signals`), or override :meth:`_reward`.

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
    supports_model_rollout : bool
        Whether :meth:`transitions` and :meth:`controller` exist, i.e. a step-based forward
        model of the simulated state can be learned and rolled out under the task's own
        lower-level policy. False for tasks modelled by decomposed event models (hockey,
        table tennis); :attr:`no_model_rollout_reason` then says why.
    """

    name: str = "task"
    context_dim: int = 0
    parameter_dim: int = 0
    context_low: np.ndarray = np.zeros(0)
    context_high: np.ndarray = np.zeros(0)
    context_names: tuple[str, ...] = ()
    worst_reward: float = -1e6
    trajectory_depends_on_context: bool = True
    supports_model_rollout: bool = False
    no_model_rollout_reason: str = "this task defines no step-based forward model"

    # ----------------------------------------------------------------- contexts
    def sample_context(self, rng=None, n: int | None = None) -> np.ndarray:
        """Draw contexts s ~ μ(s).

        Parameters
        ----------
        rng : Generator, int or None
            Randomness.
        n : int, optional
            Number of contexts (an integer ≥ 0). ``None`` returns one context of shape
            (context_dim,), otherwise shape (n, context_dim).
        """
        rng = as_generator(rng)
        size = (self.context_dim,) if n is None else (check_count(n, "n", 0), self.context_dim)
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
            the failure is reported through a ``RuntimeWarning``, never raised. A failed
            trajectory keeps the states simulated before the failure where the task records
            them (:class:`SimulationFailure`'s ``partial``), else one placeholder row.
        """
        omega = self.check_omega(omega)
        s = self.check_context(context)
        rng = as_generator(rng)
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            try:
                traj = self._simulate(omega, s, rng)
            except (SimulationFailure, FloatingPointError, OverflowError) as exc:
                partial = getattr(exc, "partial", None)
                return self._failed(omega, s, f"{type(exc).__name__}: {exc}", partial)
        if not (np.all(np.isfinite(traj.states)) and np.all(np.isfinite(traj.controls))) or not all(
            np.all(np.isfinite(v)) for v in traj.signals.values()
        ):
            return self._failed(omega, s, "non-finite values in the simulated trajectory")
        return traj

    def _failed(
        self,
        omega: np.ndarray,
        context: np.ndarray,
        message: str,
        partial: Trajectory | None = None,
    ) -> Trajectory:
        warnings.warn(
            f"{self.name}: rollout failed ({message}); reward set to {self.worst_reward:g}",
            RuntimeWarning,
            stacklevel=3,
        )
        info = {"omega": omega.tolist(), "context": context.tolist()}
        if partial is not None:
            return Trajectory(
                partial.times,
                partial.states,
                partial.controls,
                signals=partial.signals,
                info={**partial.info, **info},
                failed=True,
                message=message,
            )
        return Trajectory(
            np.zeros(1),
            np.zeros((1, 1)),
            np.zeros((1, 1)),
            info=info,
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

    # ----------------------------------------------------------------- model-based search
    def model_signals(self) -> ModelSignals:
        """The signals a forward model of this task learns (:class:`ModelSignals`)."""
        raise NotImplementedError(f"{self.name}: the task does not name its model signals")

    def transitions(self, trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The model training data of one trajectory: (x_t, u_t, x_{t+1}) at the control rate.

        The default takes the simulator's own states and controls,
        X = states[:−1], U = controls[:−1], X' = states[1:].

        Parameters
        ----------
        trajectory : Trajectory
            A trajectory of this task: a working one, or a failed one that kept the states
            before its failure (:attr:`~skillkit.trajectory.Trajectory.has_transitions`).

        Returns
        -------
        X : ndarray, shape (T−1, state_dim)
        U : ndarray, shape (T−1, control_dim)
        X_next : ndarray, shape (T−1, state_dim)

        Raises
        ------
        NotImplementedError
            If the task does not support step-based models (:attr:`supports_model_rollout`).
        ValueError
            For a failed trajectory without states or one of the wrong shape.
        """
        self._require_model_rollout("transitions")
        sig = self.model_signals()
        return state_transitions(trajectory, sig.state_dim, sig.control_dim)

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """``n`` draws of the start state x_0 ~ p(x_0; s) of model rollouts (Eq. 4.3).

        Parameters
        ----------
        context : array_like, shape (context_dim,) or None
        n : int
            Number of draws, ≥ 1.
        rng : Generator, int or None
            Randomness (unused by tasks with a deterministic start).

        Returns
        -------
        ndarray, shape (n, state_dim)
        """
        raise NotImplementedError(f"{self.name}: the task defines no start distribution")

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """The lower-level policy of B (ω, s) pairs as one batched torch callable.

        Exactly the controller the simulator runs, evaluated on (predicted) states, in the
        form :func:`~skillkit.models.sampling.sample_trajectories` takes:
        ``policy(t, x, pair) -> u`` with ``t`` the control step (int), ``x`` Tensor
        (n, state_dim), ``pair`` LongTensor (n,) in [0, B), ``u`` Tensor (n, control_dim)
        on the device and dtype of the policy.

        Parameters
        ----------
        omegas : array_like, shape (B, parameter_dim)
        contexts : array_like, shape (B, context_dim), optional
        device : str or torch.device, optional
            Where the policy's tensors live (default: the CPU).
        dtype : torch.dtype, optional
            Default ``torch.float64``.

        Raises
        ------
        NotImplementedError
            If the task does not support step-based models (:attr:`supports_model_rollout`).
        """
        self._require_model_rollout("controller")
        raise NotImplementedError(f"{self.name}: controller is not implemented")

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """Rewards R(τ_b, s_b) of a batch of (simulated or predicted) trajectories.

        The one definition of the task's reward: :meth:`reward` calls it on a batch of one.

        Parameters
        ----------
        states : array_like or Tensor, shape (B, T, state_dim)
        controls : array_like or Tensor, shape (B, T, control_dim)
        signals : dict of str to array_like, each (B, ...)
            The named signals of :meth:`reward_signals` (batch first).
        contexts : array_like, shape (B, context_dim)

        Returns
        -------
        ndarray or Tensor, shape (B,)
        """
        raise NotImplementedError(f"{self.name}: reward_batch is not implemented")

    def failed_batch(self, states) -> np.ndarray:
        """Which trajectories of a batch the task's simulator would stop as failed.

        The task's divergence rule (the one its rollouts raise :class:`SimulationFailure`
        by) applied to whole state paths, so that a predicted path is scored as a real rollout
        through the same states is: with :attr:`worst_reward`
        (:func:`~skillkit.search.model_rollouts.worst_if_failed`). Default: the task stops no
        run for its states (all False).

        Parameters
        ----------
        states : array_like, shape (B, T + 1, state_dim)

        Returns
        -------
        ndarray of bool, shape (B,)
        """
        states = check_array(states, "states", ndim=3, finite=False)
        return np.zeros(states.shape[0], dtype=bool)

    def reward_signals(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """The named signals :meth:`reward_batch` reads from one trajectory (unbatched).

        Default: none.
        """
        return {}

    def scene_model(self):
        """What the viewer draws: the task's compiled ``mujoco.MjModel``, or None when the
        task has no MuJoCo model (the viewer then draws a dedicated scene)."""
        return None

    def _require_model_rollout(self, what: str) -> None:
        if not self.supports_model_rollout:
            raise NotImplementedError(
                f"{self.name}: {what} is not available: {self.no_model_rollout_reason}"
            )

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        """R(τ, s) through :meth:`reward_batch` on a batch of one."""
        signals = {k: np.asarray(v)[None] for k, v in self.reward_signals(trajectory).items()}
        r = self.reward_batch(
            trajectory.states[None], trajectory.controls[None], signals, context[None]
        )
        return float(r[0])

    # ----------------------------------------------------------------- subclass hooks
    @abstractmethod
    def _simulate(
        self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator
    ) -> Trajectory:
        """Simulate one episode (inputs already validated)."""

    @abstractmethod
    def initial_policy(self):
        """The thesis's initial upper-level policy π(ω|s) (imitation / thesis setting)."""

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, context_dim={self.context_dim}, "
            f"parameter_dim={self.parameter_dim})"
        )
