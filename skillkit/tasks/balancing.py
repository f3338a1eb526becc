"""Balancing the planar 4-link robot (Sec. 4.3.1, Sec. 5.4) with u = G (x − x_up), and the
helpers of the model experiments of Chs. 4–5: balancing gains, data collection and the batched
torch feedback policy."""

from __future__ import annotations

import mujoco
import numpy as np
import scipy.linalg

from skillkit._validation import as_generator, check_array, check_positive
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.tasks.base import ModelSignals, SimulationFailure, Task, check_count
from skillkit.tasks.controllers import control_substeps, run_feedback
from skillkit.tasks.planar_model import (
    STATE_NAMES,
    TIMESTEP,
    TORQUE_NAMES,
    UPRIGHT,
    PlanarRobot,
)
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

__all__ = [
    "X_UP",
    "Balancing",
    "collect_balancing",
    "design_policy",
    "feedback_policy",
    "random_lqr_gains",
    "sampled_rewards",
    "stable_gains",
]

X_UP = np.concatenate([UPRIGHT, np.zeros(4)])
"""The upright state x_up = [q_up, 0] (8,)."""


class Balancing(Task):
    """Balancing the planar 4-link robot around upright (Sec. 4.3.1; Sec. 5.4 settings).

    ω (32) is G (4 × 8) row-major of u_t = G x̃_t + ξ_t, x̃_t = [q_t − q_up, q̇_t]; the
    excitation ξ_t ~ N(0, ``excitation_std``²) is recorded in the control, the torque noise
    (``torque_noise_std``, N m) only applied. x_0 ~ N(x_up, ``initial_std``² I), T =
    ``n_steps`` steps of ``control_dt``. Reward R(τ) = −Σ_{t=1}^{T} (x̃_tᵀ Q x̃_t + r_u u_tᵀ u_t),
    Q = ``state_weights`` ((8,) or (8, 8) PSD, default I₈), r_u = ``control_weight``. A joint
    beyond ``max_angle`` rad from upright or ``max_joint_speed`` rad/s stops the run. Signals
    ``torque_noise`` and ``excitation`` (T, 4).
    """

    name = "balancing"
    parameter_dim = 32
    trajectory_depends_on_context = False
    worst_reward = -1e7

    def __init__(
        self,
        initial_std: float = 0.3,
        torque_noise_std: float = 0.0,
        n_steps: int = 40,
        control_dt: float = 0.05,
        state_weights=None,
        control_weight: float = 0.0,
        excitation_std: float = 0.0,
        max_angle: float = 20.0,
        max_joint_speed: float = 100.0,
    ) -> None:
        self.robot = PlanarRobot(TIMESTEP)
        self.initial_std = check_positive(initial_std, "initial_std", allow_zero=True)
        self.torque_noise_std = check_positive(
            torque_noise_std, "torque_noise_std", allow_zero=True
        )
        self.n_steps = check_count(n_steps, "n_steps")
        self.control_dt = check_positive(control_dt, "control_dt")
        control_substeps(self.robot.model, self.control_dt)
        q_w = np.ones(8) if state_weights is None else state_weights
        q_w = check_array(q_w, "state_weights", ndim=(1, 2))
        q_w = np.diag(q_w) if q_w.ndim == 1 else q_w
        if q_w.shape != (8, 8):
            raise ValueError(f"state_weights: expected shape (8,) or (8, 8), got {q_w.shape}")
        asymmetric = np.max(np.abs(q_w - q_w.T)) > 1e-12 * max(1.0, np.max(np.abs(q_w)))
        if asymmetric or np.min(np.linalg.eigvalsh(q_w)) < 0:
            raise ValueError("state_weights: expected a symmetric positive semi-definite matrix")
        self.state_weights = q_w
        self.control_weight = check_positive(control_weight, "control_weight", allow_zero=True)
        self.excitation_std = check_positive(excitation_std, "excitation_std", allow_zero=True)
        self.max_angle = check_positive(max_angle, "max_angle")
        self.max_joint_speed = check_positive(max_joint_speed, "max_joint_speed")

    @staticmethod
    def gain_matrix(omega) -> np.ndarray:
        """G (4, 8) from ω (32,), row-major."""
        return check_array(omega, "omega", shape=(32,)).reshape(4, 8)

    def _simulate(self, omega, context, rng) -> Trajectory:
        G = self.gain_matrix(omega)
        start, reference, feedforward = getattr(self, "_episode", None) or (None, None, None)
        if start is None:
            q0 = UPRIGHT + self.initial_std * rng.standard_normal(4)
            qd0 = self.initial_std * rng.standard_normal(4)
        else:
            q0, qd0 = start[:4].copy(), start[4:].copy()
        ref = np.broadcast_to(X_UP, (self.n_steps + 1, 8)) if reference is None else reference
        ff = np.zeros((self.n_steps + 1, 4)) if feedforward is None else feedforward
        noise = self.torque_noise_std * rng.standard_normal((self.n_steps, 4))
        excitation = np.zeros((self.n_steps, 4))
        if self.excitation_std:  # drawn only when used: feedback-only runs keep their streams
            excitation = self.excitation_std * rng.standard_normal((self.n_steps, 4))
        commanded = np.empty((self.n_steps + 1, 4))
        states = np.empty((self.n_steps + 1, 8))

        def feedback(t: int, q: np.ndarray, qd: np.ndarray, data: mujoco.MjData) -> np.ndarray:
            states[t, :4], states[t, 4:] = q, qd
            self._check_state(t, states, commanded, noise, excitation)
            commanded[t] = G @ (states[t] - ref[t]) + ff[t] + excitation[t]
            return commanded[t] + noise[t]

        robot = self.robot
        robot.reset(q0, qd0)
        run_feedback(robot.model, robot.data, feedback, self.n_steps, self.control_dt)
        states[-1, :4], states[-1, 4:] = robot.data.qpos, robot.data.qvel
        self._check_state(self.n_steps, states, commanded, noise, excitation)
        commanded[-1] = G @ (states[-1] - ref[-1]) + ff[-1]
        times = np.arange(self.n_steps + 1) * self.control_dt
        return Trajectory(
            times,
            states,
            commanded,
            signals={"torque_noise": noise, "excitation": excitation},
            info={"initial_state": np.concatenate([q0, qd0]).tolist()},
        )

    def rollout_from(
        self, omega, initial_state, rng=None, *, reference=None, feedforward=None
    ) -> Trajectory:
        """One episode from x_0 = ``initial_state`` (8,) under u_t = G (x_t − r_t) + u_ff,t + ξ_t
        (Sec. 4.2.2), ``reference`` r_t (T+1, 8) default x_up, ``feedforward`` (T+1, 4) default 0.
        """
        T1 = self.n_steps + 1
        x0 = check_array(initial_state, "initial_state", shape=(8,))
        ref = None if reference is None else check_array(reference, "reference", shape=(T1, 8))
        ff = None if feedforward is None else check_array(feedforward, "feedforward", shape=(T1, 4))
        self._episode = (x0, ref, ff)
        try:
            return self.rollout(omega, rng=rng)
        finally:
            self._episode = None

    def swing_reference(
        self, amplitudes, period: float = 4.0, phases=(0.0, 0.5, 1.0, 1.5)
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reference q_r(t) = q_up + a ⊙ sin(2π t / P + φ) as [q_r, q̇_r] (T+1, 8) and its
        feed-forward u_ff = M(q_r) q̈_r + c(q_r, q̇_r) (T+1, 4), for :meth:`rollout_from`."""
        a = np.broadcast_to(check_array(amplitudes, "amplitudes", ndim=(0, 1)), (4,))
        phi = check_array(phases, "phases", shape=(4,))
        w = 2.0 * np.pi / check_positive(period, "period")
        t = np.arange(self.n_steps + 1)[:, None] * self.control_dt
        q = UPRIGHT + a * np.sin(w * t + phi)
        qd = a * w * np.cos(w * t + phi)
        qdd = -a * w**2 * np.sin(w * t + phi)
        model, data = self.robot.model, self.robot.data
        ff = np.empty((len(t), 4))
        for i in range(len(t)):
            self.robot.reset(q[i], qd[i])
            data.qacc[:] = qdd[i]
            mujoco.mj_inverse(model, data)
            ff[i] = data.qfrc_inverse
        return np.hstack([q, qd]), ff

    def _beyond_limits(self, x: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            speed = np.abs(x[..., 4:]).max(axis=-1)
            angle = np.abs(x[..., :4] - UPRIGHT).max(axis=-1)
            within = (speed <= self.max_joint_speed) & (angle <= self.max_angle)
        return ~(np.isfinite(x).all(axis=-1) & within)

    def failed_batch(self, states) -> np.ndarray:
        """Paths (B, T + 1, 8) with a state beyond the divergence limits, shape (B,)."""
        states = check_array(states, "states", shape=(None, None, 8), finite=False)
        return self._beyond_limits(states).any(axis=1)

    def _check_state(self, t, states, commanded, noise, excitation) -> None:
        """Raise :class:`SimulationFailure` (keeping x_0 … x_{t−1}) if x_t diverged."""
        x = states[t]
        if not self._beyond_limits(x):
            return
        if not np.all(np.isfinite(x)):
            what = "non-finite state"
        elif np.abs(x[4:]).max() > self.max_joint_speed:
            what = f"a joint speed exceeds {self.max_joint_speed:g} rad/s"
        else:
            what = f"a joint is more than {self.max_angle:g} rad from upright"
        partial = None
        if t >= 2:
            partial = Trajectory(
                np.arange(t) * self.control_dt,
                states[:t].copy(),
                commanded[:t].copy(),
                signals={"torque_noise": noise[: t - 1], "excitation": excitation[: t - 1]},
                info={"initial_state": states[0].tolist(), "steps_before_failure": t - 1},
            )
        raise SimulationFailure(f"diverged: {what} at t = {t * self.control_dt:.3f} s", partial)

    def reward_batch(self, states, controls, signals=None, contexts=None):
        """R(τ) of states (B, T+1, 8) and torques (B, T+1, 4), numpy or torch, shape (B,)."""
        if type(states).__module__.startswith("torch"):
            import torch

            xp, kw = torch, {"dtype": states.dtype, "device": states.device}
            up, q_w = (torch.as_tensor(a, **kw) for a in (X_UP, self.state_weights))
        else:
            xp, up, q_w = np, X_UP, self.state_weights
            states, controls = np.asarray(states), np.asarray(controls)
        x, u = states[:, 1:] - up, controls[:, 1:]
        cost = xp.einsum("bti,ij,btj->b", x, q_w, x)
        return -(cost + self.control_weight * (u**2).sum((1, 2)))

    def immediate_reward(self, states, controls):
        """r(x, u) = −(x̃ᵀ Q x̃ + r_u uᵀu) of states (..., 8), controls (..., 4), shape (...);
        summed over rows 1..T it is :meth:`reward_batch` (Eq. 5.17 predicts it per step)."""
        d = np.asarray(states) - X_UP
        return -(
            np.einsum("...i,ij,...j->...", d, self.state_weights, d)
            + self.control_weight * (np.asarray(controls) ** 2).sum(-1)
        )

    supports_model_rollout = True

    def model_signals(self) -> ModelSignals:
        """x = [q, q̇] (8), u = the commanded joint torques (4)."""
        return ModelSignals(STATE_NAMES, TORQUE_NAMES)

    def initial_states(self, context=None, n: int = 1, rng=None) -> np.ndarray:
        """x_0 = x_up + σ ξ, ξ ~ N(0, I₈): the simulator's start distribution, shape (n, 8)."""
        self.check_context(context)
        return X_UP + self.initial_std * as_generator(rng).standard_normal((check_count(n), 8))

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """u = G_b (x − x_up), G_b = ω_b row-major (:func:`feedback_policy`)."""
        import torch

        dtype = torch.float64 if dtype is None else dtype
        gains = check_array(omegas, "omegas", shape=(None, 32)).reshape(-1, 4, 8)
        return feedback_policy(torch.as_tensor(gains, dtype=dtype, device=device))

    def scene_model(self) -> mujoco.MjModel:
        """The planar robot's compiled MuJoCo model."""
        return self.robot.model

    def linearization(self) -> tuple[np.ndarray, np.ndarray]:
        """Linearisation at upright per control period, A_c = A^k (8, 8), B_c = Σ_{i<k} A^i B
        (8, 4), from one physics step's ``mujoco.mjd_transitionFD``."""
        model, data = self.robot.model, self.robot.data
        self.robot.reset(UPRIGHT, np.zeros(4))
        data.ctrl[:] = 0.0
        a = np.zeros((8, 8))
        b = np.zeros((8, 4))
        mujoco.mjd_transitionFD(model, data, 1e-6, True, a, b, None, None)
        a_c, b_c = np.eye(8), np.zeros((8, 4))
        for _ in range(control_substeps(model, self.control_dt)):
            a_c, b_c = a @ a_c, a @ b_c + b
        return a_c, b_c

    def lqr_gain(self, state_weights=None, control_weight: float = 1e-4) -> np.ndarray:
        """Discrete LQR gain G = −K = −(R + B_cᵀ P B_c)⁻¹ B_cᵀ P A_c (4, 8) at upright, P the
        Riccati solution for Σ x̃ᵀ Q x̃ + uᵀ R u, Q = ``state_weights`` (default the reward's),
        R = ``control_weight`` I₄."""
        q_w = self.state_weights if state_weights is None else state_weights
        q_w = check_array(q_w, "state_weights", shape=(8, 8))
        r_w = check_positive(control_weight, "control_weight") * np.eye(4)
        a_c, b_c = self.linearization()
        p = scipy.linalg.solve_discrete_are(a_c, b_c, q_w, r_w)
        k = np.linalg.solve(r_w + b_c.T @ p @ b_c, b_c.T @ p @ a_c)
        return -k

    def pd_gain(self, natural_frequency: float = 3.0, damping: float = 1.5) -> np.ndarray:
        """PD gain G = [K_p, K_d] (4, 8), K_p = K_g − ω² M, K_d = −2 ζ ω M for the upright
        linearisation M q̈ = u − K_g q̃: modes q̈ = −ω² q̃ − 2ζω q̇ (Secs 4.2.3, 5.4)."""
        w = check_positive(natural_frequency, "natural_frequency")
        z = check_positive(damping, "damping")
        model, data = self.robot.model, self.robot.data
        self.robot.reset(UPRIGHT, np.zeros(4))
        mass = np.zeros((4, 4))
        mujoco.mj_fullM(model, data, mass)
        step = 1e-6
        stiffness = np.empty((4, 4))
        for j in range(4):
            dq = np.zeros(4)
            dq[j] = step
            self.robot.reset(UPRIGHT + dq, np.zeros(4))
            plus = data.qfrc_bias.copy()
            self.robot.reset(UPRIGHT - dq, np.zeros(4))
            stiffness[:, j] = (plus - data.qfrc_bias) / (2 * step)
        return np.hstack([stiffness - w**2 * mass, -2.0 * z * w * mass])

    exploration_std_fraction = 0.002
    """Default exploration of :meth:`initial_policy`: σ = 0.2% of |G_lqr| entry-wise."""

    def lqr_policy(
        self, control_weight: float = 1e-4, exploration_std_fraction: float | None = None
    ) -> GaussianPolicy:
        """N(ω | vec G, Σ) around :meth:`lqr_gain` (R = ``control_weight`` I), Σ diagonal with
        std ``exploration_std_fraction`` (default :attr:`exploration_std_fraction`) × |G|."""
        if exploration_std_fraction is None:
            exploration_std_fraction = self.exploration_std_fraction
        frac = check_positive(exploration_std_fraction, "exploration_std_fraction")
        g = self.lqr_gain(control_weight=control_weight).ravel()
        return GaussianPolicy(g, np.diag((frac * np.abs(g)) ** 2))

    def initial_policy(self) -> GaussianPolicy:
        """:meth:`lqr_policy` with R = 1e-4 I and exploration 0.2%: all samples balance."""
        return self.lqr_policy()


def feedback_policy(gains, reference=None, feedforward=None):
    """The sampler policy u = G_b (x − r_t) + u_ff,t (default r_t = x_up, u_ff = 0).

    ``gains`` Tensor (B, 4, 8), ``reference`` (T+1, 8), ``feedforward`` (T+1, 4); returns
    ``policy(t, x, pair) -> u`` on the device and dtype of ``gains``.
    """
    import torch

    def tensor(value):
        return torch.as_tensor(value, dtype=gains.dtype, device=gains.device)

    ref = tensor(X_UP)[None] if reference is None else tensor(reference)
    ff = None if feedforward is None else tensor(feedforward)

    def policy(t: int, x, pair):
        u = torch.einsum("nij,nj->ni", gains[pair], x - ref[0 if reference is None else t])
        return u if ff is None else u + ff[t]

    return policy


def sampled_rewards(task: Balancing, states, gains) -> np.ndarray:
    """Rewards (B, L) of sampled states (B, L, T+1, 8) under u = G_b x̃, gains (B, 4, 8);
    non-finite rewards become :attr:`Balancing.worst_reward`."""
    B, L, T1, _ = states.shape
    controls = np.einsum("bij,bltj->blti", gains, states - X_UP)
    r = task.reward_batch(states.reshape(B * L, T1, 8), controls.reshape(B * L, T1, 4))
    return np.where(np.isfinite(r), r, task.worst_reward).reshape(B, L)


def stable_gains(
    task: Balancing,
    n: int,
    rng: np.random.Generator,
    max_spectral_radius: float = 0.98,
    policy: GaussianPolicy | None = None,
) -> np.ndarray:
    """``n`` samples ω ~ π(ω) (default the initial policy), (n, 32), with ρ(A_c + B_c G) ≤
    ``max_spectral_radius`` (Sec. 4.2.3); RuntimeError after 100 n tries."""
    rng = as_generator(rng)
    A, B = task.linearization()
    policy = task.initial_policy() if policy is None else policy
    out: list[np.ndarray] = []
    tried = 0
    while len(out) < n:
        batch = policy.sample(np.zeros((max(n, 16), 0)), rng=rng)
        for w in batch:
            tried += 1
            if (
                len(out) < n
                and np.abs(np.linalg.eigvals(A + B @ w.reshape(4, 8))).max() <= max_spectral_radius
            ):
                out.append(w)
        if tried > 100 * n:
            raise RuntimeError(
                f"stable_gains: only {len(out)} of {tried} samples have spectral radius "
                f"<= {max_spectral_radius}"
            )
    return np.array(out)


def collect_balancing(
    task: Balancing,
    n_trajectories: int,
    rng: np.random.Generator,
    max_spectral_radius: float = 0.98,
    policy: GaussianPolicy | None = None,
    gain=None,
) -> dict:
    """Roll out ``n_trajectories`` balancing ω (:func:`stable_gains`), or one fixed ``gain``
    (4, 8), from random x_0; failed rollouts are replaced and counted.

    Returns
    -------
    dict
        ``omegas`` (n, 32), ``trajectories``, transitions ``x``, ``u``, ``x_next``, ``n_failed``.
    """
    rng = as_generator(rng)
    omegas, trajs, n_failed = [], [], 0
    if gain is not None and policy is not None:
        raise ValueError("gain: give either a fixed gain or a policy, not both")
    fixed = None if gain is None else _gain_vector(gain, "gain")
    candidates, n_draw = [], n_trajectories  # one batch, then one at a time
    while len(trajs) < n_trajectories:
        if fixed is None and not candidates:
            candidates = list(stable_gains(task, n_draw, rng, max_spectral_radius, policy))
            n_draw = 1
        omega = fixed if fixed is not None else candidates.pop(0)
        traj = task.rollout(omega, rng=rng)
        if traj.failed:
            n_failed += 1
            if n_failed > 10 * n_trajectories:
                raise RuntimeError(f"collect_balancing: {n_failed} of the rollouts failed")
            continue
        omegas.append(omega)
        trajs.append(traj)
    parts = [task.transitions(t) for t in trajs]
    return {
        "omegas": np.array(omegas),
        "trajectories": trajs,
        "x": np.vstack([p[0] for p in parts]),
        "u": np.vstack([p[1] for p in parts]),
        "x_next": np.vstack([p[2] for p in parts]),
        "n_failed": n_failed,
    }


def _gain_vector(value, name: str) -> np.ndarray:
    """ω (32,) from a gain of shape (4, 8) or (32,)."""
    g = check_array(value, name, ndim=(1, 2)).reshape(-1)
    if g.size != 32:
        raise ValueError(f"{name}: expected shape (4, 8) or (32,), got {np.shape(value)}")
    return g


def random_lqr_gains(
    task: Balancing, n: int, spread: float, control_weight: float, rng
) -> np.ndarray:
    """``n`` LQR gains (n, 4, 8) for Q = diag(q_task ⊙ exp(s ξ)), R = r₀ exp(s ξ') I,
    ξ ~ N(0, I₈), ξ' ~ N(0, 1), s = ``spread``, r₀ = ``control_weight``."""
    n = check_count(n, "n")
    spread = check_positive(spread, "spread", allow_zero=True)
    rng = as_generator(rng)
    q0 = np.diag(task.state_weights)
    out = np.empty((n, 4, 8))
    for i in range(n):
        q = q0 * np.exp(spread * rng.standard_normal(8))
        r = control_weight * np.exp(spread * rng.standard_normal())
        out[i] = task.lqr_gain(state_weights=np.diag(q), control_weight=r)
    return out


def design_policy(
    task: Balancing,
    mean,
    exploration: float = 0.7,
    n_designs: int = 300,
    spread: float = 2.0,
    control_weight: float = 1e-2,
    scale_std: float = 0.15,
    rng=0,
) -> GaussianPolicy:
    """π(ω) = N(ω | mean, c² Σ_d), Σ_d the sample covariance (+ 10⁻⁶ of its mean variance)
    of ``n_designs`` ω_i = exp(β ξ_i) vec G_i (:func:`random_lqr_gains`), β = ``scale_std``,
    c = ``exploration``, ``mean`` (32,) or (4, 8)."""
    mu = _gain_vector(mean, "mean")
    c = check_positive(exploration, "exploration")
    n = check_count(n_designs, "n_designs")
    if n < 2:
        raise ValueError(f"n_designs: expected at least 2 designs, got {n}")
    beta = check_positive(scale_std, "scale_std", allow_zero=True)
    rng = as_generator(rng)
    gains = random_lqr_gains(task, n, spread, control_weight, rng).reshape(n, 32)
    designs = np.exp(beta * rng.standard_normal(n))[:, None] * gains
    cov = np.cov(designs, rowvar=False)
    cov = c**2 * (cov + 1e-6 * np.trace(cov) / 32 * np.eye(32))
    return GaussianPolicy(mu, 0.5 * (cov + cov.T))


@register("balancing", "planar", "context-free")
def balancing(**kwargs) -> Balancing:
    """Balancing (Sec. 4.3.1): deterministic, initial std 0.3, Q = I, 40 steps at 20 Hz."""
    return Balancing(**kwargs)


@register("balancing-noisy", "planar", "context-free")
def balancing_noisy(**kwargs) -> Balancing:
    """Balancing with Sec. 5.4's torque noise (4 N m) and reward weights."""
    kwargs.setdefault("torque_noise_std", 4.0)
    kwargs.setdefault("state_weights", np.concatenate([np.full(4, 10.0), np.full(4, 0.1)]))
    kwargs.setdefault("control_weight", 1e-5)
    return Balancing(**kwargs)
