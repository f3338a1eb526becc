"""The demonstrated hitting stroke the hockey DMP imitates (and its shipped file)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from skillkit._validation import check_positive
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.hockey.arm import BLADE_HALF, N_JOINTS, TIMESTEP, arm_model
from skillkit.tasks.hockey.table import CONTROL_PUCK_START, TARGET_CENTRE

DEMO_DURATION = 0.5
"""Duration of the demonstrated stroke, s."""
DEMO_BACKSWING = 0.35
"""Length of the demonstrated straight blade path, m."""
DEMO_HIT_SPEED = 1.0
"""Blade speed at the end of the demonstrated stroke, m/s."""
DEMO_BLADE_HEIGHT = 0.045
"""Height of the blade centre above the table during the demonstration, m."""
DEMO_POSTURE = np.array([-0.5, 0.6, 0.0, 1.5, 0.0, 1.0, 0.0])
"""Nominal posture the demonstration's inverse kinematics stays close to, rad."""
DEMO_PATH = Path(__file__).resolve().parents[2] / "data" / "demonstrations" / "hockey.npz"
"""The shipped demonstration: ``np.savez(path, **make_demonstration())``."""


def _ik_blade(model, data, site: int, position, rotation, q, posture) -> np.ndarray:
    """Damped least-squares IK for the blade pose with a null-space pull towards ``posture``."""
    jacp, jacr = np.zeros((3, N_JOINTS)), np.zeros((3, N_JOINTS))
    q = q.copy()
    for _ in range(300):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        r = rotation @ data.site_xmat[site].reshape(3, 3).T
        axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
        err = np.concatenate([position - data.site_xpos[site], 0.5 * axis])
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        jac = np.vstack([jacp, jacr])
        pinv = jac.T @ np.linalg.inv(jac @ jac.T + 1e-10 * np.eye(6))
        step = pinv @ err + (np.eye(N_JOINTS) - pinv @ jac) @ (0.2 * (posture - q))
        q = q + step
        if np.linalg.norm(err) < 1e-10 and np.linalg.norm(step) < 1e-8:
            break
    else:
        raise RuntimeError(f"demonstration IK did not converge (error {np.linalg.norm(err):.2e})")
    return q


def make_demonstration(dt: float = TIMESTEP) -> dict[str, np.ndarray]:
    """The demonstrated stroke every ``dt`` s: the upright blade slides :data:`DEMO_BACKSWING`
    towards :data:`TARGET_CENTRE`, reaching the control puck at :data:`DEMO_HIT_SPEED` after
    :data:`DEMO_DURATION` (quintic timing, damped least-squares IK). Returns ``times`` (N,),
    ``q``, ``qd``, ``qdd`` (N, 7), ``blade`` (N, 3), ``control_puck_start``, ``direction`` (2,).
    """
    dt = check_positive(dt, "dt")
    model = arm_model()
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "blade")
    direction = TARGET_CENTRE - CONTROL_PUCK_START
    direction /= np.linalg.norm(direction)
    normal = np.array([direction[0], direction[1], 0.0])
    shaft = np.array([0.0, 0.0, -1.0])
    rotation = np.column_stack([np.cross(normal, shaft), normal, shaft])
    end = np.append(CONTROL_PUCK_START - BLADE_HALF[1] * direction, DEMO_BLADE_HEIGHT)
    start = end - DEMO_BACKSWING * normal
    n = int(round(DEMO_DURATION / dt))
    times = dt * np.arange(n + 1)
    s, _, _ = quintic(times, DEMO_DURATION, end_velocity=DEMO_HIT_SPEED / DEMO_BACKSWING)
    blade = start + s[:, None] * (end - start)
    q = np.empty((n + 1, N_JOINTS))
    guess = DEMO_POSTURE.copy()
    for i in range(n + 1):
        guess = _ik_blade(model, data, site, blade[i], rotation, guess, DEMO_POSTURE)
        q[i] = guess
    qd = np.gradient(q, dt, axis=0, edge_order=2)
    qdd = np.gradient(qd, dt, axis=0, edge_order=2)
    qd[0] = 0.0
    qdd[0] = 0.0
    return {
        "times": times,
        "q": q,
        "qd": qd,
        "qdd": qdd,
        "blade": blade,
        "control_puck_start": CONTROL_PUCK_START.copy(),
        "direction": direction,
    }


def load_demonstration(path: str | Path = DEMO_PATH) -> dict[str, np.ndarray]:
    """Read the demonstration written by ``np.savez(path, **make_demonstration())``."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"path: no hockey demonstration at {path} (see make_demonstration)")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}
