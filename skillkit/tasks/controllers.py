"""Low-level trackers of the robot tasks (Appendix C): the zero-order-hold MuJoCo feedback
loop :func:`run_feedback` and :func:`track_reference`, which PD-tracks a joint reference (a DMP,
Eqs. 2.21–2.23). Torques go through ``data.qfrc_applied``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import mujoco
import numpy as np

from skillkit._validation import check_array, check_count, check_positive
from skillkit.tasks.base import SimulationFailure

__all__ = ["control_substeps", "run_feedback", "track_reference"]

_INSTABILITY_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


def _instability_count(data: mujoco.MjData) -> int:
    return sum(data.warning[w].number for w in _INSTABILITY_WARNINGS)


def _joints(model: mujoco.MjModel, joint_ids: Sequence[int] | None):
    """Joint ids (default every joint; hinges or slides), their ``qpos`` and dof addresses."""
    ids = np.arange(model.njnt) if joint_ids is None else np.asarray(joint_ids, dtype=int).ravel()
    if ids.size == 0:
        raise ValueError("joint_ids: expected at least one joint")
    if np.any(ids < 0) or np.any(ids >= model.njnt):
        raise ValueError(f"joint_ids: expected ids in [0, {model.njnt}), got {ids.tolist()}")
    one_dof = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    bad = [int(j) for j in ids if int(model.jnt_type[j]) not in one_dof]
    if bad:
        raise ValueError(f"joint_ids: joints {bad} are not hinge or slide joints")
    return ids, _as_slice(model.jnt_qposadr[ids]), _as_slice(model.jnt_dofadr[ids])


def run_feedback(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    controller: Callable[[int, np.ndarray, np.ndarray, mujoco.MjData], np.ndarray],
    n_steps: int,
    control_dt: float,
    *,
    joint_ids: Sequence[int] | None = None,
    on_step: Callable[[int, mujoco.MjData], None] | None = None,
) -> dict[str, np.ndarray]:
    """Run MuJoCo under a state-feedback law, u[t] = controller(t, q[t], q̇[t], data) held
    for ``control_dt`` (after ``on_step(t, data)``), from the state in ``data``.

    Parameters
    ----------
    model, data : mujoco.MjModel, mujoco.MjData
    controller : callable
        ``controller(t, q, qd, data) -> u``, each of shape (n,).
    n_steps, control_dt : int, float
        Control steps T; control period (s), a multiple of ``model.opt.timestep``.
    joint_ids : sequence of int, optional
        The n controlled joints (default every joint).
    on_step : callable, optional

    Returns
    -------
    dict
        ``q``, ``qd``, ``u`` (T, n) at the control steps.

    Raises
    ------
    SimulationFailure
        On a non-finite state or torque, or an instability MuJoCo flagged (and reset).
    """
    ids, qadr, dadr = _joints(model, joint_ids)
    n = ids.size
    n_steps = check_count(n_steps, "n_steps", 0)
    substeps = control_substeps(model, control_dt)
    rk4 = int(model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4)

    q_out, qd_out, u_out = (np.empty((n_steps, n)) for _ in range(3))
    warn0 = _instability_count(data)
    data.qfrc_applied[dadr] = 0.0
    for t in range(n_steps):
        (mujoco.mj_forward if rk4 else mujoco.mj_step1)(model, data)
        q_out[t] = data.qpos[qadr]
        qd_out[t] = data.qvel[dadr]
        if on_step is not None:
            on_step(t, data)
        u_out[t] = controller(t, q_out[t], qd_out[t], data)
        data.qfrc_applied[dadr] = u_out[t]
        (mujoco.mj_step if rk4 else mujoco.mj_step2)(model, data)
        if substeps > 1:
            mujoco.mj_step(model, data, nstep=substeps - 1)
    data.qfrc_applied[dadr] = 0.0
    if _instability_count(data) != warn0:
        raise SimulationFailure(
            "MuJoCo flagged an unstable simulation (non-finite or huge "
            "positions, velocities or accelerations) and reset it"
        )
    for name, arr in (("joint state", q_out), ("joint velocity", qd_out), ("torque", u_out)):
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            t = int(np.argmax(bad))
            raise SimulationFailure(
                f"non-finite {name} at control step {t} (t = {t * control_dt:.3f} s)"
            )
    return {"q": q_out, "qd": qd_out, "u": u_out}


def track_reference(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    q_ref,
    qd_ref,
    control_dt: float,
    kp,
    kd,
    *,
    joint_ids: Sequence[int] | None = None,
    gravity_compensation: bool = True,
    torque_limit=None,
    on_step: Callable[[int, mujoco.MjData], None] | None = None,
    qdd_ref=None,
    inertia_weighted: bool = False,
) -> dict[str, np.ndarray]:
    """Track a joint reference with PD torques (:func:`run_feedback`).

    u[t] = kp ⊙ e[t] + kd ⊙ ė[t] + c(q[t], q̇[t]), e = q_ref − q, c the bias force
    ``qfrc_bias`` (with ``gravity_compensation``); with ``inertia_weighted`` the computed-torque
    tracker u[t] = M(q[t]) (q̈_ref[t] + kp ⊙ e[t] + kd ⊙ ė[t]) + c. ``torque_limit`` clips |u|.

    Parameters
    ----------
    model, data, control_dt, joint_ids, on_step
        As :func:`run_feedback`'s.
    q_ref, qd_ref : array_like, shape (T, n)
        Reference at the control steps, columns in ``joint_ids`` order.
    kp, kd, torque_limit : float or array_like, shape (n,)
    qdd_ref : array_like, shape (T, n), optional
        Fed-forward acceleration (only with ``inertia_weighted``).

    Returns
    -------
    dict
        ``q``, ``qd``, ``u`` (T, n) and ``n_saturated``.
    """
    ids, _, dadr = _joints(model, joint_ids)
    n = ids.size
    q_ref = check_array(q_ref, "q_ref", shape=(None, n))
    qd_ref = check_array(qd_ref, "qd_ref", shape=(q_ref.shape[0], n))
    kp = _gain(kp, "kp", n)
    kd = _gain(kd, "kd", n)
    limit = None if torque_limit is None else _gain(torque_limit, "torque_limit", n)
    if qdd_ref is not None:
        if not inertia_weighted:
            raise ValueError("qdd_ref: the feed-forward acceleration needs inertia_weighted=True")
        qdd_ref = check_array(qdd_ref, "qdd_ref", shape=(q_ref.shape[0], n))
    n_saturated = 0
    full_m = np.zeros((model.nv, model.nv))
    block = np.ix_(np.arange(model.nv)[dadr], np.arange(model.nv)[dadr])

    def pd(t: int, q: np.ndarray, qd: np.ndarray, d: mujoco.MjData) -> np.ndarray:
        nonlocal n_saturated
        u = kp * (q_ref[t] - q) + kd * (qd_ref[t] - qd)
        if inertia_weighted:
            if qdd_ref is not None:
                u = u + qdd_ref[t]
            mujoco.mj_fullM(model, d, full_m)
            u = full_m[block] @ u
        if gravity_compensation:
            u = u + d.qfrc_bias[dadr]
        if limit is not None:
            n_saturated += int(np.count_nonzero(np.abs(u) > limit))
            u = np.clip(u, -limit, limit)
        return u

    out = run_feedback(model, data, pd, q_ref.shape[0], control_dt, joint_ids=ids, on_step=on_step)
    out["n_saturated"] = n_saturated
    return out


def control_substeps(model: mujoco.MjModel, control_dt: float) -> int:
    """Physics steps per control period; ``ValueError`` unless a positive whole number."""
    control_dt = check_positive(control_dt, "control_dt")
    step = model.opt.timestep
    ratio = control_dt / step
    substeps = int(round(ratio))
    if substeps < 1 or abs(ratio - substeps) > 1e-6 * max(ratio, 1.0):
        raise ValueError(f"control_dt: expected a whole multiple of {step:g} s, got {control_dt}")
    return substeps


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


def _gain(value, name: str, n: int) -> np.ndarray:
    g = check_array(value, name, ndim=(0, 1))
    if g.ndim == 1 and g.shape[0] != n:
        raise ValueError(f"{name}: expected a scalar or shape ({n},), got {g.shape}")
    if np.any(g < 0):
        raise ValueError(f"{name}: expected non-negative gains, got {g.tolist()}")
    return g
