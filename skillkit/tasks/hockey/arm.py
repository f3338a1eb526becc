"""The KUKA-LWR-like 7-DoF arm with its hockey racket (MuJoCo model and numpy kinematics)."""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from skillkit._validation import check_array
from skillkit.tasks._mjcf import mjcf_root

N_JOINTS = 7
JOINT_AXES = ((0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1))
LINK_OFFSETS = (0.1575, 0.1530, 0.2000, 0.2000, 0.2000, 0.1900, 0.0000)
"""Position of joint i+1 along the z axis of link i (link 0 = base), m (LWR-4 d1, d3, d5)."""
FLANGE_OFFSET = 0.078
"""Flange distance from the wrist along the last link's z axis (LWR-4 d7), m."""
LINK_MASSES = (2.7, 2.7, 2.7, 2.7, 1.7, 1.6, 0.3)
"""Link masses, kg (approximate LWR-4 values)."""
ARMATURE = (0.4, 0.4, 0.2, 0.2, 0.1, 0.1, 0.05)
"""Reflected motor inertia per joint, kg m² (our estimate for harmonic-drive joints)."""
JOINT_LIMITS = np.deg2rad([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 170.0])
"""Symmetric joint ranges ±limit, rad (LWR-4)."""
TORQUE_LIMITS = np.array([176.0, 176.0, 100.0, 100.0, 100.0, 38.0, 38.0])
"""Actuator torque limits, N m (LWR-4)."""
KP = np.array([2500.0, 2500.0, 1200.0, 1200.0, 400.0, 400.0, 150.0])
"""PD stiffness per joint, N m / rad."""
KD = np.array([90.0, 90.0, 45.0, 45.0, 14.0, 14.0, 5.0])
"""PD damping per joint, N m s / rad."""
SHAFT_LENGTH, SHAFT_MASS, SHAFT_RADIUS = 0.45, 0.25, 0.012
BLADE_HALF = (0.10, 0.008, 0.04)
"""Blade half sizes along the flange's x (long side), y (face normal) and z axes, m."""
BLADE_MASS = 0.15
BLADE_OFFSET = FLANGE_OFFSET + SHAFT_LENGTH + BLADE_HALF[2]
"""Blade centre distance from the wrist along the last link's z axis, m."""
TIMESTEP = 0.002
"""MuJoCo time step, s."""
CONTROL_DT = 0.004
"""Control period of the PD tracker (250 Hz) and time step of the puck table, s."""
TABLE_FRICTION = 0.1
"""Coulomb friction between the blade and the table (our choice; the thesis gives none)."""
CONTACT_SOLREF = (0.004, 1.0)
"""MuJoCo ``solref`` (time constant, damping ratio) of the blade–table contact (2 Δt: the
stiffest the step allows)."""


@functools.lru_cache(maxsize=4)
def _arm_xml(timestep: float) -> str:
    root = mjcf_root("lwr_hockey", timestep, geom_rgba=[1.0, 0.55, 0.1, 1.0])
    root.worldbody.add("light", pos=[0, 0, 3], dir=[0, 0, -1])
    contact = {"friction": [TABLE_FRICTION, 0.005, 0.0001], "solref": list(CONTACT_SOLREF)}
    table = {"size": [3, 2, 0.1], "pos": [1.2, 0.3, 0], "rgba": [0.9, 0.9, 0.88, 1]}
    root.worldbody.add(
        "geom", name="table", type="plane", contype=1, conaffinity=0, **table, **contact
    )
    half = LINK_OFFSETS[0] / 2
    base = {"size": [0.08, half], "pos": [0, 0, half], "mass": 5.0, "rgba": [0.3, 0.3, 0.3, 1]}
    root.worldbody.add("geom", name="base", type="cylinder", **base)
    parent = root.worldbody
    for i in range(N_JOINTS):
        body = parent.add("body", name=f"link{i + 1}", pos=[0, 0, LINK_OFFSETS[i]])
        hinge = {"type": "hinge", "axis": list(JOINT_AXES[i]), "limited": True}
        limits = [-JOINT_LIMITS[i], JOINT_LIMITS[i]]
        body.add("joint", name=f"j{i + 1}", range=limits, armature=ARMATURE[i], **hinge)
        length = LINK_OFFSETS[i + 1] if i + 1 < N_JOINTS else FLANGE_OFFSET
        tip = [0, 0, 0, 0, 0, max(length, 0.04)]
        link = {"size": [0.06 - 0.004 * i], "fromto": tip, "mass": LINK_MASSES[i]}
        body.add("geom", name=f"link{i + 1}_geom", type="capsule", **link)
        parent = body
    parent.add("site", name="flange", pos=[0, 0, FLANGE_OFFSET], size=[0.01])
    ends = [0, 0, FLANGE_OFFSET, 0, 0, FLANGE_OFFSET + SHAFT_LENGTH]
    shaft = {"size": [SHAFT_RADIUS], "mass": SHAFT_MASS, "rgba": [0.2, 0.2, 0.2, 1]}
    parent.add("geom", name="shaft", type="capsule", fromto=ends, **shaft)
    blade = {"size": list(BLADE_HALF), "mass": BLADE_MASS, "pos": [0, 0, BLADE_OFFSET]}
    blade.update(rgba=[0.1, 0.1, 0.1, 1], contype=0, conaffinity=1, **contact)
    parent.add("geom", name="blade", type="box", **blade)
    parent.add("site", name="blade", pos=[0, 0, BLADE_OFFSET], size=[0.01])
    return root.to_xml_string()


def arm_model(timestep: float = TIMESTEP) -> mujoco.MjModel:
    """A fresh compiled ``MjModel`` of the arm: bodies ``link1`` … ``link7`` with hinge joints
    ``j1`` … ``j7`` (:data:`JOINT_AXES`, :data:`JOINT_LIMITS`, :data:`ARMATURE`), sites
    ``flange`` and ``blade``; only the blade box and the table plane collide
    (:data:`TABLE_FRICTION`, :data:`CONTACT_SOLREF`). ``timestep`` in s."""
    return mujoco.MjModel.from_xml_string(_arm_xml(float(timestep)))


def _axis_rotation(axis: tuple[int, int, int], angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about a coordinate axis, shape (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == (0, 0, 1):
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    else:  # the y axis
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def arm_forward_kinematics(q) -> tuple[np.ndarray, np.ndarray]:
    """Blade pose p = Σ_i R_0 … R_{i−1} [0, 0, l_i] + R_0 … R_6 [0, 0, BLADE_OFFSET] by an
    independent numpy chain, l_i = :data:`LINK_OFFSETS`.

    Parameters
    ----------
    q : array_like, shape (..., 7)
        Joint angles, rad.

    Returns
    -------
    position, rotation : ndarray, shape (..., 3), (..., 3, 3)
        Blade centre (m) and frame (columns: long side, face normal, shaft).
    """
    q = check_array(q, "q", ndim=(1, 2))
    if q.shape[-1] != N_JOINTS:
        raise ValueError(f"q: expected shape (..., {N_JOINTS}), got {q.shape}")
    rot = np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3)).copy()
    pos = np.zeros(q.shape[:-1] + (3,))
    for i in range(N_JOINTS):
        pos = pos + rot[..., :, 2] * LINK_OFFSETS[i]
        rot = rot @ _axis_rotation(JOINT_AXES[i], q[..., i])
    pos = pos + rot[..., :, 2] * BLADE_OFFSET
    return pos, rot


def blade_pose(position, rotation) -> np.ndarray:
    """Blade [x, y, z, yaw, z_low, z_high], shape (..., 6), from its centre (..., 3) and frame
    (..., 3, 3) (columns: long side, face normal, shaft); yaw is the long side's heading and
    z_low, z_high the lowest and highest corner heights."""
    position = np.asarray(position, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64)
    reach = np.abs(rotation[..., 2, :]) @ np.asarray(BLADE_HALF)
    yaw = np.arctan2(rotation[..., 1, 0], rotation[..., 0, 0])
    z = position[..., 2]
    return np.concatenate(
        [position, yaw[..., None], (z - reach)[..., None], (z + reach)[..., None]], axis=-1
    )
