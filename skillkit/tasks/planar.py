"""Tasks on the planar 4-link robot of Appendix C.1: ball throwing (3.4.1) and balancing (4.3.1).

The robot (masses [17.5, 17.5, 26.5, 8.5] kg, lengths [0.5, 0.5, 1.0, 1.0] m, ankle–knee–
hip–shoulder hinges, base fixed to the ground, every joint torque-actuated) is the MuJoCo
model of :mod:`skillkit.tasks.planar_model`; see there for the joint conventions
(``q = [0, 0, 0, π]`` is upright with the arm pointing up). Both tasks step the compiled
``mujoco.MjModel``/``MjData`` directly with ``mujoco.mj_step`` (1 ms physics step) through
:func:`skillkit.tasks.controllers.run_feedback`, with torques held constant over each
control period (zero-order hold).

* :class:`Throwing` (registered ``throwing``, and ``throwing-noisy`` with release noise): a
  DMP reference tracked by an inertia-weighted PD controller with gravity compensation; the
  ball leaves the hand at the release time t_r and flies to the ground. Context s = [x, y],
  the target.
* :class:`Balancing` (registered ``balancing`` and ``balancing-noisy``): a linear state
  feedback u = G x̃ around upright from a random initial state. Context-free.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np
import scipy.linalg

from skillkit._validation import check_array, check_positive
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.base import SimulationFailure, Task
from skillkit.tasks.controllers import control_substeps, run_feedback, track_reference
from skillkit.tasks.planar_model import (
    LINK_LENGTHS,
    TIMESTEP,
    UPRIGHT,
    compile_planar_robot,
)
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

__all__ = [
    "Balancing",
    "Throwing",
    "balancing_transitions",
    "ballistic_flight",
    "hand_kinematics",
    "joint_limit_penalty",
    "path_distance",
    "throwing_demonstration",
    "write_throwing_demonstration",
]

DEMONSTRATION_FILE = (
    Path(__file__).resolve().parents[1] / "data" / "demonstrations" / "throwing.npz"
)
"""The shipped throwing demonstration (regenerate with :func:`write_throwing_demonstration`)."""

# Joint and velocity limits of Appendix C.1, x = [q, q̇].
Q_LOWER = np.array([-0.8, -2.5, -0.1, 0.0])
Q_UPPER = np.array([0.8, 0.05, 2.0, 1.5 * np.pi])
QD_LIMIT = 50.0
X_LOWER = np.concatenate([Q_LOWER, np.full(4, -QD_LIMIT)])
X_UPPER = np.concatenate([Q_UPPER, np.full(4, QD_LIMIT)])


class _PlanarRobot:
    """Compiled planar robot (one per task instance) and its hand site."""

    def __init__(self, timestep: float) -> None:
        self.physics = compile_planar_robot(timestep)
        self.model: mujoco.MjModel = self.physics.model.ptr
        self.data: mujoco.MjData = self.physics.data.ptr
        self.hand = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "hand")
        self.gravity = float(-self.model.opt.gravity[2])
        self._vel = np.zeros(6)

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        self.data.qvel[:] = qd
        mujoco.mj_forward(self.model, self.data)

    def hand_state(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Hand position and velocity in the robot plane, [x, z] each (current kinematics)."""
        mujoco.mj_objectVelocity(
            self.model, data, mujoco.mjtObj.mjOBJ_SITE, self.hand, self._vel, 0
        )
        return data.site_xpos[self.hand][[0, 2]].copy(), self._vel[[3, 5]].copy()


def hand_kinematics(q, qd=None) -> tuple[np.ndarray, np.ndarray | None]:
    """Closed-form planar forward kinematics of the hand (tip of the arm).

    With absolute link angles θ_k = q_1 + … + q_k (from the upward vertical, positive
    forwards), links 1–3 point along (sin θ_k, cos θ_k) and the arm, hanging at q_4 = 0,
    along (−sin θ_4, −cos θ_4).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Joint angles.
    qd : array_like, shape (..., 4), optional
        Joint velocities.

    Returns
    -------
    position : ndarray, shape (..., 2)
        Hand [x, y] (y up).
    velocity : ndarray, shape (..., 2) or None
        Hand velocity if ``qd`` is given.
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
    """Drag-free flight of a point mass from ``position`` until it reaches the ground y = 0.

    b(t) = p_0 + v_0 t − ½ g t² e_y, sampled every ``dt`` seconds and at the landing time
    t_land = (v_y + √(v_y² + 2 g p_y)) / g (so the last sample lies exactly on the ground).
    A ball released at or below the ground (p_y ≤ 0) lands at once (t_land = 0).

    Parameters
    ----------
    position, velocity : array_like, shape (2,)
        Release state [x, y], [v_x, v_y] (y up).
    gravity : float
        g in m/s².
    dt : float
        Sampling period in seconds.

    Returns
    -------
    times : ndarray, shape (N,)
        Times since release, from 0 to t_land.
    path : ndarray, shape (N, 2)
        Ball positions.
    """
    p = check_array(position, "position", shape=(2,))
    v = check_array(velocity, "velocity", shape=(2,))
    g = check_positive(gravity, "gravity")
    dt = check_positive(dt, "dt")
    if p[1] <= 0.0:
        t_land = 0.0
    else:
        t_land = (v[1] + np.sqrt(v[1] ** 2 + 2.0 * g * p[1])) / g
    n = int(np.floor(t_land / dt))
    t = np.append(np.arange(n + 1) * dt, t_land) if t_land > n * dt else np.arange(n + 1) * dt
    path = p + np.outer(t, v)
    path[:, 1] -= 0.5 * g * t**2
    if t_land > 0:
        path[-1, 1] = 0.0  # the root of the quadratic, up to rounding
    return t, path


def path_distance(path, point) -> float:
    """Smallest distance from ``point`` to the polyline through ``path`` (its segments).

    The thesis's min_t ‖b_t − s‖ over a finely sampled ball trajectory; measuring to the
    segments rather than the samples removes the sampling error (the chord of a parabola
    sampled every 10 ms deviates from it by at most g·dt²/8 ≈ 0.1 mm).

    Parameters
    ----------
    path : array_like, shape (N, 2)
    point : array_like, shape (2,)
    """
    path = check_array(path, "path", shape=(None, 2))
    point = check_array(point, "point", shape=(2,))
    if path.shape[0] == 0:
        raise ValueError("path: expected at least one point")
    if path.shape[0] == 1:
        return float(np.linalg.norm(path[0] - point))
    a, ab = path[:-1], np.diff(path, axis=0)
    len2 = np.einsum("ij,ij->i", ab, ab)
    proj = np.einsum("ij,ij->i", point - a, ab)
    frac = np.divide(proj, len2, out=np.zeros_like(proj), where=len2 > 0)
    frac = np.clip(frac, 0.0, 1.0)  # the closest point lies on the segment
    closest = a + frac[:, None] * ab
    return float(np.min(np.linalg.norm(closest - point, axis=1)))


def joint_limit_penalty(states) -> np.ndarray:
    """Joint-limit penalty f_c(x_t) of Appendix C.1 for each time step.

    f_c(x) = (x_l − x)ᵀ 1_l (x_l − x) + (x_u − x)ᵀ 1_u (x_u − x), where 1_l (1_u) selects the
    entries at or below the lower (at or above the upper) limit; x = [q, q̇] with
    q_l = [−0.8, −2.5, −0.1, 0], q_u = [0.8, 0.05, 2, 1.5π] rad and |q̇| ≤ 50 rad/s.

    Parameters
    ----------
    states : array_like, shape (T, 8)

    Returns
    -------
    ndarray, shape (T,)
    """
    x = check_array(states, "states", shape=(None, 8))
    low = np.where(x <= X_LOWER, X_LOWER - x, 0.0)
    high = np.where(x >= X_UPPER, X_UPPER - x, 0.0)
    return (low**2).sum(axis=1) + (high**2).sum(axis=1)


def _check_divergence(qd: np.ndarray, limit: float, control_dt: float) -> None:
    """Raise :class:`SimulationFailure` if a joint speed exceeds ``limit`` (rad/s)."""
    fast = np.abs(qd).max(axis=1) > limit
    if fast.any():
        t = int(np.argmax(fast))
        raise SimulationFailure(
            f"diverged: a joint speed exceeds {limit:g} rad/s at t = {t * control_dt:.3f} s"
        )


def _bump(t: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, ...]:
    """Smooth 0→1→0 bump sin²(π u) on [t0, t1], u = (t − t0)/(t1 − t0), with derivatives."""
    T = t1 - t0
    u = np.clip((t - t0) / T, 0.0, 1.0)
    inside = (t >= t0) & (t <= t1)
    w = np.pi / T
    s = np.sin(np.pi * u) ** 2
    sd = np.where(inside, w * np.sin(2 * np.pi * u), 0.0)
    sdd = np.where(inside, 2 * w**2 * np.cos(2 * np.pi * u), 0.0)
    return s, sd, sdd


THROW_START = np.zeros(4)
"""Initial posture of the throwing task: standing upright, arm hanging (q = 0)."""
DEMO_RELEASE_TIME = 0.61
"""Release time of the shipped demonstration (s)."""


def throwing_demonstration(dt: float = 1e-3, duration: float = 1.0) -> dict[str, np.ndarray]:
    """The scripted throwing swing the initial policy imitates (deterministic).

    From standing (q = 0, arm hanging) to upright (q = [0, 0, 0, π]) in ``duration``
    seconds: the robot dips (ankle +0.15 rad, knee −0.4 rad, hip +0.3 rad, each a sin² bump
    over the first 0.8 s) while the arm swings backwards, over the head, to pointing up (a
    minimum-jerk turn of π between 0.1 s and 0.9 s). The ball is released at
    :data:`DEMO_RELEASE_TIME` (0.61 s), when the hand moves forwards and up at about 45°.

    Returns
    -------
    dict
        ``times`` (N,), ``q``, ``qd``, ``qdd`` (N, 4), ``release_time`` (scalar array).
    """
    t = np.arange(int(round(duration / dt)) + 1) * dt
    q = np.zeros((t.size, 4))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    for j, amp in enumerate((0.15, -0.4, 0.3)):
        s, sd, sdd = _bump(t, 0.0, 0.8)
        q[:, j], qd[:, j], qdd[:, j] = amp * s, amp * sd, amp * sdd
    s, sd, sdd = quintic(t - 0.1, 0.9 - 0.1, clip=True)  # minimum jerk on [0.1, 0.9]
    q[:, 3], qd[:, 3], qdd[:, 3] = np.pi * s, np.pi * sd, np.pi * sdd
    return {"times": t, "q": q, "qd": qd, "qdd": qdd, "release_time": np.array(DEMO_RELEASE_TIME)}


def write_throwing_demonstration(path: str | Path = DEMONSTRATION_FILE) -> Path:
    """Regenerate the shipped demonstration file (``skillkit/data/demonstrations/throwing.npz``).

    Deterministic: the file holds exactly :func:`throwing_demonstration`'s arrays.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **throwing_demonstration())
    return path


# ============================================================================ throwing
class Throwing(Task):
    """Ball throwing with the planar 4-link robot (Sec. 3.4.1, Appendix C.1).

    **Context** s = [x, y]: the target, x ∈ [5, 15] m ahead of the ankle and y ∈ [1, 3] m
    above the ground, uniform. (Appendix C.1 says y ∈ [0, 3], Sec. 3.4.1 y ∈ [1, 3]; we use
    3.4.1's range, the setting of Fig. 3.3, and let ``target_y`` change it.)

    **Lower-level policy** ω (41): the shape weights of a 4-joint DMP with 10 basis
    functions per joint (joint-major, :class:`~skillkit.policies.dmp.DMPParameters` with
    ``learn=("weights",)``) and the release time t_r (s). The DMP starts at the initial
    posture :data:`THROW_START` at rest and its goal is fixed to upright ``[0, 0, 0, π]``
    with zero final velocity (τ = 1, nominal duration 1 s). The DMP reference is tracked
    for ``horizon`` seconds (1.25 s) at ``control_dt`` (100 Hz default) by the PD tracker
    of :func:`~skillkit.tasks.controllers.track_reference` in its inertia-weighted form,
    u = M(q)(q̈_ref + kp e + kd ė) + c(q, q̇), with MuJoCo's bias force c (gravity and
    Coriolis) as compensation and the DMP's acceleration fed forward; kp = 900 s⁻²,
    kd = 60 s⁻¹ (every joint-space mode at 30 rad/s, critically damped). A plain diagonal
    PD cannot do this on this robot: the light shin/thigh on the heavy torso make M(q)
    badly conditioned, and at 200 Hz the best stable diagonal gains left the slow
    whole-body mode at 5 rad/s with damping ratio 0.06 (0.17 rad errors on a 0.5 Hz
    reference, against 2 mm here). Tracking errors of the demonstration: about 2 mm. The
    1 ms physics step moves the landing point by about 1 cm compared with 0.5 ms.

    **Ball.** Held at the hand (tip of the arm) until t_r; the release state is the hand's
    position and velocity at t_r, interpolated between control steps with a cubic Hermite
    polynomial (so the outcome is smooth in t_r). A release time outside [0, horizon] is
    moved to the nearest end (the hand opens at the first or last instant) and reported
    as ``info["release_clamped"]``. The flight is **closed-form drag-free ballistic
    motion** (:func:`ballistic_flight`), exact for a point mass and sampled every
    ``ball_dt`` = 10 ms until the ball reaches the ground y = 0: Appendix C.1 describes no
    drag, and a closed form has no integration error. Optional Gaussian noise on the
    release state (``release_noise``: position and velocity std, Sec. 4.3.2.2) makes the
    task stochastic.

    **Reward** (Appendix C.1)

        R(τ, s) = −c1 min_t ‖b_t − s‖ − c2 Σ_t f_c(x_t) − c3 Σ_t u_tᵀ u_t,

    c1 = 1e2, c2 = 1e3, c3 = 1e-8, with the ball path b (held part and flight) measured to
    its segments (:func:`path_distance`), the joint-limit penalty f_c of
    :func:`joint_limit_penalty` and the applied torques u, both summed over the control
    steps. The trajectory does not depend on s, so it can be re-scored in other contexts.

    **Failures.** A rollout whose joint speed exceeds ``max_joint_speed`` (200 rad/s, four
    times the limit of C.1) is stopped as diverged (:class:`SimulationFailure`), as are
    non-finite states; both get :attr:`worst_reward` = −1e10, far below the rewards of
    working rollouts in practice (the exploring initial policy scores −50 to −5000).

    Trajectory: ``states`` (T, 8) = [q, q̇] at the control steps, ``controls`` (T, 4)
    torques (N m); signals ``end_effector`` (T, 2), ``ball`` (T_b, 2) and ``ball_times``
    (T_b,) in [x, y] (y up, metres); ``info`` holds the release time, release state,
    landing point and flight time.

    Parameters
    ----------
    control_dt : float
        Control period (s), a multiple of the 1 ms physics step.
    horizon : float
        Simulated duration of the movement (s).
    kp, kd : float or array_like, shape (4,)
        Inertia-weighted PD gains (1/s², 1/s).
    target_y : tuple of float
        Range of the target height y.
    release_noise : tuple of float
        Standard deviations of Gaussian noise added to the release position (m) and
        velocity (m/s); (0, 0) is the deterministic task.
    ball_dt : float
        Sampling period of the ball flight (s).
    max_joint_speed : float
        Divergence threshold (rad/s).
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
        kp=900.0,
        kd=60.0,
        target_y: tuple[float, float] = (1.0, 3.0),
        release_noise: tuple[float, float] = (0.0, 0.0),
        ball_dt: float = 0.01,
        max_joint_speed: float = 200.0,
    ) -> None:
        self.robot = _PlanarRobot(TIMESTEP)
        self.control_dt = check_positive(control_dt, "control_dt")
        control_substeps(self.robot.model, self.control_dt)
        self.horizon = check_positive(horizon, "horizon")
        self.n_steps = int(round(self.horizon / self.control_dt))
        if self.n_steps < 2:
            raise ValueError(f"horizon: expected at least two control steps, got {horizon:g} s")
        self.times = np.arange(self.n_steps) * self.control_dt
        self.kp = np.broadcast_to(check_array(kp, "kp", ndim=(0, 1)), (4,)).copy()
        self.kd = np.broadcast_to(check_array(kd, "kd", ndim=(0, 1)), (4,)).copy()
        lo, hi = check_array(target_y, "target_y", shape=(2,))
        if not 0.0 <= lo <= hi:
            raise ValueError(f"target_y: expected 0 <= low <= high, got {target_y}")
        self.context_low = np.array([5.0, lo])
        self.context_high = np.array([15.0, hi])
        noise = check_array(release_noise, "release_noise", shape=(2,))
        if np.any(noise < 0):
            raise ValueError(
                f"release_noise: expected non-negative standard deviations, got {noise}"
            )
        self.release_noise = noise
        self.ball_dt = check_positive(ball_dt, "ball_dt")
        self.max_joint_speed = check_positive(max_joint_speed, "max_joint_speed")
        dmp = DMP(4, n_basis=self.n_basis, dt=1e-3, duration=1.0)
        dmp.goal = UPRIGHT.copy()
        self.parameters = DMPParameters(dmp, learn=("weights",))

    # ------------------------------------------------------------------ episodes
    def reference(self, omega) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The DMP reference (q_ref, q̇_ref, q̈_ref), each (T, 4), at the control steps for ω."""
        omega = self.check_omega(omega)
        dmp = self.parameters.from_vector(omega[:-1])
        return dmp.rollout(
            self.times, THROW_START, goal=UPRIGHT, goal_velocity=np.zeros(4), tau=1.0
        )

    def _simulate(
        self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator
    ) -> Trajectory:
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
            gravity_compensation=True,
            qdd_ref=qdd_ref,
            inertia_weighted=True,
        )
        _check_divergence(out["qd"], self.max_joint_speed, self.control_dt)
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
        """Hand position/velocity at t_rel: cubic Hermite between the control steps."""
        h = self.control_dt
        k = min(int(np.floor(t_rel / h)), self.n_steps - 2)
        u = (t_rel - k * h) / h
        p0, p1, m0, m1 = hand_p[k], hand_p[k + 1], hand_v[k] * h, hand_v[k + 1] * h
        h00, h10, h01, h11 = (
            2 * u**3 - 3 * u**2 + 1,
            u**3 - 2 * u**2 + u,
            -2 * u**3 + 3 * u**2,
            u**3 - u**2,
        )
        d00, d10, d01, d11 = (
            6 * u**2 - 6 * u,
            3 * u**2 - 4 * u + 1,
            -6 * u**2 + 6 * u,
            3 * u**2 - 2 * u,
        )
        pos = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
        vel = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / h
        return pos, vel

    # ------------------------------------------------------------------ reward
    def reward_terms(self, trajectory: Trajectory, context) -> dict[str, float]:
        """The three terms of the reward (Appendix C.1) before weighting.

        Returns
        -------
        dict
            ``distance`` min_t ‖b_t − s‖ (m), ``joint_penalty`` Σ_t f_c(x_t) and
            ``energy`` Σ_t u_tᵀu_t.
        """
        s = self.check_context(context)
        return {
            "distance": path_distance(trajectory.signals["ball"], s),
            "joint_penalty": float(joint_limit_penalty(trajectory.states).sum()),
            "energy": float(np.sum(trajectory.controls**2)),
        }

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        terms = self.reward_terms(trajectory, context)
        return -(
            self.c1 * terms["distance"]
            + self.c2 * terms["joint_penalty"]
            + self.c3 * terms["energy"]
        )

    # ------------------------------------------------------------------ policy
    @cached_property
    def demonstration_omega(self) -> np.ndarray:
        """ω of the shipped demonstration: DMP weights fitted to it (Eq. 2.23) and its t_r."""
        with np.load(DEMONSTRATION_FILE) as demo:
            times, q, qd, qdd = demo["times"], demo["q"], demo["qd"], demo["qdd"]
            t_r = float(demo["release_time"])
        dmp = DMP(4, n_basis=self.n_basis, dt=1e-3, duration=1.0).fit(times, q, qd, qdd)
        weights = self.parameters.to_vector(dmp)
        return np.append(weights, t_r)

    exploration_std_fraction = 0.1
    release_time_std = 0.02

    def initial_policy(self) -> LinearGaussianPolicy:
        """Imitation initial policy: N(ω | ω_demo, Σ_0), no context gain.

        The mean is :attr:`demonstration_omega` (the DMP fitted to the shipped scripted
        swing); its ball lands at x = 4.97 m, the thesis's "about 5 m", but without the
        thesis's "high penalties": the swing stays inside the joint limits up to tracking
        errors (reward −50 for the target [5, 1]). Σ_0 is diagonal: each joint's shape
        weights have standard deviation :attr:`exploration_std_fraction` (10%) of that
        joint's largest demonstrated weight magnitude, and t_r has
        :attr:`release_time_std` (20 ms). Sampled throws land between about 3.6 and 6.5 m
        (rewards −200 to −1900 on random targets).
        """
        mean = self.demonstration_omega
        w = mean[:-1].reshape(4, self.n_basis)
        std_w = self.exploration_std_fraction * np.max(np.abs(w), axis=1, keepdims=True)
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


# =========================================================================== balancing
class Balancing(Task):
    """Balancing the planar 4-link robot around upright (Sec. 4.3.1; Sec. 5.4 settings).

    **Lower-level policy** (32 parameters): the linear feedback u_t = G x̃_t with
    x̃_t = [q_t − q_up, q̇_t] the deviation from upright q_up = [0, 0, 0, π] and the gain
    matrix G (4 × 8) = ω reshaped **row-major** (``G[i, j] = ω[8 i + j]``: row i gives the
    torque of joint i). No gravity compensation: gravity exerts no torque at upright.
    Optional Gaussian torque noise (``torque_noise_std``, N m) is added to the applied
    torque, making the dynamics stochastic (Sec. 5.4 uses 4).

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
    speed above ``max_joint_speed`` (100 rad/s) is stopped as diverged
    (:class:`SimulationFailure`), so every working rollout has a bounded reward and
    :attr:`worst_reward` (−1e7) lies below it in practice.

    Trajectory: ``times`` (T+1,), ``states`` (T+1, 8) = [q, q̇] at the control steps,
    ``controls`` (T+1, 4) commanded torques; signal ``torque_noise`` (T, 4). Use
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
        max_angle: float = 20.0,
        max_joint_speed: float = 100.0,
    ) -> None:
        self.robot = _PlanarRobot(TIMESTEP)
        self.initial_std = check_positive(initial_std, "initial_std", allow_zero=True)
        self.torque_noise_std = check_positive(
            torque_noise_std, "torque_noise_std", allow_zero=True
        )
        if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
            raise ValueError(f"n_steps: expected a positive integer, got {n_steps!r}")
        self.n_steps = int(n_steps)
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
        q0 = UPRIGHT + self.initial_std * rng.standard_normal(4)
        qd0 = self.initial_std * rng.standard_normal(4)
        noise = self.torque_noise_std * rng.standard_normal((self.n_steps, 4))
        commanded = np.empty((self.n_steps + 1, 4))

        def feedback(t: int, q: np.ndarray, qd: np.ndarray, data: mujoco.MjData) -> np.ndarray:
            commanded[t] = G @ np.concatenate([q - UPRIGHT, qd])
            return commanded[t] + noise[t]

        robot = self.robot
        robot.reset(q0, qd0)
        out = run_feedback(robot.model, robot.data, feedback, self.n_steps, self.control_dt)
        q = np.vstack([out["q"], robot.data.qpos])
        qd = np.vstack([out["qd"], robot.data.qvel])
        self._check_divergence(q, qd)
        commanded[-1] = G @ np.concatenate([q[-1] - UPRIGHT, qd[-1]])
        times = np.arange(self.n_steps + 1) * self.control_dt
        return Trajectory(
            times,
            np.hstack([q, qd]),
            commanded,
            signals={"torque_noise": noise},
            info={"initial_state": np.concatenate([q0, qd0]).tolist()},
        )

    def _check_divergence(self, q: np.ndarray, qd: np.ndarray) -> None:
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise SimulationFailure("non-finite final state")
        _check_divergence(qd, self.max_joint_speed, self.control_dt)
        far = np.abs(q - UPRIGHT).max(axis=1) > self.max_angle
        if far.any():
            t = int(np.argmax(far))
            raise SimulationFailure(
                f"diverged: a joint is more than {self.max_angle:g} rad from "
                f"upright at t = {t * self.control_dt:.3f} s"
            )

    # ------------------------------------------------------------------ reward
    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        x = trajectory.states[1:] - np.concatenate([UPRIGHT, np.zeros(4)])
        u = trajectory.controls[1:]
        cost = np.einsum("ti,ij,tj->", x, self.state_weights, x)
        return -float(cost + self.control_weight * np.sum(u**2))

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

    exploration_std_fraction = 0.01

    def initial_policy(self) -> GaussianPolicy:
        """N(ω | vec(G_lqr), Σ_0): a stabilising gain with cautious exploration.

        The mean is the LQR gain of :meth:`lqr_gain` (Q = the task's state weights,
        R = 1e-4 I), flattened row-major. Σ_0 is diagonal with standard deviations
        :attr:`exploration_std_fraction` (1%) of |G_lqr| entry-wise. The closed loop at 20 Hz
        is sensitive to independent perturbations of the 32 gains: with 10% relative
        exploration about half of the sampled controllers let the robot fall or diverge,
        with 1% none did in our checks.
        """
        g = self.lqr_gain().ravel()
        std = self.exploration_std_fraction * np.abs(g)
        return GaussianPolicy(g, np.diag(std**2))


def balancing_transitions(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (x_t, u_t, x_{t+1}) transitions of a balancing trajectory at the control rate.

    The training data of GP forward models and conditional embeddings (Chs. 4–5).

    Parameters
    ----------
    trajectory : Trajectory
        A (non-failed) :class:`Balancing` trajectory with T + 1 states.

    Returns
    -------
    x : ndarray, shape (T, 8)
        States [q, q̇] at t = 0..T−1.
    u : ndarray, shape (T, 4)
        Commanded torques (the torque noise is part of the stochastic dynamics).
    x_next : ndarray, shape (T, 8)
        Successor states at t = 1..T.
    """
    if trajectory.failed:
        raise ValueError(
            f"trajectory: a failed trajectory has no transitions ({trajectory.message})"
        )
    states = check_array(trajectory.states, "trajectory.states", shape=(None, 8))
    controls = check_array(trajectory.controls, "trajectory.controls", shape=(states.shape[0], 4))
    return states[:-1], controls[:-1], states[1:]


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
