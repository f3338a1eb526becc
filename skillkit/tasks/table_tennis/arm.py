"""The 8-DoF table-tennis arm (MuJoCo model built with ``dm_control.mjcf``)."""

from __future__ import annotations

from functools import lru_cache

import mujoco
import numpy as np

from skillkit.tasks._mjcf import mjcf_root

JOINT_NAMES = (
    "base_x",
    "base_y",
    "shoulder_yaw",
    "shoulder_pitch",
    "upper_arm_roll",
    "elbow",
    "forearm_roll",
    "wrist",
)
"""The 8 tracked joints, in the column order of q and of the DMP."""
PLATFORM_POSITION = np.array([-2.0, 0.5])
"""Where the platform stands at q = 0 (m), behind the robot's end line and left of the centre
line (the ball passes on the robot's right: a forehand)."""
SHOULDER_HEIGHT = 1.2
"""Height of the shoulder above the floor (m)."""
LINK_LENGTHS = (0.30, 0.28, 0.18)
"""Upper arm, forearm, wrist-to-blade-centre (m)."""
LINK_MASSES = (8.0, 1.0, 0.5, 0.35, 0.17)
"""Platform, shoulder housing, upper arm, forearm, hand + racket (kg): light like BioRob."""
ARMATURE = (2.0, 2.0, 0.02, 0.02, 0.01, 0.01, 0.005, 0.005)
"""Reflected drive inertia per joint (kg or kg m²): motors behind gears/tendons."""
KP = np.array([4000.0, 4000.0, 400.0, 400.0, 150.0, 150.0, 60.0, 60.0])
"""PD proportional gains (N/m for the axes, N m/rad for the revolute joints)."""
KD = np.array([250.0, 250.0, 12.0, 12.0, 4.0, 4.0, 1.2, 1.2])
"""PD derivative gains (N s/m, N m s/rad)."""
TORQUE_LIMIT = np.array([500.0, 500.0, 80.0, 80.0, 40.0, 40.0, 15.0, 15.0])
"""Actuator limits (N, N m); saturation is counted in ``info["n_saturated"]``."""
INITIAL_STD = np.concatenate([[0.05, 0.1], np.full(6, 0.08), [0.15, 0.15], np.full(6, 0.3), [0.03]])
"""Exploration std of the initial policy per entry of ω = [g (8), ġ (8), τ] (m, rad, m/s,
rad/s; y varies most, as the ball's arrival does)."""
RACKET_SITE = "racket"
"""Site at the blade centre; its local y axis is the blade normal."""


@lru_cache(maxsize=4)
def arm_model(timestep: float = 0.002):
    """The 8-DoF arm as a compiled MuJoCo model (``timestep`` in s; cached, read-only here).

    Two prismatic axes move a platform carrying a 1.2 m column with a 6-DoF arm pointing along
    +x at q = 0 (shoulder yaw z and pitch y, upper-arm roll x, elbow y, forearm roll x, wrist
    z), a handle and a disc blade of radius 8 cm whose normal is the hand's y axis. Contacts
    are disabled (the ball is simulated outside MuJoCo).
    """
    l1, l2, l3 = LINK_LENGTHS
    m_base, m_shoulder, m_upper, m_fore, m_hand = LINK_MASSES
    root = mjcf_root("table_tennis_arm", float(timestep), contacts=False)
    arm = iter(ARMATURE)

    def joint(body, name, kind, axis):
        body.add("joint", name=name, type=kind, axis=axis, armature=next(arm))

    platform_xyz = [PLATFORM_POSITION[0], PLATFORM_POSITION[1], 0.0]
    platform = root.worldbody.add("body", name="platform", pos=platform_xyz)
    joint(platform, "base_x", "slide", [1, 0, 0])
    joint(platform, "base_y", "slide", [0, 1, 0])
    h = 0.5 * SHOULDER_HEIGHT
    column = {
        "size": [0.12, 0.12, h],
        "pos": [0, 0, h],
        "mass": m_base,
        "rgba": [0.4, 0.4, 0.45, 1],
    }
    platform.add("geom", name="column", type="box", **column)
    shoulder = platform.add("body", name="upper_arm", pos=[0, 0, SHOULDER_HEIGHT])
    joint(shoulder, "shoulder_yaw", "hinge", [0, 0, 1])
    joint(shoulder, "shoulder_pitch", "hinge", [0, 1, 0])
    blue = [0.2, 0.3, 0.6, 1]
    shoulder.add("geom", name="shoulder", type="sphere", size=[0.06], mass=m_shoulder, rgba=blue)
    upper = {"fromto": [0, 0, 0, l1, 0, 0], "size": [0.035], "mass": m_upper, "rgba": blue}
    shoulder.add("geom", name="upper_arm", type="capsule", **upper)
    forearm = shoulder.add("body", name="forearm", pos=[l1, 0, 0])
    joint(forearm, "upper_arm_roll", "hinge", [1, 0, 0])
    joint(forearm, "elbow", "hinge", [0, 1, 0])
    fore = {"fromto": [0, 0, 0, l2, 0, 0], "size": [0.03], "mass": m_fore, "rgba": blue}
    forearm.add("geom", name="forearm", type="capsule", **fore)
    hand = forearm.add("body", name="hand", pos=[l2, 0, 0])
    joint(hand, "forearm_roll", "hinge", [1, 0, 0])
    joint(hand, "wrist", "hinge", [0, 0, 1])
    handle = {"fromto": [0, 0, 0, l3 - 0.08, 0, 0], "size": [0.015], "mass": 0.3 * m_hand}
    hand.add("geom", name="handle", type="capsule", rgba=[0.6, 0.4, 0.2, 1], **handle)
    blade = {"fromto": [l3, -0.005, 0, l3, 0.005, 0], "size": [0.08], "mass": 0.7 * m_hand}
    hand.add("geom", name="blade", type="cylinder", rgba=[0.8, 0.1, 0.1, 1], **blade)
    hand.add("site", name=RACKET_SITE, pos=[l3, 0, 0], size=[0.01])
    return mujoco.MjModel.from_xml_string(root.to_xml_string())


def racket_pose(model, data) -> tuple[np.ndarray, np.ndarray]:
    """Blade centre (3,) and unit normal (3,) from the current kinematics of ``data``."""
    sid = model.site(RACKET_SITE).id
    return data.site_xpos[sid].copy(), data.site_xmat[sid].reshape(3, 3)[:, 1].copy()
