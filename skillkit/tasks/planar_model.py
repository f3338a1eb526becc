"""The planar 4-link robot of Appendix C.1 (Sec. 3.4.1, Fig. 3.1) built with ``dm_control.mjcf``.

Links shin, thigh, torso, arm (:data:`LINK_MASSES`, :data:`LINK_LENGTHS`) hinge about +y at
the ankle (fixed at the origin), knee, hip and shoulder (top of the torso). MuJoCo's x–z plane
is the thesis's [x, y]; a positive angle tilts an upward link forwards; at q = 0 the arm hangs
down, so upright is q = [0, 0, 0, π]. Uniform thin rods (inertia m l²/12, our assumption), no
joint limits, damping or contacts (C.1's limits are soft, in the reward), unit-gear motors,
1 ms semi-implicit Euler steps; a site ``hand`` marks the arm's tip.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np
from dm_control import mjcf

from skillkit.tasks._mjcf import GRAVITY, mjcf_root

LINK_NAMES = ("shin", "thigh", "torso", "arm")
JOINT_NAMES = ("ankle", "knee", "hip", "shoulder")
LINK_MASSES = np.array([17.5, 17.5, 26.5, 8.5])
LINK_LENGTHS = np.array([0.5, 0.5, 1.0, 1.0])
STATE_NAMES = JOINT_NAMES + tuple(f"{j}_velocity" for j in JOINT_NAMES)
TORQUE_NAMES = tuple(f"{j}_torque" for j in JOINT_NAMES)
UPRIGHT = np.array([0.0, 0.0, 0.0, np.pi])
"""Upright posture q = [0, 0, 0, π] (rad): legs and torso vertical, arm pointing up."""
TIMESTEP = 1e-3
"""Physics time step in seconds."""


def compile_planar_robot(timestep: float = TIMESTEP) -> mjcf.Physics:
    """The planar 4-link robot (Appendix C.1) as a compiled ``dm_control.mjcf.Physics``."""
    root = mjcf_root("planar_4link", timestep, geom_rgba=[0.55, 0.6, 0.7, 1.0])
    root.worldbody.add("light", pos=[0, -6, 4], dir=[0, 1, -0.5])
    root.worldbody.add(
        "geom",
        name="ground",
        type="plane",
        size=[20, 2, 0.1],
        pos=[7, 0, 0],
        rgba=[0.85, 0.85, 0.8, 1],
    )

    parent = root.worldbody
    attach_z = 0.0
    for i, (link, joint) in enumerate(zip(LINK_NAMES, JOINT_NAMES, strict=True)):
        m, length = float(LINK_MASSES[i]), float(LINK_LENGTHS[i])
        sign = -1.0 if link == "arm" else 1.0  # the arm hangs down from the shoulder at q4 = 0
        body = parent.add("body", name=link, pos=[0, 0, attach_z])
        body.add("joint", name=joint, type="hinge", axis=[0, 1, 0], pos=[0, 0, 0])
        i_rod = m * length**2 / 12.0
        body.add(
            "inertial",
            pos=[0, 0, sign * length / 2],
            mass=m,
            diaginertia=[i_rod, i_rod, 1e-6 * max(i_rod, 1.0)],
        )
        body.add(
            "geom",
            name=f"{link}_geom",
            type="capsule",
            size=[0.04 if link != "torso" else 0.08],
            fromto=[0, 0, 0, 0, 0, sign * length],
            mass=0,
        )
        root.actuator.add("motor", name=f"{joint}_motor", joint=body.find("joint", joint), gear=[1])
        parent, attach_z = body, length
    parent.add(
        "site", name="hand", pos=[0, 0, -LINK_LENGTHS[3]], size=[0.06], rgba=[0.9, 0.2, 0.2, 1]
    )
    return mjcf.Physics.from_mjcf_model(root)


@functools.cache
def _chain_constants() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H (4, 4), b (4,) and the rod inertias I (4,) of :func:`rigid_body_terms`."""
    a = np.zeros((4, 4))  # a[k, j]: lever of absolute angle θ_j in the centre of mass of link k
    for k in range(4):
        a[k, :k] = LINK_LENGTHS[:k]
        a[k, k] = (-1.0 if LINK_NAMES[k] == "arm" else 1.0) * LINK_LENGTHS[k] / 2
    out = (a.T @ np.diag(LINK_MASSES) @ a, a.T @ LINK_MASSES, LINK_MASSES * LINK_LENGTHS**2 / 12.0)
    for arr in out:
        arr.flags.writeable = False  # shared by every call
    return out


def rigid_body_terms(q, qd, gravity: float = GRAVITY):
    """Joint-space inertia M(q) (..., 4, 4) and bias force c(q, q̇) (..., 4) in closed form.

    MuJoCo's ``qM`` and ``qfrc_bias`` of torch ``q``, ``qd`` (..., 4). With absolute angles
    θ = L q (L lower-triangular ones) and link centres p_k = Σ_j a_kj (sin θ_j, cos θ_j),
    H = Aᵀ diag(m) A and b = Aᵀ m, Lagrange's equations give
    M_θ = H ⊙ cos(θ_i − θ_j) + diag I, h_θ,i = Σ_j H_ij sin(θ_i − θ_j) θ̇_j² − g b_i sin θ_i,
    and M = Lᵀ M_θ L, c = Lᵀ h_θ.
    """
    import torch

    h_np, b_np, i_np = _chain_constants()
    kw = {"dtype": q.dtype, "device": q.device}
    h, b = torch.tensor(h_np, **kw), torch.tensor(b_np, **kw)  # copies: h_np is read-only
    lower = torch.tril(torch.ones(4, 4, **kw))
    theta, theta_d = q @ lower.T, qd @ lower.T
    diff = theta[..., :, None] - theta[..., None, :]
    m_theta = h * torch.cos(diff) + torch.diag(torch.tensor(i_np, **kw))
    h_theta = (h * torch.sin(diff) * theta_d[..., None, :] ** 2).sum(-1) - gravity * b * torch.sin(
        theta
    )
    return lower.T @ m_theta @ lower, h_theta @ lower


class PlanarRobot:
    """Compiled planar robot (one per task instance)."""

    def __init__(self, timestep: float) -> None:
        self.physics = compile_planar_robot(timestep)
        self.model: mujoco.MjModel = self.physics.model.ptr
        self.data: mujoco.MjData = self.physics.data.ptr
        self.gravity = float(-self.model.opt.gravity[2])

    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set the state (q, q̇) and recompute its kinematics."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        self.data.qvel[:] = qd
        mujoco.mj_forward(self.model, self.data)
