"""The table-tennis task (Sec. 3.4.3, Appendix C.3): DMP stroke, arm, ball, reward."""

from __future__ import annotations

import mujoco
import numpy as np

from skillkit._validation import check_array, check_positive, check_type
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks.base import ModelSignals, SimulationFailure, Task, check_count
from skillkit.tasks.controllers import control_substeps, track_reference
from skillkit.tasks.registry import register
from skillkit.tasks.table_tennis.arm import (
    INITIAL_STD,
    JOINT_NAMES,
    KD,
    KP,
    RACKET_SITE,
    TORQUE_LIMIT,
    arm_model,
)
from skillkit.tasks.table_tennis.ball import (
    RETURN_HIGH,
    RETURN_LOW,
    RETURN_NEAR_HIGH,
    RETURN_NEAR_LOW,
    SERVE_POSITION,
    VELOCITY_HIGH,
    VELOCITY_LOW,
    BallPhysics,
    RacketPath,
    on_table,
    simulate_ball,
)
from skillkit.tasks.table_tennis.demonstration import load_demonstration
from skillkit.trajectory import Trajectory


class TableTennis(Task):
    """Return an incoming ball to a target on the opponent's side (Sec. 3.4.3, App. C.3).

    ω = [g (8), ġ (8), τ] of a per-joint DMP fitted to the forehand demonstration, PD-tracked
    at ``control_dt`` for ``duration`` s; the ball is followed until it lands. s = [v_x, v_y,
    v_z, b_x, b_y] is uniform on :data:`VELOCITY_LOW`/:data:`VELOCITY_HIGH` ×
    ``return_low``/``return_high``. Deterministic (``rng`` unused).

    Parameters
    ----------
    return_low, return_high : array_like, shape (2,)
        Corners of the return zone (m) on the opponent's half (default the whole half, C.3).
    reward_weights : tuple of float
        (c₁, c₂) of Eq. C.1, in 1/m.
    duration, control_dt, physics_dt : float
        Episode length, control (and recording) period and MuJoCo step (s).
    ball : BallPhysics, optional
    name : str

    Notes
    -----
    Signals ``ball``, ``racket``, ``racket_normal`` (T, 3); ``info``: ``hit``, ``net``,
    ``landing_point`` p (2,), ``outcome`` (returned/net/out/missed), ``hit_time``,
    ``incoming_end`` (the first racket contact, else the landing), ``landing_time``,
    ``n_saturated``.
    """

    context_dim = 5
    parameter_dim = 17
    context_names = ("v_x", "v_y", "v_z", "b_x", "b_y")
    worst_reward = -5.0
    """Below any working rollout (drag bounds the flight, so R > −2)."""

    def __init__(
        self,
        reward_weights: tuple[float, float] = (0.1, 0.1),
        duration: float = 1.2,
        control_dt: float = 0.004,
        physics_dt: float = 0.002,
        ball: BallPhysics | None = None,
        name: str = "table-tennis",
        return_low=RETURN_LOW,
        return_high=RETURN_HIGH,
    ):
        low = check_array(return_low, "return_low", shape=(2,))
        high = check_array(return_high, "return_high", shape=(2,))
        if np.any(low > high) or low[0] < 0.0 or not (on_table(*low) and on_table(*high)):
            raise ValueError(
                f"return_low, return_high: expected corners low <= high of a zone on the "
                f"opponent's half of the table, got {low.tolist()} and {high.tolist()}"
            )
        self.context_low = np.concatenate([VELOCITY_LOW, low])
        self.context_high = np.concatenate([VELOCITY_HIGH, high])
        c = check_array(reward_weights, "reward_weights", shape=(2,))
        if np.any(c < 0):
            raise ValueError(f"reward_weights: expected non-negative (c1, c2), got {c.tolist()}")
        self.reward_weights = (float(c[0]), float(c[1]))
        self.duration = check_positive(duration, "duration")
        self.control_dt = check_positive(control_dt, "control_dt")
        self.physics_dt = check_positive(physics_dt, "physics_dt")
        self.ball = check_type(
            BallPhysics() if ball is None else ball, BallPhysics, "ball", "a BallPhysics"
        )
        self.name = name
        demo = load_demonstration()
        self.dmp = DMP(len(JOINT_NAMES), n_basis=10, alpha_z=4.0, dt=self.control_dt).fit(
            demo["times"], demo["q"], demo["qd"], demo["qdd"]
        )
        self.parameters = DMPParameters(self.dmp, learn=("goal", "goal_velocity", "tau"))
        self.q0 = np.asarray(demo["q"][0], dtype=np.float64).copy()
        self.times = self.control_dt * np.arange(int(round(self.duration / self.control_dt)) + 1)
        if self.times.shape[0] < 2:
            raise ValueError(f"duration: expected at least one control period, got {duration:g} s")
        self.model = arm_model(self.physics_dt)
        control_substeps(self.model, self.control_dt)  # a whole multiple of physics_dt
        self.data = mujoco.MjData(self.model)
        self._site = self.model.site(RACKET_SITE).id

    def check_omega(self, omega, name: str = "omega") -> np.ndarray:
        """Shape (17,), finite, and a positive time scaling τ = ω[16]."""
        omega = super().check_omega(omega, name)
        if omega[-1] <= 0:
            raise ValueError(f"{name}: its tau entry (index 16) must be > 0, got {omega[-1]:g}")
        return omega

    def initial_policy(self) -> LinearGaussianPolicy:
        """π(ω|s) = N(ω_demo, diag(:data:`INITIAL_STD`²)), zero context gain (Sec. 3.5)."""
        return LinearGaussianPolicy(
            self.parameters.to_vector(), np.diag(INITIAL_STD**2), context_dim=5
        )

    def _simulate(self, omega, context, rng) -> Trajectory:
        dmp = self.parameters.from_vector(omega)
        q_ref, qd_ref, _ = dmp.rollout(self.times, self.q0)
        model, data, sid = self.model, self.data, self._site
        T = self.times.shape[0]
        center, normal = np.empty((T, 3)), np.empty((T, 3))
        velocity, spin = np.empty((T, 3)), np.empty((T, 3))
        buf = np.empty(6)

        def record(k: int, d) -> None:
            center[k] = d.site_xpos[sid]
            normal[k] = d.site_xmat[sid, 1::3]
            mujoco.mj_objectVelocity(model, d, mujoco.mjtObj.mjOBJ_SITE, sid, buf, 0)
            spin[k], velocity[k] = buf[:3], buf[3:]

        mujoco.mj_resetData(model, data)
        data.qpos[:] = self.q0
        out = track_reference(
            model,
            data,
            q_ref,
            qd_ref,
            self.control_dt,
            KP,
            KD,
            torque_limit=TORQUE_LIMIT,
            on_step=record,
        )
        if not (np.all(np.isfinite(center)) and np.all(np.isfinite(normal))):
            raise SimulationFailure("non-finite racket pose")
        racket = RacketPath(self.times, center, normal, velocity, spin)
        flight = simulate_ball(
            SERVE_POSITION,
            context[:3],
            self.duration,
            dt=self.control_dt,
            physics=self.ball,
            racket=racket,
        )
        end = flight.terminal
        if end is None:
            raise SimulationFailure("the ball did not come down within the simulated time")
        hit = flight.first("racket")
        p = end.position[:2]
        if hit is None:
            outcome = "missed"
        elif end.kind == "net":
            outcome = "net"
        elif p[0] > 0 and on_table(p[0], p[1]):
            outcome = "returned"
        else:
            outcome = "out"
        info = {
            "hit": hit is not None,
            "net": hit is not None and end.kind == "net",
            "landing_point": p.tolist(),
            "outcome": outcome,
            "hit_time": None if hit is None else float(hit.time),
            "incoming_end": float(end.time if hit is None else hit.time),
            "landing_time": float(end.time),
            "n_saturated": int(out["n_saturated"]),
        }
        return Trajectory(
            times=self.times.copy(),
            states=np.hstack([out["q"], out["qd"]]),
            controls=out["u"],
            signals={"ball": flight.positions, "racket": center, "racket_normal": normal},
            info=info,
        )

    def reward_signals(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """``ball``, ``racket`` (T, 3), ``landing_point`` p (2,) and ``incoming_steps``, the
        samples up to ``info["incoming_end"]`` and one after it."""
        t = trajectory.times
        keep = min(
            int(np.searchsorted(t, trajectory.info["incoming_end"], side="right")) + 1, t.shape[0]
        )
        return {
            "ball": trajectory.signals["ball"],
            "racket": trajectory.signals["racket"],
            "landing_point": np.asarray(trajectory.info["landing_point"], dtype=np.float64),
            "incoming_steps": np.asarray(float(keep)),
        }

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """R = −c₁ min_t ‖τ_b − τ_r‖ − c₂ ‖b − p‖ (Eq. C.1), shape (B,), of ``signals`` ``ball``,
        ``racket`` (B, T, 3), ``landing_point`` (B, 2) and ``incoming_steps`` (B,); the minimum
        runs over the first ``incoming_steps`` samples (:func:`min_segment_distance`)."""
        c1, c2 = self.reward_weights
        ball = check_array(signals["ball"], "signals['ball']", shape=(None, None, 3), finite=False)
        n, T = ball.shape[:2]
        racket = check_array(signals["racket"], "signals['racket']", shape=(n, T, 3), finite=False)
        p = check_array(
            signals["landing_point"], "signals['landing_point']", shape=(n, 2), finite=False
        )
        steps = check_array(signals["incoming_steps"], "signals['incoming_steps']", shape=(n,))
        if np.any(steps != np.round(steps)) or np.any(steps < 1) or np.any(steps > T):
            raise ValueError(f"incoming_steps: expected integers in [1, {T}], got {steps}")
        steps = steps.astype(int)
        b = check_array(contexts, "contexts", shape=(n, self.context_dim))[:, 3:5]
        return np.array(
            [
                -c1 * min_segment_distance(ball[i, : steps[i]] - racket[i, : steps[i]])
                - c2 * float(np.linalg.norm(b[i] - p[i]))
                for i in range(ball.shape[0])
            ]
        )

    supports_model_rollout = False
    no_model_rollout_reason = (
        "table tennis is modelled by decomposed GP models of ball events (Sec. 4.3.4: the "
        "ball state where it meets the racket, the return after the hit), not by a step "
        "model of the arm under its tracking controller"
    )

    def model_signals(self) -> ModelSignals:
        """The ball's position and velocity; no control input (ω enters the event models)."""
        return ModelSignals(
            state=("ball_x", "ball_y", "ball_z", "ball_vx", "ball_vy", "ball_vz"),
            signals=("ball", "racket", "landing_point", "incoming_steps"),
        )

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """The served ball [:data:`SERVE_POSITION`, s[:3]] for every draw, shape (n, 6)."""
        s = self.check_context(context)
        return np.tile(np.concatenate([SERVE_POSITION, s[:3]]), (check_count(n), 1))

    def scene_model(self):
        """The arm's compiled MuJoCo model (table, net and ball are drawn by the viewer)."""
        return self.model


def min_segment_distance(relative) -> float:
    """Smallest ‖d‖ along the polyline through the rows of ``relative`` (n, 3)."""
    d = check_array(relative, "relative", ndim=2)
    if d.shape[0] == 1:
        return float(np.linalg.norm(d[0]))
    a, delta = d[:-1], np.diff(d, axis=0)
    dd = np.einsum("ij,ij->i", delta, delta)
    u = np.where(dd > 0, -np.einsum("ij,ij->i", a, delta) / np.where(dd > 0, dd, 1.0), 0.0)
    closest = a + np.clip(u, 0.0, 1.0)[:, None] * delta
    return float(np.sqrt(np.einsum("ij,ij->i", closest, closest).min()))


@register("table-tennis", "contextual")
def table_tennis(**kwargs) -> TableTennis:
    """Sec. 3.4.3 / App. C.3 setting: targets on the whole opponent's half, c₁ = c₂ = 0.1."""
    return TableTennis(**kwargs)


@register("table-tennis-near", "contextual")
def table_tennis_near(**kwargs) -> TableTennis:
    """Targets only in the near return zone x ∈ [0.2, 0.6], y ∈ [−0.4, 0.4] m."""
    kwargs.setdefault("return_low", RETURN_NEAR_LOW)
    kwargs.setdefault("return_high", RETURN_NEAR_HIGH)
    kwargs.setdefault("name", "table-tennis-near")
    return TableTennis(**kwargs)
