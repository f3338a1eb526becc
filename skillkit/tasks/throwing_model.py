"""The decomposed reward model of the ball-throwing task (Sec. 4.3.2, Fig. 4.2).

Three learned models chained as in Fig. 4.2: 1. **robot dynamics** x_{t+1} ~ p(x_{t+1} | x_t,
a_t) of x = [q, q̇] with the tracker's commanded acceleration a as control
(:meth:`~skillkit.tasks.planar.Throwing.acceleration_controller`); 2. **release** b_0 = [p, v]
from x(t_r), learned from the hand at every step, plus a Gaussian release error from the
observed releases; 3. **free flight** b_{k+1} ~ p(b_{k+1} | b_k) every ``ball_dt`` until the
ground. The task's reward scores the predicted states, torques and flight; Eq. (4.1) averages
the L rewards of each pair.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from skillkit._validation import as_generator, check_array, check_count, check_positive, check_type
from skillkit.models.gp import DTYPE, ExactGP, ForwardModel, GPRegression, check_dtype
from skillkit.models.reward import (
    Prediction,
    RewardModel,
    gp_stats,
    set_factories,
    subsample,
    usable_trajectories,
    warm_start_hypers,
    worst_if_failed,
    worst_if_nonfinite,
)
from skillkit.models.sampling import sample_trajectories, sampling_dtype
from skillkit.tasks.planar import Throwing

__all__ = ["ThrowingPrediction", "ThrowingRewardModel", "land"]


def _robot_model() -> ForwardModel:
    from skillkit.models.sparse import FITC

    return ForwardModel(FITC(n_inducing=50), target="delta")


def _release_model() -> GPRegression:
    return ExactGP()


_flight_model = _robot_model


def land(paths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stop ball paths (B, K, 2) at the ground y = 0: the first sample at or below it (after
    the release) is interpolated onto it and repeated. Returns the paths and ``landed`` (B,)."""
    paths = check_array(paths, "paths", shape=(None, None, 2))
    below = paths[:, :, 1] <= 0.0
    below[:, 0] = False  # the release point itself never counts as the landing
    landed = below.any(axis=1)
    k = np.where(landed, below.argmax(axis=1), paths.shape[1])  # K: nothing replaced
    rows = np.flatnonzero(landed)
    a, b = paths[rows, k[rows] - 1], paths[rows, k[rows]]
    frac = a[:, 1] / np.where(a[:, 1] - b[:, 1] > 0, a[:, 1] - b[:, 1], 1.0)
    point = np.zeros((paths.shape[0], 2))
    point[rows] = a + np.clip(frac, 0.0, 1.0)[:, None] * (b - a)
    point[:, 1] = 0.0
    after = np.arange(paths.shape[1])[None, :] >= k[:, None]
    return np.where(after[..., None], point[:, None, :], paths), landed


@dataclass(frozen=True)
class ThrowingPrediction(Prediction):
    """L predicted throws for each of B (ω, s) pairs: ``states`` (B, L, T, 8), ``torques``
    (B, L, T, 4), ``release`` [p, v] (B, L, 4) at t_r, the ``ball`` flight (B, L, K, 2) stopped
    at the ground (:func:`land`), ``rewards``, ``landed`` and ``failed`` (B, L)."""

    states: np.ndarray
    torques: np.ndarray
    release: np.ndarray
    ball: np.ndarray
    rewards: np.ndarray
    landed: np.ndarray
    failed: np.ndarray

    def __repr__(self) -> str:
        B, L, T, _ = self.states.shape
        r = self.expected_rewards
        return (
            f"ThrowingPrediction(pairs={B}, trajectories={L}, steps={T}, "
            f"flight_samples={self.ball.shape[2]}, expected_reward={r.min():.4g}…{r.max():.4g}, "
            f"not_landed={int((~self.landed).sum())})"
        )


class ThrowingRewardModel(RewardModel):
    """Decomposed GPREPS reward model of :class:`~skillkit.tasks.planar.Throwing` (Fig. 4.2).

    Parameters
    ----------
    task : Throwing
    make_robot_model, make_release_model, make_flight_model : callable, optional
        Module-level factories: forward models of x and of the ball (default FITC, 50
        inducing points), the regression x → [p, v] (default ``ExactGP()``).
    max_robot_points, max_release_points, max_flight_points : int
        Each GP is fitted on at most this many random points.
    flight_time : float
        Seconds of predicted flight.
    warm_start : bool
        Start each hyper-parameter optimisation at the previous values.
    device : str or torch.device, optional
        Where trajectories are sampled.
    dtype : torch.float64 (default), torch.float32 or None
        Precision of the sampled trajectories; None: per sampled model (robot, flight) float32
        where it passes :func:`~skillkit.models.sampling.sampling_dtype` on its training
        inputs, else float64 (decided at each fit, recorded in its statistics).
    stop_flight_at_ground : bool
        Stop propagating a landed ball (the stored fig4.6, fig4.7, fig4.9 results pin False).
    """

    def __init__(
        self,
        task: Throwing,
        make_robot_model: Callable[[], Any] | None = None,
        make_release_model: Callable[[], Any] | None = None,
        make_flight_model: Callable[[], Any] | None = None,
        max_robot_points: int = 2000,
        max_release_points: int = 300,
        max_flight_points: int = 1000,
        flight_time: float = 2.5,
        warm_start: bool = True,
        device=None,
        dtype: torch.dtype | None = DTYPE,
        stop_flight_at_ground: bool = True,
    ):
        check_type(task, Throwing, "task", "a Throwing task")
        set_factories(
            self,
            make_robot_model=(make_robot_model, _robot_model),
            make_release_model=(make_release_model, _release_model),
            make_flight_model=(make_flight_model, _flight_model),
        )
        self.task = task
        self.max_robot_points = check_count(max_robot_points, "max_robot_points", 2)
        self.max_release_points = check_count(max_release_points, "max_release_points", 2)
        self.max_flight_points = check_count(max_flight_points, "max_flight_points", 2)
        self.flight_steps = int(np.ceil(check_positive(flight_time, "flight_time") / task.ball_dt))
        self.warm_start = bool(warm_start)
        self.device = device
        self.dtype = None if dtype is None else check_dtype(dtype)
        self.sample_dtypes = {"robot": self.dtype, "flight": self.dtype}
        if not isinstance(stop_flight_at_ground, bool):
            got = type(stop_flight_at_ground).__name__
            raise ValueError(f"stop_flight_at_ground: expected a bool, got {got}")
        self.stop_flight_at_ground = stop_flight_at_ground
        self.robot: Any = None
        self.release: Any = None
        self.flight: Any = None
        self.release_var = np.zeros(4)
        self._hypers: dict[str, dict | None] = {"robot": None, "release": None, "flight": None}
        self.n_data = 0

    def _state_at(self, states: np.ndarray, times: np.ndarray) -> np.ndarray:
        """States (..., T, 8) linearly interpolated at times (...,) between control steps."""
        task = self.task
        t = np.clip(times, 0.0, task.times[-1])
        k = np.minimum(np.floor(t / task.control_dt).astype(int), task.n_steps - 2)
        f = (t - k * task.control_dt) / task.control_dt
        lo = np.take_along_axis(states, k[..., None, None], axis=-2)[..., 0, :]
        hi = np.take_along_axis(states, k[..., None, None] + 1, axis=-2)[..., 0, :]
        return (1.0 - f[..., None]) * lo + f[..., None] * hi

    def _fit_gp(self, key: str, model, x: np.ndarray, y_or_u, xn=None, rng=None):
        gp = getattr(model, "gp", model)
        if self.warm_start and isinstance(gp, GPRegression):
            inputs = x if xn is None else np.hstack([x, y_or_u])
            warm_start_hypers(gp, self._hypers[key], inputs)
        if xn is None:
            model.fit(x, y_or_u, rng)
        else:
            model.fit(x, y_or_u, xn, rng=rng)
        if isinstance(gp, GPRegression):
            self._hypers[key] = gp.hyperparameters
        return model

    def fit(self, contexts, omegas, rewards, trajectories, rng=None) -> dict[str, Any]:
        """Refit the three models on every non-failed real throw; returns ``n_data``,
        ``n_robot``, ``n_trajectories``, ``n_release``, ``n_flight``, ``release_std`` (4,) and
        per GP its :func:`~skillkit.models.reward.gp_stats`."""
        ok = usable_trajectories(trajectories, "throwing")
        rng = as_generator(rng)
        # robot dynamics: transitions (x_t, a_t, x_{t+1}), a the commanded accelerations
        x, u, xn = (np.concatenate(p) for p in zip(*map(self.task.transitions, ok), strict=True))
        n_robot = x.shape[0]
        a = self.task.commanded_accelerations(x, u)
        x, a, xn = subsample(rng, self.max_robot_points, x, a, xn)
        self.robot = self._fit_gp("robot", self.make_robot_model(), x, a, xn, rng)
        # release: arm state x_t ↦ the hand's [p, v] at every step, plus the observed release error
        hand = [t.signals["end_effector"] for t in ok]
        dt = self.task.control_dt
        hb = np.concatenate([np.hstack([p, np.gradient(p, dt, axis=0)]) for p in hand])
        hx, hb = subsample(rng, self.max_release_points, np.concatenate([t.states for t in ok]), hb)
        self.release = self._fit_gp("release", self.make_release_model(), hx, hb, rng=rng)
        rx = self._state_at(
            np.stack([t.states for t in ok]), np.array([t.info["release_time"] for t in ok])
        )
        rb = np.array([np.r_[t.info["release_position"], t.info["release_velocity"]] for t in ok])
        mean, _ = self.release.predict(rx)
        self.release_var = np.mean((rb - mean) ** 2, axis=0)
        # free flight: transitions (b_k, b_{k+1}), b = [p, v] every ball_dt after the release
        flights = []
        for t in ok:
            n_held = int(np.sum(t.signals["ball_times"] < t.info["release_time"]))
            p = t.signals["ball"][n_held:-1]
            if p.shape[0] >= 3:
                flights.append(np.hstack([p, np.gradient(p, self.task.ball_dt, axis=0)]))
        if not flights:
            raise ValueError("trajectories: no ball flight of three or more samples to learn from")
        fx = np.concatenate([b[:-1] for b in flights])
        fx, fxn = subsample(
            rng, self.max_flight_points, fx, np.concatenate([b[1:] for b in flights])
        )
        self.flight = self._fit_gp(
            "flight", self.make_flight_model(), fx, np.zeros((fx.shape[0], 0)), fxn, rng
        )
        self.n_data = int(n_robot)
        stats: dict[str, Any] = {
            "n_data": int(n_robot),
            "n_robot": int(x.shape[0]),
            "n_trajectories": len(ok),
            "n_release": int(hx.shape[0]),
            "n_flight": int(fx.shape[0]),
            "release_std": np.sqrt(self.release_var).tolist(),
        }
        for key, model, n in (
            ("robot", self.robot, x.shape[0]),
            ("release", self.release, hx.shape[0]),
            ("flight", self.flight, fx.shape[0]),
        ):
            gp = getattr(model, "gp", model)
            if isinstance(gp, GPRegression):
                stats[key] = gp_stats(gp, n)
        for key, z in (("robot", (x, a)), ("flight", (fx, fx[:, :0]))):
            dtype, error = sampling_dtype(getattr(self, key), *z, self.device, self.dtype)
            self.sample_dtypes[key] = dtype
            stats.setdefault(key, {}).update(sampling_dtype=str(dtype)[6:], precision_error=error)
        return stats

    def predict(self, contexts, omegas, n_trajectories: int, rng=None) -> ThrowingPrediction:
        """Sample L = ``n_trajectories`` throws for each of B pairs, ``contexts`` (B, 2) and
        ``omegas`` (B, 41), through the three models."""
        w, s, L, rng = self._pairs(self.robot is not None, contexts, omegas, n_trajectories, rng)
        task = self.task
        B, T = w.shape[0], task.n_steps
        device = torch.device("cpu" if self.device is None else self.device)
        # the start does not depend on s (which may lie outside the task's range)
        x0 = np.broadcast_to(task.initial_states(task.context_low, 1), (B, L, 8))
        dtype = self.sample_dtypes["robot"]
        accel = task.acceleration_controller(w, device=device)  # float64: a_T and the torques
        step = accel  # the sampler's controller in its own precision
        if dtype != torch.float64:
            step = task.acceleration_controller(w, device=device, dtype=dtype)
        arm = sample_trajectories(self.robot, x0, step, T - 1, L, rng, device=device, dtype=dtype)
        states = arm.states.reshape(B * L, T, 8).to(torch.float64)
        pair = torch.arange(B, device=device).repeat_interleave(L)
        with torch.no_grad():
            a_last = accel(T - 1, states[:, -1], pair)[:, None]
            controls = arm.controls.reshape(B * L, T - 1, 4).to(torch.float64)
            acc = torch.cat([controls, a_last], dim=1)
            torques = task.torques(states, acc)  # all steps at once, (B·L, T, 4)
        states_np = states.cpu().numpy()

        t_rel = np.repeat(w[:, -1], L)
        x_rel = self._state_at(states_np, t_rel)
        mean, var = self.release.predict(x_rel, include_noise=False)
        std = np.sqrt(np.maximum(var, 0.0) + self.release_var)
        b0 = mean + std * rng.standard_normal(mean.shape)

        flight = sample_trajectories(
            self.flight,
            b0,
            _no_control,
            self.flight_steps,
            1,
            rng,
            device=device,
            dtype=self.sample_dtypes["flight"],
            stop=_on_ground if self.stop_flight_at_ground else None,
        )
        paths, landed = land(flight.states[:, 0, :, :2].to(torch.float64).cpu().numpy())
        rewards = task.reward_batch(
            states_np, torques.cpu().numpy(), {"ball": paths}, np.repeat(s, L, axis=0)
        )
        rewards, failed = worst_if_failed(rewards, states_np, task)
        rewards = worst_if_nonfinite(rewards, task, "ThrowingRewardModel.predict")
        return ThrowingPrediction(
            states_np.reshape(B, L, T, 8),
            torques.cpu().numpy().reshape(B, L, T, 4),
            b0.reshape(B, L, 4),
            paths.reshape(B, L, -1, 2),
            rewards.reshape(B, L),
            landed.reshape(B, L),
            failed.reshape(B, L),
        )

    def __repr__(self) -> str:
        state = "unfitted" if self.robot is None else f"{self.n_data} robot transitions"
        return (
            f"ThrowingRewardModel(task={self.task.name!r}, {state}, "
            f"release_std={np.round(np.sqrt(self.release_var), 4).tolist()}, "
            f"flight_steps={self.flight_steps})"
        )


def _on_ground(k: int, b: torch.Tensor) -> torch.Tensor:
    """A ball at or below the ground y = 0 has landed."""
    return b[:, 1] <= 0.0


def _no_control(t: int, x: torch.Tensor, pair: torch.Tensor) -> torch.Tensor:
    """The ball in flight has no control input: an (n, 0) tensor."""
    return x.new_zeros((x.shape[0], 0))
