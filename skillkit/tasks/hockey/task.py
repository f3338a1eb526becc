"""The hockey task (Appendix C.2): context, DMP policy, arm and puck simulation, reward."""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np

from skillkit._validation import check_array, check_type
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks.base import ModelSignals, SimulationFailure, Task, check_count
from skillkit.tasks.controllers import control_substeps, track_reference
from skillkit.tasks.hockey.arm import (
    KD,
    KP,
    N_JOINTS,
    TIMESTEP,
    TORQUE_LIMITS,
    arm_model,
    blade_pose,
)
from skillkit.tasks.hockey.demonstration import load_demonstration
from skillkit.tasks.hockey.reward import Observation, butterworth_smooth, hockey_reward_batch
from skillkit.tasks.hockey.table import CONTROL_PUCK_START, PuckTable, TablePhysics
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

CONTEXT_LOW = np.array([1.5, 0.5, 0.0])
CONTEXT_HIGH = np.array([2.5, 1.0, 1.0])
REAL_CONTEXT_LOW = np.array([1.5, 0.4, 0.0])
REAL_CONTEXT_HIGH = np.array([2.0, 0.8, 0.6])
TAU_RANGE = (0.25, 4.0)
"""Admissible DMP time scaling τ (stroke durations 2 s … 0.125 s)."""
FOLLOW_THROUGH = 0.2
"""Duration of the follow-through after the DMP ends, s."""
FOLLOW_THROUGH_TAU = 0.05
"""Time constant of the follow-through's velocity decay, s."""
MAX_DURATION = 8.0
"""Longest episode, s (the pucks usually stop earlier)."""
RECORD_DT = 0.008
"""Sampling period of the recorded arm and puck signals, s."""
EXPLORATION_STD = np.concatenate(
    [[0.06, 0.04, 0.06, 0.05, 0.06, 0.05, 0.2], np.full(N_JOINTS, 0.25), [0.1]]
)
"""Default initial exploration standard deviations of ω = [g, ġ, τ], shape (15,)."""


class Hockey(Task):
    """Robot hockey of Appendix C.2 (:mod:`skillkit.tasks.hockey`).

    Parameters
    ----------
    context_low, context_high : array_like, shape (3,)
        Ranges of s = [b_x, b_y, d*] (default: the simulated task of C.2).
    physics : TablePhysics
    observation : Observation, optional
        Noisy puck tracking of the real-robot setting, read (smoothed) by the reward.
    exploration_std : array_like, shape (15,), optional
        Of the initial policy (default :data:`EXPLORATION_STD`).
    name : str
    """

    context_dim = 3
    parameter_dim = 2 * N_JOINTS + 1
    context_names = ("b_x", "b_y", "d_star")
    worst_reward = -20.0
    """Below any working rollout (‖x_0 − b‖ < 3 m; a launched puck travels a few metres)."""

    def __init__(
        self,
        context_low=CONTEXT_LOW,
        context_high=CONTEXT_HIGH,
        physics: TablePhysics = TablePhysics(),  # noqa: B008  (frozen dataclass)
        observation: Observation | None = None,
        exploration_std=None,
        name: str = "hockey",
    ) -> None:
        self.name = name
        self.context_low = check_array(context_low, "context_low", shape=(3,)).copy()
        self.context_high = check_array(context_high, "context_high", shape=(3,)).copy()
        if np.any(self.context_low > self.context_high):
            raise ValueError("context_high: expected context_low <= context_high elementwise")
        check_type(physics, TablePhysics, "physics", "a TablePhysics")
        if observation is not None and not isinstance(observation, Observation):
            raise ValueError(f"observation: expected an Observation, got {observation!r}")
        self.physics = physics
        self.observation = observation
        self.model = arm_model(TIMESTEP)
        try:
            control_substeps(self.model, physics.dt)
        except ValueError as exc:  # the arm's control period is the table's time step
            raise ValueError(f"physics: dt is the arm's control period; {exc}") from None
        self.data = mujoco.MjData(self.model)
        self._site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "blade")
        demo = load_demonstration()
        dmp = DMP(N_JOINTS, n_basis=10, dt=TIMESTEP)
        dmp.fit(demo["times"], demo["q"], demo["qd"], demo["qdd"])
        self.q0 = demo["q"][0].copy()
        self.dmp_parameters = DMPParameters(dmp, learn=("goal", "goal_velocity", "tau"))
        self.demo_omega = self.dmp_parameters.to_vector()
        std = EXPLORATION_STD.copy() if exploration_std is None else exploration_std
        self.exploration_std = check_array(std, "exploration_std", shape=(self.parameter_dim,))
        if np.any(self.exploration_std <= 0):
            raise ValueError("exploration_std: expected positive standard deviations")
        self._record_every = max(1, int(round(RECORD_DT / physics.dt)))

    def initial_policy(self):
        """π(ω|s) = N(ω_demo, Σ₀), zero gain (Sec. 3.4.2): Σ₀ = blockdiag(P D_g P + (0.1 σ̄_g)² I,
        P D_ġ P + (0.1 σ̄_ġ)² I, σ_τ²), D the squared :attr:`exploration_std`, σ̄ their means,
        P = I − n nᵀ removing the blade-height direction n ∝ ∂z/∂q at the demonstrated goal."""
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.demo_omega[:N_JOINTS]
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        jacp = np.zeros((3, N_JOINTS))
        mujoco.mj_jacSite(self.model, data, jacp, None, self._site)
        n = jacp[2] / np.linalg.norm(jacp[2])
        proj = np.eye(N_JOINTS) - np.outer(n, n)
        cov = np.zeros((self.parameter_dim, self.parameter_dim))
        for block in (slice(0, N_JOINTS), slice(N_JOINTS, 2 * N_JOINTS)):
            std = self.exploration_std[block]
            cov[block, block] = proj @ np.diag(std**2) @ proj + (0.1 * std.mean()) ** 2 * np.eye(
                N_JOINTS
            )
        cov[-1, -1] = self.exploration_std[-1] ** 2
        return LinearGaussianPolicy(self.demo_omega.copy(), cov, context_dim=self.context_dim)

    def reference(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times (T,), q_ref, qd_ref (T, 7) of ω's DMP stroke and follow-through at ``physics.dt``;
        :class:`SimulationFailure` for τ outside :data:`TAU_RANGE`."""
        tau = float(omega[-1])
        if not TAU_RANGE[0] <= tau <= TAU_RANGE[1]:
            raise SimulationFailure(
                f"tau={tau:g} is outside the executable range [{TAU_RANGE[0]:g}, {TAU_RANGE[1]:g}]"
            )
        dmp = self.dmp_parameters.from_vector(omega)
        dt = self.physics.dt
        n_dmp = int(math.ceil(dmp.duration / tau / dt - 1e-9))
        q, qd, _ = dmp.rollout(dt * np.arange(n_dmp + 1), self.q0)
        s = dt * np.arange(1, int(round(FOLLOW_THROUGH / dt)) + 1)
        decay = np.exp(-s / FOLLOW_THROUGH_TAU)
        q_ft = q[-1] + qd[-1] * (FOLLOW_THROUGH_TAU * (1.0 - decay))[:, None]
        qd_ft = qd[-1] * decay[:, None]
        q_ref = np.vstack([q, q_ft])
        qd_ref = np.vstack([qd, qd_ft])
        return dt * np.arange(q_ref.shape[0]), q_ref, qd_ref

    def simulate_arm(self, omega: np.ndarray) -> dict[str, np.ndarray]:
        """Track the reference of ω in MuJoCo: ``times`` (T,), ``q``, ``qd``, ``u`` (T, 7), the
        ``blade`` pose (T, 6) of :func:`blade_pose` and ``n_saturated``."""
        times, q_ref, qd_ref = self.reference(omega)
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = self.q0
        mujoco.mj_forward(model, data)
        site_pos, site_mat, site = np.empty((len(times), 3)), np.empty((len(times), 9)), self._site

        def record(t: int, d: mujoco.MjData) -> None:
            site_pos[t] = d.site_xpos[site]
            site_mat[t] = d.site_xmat[site]

        out = track_reference(
            model,
            data,
            q_ref,
            qd_ref,
            self.physics.dt,
            KP,
            KD,
            torque_limit=TORQUE_LIMITS,
            on_step=record,
        )
        out["times"] = times
        out["blade"] = blade_pose(site_pos, site_mat.reshape(-1, 3, 3))
        return out

    def _simulate(self, omega, context, rng) -> Trajectory:
        arm = self.simulate_arm(omega)
        phys = self.physics
        table = PuckTable(CONTROL_PUCK_START, context[:2], phys)
        blade = arm["blade"]
        down = (blade[:, 4] < phys.puck_height) & (blade[:, 5] > 0.0)
        every = self._record_every
        puck_times, pucks = [0.0], [table.positions]
        n_arm = blade.shape[0]
        for k in range(n_arm - 1):  # racket phase: one table step per control step
            table.move_racket(blade[k, [0, 1, 3]], blade[k + 1, [0, 1, 3]], bool(down[k]))
            table.step()
            if (k + 1) % every == 0:
                puck_times.append(table.time)
                pucks.append(table.positions)
        table.lift_racket()
        while table.time < MAX_DURATION - 1e-9 and not table.at_rest:  # pucks only
            table.step(phys.free_dt)
            puck_times.append(table.time)
            pucks.append(table.positions)
        if puck_times[-1] < table.time:
            puck_times.append(table.time)
            pucks.append(table.positions)
        puck_times, pucks = np.array(puck_times), np.array(pucks)
        if not np.all(np.isfinite(pucks)):
            raise SimulationFailure("non-finite puck positions in pymunk")
        arm_rows = slice(0, n_arm, every)
        signals = {
            "racket": blade[arm_rows, :4],
            "puck_times": puck_times,
            "control_puck": pucks[:, 0],
            "target_puck": pucks[:, 1],
        }
        if self.observation is not None:
            signals.update(self._observe(puck_times, pucks, rng))
        displacement = float(np.linalg.norm(pucks[-1, 1] - pucks[0, 1]))
        info = {
            "hit": table.hit_time is not None,
            "hit_time": table.hit_time,
            "racket_touched": bool(table.racket_touched),
            "displacement": displacement,
            "tau": float(omega[-1]),
            "n_saturated": int(arm["n_saturated"]),
            "blade_lowest": float(blade[:, 4].min()),
            "pucks_at_rest": bool(table.at_rest),
        }
        return Trajectory(
            times=arm["times"][arm_rows],
            states=np.hstack([arm["q"], arm["qd"]])[arm_rows],
            controls=arm["u"][arm_rows],
            signals=signals,
            info=info,
        )

    def _observe(self, puck_times, pucks, rng) -> dict[str, np.ndarray]:
        """Noisy samples of both pucks at the observation rate (linear interpolation)."""
        obs = self.observation
        t_obs = np.arange(0.0, puck_times[-1] + 1e-12, 1.0 / obs.rate)
        out = {"observation_times": t_obs}
        for j, key in enumerate(("control_puck_observed", "target_puck_observed")):
            clean = np.column_stack([np.interp(t_obs, puck_times, pucks[:, j, i]) for i in (0, 1)])
            out[key] = clean + obs.noise * rng.standard_normal(clean.shape)
        return out

    def reward_signals(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """The puck trajectories (T, 2) the reward reads (observed in the real setting)."""
        sig = trajectory.signals
        keys = self._reward_keys()
        if any(k not in sig for k in keys):
            raise ValueError(f"trajectory: the {self.name} reward needs the signals {keys}")
        return {k: sig[k] for k in keys}

    def _reward_keys(self) -> tuple[str, str]:
        if self.observation is None:
            return ("control_puck", "target_puck")
        return ("control_puck_observed", "target_puck_observed")

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """R = −min_t ‖x_t − b‖ − |d_T − d*| (:func:`hockey_reward_batch`) of the puck paths in
        ``signals`` (B, T, 2) (Butterworth-smoothed first in the real setting), shape (B,)."""
        x, y = (np.asarray(signals[k], dtype=np.float64) for k in self._reward_keys())
        obs = self.observation
        if obs is not None:
            smooth = functools.partial(
                butterworth_smooth, rate=obs.rate, cutoff=obs.cutoff, order=obs.order, axis=1
            )
            x, y = smooth(x), smooth(y)
        return hockey_reward_batch(x, y, contexts)

    supports_model_rollout = False
    no_model_rollout_reason = (
        "hockey is modelled by decomposed GP models of discrete puck events (Sec. 4.3.3: "
        "the puck state past the racket from ω, free sliding, puck contact), not by a step "
        "model of the arm under its tracking controller"
    )

    def model_signals(self) -> ModelSignals:
        """The pucks' (x, y) positions; no control input (ω enters the event models)."""
        return ModelSignals(
            state=("control_puck_x", "control_puck_y", "target_puck_x", "target_puck_y"),
            signals=self._reward_keys(),
        )

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """The pucks at rest, [x_control, b] for every draw, shape (n, 4); ``rng`` unused."""
        s = self.check_context(context)
        return np.tile(np.concatenate([CONTROL_PUCK_START, s[:2]]), (check_count(n), 1))

    def scene_model(self) -> mujoco.MjModel:
        """The arm's compiled MuJoCo model (the pucks and table are drawn by the viewer)."""
        return self.model


@register("hockey", "contextual")
def hockey(**kwargs) -> Hockey:
    """Simulated hockey of Appendix C.2: b_x ∈ [1.5, 2.5], b_y ∈ [0.5, 1], d* ∈ [0, 1] m."""
    return Hockey(**kwargs)


@register("hockey-real", "contextual")
def hockey_real(**kwargs) -> Hockey:
    """Real-robot setting of C.2: b_x ∈ [1.5, 2], b_y ∈ [0.4, 0.8], d* ∈ [0, 0.6] m, pucks
    observed at 30 Hz with 1 cm noise and Butterworth-smoothed before the reward."""
    kwargs.setdefault("context_low", REAL_CONTEXT_LOW)
    kwargs.setdefault("context_high", REAL_CONTEXT_HIGH)
    kwargs.setdefault("observation", Observation())
    kwargs.setdefault("name", "hockey-real")
    return Hockey(**kwargs)
