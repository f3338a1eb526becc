"""Ball throwing (Sec. 3.4.1) on the planar 4-link robot of Appendix C.1
(:mod:`skillkit.tasks.planar_model`), stepped at 1 ms with torques held per control period."""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np

from skillkit._validation import check_array, check_positive
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.base import ModelSignals, SimulationFailure, Task, check_count
from skillkit.tasks.controllers import control_substeps, track_reference
from skillkit.tasks.planar_model import (
    LINK_LENGTHS,
    STATE_NAMES,
    TIMESTEP,
    TORQUE_NAMES,
    UPRIGHT,
    PlanarRobot,
    rigid_body_terms,
)
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

__all__ = [
    "Throwing",
    "ballistic_flight",
    "hand_kinematics",
    "joint_limit_penalty",
    "path_distances",
    "throwing_demonstration",
]

DEMONSTRATION_FILE = (
    Path(__file__).resolve().parents[1] / "data" / "demonstrations" / "throwing.npz"
)
"""The shipped demonstration: ``np.savez_compressed(path, **throwing_demonstration())``."""

# Joint and velocity limits of Appendix C.1, x = [q, q̇].
X_LOWER = np.array([-0.8, -2.5, -0.1, 0.0, -50.0, -50.0, -50.0, -50.0])
X_UPPER = np.array([0.8, 0.05, 2.0, 1.5 * np.pi, 50.0, 50.0, 50.0, 50.0])
#: Numbers per block of the row-wise batch computations (:func:`_by_rows`).
BLOCK_ENTRIES = 1 << 18


def hand_kinematics(q, qd=None) -> tuple[np.ndarray, np.ndarray | None]:
    """Closed-form hand [x, y] (y up) of ``q`` (..., 4) and its velocity for ``qd`` (else None).

    Absolute angles θ_k = q_1 + … + q_k; links 1–3 point along (sin θ_k, cos θ_k), the arm
    along (−sin θ_4, −cos θ_4).
    """
    q = check_array(q, "q")
    if q.shape[-1:] != (4,):
        raise ValueError(f"q: expected shape (..., 4), got {q.shape}")
    theta = np.cumsum(q, axis=-1)
    sign = np.array([1.0, 1.0, 1.0, -1.0]) * LINK_LENGTHS
    pos = np.stack([(sign * np.sin(theta)).sum(-1), (sign * np.cos(theta)).sum(-1)], axis=-1)
    if qd is None:
        return pos, None
    qd = check_array(qd, "qd", shape=q.shape)
    theta_d = np.cumsum(qd, axis=-1)
    vel = np.stack(
        [(sign * np.cos(theta) * theta_d).sum(-1), (-sign * np.sin(theta) * theta_d).sum(-1)],
        axis=-1,
    )
    return pos, vel


def ballistic_flight(
    position, velocity, gravity: float = 9.81, dt: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Drag-free flight b(t) = p_0 + v_0 t − ½ g t² e_y from the release ``position`` [x, y]
    and ``velocity`` (y up), sampled every ``dt`` s and at the landing time
    t_land = (v_y + √(v_y² + 2 g p_y)) / g (0 for p_y ≤ 0). Returns times (N,), path (N, 2).
    """
    p = check_array(position, "position", shape=(2,))
    v = check_array(velocity, "velocity", shape=(2,))
    g = check_positive(gravity, "gravity")
    dt = check_positive(dt, "dt")
    t_land = 0.0 if p[1] <= 0.0 else (v[1] + np.sqrt(v[1] ** 2 + 2.0 * g * p[1])) / g
    n = int(np.floor(t_land / dt))
    t = np.append(np.arange(n + 1) * dt, t_land) if t_land > n * dt else np.arange(n + 1) * dt
    path = p + np.outer(t, v)
    path[:, 1] -= 0.5 * g * t**2
    if t_land > 0:
        path[-1, 1] = 0.0  # the root of the quadratic, up to rounding
    return t, path


def path_distances(paths, points) -> np.ndarray:
    """min_t ‖b_t − s‖ of Appendix C.1: distances (B,) from ``points`` (B, 2) to the polylines
    ``paths`` (B, N, 2) (segments between the samples)."""
    paths = check_array(paths, "paths", shape=(None, None, 2))
    points = check_array(points, "points", shape=(paths.shape[0], 2))
    if paths.shape[1] == 0:
        raise ValueError("path: expected at least one point")
    if paths.shape[1] == 1:
        return np.array([np.linalg.norm(p[0] - s) for p, s in zip(paths, points, strict=True)])
    return _by_rows(_path_distances, paths, points)


def _by_rows(fn, *arrays, entries: int = BLOCK_ENTRIES):
    """``fn(*arrays)`` of a row-wise function on blocks of about ``entries`` numbers."""
    n, per_row = arrays[0].shape[0], max(1, math.prod(arrays[0].shape[1:]))
    rows = max(1, entries // per_row)
    if n <= rows:
        return fn(*arrays)
    parts = [fn(*(a[i : i + rows] for a in arrays)) for i in range(0, n, rows)]
    if isinstance(parts[0], np.ndarray):
        return np.concatenate(parts)
    import torch

    return torch.cat(parts)


def _path_distances(paths: np.ndarray, points: np.ndarray) -> np.ndarray:
    point = points[:, None, :]
    a, ab = paths[:, :-1], np.diff(paths, axis=1)
    len2 = np.einsum("bij,bij->bi", ab, ab)
    proj = np.einsum("bij,bij->bi", point - a, ab)
    frac = np.divide(proj, len2, out=np.zeros_like(proj), where=len2 > 0)
    frac = np.clip(frac, 0.0, 1.0)  # the closest point lies on the segment
    closest = a + frac[..., None] * ab
    return np.min(np.linalg.norm(closest - point, axis=-1), axis=1)


def joint_limit_penalty(states) -> np.ndarray:
    """Joint-limit penalty f_c(x) = (x_l − x)ᵀ 1_l (x_l − x) + (x_u − x)ᵀ 1_u (x_u − x) of
    Appendix C.1 of states (..., 8), shape (...); 1_l (1_u) selects entries beyond the lower
    (upper) limits :data:`X_LOWER`, :data:`X_UPPER`."""
    x = check_array(states, "states")
    if x.shape[-1:] != (8,):
        raise ValueError(f"states: expected shape (..., 8), got {x.shape}")
    low = np.where(x <= X_LOWER, X_LOWER - x, 0.0)
    high = np.where(x >= X_UPPER, X_UPPER - x, 0.0)
    return (low**2).sum(axis=-1) + (high**2).sum(axis=-1)


def _too_fast(qd: np.ndarray, limit: float) -> np.ndarray:
    """Whether a joint speed exceeds ``limit`` at each step of ``qd`` (..., 4)."""
    with np.errstate(invalid="ignore"):
        return np.abs(qd).max(axis=-1) > limit


THROW_START = np.zeros(4)
"""Initial posture of the throwing task: standing upright, arm hanging (q = 0)."""
DEMO_RELEASE_TIME = 0.61
"""Release time of the shipped demonstration (s)."""


def throwing_demonstration(dt: float = 1e-3, duration: float = 1.0) -> dict[str, np.ndarray]:
    """The scripted swing the initial policy imitates: from q = 0 to upright, ankle +0.15,
    knee −0.4, hip +0.3 rad sin² bumps over [0, 0.8] s, a minimum-jerk arm turn of π over
    [0.1, 0.9] s, release at :data:`DEMO_RELEASE_TIME`. Returns ``times`` (N,), ``q``, ``qd``,
    ``qdd`` (N, 4) and ``release_time``."""
    t = np.arange(int(round(duration / dt)) + 1) * dt
    q = np.zeros((t.size, 4))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    u, inside, w = np.clip(t / 0.8, 0.0, 1.0), t <= 0.8, np.pi / 0.8  # sin²(π t / 0.8) bumps
    s = np.sin(np.pi * u) ** 2
    sd = np.where(inside, w * np.sin(2 * np.pi * u), 0.0)
    sdd = np.where(inside, 2 * w**2 * np.cos(2 * np.pi * u), 0.0)
    for j, amp in enumerate((0.15, -0.4, 0.3)):
        q[:, j], qd[:, j], qdd[:, j] = amp * s, amp * sd, amp * sdd
    s, sd, sdd = quintic(t - 0.1, 0.9 - 0.1, clip=True)  # minimum jerk on [0.1, 0.9]
    q[:, 3], qd[:, 3], qdd[:, 3] = np.pi * s, np.pi * sd, np.pi * sdd
    return {"times": t, "q": q, "qd": qd, "qdd": qdd, "release_time": np.array(DEMO_RELEASE_TIME)}


class Throwing(Task):
    """Ball throwing with the planar 4-link robot (Sec. 3.4.1, Appendix C.1).

    The target s = [x, y] is uniform on [5, 15] m × ``target_y`` (Sec. 3.4.1's [1, 3] m; C.1
    says [0, 3]). ω (41): the joint-major weights of a 4-joint, 10-basis DMP from
    :data:`THROW_START` to upright, and the release time t_r (s). The DMP is tracked by
    u = M(q)(q̈_ref + kp e + kd ė) + c(q, q̇), kp = 900, kd = 60
    (:func:`~skillkit.tasks.controllers.track_reference`). At t_r (clamped to [0, horizon])
    the ball leaves the hand with its interpolated state plus Gaussian ``release_noise`` (m,
    m/s; Sec. 4.3.2.2) and flies drag-free to y = 0. Reward (Appendix C.1)

        R(τ, s) = −c1 min_t ‖b_t − s‖ − c2 Σ_t f_c(x_t) − c3 Σ_t u_tᵀ u_t,

    c1 = 1e2, c2 = 1e3, c3 = 1e-8 (:func:`path_distances`, :func:`joint_limit_penalty`). A
    joint faster than ``max_joint_speed`` rad/s fails the rollout. Signals ``end_effector``
    (T, 2), ``ball`` (T_b, 2), ``ball_times`` (T_b,).
    """

    name = "throwing"
    context_dim = 2
    parameter_dim = 41
    context_names = ("x", "y")
    trajectory_depends_on_context = False
    worst_reward = -1e10
    c1, c2, c3 = 1e2, 1e3, 1e-8
    n_basis = 10

    def __init__(
        self,
        control_dt: float = 0.01,
        horizon: float = 1.25,
        target_y: tuple[float, float] = (1.0, 3.0),
        release_noise: tuple[float, float] = (0.0, 0.0),
        max_joint_speed: float = 200.0,
    ) -> None:
        self.robot = PlanarRobot(TIMESTEP)
        self.control_dt = check_positive(control_dt, "control_dt")
        control_substeps(self.robot.model, self.control_dt)
        self.horizon = check_positive(horizon, "horizon")
        self.n_steps = int(round(self.horizon / self.control_dt))
        if self.n_steps < 2:
            raise ValueError(f"horizon: expected at least two control steps, got {horizon:g} s")
        self.times = np.arange(self.n_steps) * self.control_dt
        self.kp, self.kd = np.full(4, 900.0), np.full(4, 60.0)
        lo, hi = check_array(target_y, "target_y", shape=(2,))
        if not 0.0 <= lo <= hi:
            raise ValueError(f"target_y: expected 0 <= low <= high, got {target_y}")
        self.context_low, self.context_high = np.array([5.0, lo]), np.array([15.0, hi])
        noise = check_array(release_noise, "release_noise", shape=(2,))
        if np.any(noise < 0):
            raise ValueError(f"release_noise: expected standard deviations >= 0, got {noise}")
        self.release_noise = noise
        self.ball_dt = 0.01  # s, the flight's sampling period
        self.max_joint_speed = check_positive(max_joint_speed, "max_joint_speed")
        dmp = DMP(4, n_basis=self.n_basis, dt=1e-3, duration=1.0)
        dmp.goal = UPRIGHT.copy()
        self.parameters = DMPParameters(dmp, learn=("weights",))

    def reference(self, omega) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The DMP reference (q_ref, q̇_ref, q̈_ref), each (T, 4), at the control steps for ω."""
        omega = self.check_omega(omega)
        dmp = self.parameters.from_vector(omega[:-1])
        return dmp.rollout(
            self.times, THROW_START, goal=UPRIGHT, goal_velocity=np.zeros(4), tau=1.0
        )

    def _simulate(self, omega, context, rng) -> Trajectory:
        q_ref, qd_ref, qdd_ref = self.reference(omega)
        robot = self.robot
        robot.reset(THROW_START, np.zeros(4))
        out = track_reference(
            robot.model,
            robot.data,
            q_ref,
            qd_ref,
            self.control_dt,
            self.kp,
            self.kd,
            qdd_ref=qdd_ref,
            inertia_weighted=True,
        )
        fast = _too_fast(out["qd"], self.max_joint_speed)
        if fast.any():
            raise SimulationFailure(
                f"diverged: a joint speed exceeds {self.max_joint_speed:g} rad/s at "
                f"t = {int(np.argmax(fast)) * self.control_dt:.3f} s"
            )
        hand_p, hand_v = hand_kinematics(out["q"], out["qd"])
        t_req = float(omega[-1])
        t_rel = min(max(t_req, 0.0), float(self.times[-1]))
        p0, v0 = self._release_state(t_rel, hand_p, hand_v)
        if np.any(self.release_noise > 0):
            p0 = p0 + self.release_noise[0] * rng.standard_normal(2)
            v0 = v0 + self.release_noise[1] * rng.standard_normal(2)
        t_flight, flight = ballistic_flight(p0, v0, robot.gravity, self.ball_dt)
        held = self.times < t_rel
        ball = np.vstack([hand_p[held], flight])
        ball_times = np.concatenate([self.times[held], t_rel + t_flight])
        info = {
            "release_time": t_rel,
            "release_time_requested": t_req,
            "release_clamped": bool(t_rel != t_req),
            "release_position": p0.tolist(),
            "release_velocity": v0.tolist(),
            "landing_x": float(flight[-1, 0]),
            "flight_time": float(t_flight[-1]),
        }
        return Trajectory(
            self.times,
            np.hstack([out["q"], out["qd"]]),
            out["u"],
            signals={"end_effector": hand_p, "ball": ball, "ball_times": ball_times},
            info=info,
        )

    def _release_state(
        self, t_rel: float, hand_p: np.ndarray, hand_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Hand position and velocity at t_rel, cubic Hermite between control steps."""
        h = self.control_dt
        k = min(int(np.floor(t_rel / h)), self.n_steps - 2)
        u = (t_rel - k * h) / h
        p0, p1, m0, m1 = hand_p[k], hand_p[k + 1], hand_v[k] * h, hand_v[k + 1] * h
        h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
        h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
        d00, d10 = 6 * u**2 - 6 * u, 3 * u**2 - 4 * u + 1
        d01, d11 = -6 * u**2 + 6 * u, 3 * u**2 - 2 * u
        pos = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
        vel = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / h
        return pos, vel

    def reward_terms(self, trajectory: Trajectory, context) -> dict[str, float]:
        """The unweighted reward terms ``distance`` min_t ‖b_t − s‖ (m), ``joint_penalty``
        Σ_t f_c(x_t) and ``energy`` Σ_t u_tᵀu_t (Appendix C.1)."""
        s = self.check_context(context)[None]
        arrays = (trajectory.states, trajectory.controls, trajectory.signals["ball"])
        terms = self.reward_terms_batch(*(a[None] for a in arrays), s)
        return {k: float(v[0]) for k, v in terms.items()}

    @staticmethod
    def reward_terms_batch(states, controls, ball, contexts) -> dict[str, np.ndarray]:
        """:meth:`reward_terms` of states (B, T, 8), controls (B, T, 4), ball paths (B, N, 2)
        and targets (B, 2); each term (B,)."""
        states = check_array(states, "states", shape=(None, None, 8))
        controls = check_array(controls, "controls", shape=(states.shape[0], None, 4))
        return {
            "distance": path_distances(ball, contexts),
            "joint_penalty": _by_rows(lambda x: joint_limit_penalty(x).sum(axis=1), states),
            "energy": (controls**2).sum(axis=(1, 2)),
        }

    def reward_batch(self, states, controls, signals, contexts) -> np.ndarray:
        """R = −c1 min_t ‖b_t − s‖ − c2 Σ_t f_c(x_t) − c3 Σ_t u_tᵀu_t, shape (B,) (numpy).

        ``signals["ball"]`` (B, N, 2): ball paths of equal length.
        """
        terms = self.reward_terms_batch(states, controls, signals["ball"], contexts)
        return -(
            self.c1 * terms["distance"]
            + self.c2 * terms["joint_penalty"]
            + self.c3 * terms["energy"]
        )

    def reward_signals(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """The ball path, ``{"ball": (N, 2)}``."""
        return {"ball": trajectory.signals["ball"]}

    def failed_batch(self, states) -> np.ndarray:
        """Paths (B, T + 1, 8) with a non-finite state or a joint faster than
        ``max_joint_speed``, shape (B,)."""
        states = check_array(states, "states", shape=(None, None, 8), finite=False)
        fast = _too_fast(states[..., 4:], self.max_joint_speed).any(axis=1)
        return fast | ~np.isfinite(states).all(axis=(1, 2))

    supports_model_rollout = True

    def model_signals(self) -> ModelSignals:
        """x = [q, q̇] (8), u = the joint torques (4), and the ball path."""
        return ModelSignals(STATE_NAMES, TORQUE_NAMES, ("ball",))

    def initial_states(self, context, n: int, rng=None) -> np.ndarray:
        """``n`` copies of the rest state [:data:`THROW_START`, 0], shape (n, 8)."""
        self.check_context(context)
        return np.tile(np.concatenate([THROW_START, np.zeros(4)]), (check_count(n), 1))

    def acceleration_controller(self, omegas, contexts=None, device=None, dtype=None):
        """The tracker's commanded acceleration ``policy(t, x, pair) -> a`` on predicted states,
        a = q̈_ref,t + kp (q_ref,t − q) + kd (q̇_ref,t − q̇) of ω_b's DMP (:meth:`controller`
        before :meth:`torques`; the control of the throwing model, Sec. 4.3.2)."""
        import torch

        omegas = check_array(omegas, "omegas", shape=(None, self.parameter_dim))
        dtype = torch.float64 if dtype is None else dtype
        refs = [self.reference(w) for w in omegas]
        q_ref, qd_ref, qdd_ref = (
            torch.as_tensor(np.stack([r[i] for r in refs]), dtype=dtype, device=device)
            for i in range(3)
        )
        kp = torch.as_tensor(self.kp, dtype=dtype, device=device)
        kd = torch.as_tensor(self.kd, dtype=dtype, device=device)

        def policy(t: int, x, pair):
            q, qd = x[:, :4], x[:, 4:]
            acc = kp * (q_ref[pair, t] - q) + kd * (qd_ref[pair, t] - qd)
            return acc + qdd_ref[pair, t]

        return policy

    def torques(self, states, accelerations):
        """Inverse dynamics u = M(q) a + c(q, q̇) of torch ``states`` (..., 8), ``accelerations``
        (..., 4) (:func:`~skillkit.tasks.planar_model.rigid_body_terms`)."""

        def inverse_dynamics(x, a):
            m, c = rigid_body_terms(x[..., :4], x[..., 4:], self.robot.gravity)
            return (m @ a[..., None])[..., 0] + c

        return _by_rows(inverse_dynamics, states, accelerations)

    def commanded_accelerations(self, states, controls) -> np.ndarray:
        """a = M(q)⁻¹ (u − c(q, q̇)) of logged states (N, 8) and torques (N, 4): the inverse of
        :meth:`torques`."""
        import torch

        x = torch.as_tensor(check_array(states, "states", shape=(None, 8)))
        u = torch.as_tensor(check_array(controls, "controls", shape=(x.shape[0], 4)))
        m, c = rigid_body_terms(x[:, :4], x[:, 4:], self.robot.gravity)
        return torch.linalg.solve(m, u - c).numpy()

    def controller(self, omegas, contexts=None, device=None, dtype=None):
        """The inertia-weighted PD tracker on predicted states: :meth:`torques` of
        :meth:`acceleration_controller` (``t`` below the number of control steps)."""
        accel = self.acceleration_controller(omegas, contexts, device=device, dtype=dtype)

        def policy(t: int, x, pair):
            return self.torques(x, accel(t, x, pair))

        return policy

    def scene_model(self) -> mujoco.MjModel:
        """The planar robot's compiled MuJoCo model."""
        return self.robot.model

    @cached_property
    def demonstration_omega(self) -> np.ndarray:
        """ω of the shipped demonstration: DMP weights fitted to it (Eq. 2.23) and its t_r."""
        with np.load(DEMONSTRATION_FILE) as demo:
            times, q, qd, qdd = demo["times"], demo["q"], demo["qd"], demo["qdd"]
            t_r = float(demo["release_time"])
        dmp = DMP(4, n_basis=self.n_basis, dt=1e-3, duration=1.0).fit(times, q, qd, qdd)
        return np.append(self.parameters.to_vector(dmp), t_r)

    exploration_std_fraction = 0.1
    covering_std_fraction = 0.9
    release_time_std = 0.02

    def initial_policy(self, exploration_std_fraction: float | None = None) -> LinearGaussianPolicy:
        """Imitation initial policy N(ω | :attr:`demonstration_omega`, Σ_0), no context gain.

        Σ_0 diagonal: each joint's weights have std ``exploration_std_fraction`` of its largest
        demonstrated weight, t_r :attr:`release_time_std`. :attr:`covering_std_fraction` puts
        the farthest target inside the initial exploration (Sec. 3.5; ``fig3.3``).
        """
        if exploration_std_fraction is None:
            exploration_std_fraction = self.exploration_std_fraction
        frac = check_positive(exploration_std_fraction, "exploration_std_fraction")
        mean = self.demonstration_omega
        w = mean[:-1].reshape(4, self.n_basis)
        std_w = frac * np.max(np.abs(w), axis=1, keepdims=True)
        std = np.append(np.broadcast_to(std_w, w.shape).ravel(), self.release_time_std)
        return LinearGaussianPolicy(mean, np.diag(std**2), context_dim=2)


@register("throwing", "planar", "contextual")
def throwing(**kwargs) -> Throwing:
    """Ball throwing (Sec. 3.4.1, Appendix C.1), deterministic."""
    return Throwing(**kwargs)


@register("throwing-noisy", "planar", "contextual")
def throwing_noisy(**kwargs) -> Throwing:
    """Stochastic throwing of Sec. 4.3.2.2: release noise 7.5 cm and 30 cm/s (std)."""
    kwargs.setdefault("release_noise", (0.075, 0.3))
    return Throwing(**kwargs)
