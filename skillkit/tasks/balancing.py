"""Balancing the planar 4-link robot (Sec. 4.3.1, Sec. 5.4) and its model-learning helpers.

:class:`Balancing` (registered ``balancing`` and ``balancing-noisy``) runs the linear state
feedback u = G (x − x_up) around upright on the robot of :mod:`skillkit.tasks.planar_model`.
The helpers here are the domain code of the model experiments of Chs. 4–5: the upright
state :data:`X_UP`, robustly balancing gains drawn from the initial policy
(:func:`stable_gains`) or from randomised LQR designs (:func:`random_lqr_gains`), data
collection (:func:`collect_balancing`) and the batched torch feedback policy for the
trajectory sampler (:func:`feedback_policy`).
"""

from __future__ import annotations

import mujoco
import numpy as np
import scipy.linalg

from skillkit._validation import as_generator, check_array, check_positive
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.tasks.base import (
    ModelSignals,
    SimulationFailure,
    Task,
    check_count,
    state_transitions,
)
from skillkit.tasks.controllers import control_substeps, run_feedback
from skillkit.tasks.planar_model import JOINT_NAMES, TIMESTEP, UPRIGHT, PlanarRobot
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

__all__ = [
    "X_UP",
    "Balancing",
    "balancing_transitions",
    "collect_balancing",
    "design_policy",
    "feedback_policy",
    "random_lqr_gains",
    "sampled_rewards",
    "stable_gains",
]

X_UP = np.concatenate([UPRIGHT, np.zeros(4)])
"""The upright state x_up = [q_up, 0] (8,)."""


def _is_tensor(x) -> bool:
    return type(x).__module__.startswith("torch")


class Balancing(Task):
    """Balancing the planar 4-link robot around upright (Sec. 4.3.1; Sec. 5.4 settings).

    **Lower-level policy** (32 parameters): the linear feedback u_t = G x̃_t with
    x̃_t = [q_t − q_up, q̇_t] the deviation from upright q_up = [0, 0, 0, π] and the gain
    matrix G (4 × 8) = ω reshaped **row-major** (``G[i, j] = ω[8 i + j]``: row i gives the
    torque of joint i). No gravity compensation: gravity exerts no torque at upright.
    Optional Gaussian torque noise (``torque_noise_std``, N m) is added to the applied
    torque, making the dynamics stochastic (Sec. 5.4 uses 4). Optional white torque
    *excitation* (``excitation_std``, N m) makes the lower-level policy itself random,
    u_t = G x̃_t + ξ_t: it is part of the recorded control (a forward model sees it), unlike
    the noise, and is what collects informative data for model learning (the "random policy"
    of Sec. 4.3.1's initial experience).

    **Episode.** The initial state is Gaussian around upright, q_0 ~ N(q_up, σ² I),
    q̇_0 ~ N(0, σ² I) with σ = ``initial_std`` (0.3 as in Sec. 5.4). Torques are computed
    at ``control_dt`` (20 Hz default) and held over the period (1 ms physics steps) for
    ``n_steps`` = T control steps (40, so 2 s).

    **Reward**

        R(τ) = −Σ_{t=1}^{T} (x̃_tᵀ Q x̃_t + r_u u_tᵀ u_t),

    with Q = ``state_weights`` (default I₈, the −Σ (x_t − x_r)ᵀ(x_t − x_r) of Sec. 4.2) and
    r_u = ``control_weight`` (default 0). Sec. 5.4's immediate reward
    −10 q̃ᵀq̃ − 0.1 q̇ᵀq̇ − 10⁻⁵ uᵀu is the ``balancing-noisy`` variant (Q = diag(10 I₄,
    0.1 I₄), r_u = 1e-5, torque noise 4). u_t is the commanded torque G x̃_t; u_T is the
    command at the final state (computed, not applied).

    **Failures.** A run with a joint angle more than ``max_angle`` (20 rad) from upright or a
    speed above ``max_joint_speed`` (100 rad/s) is stopped as diverged at that control step
    (:class:`SimulationFailure`), so every working rollout has a bounded reward and
    :attr:`worst_reward` (−1e7) lies below it in practice. The failed trajectory keeps the
    states before the divergence (all within the limits): they are real experience of
    where a bad gain leads, which PILCO and GPREPS learn (:meth:`transitions`).

    Trajectory: ``times`` (T+1,), ``states`` (T+1, 8) = [q, q̇] at the control steps,
    ``controls`` (T+1, 4) commanded torques (with the excitation); signals ``torque_noise``
    and ``excitation`` (T, 4). Use
    :func:`balancing_transitions` for the (x_t, u_t, x_{t+1}) transitions.

    Parameters
    ----------
    initial_std : float
        σ of the initial state distribution (rad, rad/s).
    torque_noise_std : float
        Standard deviation of the additive torque noise (N m), 0 for deterministic dynamics.
    n_steps : int
        Horizon T in control steps.
    control_dt : float
        Control period (s), a multiple of the 1 ms physics step.
    state_weights : array_like, shape (8, 8) or (8,), optional
        Q (a vector is its diagonal); default identity.
    control_weight : float
        r_u ≥ 0.
    excitation_std : float
        Standard deviation of the white torque excitation ξ_t (N m), 0 for the feedback alone.
    max_angle, max_joint_speed : float
        Divergence thresholds.
    """

    name = "balancing"
    context_dim = 0
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
        if state_weights is None:
            q_w = np.eye(8)
        else:
            q_w = check_array(state_weights, "state_weights", ndim=(1, 2))
            q_w = np.diag(q_w) if q_w.ndim == 1 else q_w
            if q_w.shape != (8, 8):
                raise ValueError(f"state_weights: expected shape (8,) or (8, 8), got {q_w.shape}")
            if np.max(np.abs(q_w - q_w.T)) > 1e-12 * max(1.0, np.max(np.abs(q_w))):
                raise ValueError("state_weights: expected a symmetric matrix")
            if np.min(np.linalg.eigvalsh(q_w)) < 0:
                raise ValueError("state_weights: expected a positive semi-definite matrix")
        self.state_weights = q_w
        self.control_weight = check_positive(control_weight, "control_weight", allow_zero=True)
        self.excitation_std = check_positive(excitation_std, "excitation_std", allow_zero=True)
        self.max_angle = check_positive(max_angle, "max_angle")
        self.max_joint_speed = check_positive(max_joint_speed, "max_joint_speed")

    # ------------------------------------------------------------------ episodes
    @staticmethod
    def gain_matrix(omega) -> np.ndarray:
        """G (4, 8) from ω (32,), row-major."""
        return check_array(omega, "omega", shape=(32,)).reshape(4, 8)

    def _simulate(
        self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator
    ) -> Trajectory:
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
        """One episode from a given x_0, optionally tracking a reference (Sec. 4.2.2).

        The controller is u_t = G (x_t − r_t) + u_ff,t + ξ_t: with the default reference
        r_t = x_up and u_ff = 0 it is :meth:`rollout`'s feedback; with a time-varying r_t it
        is the linear trajectory-tracking PD controller of Sec. 4.2.2 (linear in x_t, so
        moment matching applies with the per-step offset u_ff,t − G r_t). Failures are
        reported as in :meth:`~skillkit.tasks.base.Task.rollout`.

        Parameters
        ----------
        omega : array_like, shape (32,)
            G row-major.
        initial_state : array_like, shape (8,)
            x_0 = [q_0, q̇_0].
        rng : Generator, int or None
            The torque noise and excitation.
        reference : array_like, shape (T+1, 8), optional
            r_t (default x_up at every step).
        feedforward : array_like, shape (T+1, 4), optional
            u_ff,t (default 0).

        Returns
        -------
        Trajectory
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
        """A large-amplitude swinging reference around upright and its inverse dynamics.

        q_r(t) = q_up + a ⊙ sin(2π t / P + φ) over the task's T control steps, with q̇_r, q̈_r
        its derivatives, and the feed-forward torque u_ff(t) = M(q_r) q̈_r + c(q_r, q̇_r) + g(q_r)
        (``mujoco.mj_inverse``): with :meth:`rollout_from` this is the linear
        trajectory-tracking PD controller of Sec. 4.2.2, u = G (x − r_t) + u_ff,t.

        Parameters
        ----------
        amplitudes : array_like, shape (4,) or ()
            a (rad) per joint.
        period : float
            P (s).
        phases : array_like, shape (4,)
            φ (rad) per joint.

        Returns
        -------
        reference : ndarray, shape (T+1, 8)
            r_t = [q_r, q̇_r] at the control steps.
        feedforward : ndarray, shape (T+1, 4)
        """
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
        """Whether states x (..., 8) are non-finite, faster than ``max_joint_speed`` or more
        than ``max_angle`` from upright: the divergence rule, shape (...)."""
        with np.errstate(invalid="ignore"):
            speed = np.abs(x[..., 4:]).max(axis=-1)
            angle = np.abs(x[..., :4] - UPRIGHT).max(axis=-1)
            within = (speed <= self.max_joint_speed) & (angle <= self.max_angle)
        return ~(np.isfinite(x).all(axis=-1) & within)

    def failed_batch(self, states) -> np.ndarray:
        """Trajectories (B, T + 1, 8) with a state beyond the divergence limits (non-finite,
        a joint faster than ``max_joint_speed`` or more than ``max_angle`` from upright),
        shape (B,): the rule a rollout is stopped by (:meth:`_check_state`), so a predicted
        path through such a state scores :attr:`worst_reward` as the real rollout would."""
        states = check_array(states, "states", ndim=3, finite=False)
        if states.shape[2] != 8:
            raise ValueError(f"states: expected shape (B, T + 1, 8), got {states.shape}")
        return self._beyond_limits(states).any(axis=1)

    def _check_state(self, t, states, commanded, noise, excitation) -> None:
        """Stop the episode as diverged when x_t (``states[t]``) is non-finite or beyond the
        limits, keeping x_0 … x_{t−1} (all within them) as the failure's partial trajectory."""
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

    # ------------------------------------------------------------------ reward
    def reward_batch(self, states, controls, signals=None, contexts=None):
        """R(τ) = −Σ_{t=1}^{T} (x̃_tᵀ Q x̃_t + r_u u_tᵀ u_t) per trajectory (Sec. 4.2).

        Parameters
        ----------
        states : ndarray or Tensor, shape (B, T+1, 8)
        controls : ndarray or Tensor, shape (B, T+1, 4)
            Commanded torques u_t = G x̃_t (row 0 is not scored).
        signals, contexts
            Unused (the task is context-free).

        Returns
        -------
        ndarray or Tensor, shape (B,)
        """
        if _is_tensor(states):  # one formula for numpy and torch (einsum and sum agree)
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
        """The immediate reward r(x, u) = −(x̃ᵀ Q x̃ + r_u uᵀu), vectorised over leading axes.

        Summed over rows 1..T of a trajectory it is :meth:`reward_batch` (up to rounding:
        the trajectory reward sums in one product). Chapter 5's embeddings predict its
        expectation per step (a linear reward kernel, Eq. 5.17).

        Parameters
        ----------
        states : array_like, shape (..., 8)
        controls : array_like, shape (..., 4)

        Returns
        -------
        ndarray, shape (...)
        """
        d = np.asarray(states) - X_UP
        return -(
            np.einsum("...i,ij,...j->...", d, self.state_weights, d)
            + self.control_weight * (np.asarray(controls) ** 2).sum(-1)
        )

    # ------------------------------------------------------------------ model-based search
    supports_model_rollout = True

    def model_signals(self) -> ModelSignals:
        """x = [q, q̇] (8), u = the commanded joint torques (4); no other signal."""
        return ModelSignals(
            state=tuple(JOINT_NAMES) + tuple(f"{j}_velocity" for j in JOINT_NAMES),
            control=tuple(f"{j}_torque" for j in JOINT_NAMES),
        )

    def initial_states(self, context=None, n: int = 1, rng=None) -> np.ndarray:
        """x_0 = x_up + σ ξ, ξ ~ N(0, I₈): the simulator's start distribution, shape (n, 8)."""
        self.check_context(context)
        return X_UP + self.initial_std * as_generator(rng).standard_normal((check_count(n), 8))

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """u = G_b (x − x_up) for pair b, G_b = ω_b as (4, 8) row-major.

        The same law as :func:`feedback_policy` (which it returns).
        """
        import torch

        omegas = check_array(omegas, "omegas", shape=(None, 32))
        gains = torch.as_tensor(
            omegas.reshape(-1, 4, 8),
            dtype=torch.float64 if dtype is None else dtype,
            device=device,
        )
        return feedback_policy(gains)

    def scene_model(self) -> mujoco.MjModel:
        """The planar robot's compiled MuJoCo model."""
        return self.robot.model

    # ------------------------------------------------------------------ policy
    def linearization(self) -> tuple[np.ndarray, np.ndarray]:
        """Discrete-time linearisation at upright for one control period.

        ``mujoco.mjd_transitionFD`` (centred differences) gives x⁺ = A x + B u for one physics
        step at (q_up, 0, u = 0); holding u for the k = control_dt / timestep steps of a
        control period gives A_c = A^k and B_c = Σ_{i<k} A^i B.

        Returns
        -------
        A_c : ndarray, shape (8, 8)
        B_c : ndarray, shape (8, 4)
        """
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
        """Discrete LQR gain G = −K at upright (u = G x̃), from :meth:`linearization`.

        K = (R + B_cᵀ P B_c)⁻¹ B_cᵀ P A_c with P the solution of the discrete algebraic Riccati
        equation for cost Σ x̃ᵀ Q x̃ + uᵀ R u, R = ``control_weight`` · I₄.

        Parameters
        ----------
        state_weights : array_like, shape (8, 8), optional
            Q (default: the task's reward weights).
        control_weight : float
            R / I (> 0).

        Returns
        -------
        ndarray, shape (4, 8)
        """
        q_w = (
            self.state_weights
            if state_weights is None
            else check_array(state_weights, "state_weights", shape=(8, 8))
        )
        r_w = check_positive(control_weight, "control_weight") * np.eye(4)
        a_c, b_c = self.linearization()
        p = scipy.linalg.solve_discrete_are(a_c, b_c, q_w, r_w)
        k = np.linalg.solve(r_w + b_c.T @ p @ b_c, b_c.T @ p @ a_c)
        return -k

    def pd_gain(self, natural_frequency: float = 3.0, damping: float = 1.5) -> np.ndarray:
        """The PD controller u = G x̃ = K_p q̃ + K_d q̇ with gravity-stiffness compensation.

        Linearised at upright the robot obeys M q̈ = u − K_g q̃ (M the mass matrix, K_g =
        ∂(bias force)/∂q at rest, negative: gravity pushes the links over). With

            K_p = K_g − ω² M,    K_d = −2 ζ ω M,

        the closed loop becomes q̈ = −ω² q̃ − 2ζω q̇ in every joint coordinate: each mode has
        the poles −ζω ± ω√(ζ² − 1). The thesis's balancing controllers are PD controllers
        u = G[q̃; q̇] (Secs 4.2.3, 4.3.1, 5.4) with no values given. The defaults
        (ω = 3 rad/s, ζ = 1.5) are the lowest stiffness on a grid of (ω, ζ) whose 20 Hz closed
        loop has spectral radius ≤ 0.95 (ω = 3, ζ = 1 is unstable).

        Parameters
        ----------
        natural_frequency : float
            ω > 0 (rad/s).
        damping : float
            ζ > 0.

        Returns
        -------
        ndarray, shape (4, 8)
            G = [K_p, K_d] (row-major as ω; u = G x̃).
        """
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
        """N(ω | vec G, Σ) around the LQR gain G of :meth:`lqr_gain`, flattened row-major.

        Σ is diagonal with standard deviations ``exploration_std_fraction`` × |G| entry-wise
        (default :attr:`exploration_std_fraction`).

        Parameters
        ----------
        control_weight : float
            R / I of the LQR design (> 0): 1e-4 balances tightly, ≥ 1 is the sluggish
            minimum-effort controller (its gains barely change above 1).
        exploration_std_fraction : float, optional
            > 0.

        Returns
        -------
        GaussianPolicy
        """
        frac = (
            self.exploration_std_fraction
            if exploration_std_fraction is None
            else check_positive(exploration_std_fraction, "exploration_std_fraction")
        )
        g = self.lqr_gain(control_weight=control_weight).ravel()
        return GaussianPolicy(g, np.diag((frac * np.abs(g)) ** 2))

    def initial_policy(self) -> GaussianPolicy:
        """N(ω | vec(G_lqr), Σ_0): a stabilising gain whose samples all balance.

        :meth:`lqr_policy` with R = 1e-4 I and exploration 0.2% of |G_lqr| entry-wise: the
        20 Hz closed loop is sensitive to independent perturbations of the 32 gains (at 1% a
        quarter of the samples are unstable at upright; see :func:`design_policy` for broad
        exploration).
        """
        return self.lqr_policy()


def balancing_transitions(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (x_t, u_t, x_{t+1}) transitions of a balancing trajectory at the control rate.

    The same as :meth:`Balancing.transitions` (the training data of GP forward models and
    conditional embeddings, Chs. 4–5), for callers without a task instance.

    Parameters
    ----------
    trajectory : Trajectory
        A (non-failed) :class:`Balancing` trajectory with T + 1 states.

    Returns
    -------
    x : ndarray, shape (T, 8)
    u : ndarray, shape (T, 4)
        Commanded torques (the torque noise is part of the stochastic dynamics).
    x_next : ndarray, shape (T, 8)
    """
    return state_transitions(trajectory, 8, 4)


def feedback_policy(gains, reference=None, feedforward=None):
    """The sampler policy u = G_b (x − r_t) + u_ff,t for pair b (default r_t = x_up, u_ff = 0).

    Parameters
    ----------
    gains : Tensor, shape (B, 4, 8)
    reference : array_like, shape (T+1, 8), optional
        r_t, e.g. from :meth:`Balancing.swing_reference`.
    feedforward : array_like, shape (T+1, 4), optional

    Returns
    -------
    callable
        ``policy(t, x, pair) -> u`` for
        :func:`~skillkit.models.sampling.sample_trajectories`, on the device and dtype of
        ``gains``.
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
    """Rewards of sampled (predicted) state trajectories under the feedback u = G_b x̃.

    Parameters
    ----------
    task : Balancing
    states : ndarray, shape (B, L, T+1, 8)
        L sampled trajectories for each of B controllers.
    gains : ndarray, shape (B, 4, 8)

    Returns
    -------
    ndarray, shape (B, L)
        :meth:`Balancing.reward_batch` of each trajectory with the commanded torques
        recomputed from the states; non-finite rewards (diverged samples) are
        :attr:`Balancing.worst_reward`, as :meth:`Task.reward` scores them.
    """
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
    """``n`` samples ω ~ π(ω) whose feedback balances robustly.

    ω is kept if the closed loop of the task's linearisation at upright (Δt = control period)
    is stable with margin: ρ(A_c + B_c G) ≤ ``max_spectral_radius``, G = ω as (4, 8); Sec.
    4.2.3 uses a controller that "robustly balances" the robot.

    Parameters
    ----------
    task : Balancing
    n : int
    rng : Generator, int or None
        Randomness; one stream for every draw (same seed ⇒ same gains).
    max_spectral_radius : float
    policy : GaussianPolicy, optional
        π(ω) (default: the task's :meth:`~Balancing.initial_policy`).

    Raises
    ------
    RuntimeError
        If more than 100 n samples are needed.

    Returns
    -------
    ndarray, shape (n, 32)
    """
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
    """Roll out ``n_trajectories`` robustly balancing ω (:func:`stable_gains` of ``policy``,
    default the task's initial policy) from random x_0; or one fixed controller ``gain``.

    Failed rollouts (the robot fell or diverged) are replaced by new ones and counted.

    Parameters
    ----------
    task : Balancing
    n_trajectories : int
    rng : Generator, int or None
        Randomness of the gains, start states and noise: one stream for every rollout
        (same seed ⇒ same data).
    max_spectral_radius : float
        See :func:`stable_gains` (not used with ``gain``).
    policy : GaussianPolicy, optional
        π(ω) the controllers are drawn from (not with ``gain``).
    gain : array_like, shape (4, 8) or (32,), optional
        One controller G for every rollout (e.g. :meth:`Balancing.pd_gain`): only x_0 and
        the torque noise vary.

    Returns
    -------
    dict
        ``omegas`` (n, 32), ``trajectories`` (list), ``x``, ``u``, ``x_next`` (n·T, ·) the
        stacked transitions, ``n_failed``.
    """
    rng = as_generator(rng)
    omegas, trajs, n_failed = [], [], 0
    if gain is not None:
        if policy is not None:
            raise ValueError("gain: give either a fixed gain or a policy, not both")
        fixed = check_array(gain, "gain", ndim=(1, 2)).reshape(-1)
        if fixed.size != 32:
            raise ValueError(f"gain: expected shape (4, 8) or (32,), got {np.shape(gain)}")
        candidates = []
    else:
        candidates = list(stable_gains(task, n_trajectories, rng, max_spectral_radius, policy))
    while len(trajs) < n_trajectories:
        if gain is not None:
            candidates = [fixed]
        elif not candidates:
            candidates = list(stable_gains(task, 1, rng, max_spectral_radius, policy))
        omega = candidates.pop(0)
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


def random_lqr_gains(
    task: Balancing, n: int, spread: float, control_weight: float, rng
) -> np.ndarray:
    """Stabilising controllers: LQR gains for randomly scaled cost weights.

    Q = diag(q_task ⊙ exp(s ξ)), R = r₀ exp(s ξ') I with ξ ~ N(0, I), ξ' ~ N(0, 1), s =
    ``spread`` and r₀ = ``control_weight``; each gain is :meth:`Balancing.lqr_gain`.

    Parameters
    ----------
    task : Balancing
    n : int
        Number of gains, ≥ 1.
    spread : float
        s ≥ 0, the log-scale spread of the cost weights.
    control_weight : float
        r₀ > 0.
    rng : Generator, int or None
        Randomness (same seed ⇒ same gains).

    Returns
    -------
    ndarray, shape (n, 4, 8)
        Gains G with u = G x̃.
    """
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
    """A Gaussian π(ω) = N(ω | mean, c² Σ_d) whose exploration follows balancing controllers.

    Σ_d is the sample covariance of n designs ω_i = κ_i vec G_i: G_i the
    :func:`random_lqr_gains` for randomly scaled cost weights (log-scale ``spread``, base R
    ``control_weight``) and κ_i = exp(β ξ_i), ξ_i ~ N(0, 1), β = ``scale_std``, a random
    overall gain level. Its directions are those in which balancing gains differ, so a broad
    π(ω) still has balancing samples (isotropic exploration of a few % of |G| does not).
    Σ_d has rank below 32; 10⁻⁶ of its mean variance is added to every direction.

    Parameters
    ----------
    task : Balancing
    mean : array_like, shape (32,) or (4, 8)
        The policy mean (G row-major).
    exploration : float
        c > 0, the scale of the exploration (standard deviations relative to the designs').
    n_designs : int
        n ≥ 2.
    spread, control_weight : float
        See :func:`random_lqr_gains`.
    scale_std : float
        β ≥ 0.
    rng : Generator, int or None
        Randomness of the designs (a fixed seed gives the same π(ω) every time).

    Returns
    -------
    GaussianPolicy
    """
    mu = check_array(mean, "mean", ndim=(1, 2)).reshape(-1)
    if mu.size != 32:
        raise ValueError(f"mean: expected shape (32,) or (4, 8), got {np.shape(mean)}")
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
    """Balancing with Sec. 5.4's settings: torque noise std 4 N m, T = 40, and reward
    −10 q̃ᵀq̃ − 0.1 q̇ᵀq̇ − 1e-5 uᵀu."""
    kwargs.setdefault("torque_noise_std", 4.0)
    kwargs.setdefault("state_weights", np.concatenate([np.full(4, 10.0), np.full(4, 0.1)]))
    kwargs.setdefault("control_weight", 1e-5)
    return Balancing(**kwargs)
