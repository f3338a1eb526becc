"""The planar 4-link robot of Appendix C.1 as a MuJoCo model built with ``dm_control.mjcf``.

The robot is "roughly modeled as a human with ankle, knee, hip and shoulder joints"
(Sec. 3.4.1, Fig. 3.1): four links in one vertical plane,

==========  =====  ========  ===========================================
link        mass   length    joint at its lower end (hinge about +y)
==========  =====  ========  ===========================================
shin        17.5   0.5 m     ankle, fixed to the ground at the origin
thigh       17.5   0.5 m     knee
torso       26.5   1.0 m     hip
arm          8.5   1.0 m     shoulder, at the top of the torso
==========  =====  ========  ===========================================

(total 70 kg, standing height 2 m, as in Sec. 4.3.1). Conventions:

* MuJoCo's x–z plane is the robot's plane: +x is forward (towards the targets), +z up.
  The thesis's 2-D coordinates ``[x, y]`` of Appendix C.1 are MuJoCo's ``[x, z]``.
* The **base is fixed to the ground**: the ankle hinge is attached to the world, so the
  robot cannot tip over as a whole or slide; "losing balance" means the links fall
  around the ankle.
* All hinge axes are +y, so a positive angle tilts a link that points up forwards (+x).
  With ``q = 0`` shin, thigh and torso stand upright and the arm hangs down along the
  torso; the arm points straight up at ``q_4 = π``. The upright posture of the thesis is
  therefore ``q = [0, 0, 0, π]``, and the joint limits of Appendix C.1 read naturally:
  the knee only flexes (``q_2 ≤ 0.05``), the hip flexes forwards (``q_3 ≤ 2``) and the arm
  turns from hanging (0) backwards, over the head (π) to pointing forwards (1.5π).
* Links are uniform thin rods: mass ``m`` at the middle of the link and moment of inertia
  ``m l² / 12`` about the centre (the thesis gives no inertia; this is our assumption).
* No joint limits, damping, friction or contacts are modelled (every geom has
  ``contype = conaffinity = 0``): the thesis's limits are soft, enforced by the reward, and
  links may pass through the ground. All four joints carry a ``<motor>`` actuator (gear 1,
  unlimited), i.e. all are torque-actuated.
* The default time step is 1 ms with MuJoCo's semi-implicit Euler integrator.

A site ``hand`` marks the tip of the arm (where the ball is held in the throwing task).
:class:`PlanarRobot` is one compiled robot with its hand site, as the throwing and balancing
tasks hold it.
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
UPRIGHT = np.array([0.0, 0.0, 0.0, np.pi])
"""Upright posture q = [0, 0, 0, π] (rad): legs and torso vertical, arm pointing up."""
TIMESTEP = 1e-3
"""Physics time step in seconds."""


def build_planar_robot(timestep: float = TIMESTEP) -> mjcf.RootElement:
    """MJCF model of the planar 4-link robot (Appendix C.1).

    Parameters
    ----------
    timestep : float
        Physics time step in seconds.

    Returns
    -------
    dm_control.mjcf.RootElement
        The model; compile with ``mjcf.Physics.from_mjcf_model``.
    """
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
    return root


def compile_planar_robot(timestep: float = TIMESTEP) -> mjcf.Physics:
    """Compile :func:`build_planar_robot` into a ``dm_control.mjcf.Physics``.

    Use ``physics.model.ptr`` / ``physics.data.ptr`` (raw ``mujoco.MjModel``/``MjData``)
    with ``mujoco.mj_step`` in inner loops.
    """
    return mjcf.Physics.from_mjcf_model(build_planar_robot(timestep))


@functools.cache  # constants of the robot: computed once, not at every control step
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
    """Joint-space inertia M(q) and bias force c(q, q̇) of the robot, in closed form (torch).

    The equations of motion M(q) q̈ + c(q, q̇) = u of :func:`build_planar_robot` (MuJoCo's
    ``qM`` and ``qfrc_bias``). With absolute link angles θ = L q (L lower triangular ones)
    the centre of mass of link k is p_k = Σ_j a_kj (sin θ_j, cos θ_j) (in the x–z plane), so
    the kinetic energy is ½ θ̇ᵀ (H ⊙ cos(θ_i − θ_j) + diag I) θ̇ with H = Aᵀ diag(m) A, and
    the potential g Σ_j b_j cos θ_j with b = Aᵀ m. Lagrange's equations in θ give
    M_θ = H ⊙ cos(θ_i − θ_j) + diag I and h_θ,i = Σ_j H_ij sin(θ_i − θ_j) θ̇_j² − g b_i sin θ_i;
    in joint coordinates M = Lᵀ M_θ L and c = Lᵀ h_θ.

    Parameters
    ----------
    q, qd : Tensor, shape (..., 4)
        Joint angles and velocities.
    gravity : float
        g (m/s²).

    Returns
    -------
    M : Tensor, shape (..., 4, 4)
    c : Tensor, shape (..., 4)
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
