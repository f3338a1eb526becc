"""Your own skill as a :class:`~skillkit.tasks.base.Task`, built from a few functions.

* :class:`FunctionTask` (model-free): a black box ``rollout(omega, context, rng) -> float``;
  GPREPS runs on it with a :class:`~skillkit.search.gpreps.DirectRewardModel`.
* :class:`TrajectoryTask` (model-based): ``rollout(omega, context, rng) -> (states,
  controls)`` scored by a batched ``reward(states, controls, contexts)``; with a batched
  ``controller`` and ``initial_states`` it supports step-based forward models
  (:class:`~skillkit.search.gpreps.TrajectoryRewardModel`, Eqs. 4.1–4.3).

μ(s) is uniform on ``[context_low, context_high]`` unless ``context_sampler(rng, n)`` is given;
without bounds the task is context-free (``context=None``). A rollout that raises or returns
non-finite values is a *failed* trajectory (``worst_reward``, a ``RuntimeWarning``); a wrong
shape or type raises ``ValueError``. Checkpoints pickle the task: use module-level functions.

Example (model-free)::

    def rollout(omega, context, rng):
        return -float(np.sum((omega - 2 * context) ** 2)) + 0.01 * rng.standard_normal()

    task = FunctionTask(rollout, parameter_dim=2, context_low=[-1, -1], context_high=[1, 1])
    result = learn(task, ContextualREPS(task.initial_policy(), epsilon=0.5), 20, 30, rng=0)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.tasks.base import ModelSignals, SimulationFailure, Task
from skillkit.trajectory import Trajectory

__all__ = ["FunctionTask", "TrajectoryTask"]


def _check_callable(fn, name: str, required: bool = True):
    if fn is None and not required:
        return None
    if not callable(fn):
        raise ValueError(f"{name}: expected a callable, got {type(fn).__name__}")
    return fn


class FunctionTask(Task):
    """A model-free task from a rollout function that returns the reward (a black box).

    Parameters
    ----------
    rollout : callable
        ``rollout(omega, context, rng) -> float``: one episode with ω (parameter_dim,) in
        context s (context_dim,) or None, random only through ``rng``; returns R(τ, s).
    parameter_dim : int
    context_low, context_high : array_like, shape (context_dim,), optional
        Context bounds (omit both for a context-free task).
    context_sampler : callable, optional
        ``context_sampler(rng, n) -> (n, context_dim)`` inside the bounds.
    initial_mean : array_like, shape (d,), optional
        Mean of π₀(ω|s) = N(initial_mean, diag(initial_std²)) (default zeros, zero gain).
    initial_std : float or array_like, shape (d,)
        Its standard deviations.
    name : str
    worst_reward : float

    Notes
    -----
    The trajectory keeps only ``info["reward"]`` and its context; other contexts are refused.
    """

    def __init__(
        self,
        rollout: Callable[..., Any],
        parameter_dim: int,
        *,
        context_low=None,
        context_high=None,
        context_sampler: Callable[..., Any] | None = None,
        initial_mean=None,
        initial_std=1.0,
        name: str = "function-task",
        worst_reward: float = -1e6,
    ):
        self._rollout = _check_callable(rollout, "rollout")
        self.parameter_dim = check_count(parameter_dim, "parameter_dim")
        if not isinstance(name, str) or not name:
            raise ValueError(f"name: expected a non-empty str, got {name!r}")
        self.name = name
        self.worst_reward = float(check_array(worst_reward, "worst_reward", shape=()))
        if (context_low is None) != (context_high is None):
            raise ValueError("context_low, context_high: give both bounds, or neither")
        if context_low is None:
            if context_sampler is not None:
                raise ValueError("context_sampler: a contextual task needs context_low/high")
            self.context_dim = 0
            self.context_low, self.context_high = np.zeros(0), np.zeros(0)
        else:
            lo = check_array(context_low, "context_low", ndim=1)
            hi = check_array(context_high, "context_high", shape=lo.shape)
            if lo.shape[0] == 0:
                raise ValueError("context_low: expected at least one context dimension")
            if np.any(lo > hi):
                raise ValueError(f"context_high: expected ≥ context_low, got {hi} < {lo}")
            self.context_dim = int(lo.shape[0])
            self.context_low, self.context_high = lo, hi
        self._context_sampler = _check_callable(context_sampler, "context_sampler", required=False)
        d = self.parameter_dim
        mean = np.zeros(d) if initial_mean is None else initial_mean
        self._initial_mean = check_array(mean, "initial_mean", shape=(d,))
        std = np.broadcast_to(check_array(initial_std, "initial_std", ndim=(0, 1)), (d,))
        if np.any(std <= 0):
            raise ValueError(f"initial_std: expected positive numbers, got {initial_std!r}")
        self._initial_std = np.array(std)

    def sample_context(self, rng=None, n: int | None = None) -> np.ndarray:
        """Draw s ~ μ(s): uniform on the bounds, or ``context_sampler``'s (checked) draws."""
        if self._context_sampler is None:
            return super().sample_context(rng, n)
        rng = as_generator(rng)
        m = 1 if n is None else check_count(n, "n", 0)
        if m == 0:
            return np.zeros((0, self.context_dim))
        s = check_array(
            self._context_sampler(rng, m), "context_sampler", shape=(m, self.context_dim)
        )
        for row in s:
            self.check_context(row, "context_sampler")
        return s[0] if n is None else s

    def _call_rollout(self, omega: np.ndarray, context: np.ndarray, rng) -> Any:
        try:
            return self._rollout(omega.copy(), context.copy() if self.context_dim else None, rng)
        except Exception as exc:
            raise SimulationFailure(f"rollout raised {type(exc).__name__}: {exc}") from exc

    def _simulate(self, omega, context, rng) -> Trajectory:
        out = self._call_rollout(omega, context, rng)
        if isinstance(out, (tuple, list, Trajectory)) or np.ndim(out) != 0:
            raise ValueError(
                f"rollout: expected a scalar reward, got {type(out).__name__} {np.shape(out)}; "
                "a rollout returning (states, controls) makes a TrajectoryTask"
            )
        kind = np.asarray(out).dtype.kind if isinstance(out, (np.ndarray, np.generic)) else ""
        try:
            if isinstance(out, (str, bytes, bool, complex)) or kind in ("b", "c", "U", "S", "O"):
                raise TypeError
            r = float(out)
        except (TypeError, ValueError):
            fn = getattr(self._rollout, "__qualname__", None) or repr(self._rollout)
            raise ValueError(
                f"rollout ({fn}): expected a real reward (an int, a float or a numpy real "
                f"scalar), got {type(out).__name__} {out!r}"
            ) from None
        if not np.isfinite(r):
            raise SimulationFailure(f"rollout returned a non-finite reward ({r})")
        empty = (np.zeros(1), np.zeros((1, 0)), np.zeros((1, 0)))
        return Trajectory(*empty, info={"reward": r, "context": context.tolist()})

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        if "reward" not in trajectory.info or "context" not in trajectory.info:
            raise ValueError(f"trajectory: not a rollout of {self.name!r} (no reward recorded)")
        if not np.array_equal(np.asarray(trajectory.info["context"], dtype=float), context):
            raise ValueError(
                f"context: a black-box rollout of {self.name!r} has a reward only in the context "
                f"it ran in ({trajectory.info['context']}), not in {context.tolist()}"
            )
        return float(trajectory.info["reward"])

    def initial_policy(self) -> LinearGaussianPolicy:
        """π₀(ω|s) = N(initial_mean, diag(initial_std²)), zero gain on the context."""
        cov = np.diag(self._initial_std**2)
        if self.context_dim == 0:
            return GaussianPolicy(self._initial_mean.copy(), cov)
        return LinearGaussianPolicy(self._initial_mean.copy(), cov, context_dim=self.context_dim)


class TrajectoryTask(FunctionTask):
    """A task from a rollout function that returns the trajectory, and a reward on trajectories.

    Parameters
    ----------
    rollout : callable
        ``rollout(omega, context, rng) -> (states, controls)``, (T, state_dim) and (T,
        control_dim); the controls should be ``controller``'s (:meth:`controller_mismatch`).
    reward : callable
        ``reward(states, controls, contexts) -> rewards``, batched numpy: (B, T, state_dim),
        (B, T, control_dim), (B, context_dim) → (B,), for real and predicted trajectories.
    parameter_dim, state_dim, control_dim : int
    controller : callable, optional
        ``controller(t, x, omegas, contexts) -> u`` on torch Tensors (n, ·), u (n, control_dim).
    initial_states : callable, optional
        ``initial_states(context, n, rng) -> (n, state_dim)``, draws of x_0 ~ p(x_0; s).
    dt : float
        Time between states.
    trajectory_depends_on_context : bool
        False if the context only enters the reward (Sec. 3.4).
    name : str
    **kwargs
        ``context_low``, ``context_high``, ``context_sampler``, ``initial_mean``,
        ``initial_std``, ``worst_reward`` as for :class:`FunctionTask`.
    """

    def __init__(
        self,
        rollout: Callable[..., Any],
        reward: Callable[..., Any],
        parameter_dim: int,
        state_dim: int,
        control_dim: int,
        *,
        controller: Callable[..., Any] | None = None,
        initial_states: Callable[..., Any] | None = None,
        dt: float = 1.0,
        trajectory_depends_on_context: bool = True,
        name: str = "trajectory-task",
        **kwargs,
    ):
        super().__init__(rollout, parameter_dim, name=name, **kwargs)
        self._reward_fn = _check_callable(reward, "reward")
        self.state_dim = check_count(state_dim, "state_dim")
        self.control_dim = check_count(control_dim, "control_dim", 0)
        self._controller = _check_callable(controller, "controller", required=False)
        self._initial_states = _check_callable(initial_states, "initial_states", required=False)
        self.dt = check_positive(dt, "dt")
        self.trajectory_depends_on_context = bool(trajectory_depends_on_context)
        named = (("controller", controller), ("initial_states", initial_states))
        missing = " and ".join(n for n, f in named if f is None)
        self.supports_model_rollout = not missing
        self.no_model_rollout_reason = f"the task was built without {missing}" if missing else ""

    def _simulate(self, omega, context, rng) -> Trajectory:
        out = self._call_rollout(omega, context, rng)
        if isinstance(out, Trajectory) or not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ValueError(f"rollout: expected (states, controls), got {type(out).__name__}")
        states = check_array(out[0], "rollout (states)", shape=(None, self.state_dim), finite=False)
        if states.shape[0] == 0:
            raise ValueError("rollout (states): expected at least one state, got shape (0, ...)")
        controls = check_array(
            out[1], "rollout (controls)", shape=(states.shape[0], self.control_dim), finite=False
        )
        times = self.dt * np.arange(states.shape[0])
        return Trajectory(times, states, controls, info={"context": context.tolist()})

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """R(τ_b, s_b) through ``reward`` on float64 numpy arrays; ``ValueError`` unless (B,)."""
        x = np.asarray(states, dtype=np.float64)
        u = np.asarray(controls, dtype=np.float64)
        s = np.asarray(contexts, dtype=np.float64).reshape(x.shape[0], self.context_dim)
        r = self._reward_fn(x, u, s)
        return check_array(r, "reward", shape=(x.shape[0],), finite=False)

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        return Task._reward(self, trajectory, context)

    def model_signals(self) -> ModelSignals:
        """x = (x0, x1, …), u = (u0, u1, …)."""
        return ModelSignals(
            state=tuple(f"x{i}" for i in range(self.state_dim)),
            control=tuple(f"u{j}" for j in range(self.control_dim)),
        )

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """``n`` draws of x_0 ~ p(x_0; s) from ``initial_states``, shape (n, state_dim)."""
        self._require_model_rollout("initial_states")
        s = self.check_context(context)
        n = check_count(n, "n")
        x0 = self._initial_states(s if self.context_dim else None, n, as_generator(rng))
        return check_array(x0, "initial_states", shape=(n, self.state_dim))

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """``controller`` for B (ω, s) pairs as ``policy(t, x, pair) -> u``."""
        import torch

        self._require_model_rollout("controller")
        w = check_array(omegas, "omegas", shape=(None, self.parameter_dim))
        if self.context_dim == 0 and contexts is None:
            contexts = np.zeros((w.shape[0], 0))
        s = check_array(contexts, "contexts", shape=(w.shape[0], self.context_dim))
        dtype = torch.float64 if dtype is None else dtype
        w_t = torch.as_tensor(w, dtype=dtype, device=device)
        s_t = torch.as_tensor(s, dtype=dtype, device=device)
        fn, n_u = self._controller, self.control_dim

        def policy(t: int, x, pair):
            u = torch.as_tensor(fn(t, x, w_t[pair], s_t[pair]), dtype=x.dtype, device=x.device)
            if tuple(u.shape) != (x.shape[0], n_u):
                raise ValueError(
                    f"controller: expected shape ({x.shape[0]}, {n_u}), got {tuple(u.shape)}"
                )
            return u

        return policy

    def controller_mismatch(self, omega, context, trajectory: Trajectory) -> float:
        """max |u_t − controller(t, x_t)| over x_0 … x_{T−2} (zero for ``rollout``'s policy)."""
        import torch

        policy = self.controller(
            self.check_omega(omega)[None],
            None if self.context_dim == 0 else self.check_context(context)[None],
        )
        x = torch.as_tensor(trajectory.states, dtype=torch.float64)
        pair = torch.zeros(1, dtype=torch.long)
        got = np.stack(
            [policy(t, x[t : t + 1], pair)[0].numpy() for t in range(trajectory.n_steps - 1)]
        )
        return float(np.max(np.abs(got - trajectory.controls[:-1]), initial=0.0))
