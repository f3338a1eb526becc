"""The single-link pendulum of Sec. 5.4 (and the stochastic pendulum of Fig. 4.8).

Dynamics α̈ = −9.81 sin α + u, |u| ≤ 3, Δt = 0.1 s, under the stochastic linear feedback
u ~ N(Kᵀx, σ_u²), x = [α, α̇], clipped to the torque limit. ω = K (thesis K = [−3, −1]); the
context is the initial state s = x_0. The torque is held over each control period and the ODE
integrated with RK4 (10 sub-steps). R(τ, s) = −Σ_{t=1}^{T} (α_t² + 0.1 α̇_t²) (Fig. 4.8; the
constants are ours).
"""

from __future__ import annotations

import numpy as np

from skillkit._validation import check_array, check_positive
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks.base import ModelSignals, Task, check_count
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

GRAVITY = 9.81
TORQUE_LIMIT = 3.0
THESIS_GAINS = np.array([-3.0, -1.0])


def pendulum_dynamics(
    x: np.ndarray, u: np.ndarray, dt: float = 0.1, substeps: int = 10
) -> np.ndarray:
    """Successor of states x (..., 2) = [α, α̇] under torques u (...) held for ``dt`` (RK4)."""
    x = np.asarray(x, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    h = dt / substeps

    def f(state):
        return np.stack([state[..., 1], -GRAVITY * np.sin(state[..., 0]) + u], axis=-1)

    for _ in range(substeps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def feedback_torque(
    x: np.ndarray, gains: np.ndarray, noise: np.ndarray | float = 0.0
) -> np.ndarray:
    """u = clip(Kᵀx + noise, −3, 3) for states of shape (..., 2)."""
    return np.clip(np.asarray(x) @ np.asarray(gains) + noise, -TORQUE_LIMIT, TORQUE_LIMIT)


class Pendulum(Task):
    """Single-link pendulum under stochastic linear feedback (Sec. 5.4, Fig. 4.8).

    Parameters
    ----------
    horizon : int
        Control steps T (20 in Sec. 5.4).
    control_noise : float
        Std σ_u of the torque noise (0.05 in Sec. 5.4).
    dt : float
        Control period Δt (s).
    alpha_range, velocity_range : float
        The context (initial state) is uniform on [−α_r, α_r] × [−v_r, v_r].
    """

    context_names = ("alpha0", "alpha_dot0")
    parameter_dim = 2
    context_dim = 2

    def __init__(
        self,
        horizon: int = 20,
        control_noise: float = 0.05,
        dt: float = 0.1,
        alpha_range: float = np.pi,
        velocity_range: float = 4.0,
        name: str = "pendulum",
    ):
        self.horizon = check_count(horizon, "horizon")
        self.control_noise = check_positive(control_noise, "control_noise", allow_zero=True)
        self.dt = check_positive(dt, "dt")
        alpha_range = check_positive(alpha_range, "alpha_range")
        velocity_range = check_positive(velocity_range, "velocity_range")
        self.name = name
        self.context_low = np.array([-alpha_range, -velocity_range], dtype=float)
        self.context_high = -self.context_low

    def _simulate(self, omega, context, rng) -> Trajectory:
        T = self.horizon
        states = np.empty((T + 1, 2))
        controls = np.zeros((T + 1, 1))
        states[0] = context
        noise = self.control_noise * rng.standard_normal(T)
        for t in range(T):
            u = feedback_torque(states[t], omega, noise[t])
            controls[t, 0] = u
            states[t + 1] = pendulum_dynamics(states[t], u, self.dt)
        times = self.dt * np.arange(T + 1)
        return Trajectory(times, states, controls, info={"gains": omega.tolist()})

    supports_model_rollout = True

    def model_signals(self) -> ModelSignals:
        """x = [α, α̇], u = the applied torque."""
        return ModelSignals(state=("alpha", "alpha_dot"), control=("torque",))

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """The context is the start state: ``n`` copies of s (``rng`` is unused)."""
        s = self.check_context(context)
        return np.tile(s, (check_count(n), 1))

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """u = clip(K_bᵀ x, −3, 3), K_b = ω_b; the torque noise belongs to the learned dynamics."""
        import torch

        dtype = torch.float64 if dtype is None else dtype
        gains = check_array(omegas, "omegas", shape=(None, 2))
        gains = torch.as_tensor(gains, dtype=dtype, device=device)

        def policy(t: int, x, pair):
            u = (x * gains[pair]).sum(-1, keepdim=True)
            return u.clamp(-TORQUE_LIMIT, TORQUE_LIMIT)

        return policy

    def reward_batch(self, states, controls, signals, contexts):
        """R = −Σ_{t≥1} (α_t² + 0.1 α̇_t²) per trajectory; numpy or torch, shape (B,)."""
        x = states[:, 1:]
        return -(x[..., 0] ** 2 + 0.1 * x[..., 1] ** 2).sum(1)

    def initial_policy(self) -> LinearGaussianPolicy:
        """π(ω|s) = N(K_thesis, diag(0.5², 0.25²)), independent of the context."""
        return LinearGaussianPolicy(THESIS_GAINS.copy(), np.diag([0.5**2, 0.25**2]), context_dim=2)


@register("pendulum", "pendulum", "contextual")
def pendulum(**kwargs) -> Pendulum:
    """Sec. 5.4 setting: T = 20, σ_u = 0.05, context = initial state."""
    return Pendulum(**kwargs)


@register("pendulum-stochastic", "pendulum", "contextual")
def pendulum_stochastic(**kwargs) -> Pendulum:
    """Fig. 4.8 setting: strong torque noise (σ_u = 1.5) and T = 30."""
    kwargs.setdefault("control_noise", 1.5)
    kwargs.setdefault("horizon", 30)
    kwargs.setdefault("name", "pendulum-stochastic")
    return Pendulum(**kwargs)
