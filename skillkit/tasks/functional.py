r"""Your own skill as a :class:`~skillkit.tasks.base.Task`, built from a few functions.

Two small classes turn your simulator (or your robot) into a task that
:func:`~skillkit.search.loop.learn`, :class:`~skillkit.search.reps.ContextualREPS`,
:class:`~skillkit.search.crkr.CrKR`, :class:`~skillkit.search.rwr.RWR`,
:class:`~skillkit.search.gpreps.GPREPS` and :class:`~skillkit.search.cmaes.CMAES` accept:

* :class:`FunctionTask` — **model-free**, a black box that returns only the reward:
  ``rollout(omega, context, rng) -> float``. GPREPS runs on it with a
  :class:`~skillkit.search.gpreps.DirectRewardModel` (a GP from [s, ω] to R).
* :class:`TrajectoryTask` — **model-based**, a simulator that returns the trajectory:
  ``rollout(omega, context, rng) -> (states, controls)``, scored by your batched
  ``reward(states, controls, contexts)``. With a batched ``controller`` (the lower-level
  policy your rollout runs) and ``initial_states`` (where rollouts start) it also supports
  step-based forward models, i.e. GPREPS with a
  :class:`~skillkit.search.gpreps.TrajectoryRewardModel` (Eqs. 4.1–4.3).

The context distribution μ(s) is uniform on ``[context_low, context_high]`` unless a
``context_sampler(rng, n) -> (n, context_dim)`` is given (its draws must lie in the bounds,
which :meth:`~skillkit.tasks.base.Task.check_context` enforces for every context). Without
bounds the task is context-free and ``rollout`` gets ``context=None``.

What goes wrong, and what happens then:

* **Your rollout raises** (any ``Exception``: a simulator error, a lost connection to the
  robot) or **returns a non-finite reward or trajectory**: the rollout is recorded as a
  *failed* trajectory whose ``message`` holds the error (``"rollout raised RuntimeError:
  …"``), scored :attr:`~skillkit.tasks.base.Task.worst_reward`, reported through a
  ``RuntimeWarning``; the run goes on (the same path as a simulator failure in every
  thesis task, :meth:`~skillkit.tasks.base.Task.rollout`). A NaN reward is such a failure
  too, not an exception: a black box cannot tell a blown-up simulation from a bug, and one
  bad episode must not end a run on a robot.
* **Your functions return the wrong thing** (a reward that is not a scalar, states or controls
  of the wrong shape, a reward batch not of shape (B,), a controller output not of shape
  (n, control_dim), contexts outside the bounds): ``ValueError`` naming the function
  (``rollout``, ``reward``, ``controller``, ``initial_states``, ``context_sampler``). These
  are bugs, the same at every call, so the run stops at the first one.

Checkpoints (:class:`~skillkit.trial.TrialContext`) pickle the algorithm, and a model-based
algorithm holds the task: use module-level functions (or ``functools.partial`` of them), not
lambdas, where a run is checkpointed.

These classes are not in the task registry (they are yours, not the thesis's); they are
exported by :mod:`skillkit.tasks`.

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


def _function_name(fn) -> str:
    """The name of a user function for messages: its qualified name, else its repr."""
    return str(getattr(fn, "__qualname__", None) or repr(fn))


class FunctionTask(Task):
    """A model-free task from a rollout function that returns the reward (a black box).

    Parameters
    ----------
    rollout : callable
        ``rollout(omega, context, rng) -> float``: runs one episode with lower-level parameters
        ω (ndarray (parameter_dim,)) in context s (ndarray (context_dim,), ``None`` for a
        context-free task), with randomness from ``rng`` (a numpy Generator; use it for every
        random draw and same seed ⇒ same reward), and returns the reward R(τ, s), a real
        number (an int, a float or a numpy real scalar; a str, a bool or a complex number is
        refused with ``ValueError``). It may raise: the rollout is then recorded as failed
        (module notes).
    parameter_dim : int
        Dimension d ≥ 1 of ω.
    context_low, context_high : array_like, shape (context_dim,), optional
        Bounds of the context; μ(s) is uniform on them unless ``context_sampler`` is given.
        Omit both for a context-free task.
    context_sampler : callable, optional
        ``context_sampler(rng, n) -> (n, context_dim)``: draws s ~ μ(s) (inside the bounds).
    initial_mean : array_like, shape (d,), optional
        Mean of the initial upper-level policy π₀(ω|s) = N(initial_mean, diag(initial_std²))
        (default zeros; the gain on the context starts at zero).
    initial_std : float or array_like, shape (d,)
        Its standard deviations (> 0), the initial exploration (default 1).
    name : str
        The task's name (in messages and reprs).
    worst_reward : float
        Reward of a failed rollout: below any reward a working rollout gets.

    Notes
    -----
    The trajectory of a black-box rollout is empty (no states, no controls); its reward is
    kept in ``trajectory.info["reward"]`` with the context it was earned in, and
    :meth:`~skillkit.tasks.base.Task.reward` returns it for that context only (a black box
    cannot re-score an episode in another context, so ``extra_contexts`` is refused).
    """

    trajectory_depends_on_context = True

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
        self._set_contexts(context_low, context_high, context_sampler)
        d = self.parameter_dim
        mean = np.zeros(d) if initial_mean is None else initial_mean
        self._initial_mean = check_array(mean, "initial_mean", shape=(d,))
        std = np.broadcast_to(check_array(initial_std, "initial_std", ndim=(0, 1)), (d,))
        if std.shape != (d,) or np.any(std <= 0):
            raise ValueError(
                f"initial_std: expected a positive number or shape ({d},), got {initial_std!r}"
            )
        self._initial_std = np.array(std)

    def _set_contexts(self, low, high, sampler) -> None:
        if (low is None) != (high is None):
            raise ValueError("context_low, context_high: give both bounds, or neither")
        if low is None:
            if sampler is not None:
                raise ValueError("context_sampler: a contextual task needs context_low/high")
            self.context_dim = 0
            self.context_low, self.context_high = np.zeros(0), np.zeros(0)
        else:
            lo = check_array(low, "context_low", ndim=1)
            hi = check_array(high, "context_high", shape=lo.shape)
            if lo.shape[0] == 0:
                raise ValueError("context_low: expected at least one context dimension")
            if np.any(lo > hi):
                raise ValueError(f"context_high: expected ≥ context_low, got {hi} < {lo}")
            self.context_dim = int(lo.shape[0])
            self.context_low, self.context_high = lo, hi
        self._context_sampler = _check_callable(sampler, "context_sampler", required=False)

    # ----------------------------------------------------------------- contexts
    def sample_context(self, rng=None, n: int | None = None) -> np.ndarray:
        """Draw contexts s ~ μ(s): uniform on the bounds, or ``context_sampler``'s draws
        (checked: shape (n, context_dim), finite, inside the bounds)."""
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

    # ----------------------------------------------------------------- episodes
    def _call_rollout(self, omega: np.ndarray, context: np.ndarray, rng) -> Any:
        """The user's rollout; whatever it raises becomes a :class:`SimulationFailure`, which
        :meth:`Task.rollout` records as a failed trajectory with the error's message."""
        try:
            return self._rollout(omega.copy(), context.copy() if self.context_dim else None, rng)
        except Exception as exc:
            raise SimulationFailure(f"rollout raised {type(exc).__name__}: {exc}") from exc

    def _simulate(self, omega, context, rng) -> Trajectory:
        out = self._call_rollout(omega, context, rng)
        if isinstance(out, (tuple, list, Trajectory)) or np.ndim(out) != 0:
            raise ValueError(
                f"rollout: expected a scalar reward (a float), got {type(out).__name__}"
                + (f" of shape {np.shape(out)}" if isinstance(out, np.ndarray) else "")
                + "; a rollout that returns (states, controls) makes a TrajectoryTask"
            )
        kind = np.asarray(out).dtype.kind if isinstance(out, (np.ndarray, np.generic)) else ""
        if isinstance(out, (str, bytes, bool, complex)) or kind in ("b", "c", "U", "S", "O"):
            raise ValueError(
                f"rollout ({_function_name(self._rollout)}): expected a real reward (an int, a "
                f"float or a numpy real scalar), got {type(out).__name__} {out!r}"
            )
        try:
            r = float(out)
        except (TypeError, ValueError):
            raise ValueError(
                f"rollout ({_function_name(self._rollout)}): expected a scalar reward (a float), "
                f"got {type(out).__name__}"
            ) from None
        if not np.isfinite(r):
            raise SimulationFailure(f"rollout returned a non-finite reward ({r})")
        return Trajectory(
            np.zeros(1),
            np.zeros((1, 0)),
            np.zeros((1, 0)),
            info={"reward": r, "context": context.tolist()},
        )

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

    With ``controller`` and ``initial_states`` the task supports step-based forward models
    (``supports_model_rollout``): GPREPS's :class:`~skillkit.search.gpreps.TrajectoryRewardModel`
    learns x_{t+1} from (x_t, u_t) of the real trajectories (:meth:`Task.transitions`: states
    [:−1], controls [:−1], states [1:]), starts predicted rollouts at ``initial_states``, runs
    ``controller`` on the predicted states and scores them with ``reward``.

    Parameters
    ----------
    rollout : callable
        ``rollout(omega, context, rng) -> (states, controls)``: one episode, states of shape
        (T, state_dim) (x_0 … x_{T−1}) and controls of shape (T, control_dim) (u_t applied
        from x_t; the last row is the control at the final state). It may raise (the rollout
        is then recorded as failed). For the model-based path the controls must be what
        ``controller`` computes from the states (:meth:`controller_mismatch` measures it).
    reward : callable
        ``reward(states, controls, contexts) -> rewards``: batched and numpy, states
        (B, T, state_dim), controls (B, T, control_dim), contexts (B, context_dim) (B, 0 for
        a context-free task), rewards (B,). The one definition of R(τ, s): it scores real and
        predicted trajectories alike.
    parameter_dim, state_dim : int
        Dimensions (≥ 1) of ω and of the state x.
    control_dim : int
        Dimension (≥ 0) of the control u.
    controller : callable, optional
        ``controller(t, x, omegas, contexts) -> u``: the lower-level policy, batched and in
        torch: t the step (int), x (n, state_dim), omegas (n, parameter_dim), contexts
        (n, context_dim) Tensors (row i belongs to one (ω, s) pair); returns u (n, control_dim)
        (a Tensor, or an array converted to one). Write it with Tensor operators and torch
        functions.
    initial_states : callable, optional
        ``initial_states(context, n, rng) -> (n, state_dim)``: n draws of the start state
        x_0 ~ p(x_0; s) (``context`` None for a context-free task).
    dt : float
        Time step between states (> 0; the trajectory's time stamps).
    trajectory_depends_on_context : bool
        False if the rollout ignores the context (it only enters the reward): a trajectory can
        then be re-scored in other contexts (``extra_contexts`` of :func:`learn`, Sec. 3.4).
    context_low, context_high, context_sampler, initial_mean, initial_std, name, worst_reward
        As for :class:`FunctionTask`.
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
        context_low=None,
        context_high=None,
        context_sampler: Callable[..., Any] | None = None,
        initial_mean=None,
        initial_std=1.0,
        name: str = "trajectory-task",
        worst_reward: float = -1e6,
    ):
        super().__init__(
            rollout,
            parameter_dim,
            context_low=context_low,
            context_high=context_high,
            context_sampler=context_sampler,
            initial_mean=initial_mean,
            initial_std=initial_std,
            name=name,
            worst_reward=worst_reward,
        )
        self._reward_fn = _check_callable(reward, "reward")
        self.state_dim = check_count(state_dim, "state_dim")
        self.control_dim = check_count(control_dim, "control_dim", 0)
        self._controller = _check_callable(controller, "controller", required=False)
        self._initial_states = _check_callable(initial_states, "initial_states", required=False)
        self.dt = check_positive(dt, "dt")
        self.trajectory_depends_on_context = bool(trajectory_depends_on_context)
        self.supports_model_rollout = controller is not None and initial_states is not None
        named = (("controller", controller), ("initial_states", initial_states))
        missing = [n for n, f in named if f is None]
        self.no_model_rollout_reason = (
            f"the task was built without {' and '.join(missing)}" if missing else ""
        )

    # ----------------------------------------------------------------- episodes
    def _simulate(self, omega, context, rng) -> Trajectory:
        out = self._call_rollout(omega, context, rng)
        if isinstance(out, Trajectory) or not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ValueError(
                f"rollout: expected a pair (states, controls), got {type(out).__name__}"
            )
        states = check_array(out[0], "rollout (states)", shape=(None, self.state_dim), finite=False)
        if states.shape[0] == 0:
            raise ValueError("rollout (states): expected at least one state, got shape (0, ...)")
        controls = check_array(
            out[1], "rollout (controls)", shape=(states.shape[0], self.control_dim), finite=False
        )
        return Trajectory(
            self.dt * np.arange(states.shape[0]),
            states,
            controls,
            info={"context": context.tolist()},
        )

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """R(τ_b, s_b) of B trajectories through ``reward`` (numpy in, shape (B,) out).

        Tensors (on the CPU) are converted to numpy float64 before ``reward`` sees them.
        Raises ``ValueError`` naming ``reward`` when its output is not of shape (B,).
        """
        x = np.asarray(states, dtype=np.float64)
        u = np.asarray(controls, dtype=np.float64)
        s = np.asarray(contexts, dtype=np.float64).reshape(x.shape[0], self.context_dim)
        r = self._reward_fn(x, u, s)
        return check_array(r, "reward", shape=(x.shape[0],), finite=False)

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        return Task._reward(self, trajectory, context)

    # ----------------------------------------------------------------- model-based search
    def model_signals(self) -> ModelSignals:
        """x = (x0, x1, …), u = (u0, u1, …); no other signal."""
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
        """``controller`` for B (ω, s) pairs as ``policy(t, x, pair) -> u`` (the sampler's form,
        :meth:`Task.controller`); raises ``ValueError`` naming ``controller`` when its output
        is not of shape (n, control_dim)."""
        import torch

        self._require_model_rollout("controller")
        w = check_array(omegas, "omegas", shape=(None, self.parameter_dim))
        b = w.shape[0]
        if self.context_dim == 0 or contexts is None:
            if self.context_dim:
                raise ValueError(f"contexts: expected shape ({b}, {self.context_dim}), got None")
            s = np.zeros((b, 0))
        else:
            s = check_array(contexts, "contexts", shape=(b, self.context_dim))
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
        """Largest |u_t − controller(t, x_t)| over the trajectory's states x_0 … x_{T−2}: zero
        (up to rounding) when ``controller`` is the policy ``rollout`` ran (the premise of the
        model-based path), larger with control noise or a different controller."""
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
