"""The forehand stroke the table-tennis DMP imitates (design and shipped file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_positive
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.table_tennis.arm import RACKET_SITE, arm_model, racket_pose
from skillkit.tasks.table_tennis.ball import (
    RETURN_NEAR_HIGH,
    RETURN_NEAR_LOW,
    SERVE_POSITION,
    TABLE_HEIGHT,
    VELOCITY_HIGH,
    VELOCITY_LOW,
    BallPhysics,
    simulate_ball,
)

DEMO_PATH = Path(__file__).resolve().parents[2] / "data" / "demonstrations" / "table_tennis.npz"
"""The shipped demonstration: ``np.savez_compressed(path, **forehand_demonstration())``."""
HIT_TIME = 0.72
"""Time (s) at which the demonstrated stroke meets the ball of the nominal context."""
RETURN_FLIGHT_TIME = 0.55
"""Flight time (s) of the demonstrated return from racket to table."""
PREFERRED_POSTURE = np.array([0.0, 0.0, -0.6, 0.3, 0.0, -1.0, 0.0, 0.0])
"""A relaxed forehand posture the stroke design's IK is pulled towards."""


def nominal_context() -> np.ndarray:
    """s₀ = [v₀, b₀] (5,): the centres of the launch-velocity range and the near return zone."""
    return np.concatenate(
        [0.5 * (VELOCITY_LOW + VELOCITY_HIGH), 0.5 * (RETURN_NEAR_LOW + RETURN_NEAR_HIGH)]
    )


def design_stroke(
    context=None, hit_time: float = HIT_TIME, flight_time: float = RETURN_FLIGHT_TIME
) -> dict:
    """The racket state returning the ball of ``context`` (default :func:`nominal_context`),
    at p_h with v_in at ``hit_time``, to b after ``flight_time``, and joints for it.

    Newton gives v_out; a frictionless impact has n ∥ v_out − v_in and racket velocity
    (v_in·n + (v_out − v_in)·n / (1 + e_r)) n; IK pulled to :data:`PREFERRED_POSTURE`. Returns
    ``q``, ``qd`` (8,), ``position``, ``normal``, ``racket_velocity``, ``ball_velocity_in`` and
    ``ball_velocity_out`` (3,).
    """
    import mujoco
    from scipy.optimize import fsolve, least_squares

    s = nominal_context() if context is None else check_array(context, "context", shape=(5,))
    hit_time = check_positive(hit_time, "hit_time")
    flight_time = check_positive(flight_time, "flight_time")
    dt = 0.002
    incoming = simulate_ball(SERVE_POSITION, s[:3], hit_time, dt=dt)
    p_h, v_in = incoming.positions[-1], incoming.velocities[-1]
    b = s[3:5]

    def miss(v_out):
        events = simulate_ball(p_h, v_out, 2.0, dt=dt).events
        if not events:  # an absurd trial velocity that never comes down: far off
            return [1e3, 1e3, 1e3]
        ev = events[0]
        return [ev.position[0] - b[0], ev.position[1] - b[1], ev.time - flight_time]

    # drag-free guess with 10% more horizontal speed for the drag
    vz = (TABLE_HEIGHT + 0.02 - p_h[2]) / flight_time + 0.5 * 9.81 * flight_time
    guess = np.array([1.1 * (b[0] - p_h[0]) / flight_time, 1.1 * (b[1] - p_h[1]) / flight_time, vz])
    v_out, _, ok, msg = fsolve(miss, guess, full_output=True)
    if ok != 1:
        raise RuntimeError(f"design_stroke: no return velocity found ({msg})")
    e_r = BallPhysics().racket_restitution
    n = (v_out - v_in) / np.linalg.norm(v_out - v_in)
    v_racket = (v_in @ n + (v_out - v_in) @ n / (1.0 + e_r)) * n

    model = arm_model()
    data = mujoco.MjData(model)
    sid = model.site(RACKET_SITE).id
    w_reg = np.array([3.0, 3.0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1])

    def residual(q):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        c, normal = racket_pose(model, data)
        return np.concatenate([100 * (c - p_h), 30 * (normal - n), w_reg * (q - PREFERRED_POSTURE)])

    q = least_squares(residual, PREFERRED_POSTURE, xtol=1e-12, ftol=1e-12).x
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    jacp, jacr = np.zeros((3, 8)), np.zeros((3, 8))
    mujoco.mj_jacSite(model, data, jacp, jacr, sid)
    cost = np.sqrt(np.array([200.0, 200.0, 1, 1, 1, 1, 1, 1]))
    a = np.vstack([100 * jacp, 3 * jacr, np.diag(cost)])
    y = np.concatenate([100 * v_racket, np.zeros(11)])
    qd = np.linalg.lstsq(a, y, rcond=None)[0]
    return {
        "q": q,
        "qd": qd,
        "position": p_h,
        "normal": n,
        "racket_velocity": v_racket,
        "ball_velocity_in": v_in,
        "ball_velocity_out": v_out,
    }


def forehand_demonstration(dt: float = 0.002) -> dict[str, np.ndarray]:
    """The forehand stroke the DMP imitates (our stand-in for kinesthetic teach-in): from rest
    at q_h − 0.2 D q̇_h back to q_h − 0.6 D q̇_h at 0.35 s, then forward to (q_h, q̇_h) of
    :func:`design_stroke` at :data:`HIT_TIME` (quintics, D = HIT_TIME − 0.35 s). Returns
    ``times`` (N,), ``q``, ``qd``, ``qdd`` (N, 8)."""
    dt = check_positive(dt, "dt")
    stroke = design_stroke()
    q_h, qd_h = stroke["q"], stroke["qd"]
    t_back = 0.35
    swing = HIT_TIME - t_back
    q_ready, q_back = q_h - 0.2 * swing * qd_h, q_h - 0.6 * swing * qd_h
    n = int(round(HIT_TIME / dt))
    times = dt * np.arange(n + 1)
    first = times < t_back
    zero = np.zeros(8)
    a = quintic(times[first], t_back, q_ready, q_back, zero, zero)
    b = quintic(times[~first] - t_back, swing, q_back, q_h, zero, qd_h)
    q, qd, qdd = (np.concatenate([x, y]) for x, y in zip(a, b, strict=True))
    return {"times": times, "q": q, "qd": qd, "qdd": qdd}


def load_demonstration(path: str | Path = DEMO_PATH) -> dict[str, np.ndarray]:
    """``times``, ``q``, ``qd``, ``qdd`` of a demonstration file (default the shipped one)."""
    with np.load(Path(path), allow_pickle=False) as f:
        return {k: f[k] for k in ("times", "q", "qd", "qdd")}
