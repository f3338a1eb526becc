"""The Task contract: context distribution μ(s), parameter space, rollout, reward.

A task samples contexts, runs one episode for parameters ω (:meth:`Task.rollout`) and scores
a trajectory in a context; rewards are pure functions of both, so a context-independent
trajectory can be re-scored in other contexts (Sec. 3.4). For model-based search (Chs. 4–5)
a task names what a forward model learns (:meth:`Task.model_signals`), where model rollouts
start (:meth:`Task.initial_states`), its batched torch policy (:meth:`Task.controller`) and
its batched reward (:meth:`Task.reward_batch`).
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
    partial : Trajectory, optional
        The episode before the failure (≥ 2 time stamps), kept for model learning (Sec. 4.3.1).
    """

    def __init__(self, message: str, partial: Trajectory | None = None):
        super().__init__(message)
        if partial is not None and (not isinstance(partial, Trajectory) or partial.n_steps < 2):
            raise ValueError(
                f"partial: expected a Trajectory with at least two time stamps, got {partial!r}"
            )
        self.partial = partial


def state_transitions(trajectory: Trajectory, state_dim: int, control_dim: int):
    """(x_t, u_t, x_{t+1}) = states[:−1], controls[:−1], states[1:]; ValueError for a failed
    trajectory without states or shapes other than (T, state_dim), (T, control_dim)."""
    if not trajectory.has_transitions:
        raise ValueError(f"trajectory: a failed rollout without states ({trajectory.message})")
    states = check_array(trajectory.states, "trajectory.states", shape=(None, state_dim))
    controls = check_array(
        trajectory.controls, "trajectory.controls", shape=(states.shape[0], control_dim)
    )
    return states[:-1], controls[:-1], states[1:]


@dataclass(frozen=True)
class ModelSignals:
    """Names (in column order) of what a forward model learns: ``state`` x, ``control`` u,
    and the ``signals`` :meth:`Task.reward_batch` reads besides them."""

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
        return len(self.state)

    @property
    def control_dim(self) -> int:
        return len(self.control)


class Task(ABC):
    """Base class of every task: subclasses set the attributes and implement :meth:`_simulate`
    and :meth:`reward_batch` (with :meth:`reward_signals`), or override :meth:`_reward`.

    Attributes
    ----------
    name : str
    context_dim, parameter_dim : int
        Dimensions of s (0: context-free) and of ω.
    context_low, context_high : ndarray, shape (context_dim,)
        Bounds of the uniform μ(s).
    worst_reward : float
        Reward of a failed rollout.
    trajectory_depends_on_context, supports_model_rollout : bool
        Whether the rollout depends on s; whether model rollouts exist (else
        :attr:`no_model_rollout_reason` says why).
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

    def sample_context(self, rng=None, n: int | None = None) -> np.ndarray:
        """Draw contexts s ~ μ(s): shape (context_dim,) for ``n=None``, else (n, context_dim)."""
        rng = as_generator(rng)
        size = (self.context_dim,) if n is None else (check_count(n, "n", 0), self.context_dim)
        low, high = np.asarray(self.context_low), np.asarray(self.context_high)
        return low + (high - low) * rng.random(size)

    def check_context(self, context, name: str = "context") -> np.ndarray:
        """Validate one context: shape (context_dim,), finite, inside the task's range."""
        if context is None:
            if self.context_dim == 0:
                return np.zeros(0)
            raise ValueError(f"{name}: expected shape ({self.context_dim},), got None")
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

    def rollout(self, omega, context=None, rng=None) -> Trajectory:
        """Run one episode with ω (parameter_dim,) in context s (None if context-free).

        Same ``rng`` seed ⇒ same trajectory. A diverged episode returns a ``failed`` trajectory
        (and a ``RuntimeWarning``) keeping :class:`SimulationFailure`'s ``partial`` states.
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
        arrays = (traj.states, traj.controls, *traj.signals.values())
        if not all(np.all(np.isfinite(a)) for a in arrays):
            return self._failed(omega, s, "non-finite values in the simulated trajectory")
        return traj

    def _failed(self, omega, context, message: str, partial=None) -> Trajectory:
        warnings.warn(
            f"{self.name}: rollout failed ({message}); reward set to {self.worst_reward:g}",
            RuntimeWarning,
            stacklevel=3,
        )
        info = {"omega": omega.tolist(), "context": context.tolist()}
        if partial is None:
            one = (np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)))
            return Trajectory(*one, info=info, failed=True, message=message)
        return Trajectory(
            partial.times,
            partial.states,
            partial.controls,
            signals=partial.signals,
            info={**partial.info, **info},
            failed=True,
            message=message,
        )

    def reward(self, trajectory: Trajectory, context=None) -> float:
        """Reward R(τ, s) of a trajectory in a context; :attr:`worst_reward` if it failed."""
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

    def model_signals(self) -> ModelSignals:
        """The signals a forward model of this task learns (:class:`ModelSignals`)."""
        raise NotImplementedError(f"{self.name}: the task does not name its model signals")

    def transitions(self, trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Model training data (x_t, u_t, x_{t+1}), T − 1 rows each (:func:`state_transitions`)."""
        self._require_model_rollout("transitions")
        sig = self.model_signals()
        return state_transitions(trajectory, sig.state_dim, sig.control_dim)

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """``n`` ≥ 1 draws of the start state x_0 ~ p(x_0; s) of model rollouts (Eq. 4.3),
        shape (n, state_dim)."""
        raise NotImplementedError(f"{self.name}: the task defines no start distribution")

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """The lower-level policy of B (ω, s) pairs as a batched torch callable.

        ``policy(t, x, pair) -> u``: control step ``t``, ``x`` (n, state_dim), ``pair``
        LongTensor (n,) in [0, B), ``u`` (n, control_dim) on ``device`` in ``dtype`` (default
        float64). ``omegas`` (B, parameter_dim), ``contexts`` (B, context_dim).
        """
        self._require_model_rollout("controller")
        raise NotImplementedError(f"{self.name}: controller is not implemented")

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """Rewards R(τ_b, s_b) (B,) of simulated or predicted ``states`` (B, T, state_dim),
        ``controls`` (B, T, control_dim), :meth:`reward_signals` ``signals`` batch first and
        ``contexts`` (B, context_dim); :meth:`reward` calls it on a batch of one."""
        raise NotImplementedError(f"{self.name}: reward_batch is not implemented")

    def failed_batch(self, states) -> np.ndarray:
        """Which (predicted) state paths (B, T + 1, state_dim) the simulator would stop as
        failed, (B,); they score :attr:`worst_reward`. Default: none."""
        states = check_array(states, "states", ndim=3, finite=False)
        return np.zeros(states.shape[0], dtype=bool)

    def reward_signals(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """The named signals :meth:`reward_batch` reads from one trajectory (default none)."""
        return {}

    def scene_model(self):
        """The task's compiled ``mujoco.MjModel`` for the viewer, or None."""
        return None

    def _require_model_rollout(self, what: str) -> None:
        if not self.supports_model_rollout:
            raise NotImplementedError(
                f"{self.name}: {what} is not available: {self.no_model_rollout_reason}"
            )

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        signals = {k: np.asarray(v)[None] for k, v in self.reward_signals(trajectory).items()}
        r = self.reward_batch(
            trajectory.states[None], trajectory.controls[None], signals, context[None]
        )
        return float(r[0])

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
