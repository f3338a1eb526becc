"""Robot hockey (Appendix C.2, Sec. 3.4.2): a 7-DoF arm shoots a control puck at a target puck.

Scene
-----
The robot base stands at the origin of the table plane (z = 0), +x forward, +y left, +z
up. The **control puck** starts at :data:`CONTROL_PUCK_START` in front of the racket; the
**target puck** starts at b = [b_x, b_y] (the context). The robot must hit the target puck
with the control puck so that the target puck moves by the desired distance d*.

Context and reward (C.2)::

    s = [b_x, b_y, d*],   b_x ∈ [1.5, 2.5] m,  b_y ∈ [0.5, 1] m,  d* ∈ [0, 1] m,
    R(τ, s) = −min_t ‖x_t − b‖ − |d_T − d*|,

x_t the control-puck trajectory, d_T = ‖y_T − y_0‖ the final displacement of the target puck
y (:func:`hockey_reward`). Because the pucks touch at centre distance 2r, a hit has
min_t ‖x_t − b‖ ≈ 2r = 8 cm at best (as in the thesis). The trajectory depends on the
context (the target puck is in the scene), so ``trajectory_depends_on_context = True``.

Arm (MuJoCo, built with ``dm_control.mjcf``; :func:`build_arm_mjcf`)
--------------------------------------------------------------------
A KUKA-LWR-4-like serial chain: joint axes z, y, z, y, z, y, z; at q = 0 it points straight
up. Joint 2 sits 0.3105 m above the base (the LWR's d1), the elbow (joint 4) 0.4 m above
joint 2 (d3), the wrist (joint 6) 0.39 m above the elbow (d5), the flange 0.078 m beyond
(d7). Link masses [2.7, 2.7, 2.7, 2.7, 1.7, 1.6, 0.3] kg (close to identified LWR-4
values; they are approximate, the thesis gives none) on capsule geoms. Motor reflected
inertia is modelled as joint armature (:data:`ARMATURE`); joint ranges and torque limits are
the LWR-4's (±170°/±120°; [176, 176, 100, 100, 100, 38, 38] N m). A racket (0.45 m shaft,
0.25 kg, and a 20 cm × 1.6 cm × 8 cm blade, 0.15 kg) is rigidly attached to the flange along
its z axis; the blade's long side is the flange's x axis and its face normal the flange's y
axis. The site ``blade`` marks the blade centre. No geom collides in MuJoCo (the arm
never touches the table in MuJoCo; the pucks live in pymunk).

Lower-level policy: a 7-joint DMP (:mod:`skillkit.policies.dmp`, Eqs. 2.21–2.23 with the
moving-goal final velocity) whose shape weights are fitted to the shipped demonstration
(:func:`make_demonstration`); ω = [g (7), ġ (7), τ] (15 parameters, Sec. 3.4.2). The stroke
lasts ``duration / τ`` (0.5 s at τ = 1), then a follow-through extends the reference
with exponentially decaying velocity (time constant :data:`FOLLOW_THROUGH_TAU`, for
:data:`FOLLOW_THROUGH` seconds), after which the racket is lifted off the table. A PD
tracker with gravity/Coriolis compensation
(:func:`skillkit.policies.controllers.track_reference`, torque saturation at the LWR limits)
follows the reference at 250 Hz (MuJoCo steps at 500 Hz); the thesis used inverse-dynamics
control, so our tracking lag is larger and part of what is learned.
τ outside :data:`TAU_RANGE` is reported as a failed rollout (the stroke would be
unexecutably slow or fast), not clipped.

Pucks (pymunk 2-D, :class:`PuckTable`)
-------------------------------------
Top-down, so pymunk has no gravity; sliding friction is Coulomb friction applied in each
puck's velocity update (:func:`coulomb_friction`): the speed drops by μ g Δt per step until
the puck stops, so a puck launched at v₀ stops after v₀²/(2 μ g) (μ = 0.05 by default; plus
v₀ Δt / 2 from pymunk's semi-implicit stepping, see :class:`TablePhysics`).
Puck–puck collisions have restitution 0.9 and no tangential friction, racket–puck
collisions restitution 0.6 and friction 0.2 (set per contact in a pre-solve callback).
The racket blade is a kinematic pymunk box (its 20 cm × 1.6 cm footprint) whose pose on the
table is the ``blade`` site's (x, y, yaw) read from MuJoCo at every control step; it takes part
in collisions only while the blade's lowest corner is below the puck top (2.5 cm) and its
highest above the table, i.e. the blade is treated as a vertical plate. The racket is
kinematic, so the pucks do not push back on the arm and the arm can be simulated first.
After the racket phase the pucks slide until both are at rest or :data:`MAX_DURATION`.

Real-robot setting (``hockey-real``, C.2)
-----------------------------------------
b_x ∈ [1.5, 2] m, b_y ∈ [0.4, 0.8] m, d* ∈ [0, 0.6] m; the reward is computed from puck
positions observed at 30 Hz with Gaussian noise (σ = :data:`OBSERVATION_NOISE` = 1 cm,
Kinect-like; our choice) and smoothed with a zero-phase Butterworth low-pass filter (order
:data:`BUTTER_ORDER` = 2, cut-off :data:`BUTTER_CUTOFF` = 4 Hz, ``scipy.signal.filtfilt``;
:func:`butterworth_smooth`). The thesis gives neither noise level nor filter constants.

Trajectories
------------
``times``/``states``/``controls``: the arm at :data:`RECORD_DT` (states [q, q̇], 14;
controls the torques, 7) during the racket phase. Signals (time-major): ``"racket"``
(T_arm, 4) blade [x, y, z, yaw]; ``"puck_times"`` (T_p,); ``"control_puck"``, ``"target_puck"``
(T_p, 2); for ``hockey-real`` also ``"observation_times"`` (T_o,) and the noisy 30 Hz
``"control_puck_observed"``, ``"target_puck_observed"`` (T_o, 2). ``info``: ``hit``
(the pucks touched), ``displacement`` (true d_T), ``racket_touched``, ``hit_time``,
``tau``, ``n_saturated`` (saturated torque entries), ``pucks_at_rest``, ``blade_lowest``
(lowest blade corner height in the racket phase: negative values mean the blade went through
the table, which is not modelled in MuJoCo; reported so it can be checked).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
import pymunk
from dm_control import mjcf
from scipy import signal

from skillkit._validation import check_array, check_positive
from skillkit.policies.controllers import track_reference
from skillkit.policies.dmp import DMP, DMPParameters
from skillkit.tasks.base import SimulationFailure, Task
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

__all__ = [
    "Hockey",
    "Observation",
    "PuckTable",
    "TablePhysics",
    "arm_forward_kinematics",
    "arm_model",
    "blade_pose",
    "build_arm_mjcf",
    "butterworth_smooth",
    "coulomb_friction",
    "demonstration_path",
    "hockey_reward",
    "load_demonstration",
    "make_demonstration",
    "save_demonstration",
]

# ----------------------------------------------------------------------------- arm constants
N_JOINTS = 7
JOINT_AXES = ((0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1))
LINK_OFFSETS = (0.1575, 0.1530, 0.2000, 0.2000, 0.2000, 0.1900, 0.0000)
"""Position of joint i+1 along the z axis of link i (link 0 = base), m; joint 2 is at
0.3105 m, the elbow 0.4 m and the wrist 0.79 m further up at q = 0 (LWR-4 d1, d3, d5)."""
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
"""PD damping per joint, N m s / rad (about critical for the armature plus link inertia)."""
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

# ----------------------------------------------------------------------------- task constants
CONTROL_PUCK_START = np.array([0.45, -0.30])
"""Initial position of the control puck on the table, m."""
TARGET_CENTRE = np.array([2.0, 0.75])
"""Centre of the simulated target region; the demonstration shoots towards it."""
CONTEXT_LOW = np.array([1.5, 0.5, 0.0])
CONTEXT_HIGH = np.array([2.5, 1.0, 1.0])
REAL_CONTEXT_LOW = np.array([1.5, 0.4, 0.0])
REAL_CONTEXT_HIGH = np.array([2.0, 0.8, 0.6])
TAU_RANGE = (0.25, 4.0)
"""Admissible DMP time scaling τ (stroke durations 2 s … 0.125 s)."""
FOLLOW_THROUGH = 0.2
"""Duration of the follow-through after the DMP ends, s."""
FOLLOW_THROUGH_TAU = 0.05
"""Time constant of the follow-through's velocity decay, s."""
MAX_DURATION = 8.0
"""Longest episode, s (the pucks usually stop earlier)."""
RECORD_DT = 0.008
"""Sampling period of the recorded arm and puck signals, s (see :func:`hockey_reward`)."""
OBSERVATION_RATE = 30.0
"""Puck tracking rate of the real-robot setting (Kinect), Hz."""
OBSERVATION_NOISE = 0.01
"""Standard deviation of the observed puck positions in the real-robot setting, m."""
BUTTER_ORDER = 2
BUTTER_CUTOFF = 4.0
"""Butterworth low-pass order and cut-off frequency (Hz) of the real-robot smoothing."""

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
DEMO_FILE = "hockey.npz"


# ============================================================================= the arm
def build_arm_mjcf(timestep: float = TIMESTEP) -> mjcf.RootElement:
    """MJCF model of the KUKA-LWR-like 7-DoF arm with its hockey racket.

    Parameters
    ----------
    timestep : float
        Physics time step, s.

    Returns
    -------
    dm_control.mjcf.RootElement
        Bodies ``link1`` … ``link7`` with hinge joints ``j1`` … ``j7`` (axes
        :data:`JOINT_AXES`, ranges :data:`JOINT_LIMITS`, armature :data:`ARMATURE`), sites
        ``flange`` and ``blade``. Compile with ``mujoco.MjModel.from_xml_string(
        root.to_xml_string())`` (or use :func:`arm_model`).
    """
    timestep = check_positive(timestep, "timestep")
    root = mjcf.RootElement(model="lwr_hockey")
    root.option.timestep = timestep
    root.option.gravity = [0.0, 0.0, -9.81]
    root.option.integrator = "Euler"
    root.compiler.angle = "radian"
    root.default.geom.contype = 0
    root.default.geom.conaffinity = 0
    root.default.geom.rgba = [1.0, 0.55, 0.1, 1.0]
    root.worldbody.add("light", pos=[0, 0, 3], dir=[0, 0, -1])
    root.worldbody.add(
        "geom",
        name="table",
        type="plane",
        size=[3, 2, 0.1],
        pos=[1.2, 0.3, 0],
        rgba=[0.9, 0.9, 0.88, 1],
    )
    root.worldbody.add(
        "geom",
        name="base",
        type="cylinder",
        size=[0.08, LINK_OFFSETS[0] / 2],
        pos=[0, 0, LINK_OFFSETS[0] / 2],
        mass=5.0,
        rgba=[0.3, 0.3, 0.3, 1],
    )
    parent = root.worldbody
    for i in range(N_JOINTS):
        body = parent.add("body", name=f"link{i + 1}", pos=[0, 0, LINK_OFFSETS[i]])
        body.add(
            "joint",
            name=f"j{i + 1}",
            type="hinge",
            axis=list(JOINT_AXES[i]),
            range=[-JOINT_LIMITS[i], JOINT_LIMITS[i]],
            limited=True,
            armature=ARMATURE[i],
        )
        length = LINK_OFFSETS[i + 1] if i + 1 < N_JOINTS else FLANGE_OFFSET
        body.add(
            "geom",
            name=f"link{i + 1}_geom",
            type="capsule",
            size=[0.06 - 0.004 * i],
            fromto=[0, 0, 0, 0, 0, max(length, 0.04)],
            mass=LINK_MASSES[i],
        )
        parent = body
    parent.add("site", name="flange", pos=[0, 0, FLANGE_OFFSET], size=[0.01])
    parent.add(
        "geom",
        name="shaft",
        type="capsule",
        size=[SHAFT_RADIUS],
        mass=SHAFT_MASS,
        fromto=[0, 0, FLANGE_OFFSET, 0, 0, FLANGE_OFFSET + SHAFT_LENGTH],
        rgba=[0.2, 0.2, 0.2, 1],
    )
    parent.add(
        "geom",
        name="blade",
        type="box",
        size=list(BLADE_HALF),
        mass=BLADE_MASS,
        pos=[0, 0, BLADE_OFFSET],
        rgba=[0.1, 0.1, 0.1, 1],
    )
    parent.add("site", name="blade", pos=[0, 0, BLADE_OFFSET], size=[0.01])
    return root


@functools.lru_cache(maxsize=4)
def _compiled_arm_xml(timestep: float) -> str:
    return build_arm_mjcf(timestep).to_xml_string()


def arm_model(timestep: float = TIMESTEP) -> mujoco.MjModel:
    """The compiled arm model (:func:`build_arm_mjcf`), a fresh ``MjModel``."""
    return mujoco.MjModel.from_xml_string(_compiled_arm_xml(float(timestep)))


def _axis_rotation(axis: tuple[int, int, int], angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about a coordinate axis, shape (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == (0, 0, 1):
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    elif axis == (0, 1, 0):
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        raise ValueError(f"axis: expected the y or z axis, got {axis}")
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def arm_forward_kinematics(q) -> tuple[np.ndarray, np.ndarray]:
    """Pose of the blade centre for joint angles ``q`` (an independent numpy chain).

    The chain is p = Σ_i R_0 … R_{i−1} [0, 0, l_i] + R_0 … R_6 [0, 0, BLADE_OFFSET] with
    R_i the rotation of joint i+1 about its axis and l_i = :data:`LINK_OFFSETS`.

    Parameters
    ----------
    q : array_like, shape (..., 7)
        Joint angles, rad.

    Returns
    -------
    position : ndarray, shape (..., 3)
        Blade centre in the world (table) frame, m.
    rotation : ndarray, shape (..., 3, 3)
        Blade frame: columns are its long side, face normal and shaft direction.
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
    """Blade [x, y, z, yaw] and its lowest/highest corner heights from 3-D poses.

    Parameters
    ----------
    position : array_like, shape (..., 3)
        Blade centre.
    rotation : array_like, shape (..., 3, 3)
        Blade frame (columns: long side, face normal, shaft).

    Returns
    -------
    ndarray, shape (..., 6)
        [x, y, z, yaw, z_low, z_high]; yaw is the heading of the long side on the table.
    """
    position = np.asarray(position, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64)
    reach = np.abs(rotation[..., 2, :]) @ np.asarray(BLADE_HALF)
    yaw = np.arctan2(rotation[..., 1, 0], rotation[..., 0, 0])
    z = position[..., 2]
    return np.concatenate(
        [position, yaw[..., None], (z - reach)[..., None], (z + reach)[..., None]], axis=-1
    )


# ============================================================================= the pucks
@dataclass(frozen=True)
class TablePhysics:
    """Physical constants of the puck table (pymunk).

    Attributes
    ----------
    puck_radius, puck_mass, puck_height : float
        Puck geometry (m) and mass (kg), ice-hockey-puck-like.
    friction : float
        Coulomb sliding-friction coefficient μ between puck and table; deceleration μ g.
    restitution_pucks : float
        Coefficient of restitution of puck–puck collisions.
    restitution_racket, friction_racket : float
        Restitution and Coulomb friction of racket–puck contacts.
    gravity : float
        g, m/s², for the friction deceleration.
    dt : float
        Time step, s; the arm's PD control period too (the racket pose is read once per
        step), so a whole multiple of the MuJoCo time step :data:`TIMESTEP`.
    free_dt : float
        Time step once the racket is lifted and only the pucks move, s. Pymunk integrates
        semi-implicitly, so a puck launched at v₀ slides v₀²/(2 μ g) + O(v₀ Δt / 2) (4 mm
        at 1 m/s and 8 ms).
    """

    puck_radius: float = 0.04
    puck_mass: float = 0.17
    puck_height: float = 0.025
    friction: float = 0.05
    restitution_pucks: float = 0.9
    restitution_racket: float = 0.6
    friction_racket: float = 0.2
    gravity: float = 9.81
    dt: float = CONTROL_DT
    free_dt: float = 2 * CONTROL_DT

    def __post_init__(self) -> None:
        for name in ("puck_radius", "puck_mass", "puck_height", "gravity", "dt", "free_dt"):
            check_positive(getattr(self, name), name)
        for name in ("friction", "friction_racket"):
            check_positive(getattr(self, name), name, allow_zero=True)
        for name in ("restitution_pucks", "restitution_racket"):
            e = getattr(self, name)
            if not 0.0 <= e <= 1.0:
                raise ValueError(
                    f"{name}: expected a coefficient of restitution in [0, 1], got {e}"
                )

    @property
    def deceleration(self) -> float:
        """Sliding deceleration μ g, m/s²."""
        return self.friction * self.gravity

    def stopping_distance(self, speed: float) -> float:
        """Distance v²/(2 μ g) a puck sliding at ``speed`` travels before it stops (μ > 0)."""
        if self.friction <= 0:
            raise ValueError("friction: a frictionless puck never stops")
        return float(speed) ** 2 / (2.0 * self.deceleration)


def coulomb_friction(velocity, deceleration: float, dt: float) -> np.ndarray:
    """One step of Coulomb sliding friction: reduce the speed by ``deceleration · dt``.

    v ← v · max(0, 1 − a Δt / ‖v‖): the puck decelerates at a = μ g against its motion and
    stops exactly (instead of reversing) when the speed falls below a Δt.

    Parameters
    ----------
    velocity : array_like, shape (2,)
        Puck velocity, m/s.
    deceleration : float
        a = μ g ≥ 0, m/s².
    dt : float
        Time step, s.

    Returns
    -------
    ndarray, shape (2,)
    """
    v = np.asarray(velocity, dtype=np.float64)
    speed = math.hypot(v[0], v[1])
    if speed <= deceleration * dt:
        return np.zeros(2)
    return v * (1.0 - deceleration * dt / speed)


_PUCK, _RACKET = 1, 2


class PuckTable:
    """The pymunk table: a control puck, a target puck and an optional kinematic racket blade.

    Parameters
    ----------
    control_start, target_start : array_like, shape (2,)
        Initial puck positions, m.
    physics : TablePhysics
        Constants.
    racket : bool
        Add the kinematic blade (a box of :data:`BLADE_HALF` footprint), initially out of
        play (not colliding) until :meth:`move_racket` puts it down.

    Attributes
    ----------
    hit_time : float or None
        Time of the first puck–puck contact.
    racket_touched : bool
        Whether the racket touched a puck.
    time : float
        Simulated time, s.
    """

    def __init__(
        self,
        control_start,
        target_start,
        physics: TablePhysics = TablePhysics(),
        racket: bool = True,
    ) -> None:
        self.physics = physics
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.damping = 1.0
        space.iterations = 20
        space.collision_slop = 1e-4  # pymunk's default (0.1) assumes pixels, not metres
        self.space = space
        self.time = 0.0
        self.hit_time: float | None = None
        self.racket_touched = False
        self.control = self._add_puck(check_array(control_start, "control_start", shape=(2,)))
        self.target = self._add_puck(check_array(target_start, "target_start", shape=(2,)))
        space.on_collision(
            _PUCK,
            _PUCK,
            begin=self._on_puck_contact,
            pre_solve=self._set_contact(physics.restitution_pucks, 0.0),
        )
        space.on_collision(
            _RACKET,
            _PUCK,
            begin=self._on_racket_contact,
            pre_solve=self._set_contact(physics.restitution_racket, physics.friction_racket),
        )
        self.racket = None
        if racket:
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            body.position = (-10.0, -10.0)
            shape = pymunk.Poly.create_box(body, (2 * BLADE_HALF[0], 2 * BLADE_HALF[1]))
            shape.collision_type = _RACKET
            shape.filter = pymunk.ShapeFilter(categories=0, mask=0)
            space.add(body, shape)
            self.racket = body
            self._racket_shape = shape
            self._racket_active = False

    def _add_puck(self, position: np.ndarray) -> pymunk.Body:
        p = self.physics
        body = pymunk.Body(p.puck_mass, pymunk.moment_for_circle(p.puck_mass, 0, p.puck_radius))
        body.position = (float(position[0]), float(position[1]))
        decel = p.deceleration

        def friction(body, gravity, damping, dt):  # coulomb_friction, inlined for speed
            vx, vy = body.velocity
            if vx == 0.0 and vy == 0.0:
                return
            speed = math.hypot(vx, vy)
            scale = 0.0 if speed <= decel * dt else 1.0 - decel * dt / speed
            body.velocity = (vx * scale, vy * scale)

        body.velocity_func = friction
        shape = pymunk.Circle(body, p.puck_radius)
        shape.collision_type = _PUCK
        self.space.add(body, shape)
        return body

    @staticmethod
    def _set_contact(restitution: float, friction: float):
        def pre_solve(arbiter, space, data):
            arbiter.restitution = restitution
            arbiter.friction = friction

        return pre_solve

    def _on_puck_contact(self, arbiter, space, data) -> None:
        if self.hit_time is None:
            self.hit_time = self.time

    def _on_racket_contact(self, arbiter, space, data) -> None:
        self.racket_touched = True

    def move_racket(self, pose, next_pose, active: bool) -> None:
        """Place the blade at ``pose`` and give it the velocity that reaches ``next_pose`` in dt.

        Parameters
        ----------
        pose, next_pose : array_like, shape (3,)
            Blade [x, y, yaw] now and one step later.
        active : bool
            Whether the blade is down on the table (collides with the pucks).
        """
        if self.racket is None:
            raise ValueError("racket: this table was built without a racket")
        dt = self.physics.dt
        self.racket.position = (float(pose[0]), float(pose[1]))
        self.racket.angle = float(pose[2])
        self.racket.velocity = ((next_pose[0] - pose[0]) / dt, (next_pose[1] - pose[1]) / dt)
        dyaw = math.remainder(float(next_pose[2]) - float(pose[2]), 2 * math.pi)
        self.racket.angular_velocity = dyaw / dt
        if active != self._racket_active:
            self._racket_active = active
            self._racket_shape.filter = (
                pymunk.ShapeFilter() if active else pymunk.ShapeFilter(categories=0, mask=0)
            )

    def lift_racket(self) -> None:
        """Take the blade out of play for good."""
        if self.racket is not None:
            self.racket.velocity = (0.0, 0.0)
            self.racket.angular_velocity = 0.0
            if self._racket_active:
                self._racket_active = False
                self._racket_shape.filter = pymunk.ShapeFilter(categories=0, mask=0)

    def step(self, dt: float | None = None) -> None:
        """Advance the table by ``dt`` (default ``physics.dt``)."""
        dt = self.physics.dt if dt is None else dt
        self.space.step(dt)
        self.time += dt

    @property
    def positions(self) -> np.ndarray:
        """Control and target puck positions, shape (2, 2)."""
        c, t = self.control.position, self.target.position
        return np.array([[c.x, c.y], [t.x, t.y]])

    @property
    def velocities(self) -> np.ndarray:
        """Control and target puck velocities, shape (2, 2)."""
        c, t = self.control.velocity, self.target.velocity
        return np.array([[c.x, c.y], [t.x, t.y]])

    @property
    def at_rest(self) -> bool:
        """Both pucks stopped."""
        return all(b.velocity.x == 0.0 and b.velocity.y == 0.0 for b in (self.control, self.target))


# ============================================================================= reward, smoothing
def hockey_reward(control_puck, target_puck, context) -> float:
    """R(τ, s) = −min_t ‖x_t − b‖ − |d_T − d*| (Appendix C.2).

    Parameters
    ----------
    control_puck : array_like, shape (T, 2)
        Control-puck trajectory x_{1:T}, m. Sampled at :data:`RECORD_DT` (1 cm of travel
        at 1 m/s), the minimum over samples overestimates the continuous one by less than
        (v Δt / 2)² / (2 min‖x − b‖) ≈ 0.4 mm near a hit.
    target_puck : array_like, shape (T', 2)
        Target-puck trajectory; d_T = ‖y_{T'} − y_1‖.
    context : array_like, shape (3,)
        s = [b_x, b_y, d*].

    Returns
    -------
    float
    """
    x = check_array(control_puck, "control_puck", shape=(None, 2))
    y = check_array(target_puck, "target_puck", shape=(None, 2))
    s = check_array(context, "context", shape=(3,))
    if x.shape[0] == 0 or y.shape[0] == 0:
        raise ValueError("control_puck, target_puck: expected at least one sample")
    miss = float(np.min(np.linalg.norm(x - s[:2], axis=1)))
    displacement = float(np.linalg.norm(y[-1] - y[0]))
    return -miss - abs(displacement - float(s[2]))


def butterworth_smooth(
    values, rate: float, cutoff: float = BUTTER_CUTOFF, order: int = BUTTER_ORDER
) -> np.ndarray:
    """Zero-phase Butterworth low-pass filtering of a sampled signal (``scipy.signal.filtfilt``).

    Parameters
    ----------
    values : array_like, shape (T, ...)
        Time-major samples.
    rate : float
        Sampling rate, Hz.
    cutoff : float
        Cut-off frequency, Hz, below the Nyquist frequency rate / 2.
    order : int
        Filter order (the forward–backward pass doubles the effective order).

    Returns
    -------
    ndarray, shape (T, ...)
    """
    x = check_array(values, "values", ndim=(1, 2))
    rate = check_positive(rate, "rate")
    cutoff = check_positive(cutoff, "cutoff")
    if cutoff >= rate / 2:
        raise ValueError(
            f"cutoff: expected a frequency below the Nyquist frequency {rate / 2:g} Hz, "
            f"got {cutoff:g}"
        )
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"order: expected an integer >= 1, got {order!r}")
    b, a = signal.butter(int(order), cutoff, btype="low", fs=rate)
    padlen = 3 * max(len(a), len(b))
    if x.shape[0] <= padlen:
        raise ValueError(f"values: filtfilt needs more than {padlen} samples, got {x.shape[0]}")
    return signal.filtfilt(b, a, x, axis=0, padtype="odd", padlen=padlen)


# ============================================================================= demonstration
def _ik_blade(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    site: int,
    position: np.ndarray,
    rotation: np.ndarray,
    q: np.ndarray,
    posture: np.ndarray,
) -> np.ndarray:
    """Damped least-squares IK for the blade pose with a null-space pull towards ``posture``."""
    jacp, jacr = np.zeros((3, N_JOINTS)), np.zeros((3, N_JOINTS))
    q = q.copy()
    for _ in range(300):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        r_err = rotation @ data.site_xmat[site].reshape(3, 3).T
        err = np.concatenate(
            [
                position - data.site_xpos[site],
                0.5
                * np.array(
                    [
                        r_err[2, 1] - r_err[1, 2],
                        r_err[0, 2] - r_err[2, 0],
                        r_err[1, 0] - r_err[0, 1],
                    ]
                ),
            ]
        )
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


def _quintic(duration: float, end_rate: float, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """s(t) on [0, T] with s, ṡ, s̈ = 0, 0, 0 at 0 and 1, end_rate, 0 at T (and derivatives)."""
    T = duration
    # s = c3 u³ + c4 u⁴ + c5 u⁵, u = t/T; conditions at u = 1: s = 1, s' = k, s'' = 0.
    k = end_rate * T
    c = np.linalg.solve(
        np.array([[1.0, 1.0, 1.0], [3.0, 4.0, 5.0], [6.0, 12.0, 20.0]]), np.array([1.0, k, 0.0])
    )
    u = t / T
    s = c[0] * u**3 + c[1] * u**4 + c[2] * u**5
    sd = (3 * c[0] * u**2 + 4 * c[1] * u**3 + 5 * c[2] * u**4) / T
    sdd = (6 * c[0] * u + 12 * c[1] * u**2 + 20 * c[2] * u**3) / T**2
    return s, sd, sdd


def make_demonstration(dt: float = TIMESTEP) -> dict[str, np.ndarray]:
    """The demonstrated hitting stroke (deterministic; the shipped file is its output).

    The blade slides, upright and 4.5 cm above the table, along a straight line of
    :data:`DEMO_BACKSWING` towards :data:`TARGET_CENTRE`, face normal along the line, and
    reaches the control puck's centre line with speed :data:`DEMO_HIT_SPEED` at the end of
    :data:`DEMO_DURATION` (quintic timing: at rest at the start, zero path acceleration at
    the end). Joint angles come from damped least-squares inverse kinematics of the MuJoCo
    model, warm-started along the path; velocities and accelerations from second-order
    finite differences.

    Parameters
    ----------
    dt : float
        Sampling period, s.

    Returns
    -------
    dict
        ``times`` (N,), ``q``, ``qd``, ``qdd`` (N, 7), ``blade`` (N, 3) desired blade
        centre, ``control_puck_start`` (2,), ``direction`` (2,).
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
    s, _, _ = _quintic(DEMO_DURATION, DEMO_HIT_SPEED / DEMO_BACKSWING, times)
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


def demonstration_path() -> Path:
    """Path of the shipped demonstration ``skillkit/data/demonstrations/hockey.npz``."""
    return Path(str(resources.files("skillkit") / "data" / "demonstrations" / DEMO_FILE))


def load_demonstration(path: str | Path | None = None) -> dict[str, np.ndarray]:
    """Read the demonstration written by ``np.savez(path, **make_demonstration())``."""
    path = demonstration_path() if path is None else Path(path)
    if not path.exists():
        raise ValueError(
            f"path: no hockey demonstration at {path}; regenerate it with "
            "np.savez(path, **make_demonstration())"
        )
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def save_demonstration(path: str | Path | None = None) -> Path:
    """Regenerate the demonstration and write it (default: the shipped package file)."""
    path = demonstration_path() if path is None else Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **make_demonstration())
    return path


# ============================================================================= the task
@dataclass(frozen=True)
class Observation:
    """Puck tracking of the real-robot setting: rate (Hz), noise σ (m), Butterworth filter."""

    rate: float = OBSERVATION_RATE
    noise: float = OBSERVATION_NOISE
    cutoff: float = BUTTER_CUTOFF
    order: int = BUTTER_ORDER

    def __post_init__(self) -> None:
        check_positive(self.rate, "rate")
        check_positive(self.noise, "noise", allow_zero=True)
        check_positive(self.cutoff, "cutoff")


class Hockey(Task):
    """Robot hockey of Appendix C.2 (see the module docstring for the model).

    Parameters
    ----------
    context_low, context_high : array_like, shape (3,)
        Ranges of s = [b_x, b_y, d*] (default: the simulated task of C.2).
    physics : TablePhysics
        Puck-table constants.
    observation : Observation, optional
        Noisy 30 Hz puck tracking with Butterworth smoothing (the real-robot setting); the
        reward then uses the smoothed observations instead of the true puck positions.
    exploration_std : array_like, shape (15,), optional
        Per-parameter exploration standard deviations of the initial policy before the
        blade-height projection of :meth:`exploration_covariance` (default
        :meth:`default_exploration`).
    name : str
        Registry name.
    """

    context_dim = 3
    parameter_dim = 2 * N_JOINTS + 1
    context_names = ("b_x", "b_y", "d_star")
    trajectory_depends_on_context = True
    worst_reward = -20.0
    """Below any working rollout: the miss term is at most ‖x_0 − b‖ < 3 m and a target
    puck launched by this arm travels a few metres at most."""

    def __init__(
        self,
        context_low=CONTEXT_LOW,
        context_high=CONTEXT_HIGH,
        physics: TablePhysics = TablePhysics(),
        observation: Observation | None = None,
        exploration_std=None,
        name: str = "hockey",
    ) -> None:
        self.name = name
        self.context_low = check_array(context_low, "context_low", shape=(3,)).copy()
        self.context_high = check_array(context_high, "context_high", shape=(3,)).copy()
        if np.any(self.context_low > self.context_high):
            raise ValueError("context_high: expected context_low <= context_high elementwise")
        if not isinstance(physics, TablePhysics):
            raise ValueError(f"physics: expected a TablePhysics, got {type(physics).__name__}")
        if observation is not None and not isinstance(observation, Observation):
            raise ValueError(
                f"observation: expected an Observation or None, got {type(observation).__name__}"
            )
        self.physics = physics
        self.observation = observation
        self.model = arm_model(TIMESTEP)
        self.data = mujoco.MjData(self.model)
        self._site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "blade")
        demo = load_demonstration()
        dmp = DMP(N_JOINTS, n_basis=10, dt=TIMESTEP)
        dmp.fit(demo["times"], demo["q"], demo["qd"], demo["qdd"])
        self.q0 = demo["q"][0].copy()
        self.dmp_parameters = DMPParameters(dmp, learn=("goal", "goal_velocity", "tau"))
        self.demo_omega = self.dmp_parameters.to_vector()
        std = self.default_exploration() if exploration_std is None else exploration_std
        self.exploration_std = check_array(std, "exploration_std", shape=(self.parameter_dim,))
        if np.any(self.exploration_std <= 0):
            raise ValueError("exploration_std: expected positive standard deviations")
        self._record_every = max(1, int(round(RECORD_DT / physics.dt)))

    @staticmethod
    def default_exploration() -> np.ndarray:
        """Initial exploration standard deviations for ω = [g, ġ, τ] (before the projection
        of :meth:`exploration_covariance`).

        g: [0.06, 0.04, 0.06, 0.05, 0.06, 0.05, 0.2] rad (joint 7 rolls the blade about the
        vertical shaft and so aims the shot without moving the blade); ġ: 0.25 rad/s; τ: 0.1.
        Around the demonstration this spreads the control puck's launch direction by about
        10° and its speed by about 0.35 m/s (1.5 m/s nominal), which covers the directions
        (≈ 28°–57°) and speeds (≈ 1.1–1.9 m/s) the target region needs.
        """
        return np.concatenate(
            [[0.06, 0.04, 0.06, 0.05, 0.06, 0.05, 0.2], np.full(N_JOINTS, 0.25), [0.1]]
        )

    def exploration_covariance(self) -> np.ndarray:
        """Covariance Σ₀ of the initial policy, shape (15, 15).

        Σ₀ = blockdiag(P D_g P + (0.1 σ̄_g)² I, P D_ġ P + (0.1 σ̄_ġ)² I, σ_τ²) with D the squared
        :attr:`exploration_std`, σ̄ their means and P = I − n nᵀ, n the unit row of the blade
        height's Jacobian ∂z/∂q at the demonstrated goal. The blade touches the pucks only
        within 2 cm of its demonstrated height, so exploration that lifts the blade is
        wasted; P removes it from the goal and from the final velocity (which would make
        the blade dive or lift in the follow-through).
        """
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.demo_omega[:N_JOINTS]
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        jacp = np.zeros((3, N_JOINTS))
        mujoco.mj_jacSite(self.model, data, jacp, None, self._site)
        n = jacp[2] / np.linalg.norm(jacp[2])
        proj = np.eye(N_JOINTS) - np.outer(n, n)
        cov = np.zeros((self.parameter_dim, self.parameter_dim))
        for block in (slice(0, N_JOINTS), slice(N_JOINTS, 2 * N_JOINTS)):
            std = self.exploration_std[block]
            cov[block, block] = proj @ np.diag(std**2) @ proj + (0.1 * std.mean()) ** 2 * np.eye(
                N_JOINTS
            )
        cov[-1, -1] = self.exploration_std[-1] ** 2
        return cov

    def initial_policy(self):
        """π(ω|s) = N(ω_demo, Σ₀) with zero context gain (imitation, Sec. 3.4.2); Σ₀ from
        :meth:`exploration_covariance`."""
        from skillkit.policies.gaussian import LinearGaussianPolicy

        return LinearGaussianPolicy(
            mean=self.demo_omega.copy(),
            cov=self.exploration_covariance(),
            context_dim=self.context_dim,
        )

    # ------------------------------------------------------------------ simulation
    def reference(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint reference of ω: the DMP stroke followed by the follow-through.

        Parameters
        ----------
        omega : ndarray, shape (15,)
            [g, ġ, τ].

        Returns
        -------
        times, q_ref, qd_ref : ndarray, shapes (T,), (T, 7), (T, 7)
            At the control period ``physics.dt``.

        Raises
        ------
        SimulationFailure
            If τ is outside :data:`TAU_RANGE`.
        """
        tau = float(omega[-1])
        if not TAU_RANGE[0] <= tau <= TAU_RANGE[1]:
            raise SimulationFailure(
                f"tau={tau:g} is outside the executable range [{TAU_RANGE[0]:g}, {TAU_RANGE[1]:g}]"
            )
        dmp = self.dmp_parameters.from_vector(omega)
        dt = self.physics.dt
        n_dmp = int(math.ceil(dmp.duration / tau / dt - 1e-9))
        q, qd, _ = dmp.rollout(dt * np.arange(n_dmp + 1), self.q0)
        s = dt * np.arange(1, int(round(FOLLOW_THROUGH / dt)) + 1)
        decay = np.exp(-s / FOLLOW_THROUGH_TAU)
        q_ft = q[-1] + qd[-1] * (FOLLOW_THROUGH_TAU * (1.0 - decay))[:, None]
        qd_ft = qd[-1] * decay[:, None]
        q_ref = np.vstack([q, q_ft])
        qd_ref = np.vstack([qd, qd_ft])
        return dt * np.arange(q_ref.shape[0]), q_ref, qd_ref

    def simulate_arm(self, omega: np.ndarray) -> dict[str, np.ndarray]:
        """Track the reference of ω in MuJoCo; the blade pose at every control step.

        Returns
        -------
        dict
            ``times`` (T,), ``q``, ``qd``, ``u`` (T, 7), ``blade`` (T, 6) from
            :func:`blade_pose`, ``n_saturated``.
        """
        times, q_ref, qd_ref = self.reference(omega)
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = self.q0
        mujoco.mj_forward(model, data)
        site_pos = np.empty((times.shape[0], 3))
        site_mat = np.empty((times.shape[0], 9))
        site = self._site

        def record(t: int, d: mujoco.MjData) -> None:
            site_pos[t] = d.site_xpos[site]
            site_mat[t] = d.site_xmat[site]

        out = track_reference(
            model,
            data,
            q_ref,
            qd_ref,
            self.physics.dt,
            KP,
            KD,
            gravity_compensation=True,
            torque_limit=TORQUE_LIMITS,
            on_step=record,
        )
        blade = blade_pose(site_pos, site_mat.reshape(-1, 3, 3))
        out["times"] = times
        out["blade"] = blade
        return out

    def _simulate(
        self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator
    ) -> Trajectory:
        arm = self.simulate_arm(omega)
        phys = self.physics
        table = PuckTable(CONTROL_PUCK_START, context[:2], phys)
        blade = arm["blade"]
        down = (blade[:, 4] < phys.puck_height) & (blade[:, 5] > 0.0)
        every = self._record_every
        puck_times, pucks = [0.0], [table.positions]
        n_arm = blade.shape[0]
        for k in range(n_arm - 1):  # racket phase: one table step per control step
            table.move_racket(blade[k, [0, 1, 3]], blade[k + 1, [0, 1, 3]], bool(down[k]))
            table.step()
            if (k + 1) % every == 0:
                puck_times.append(table.time)
                pucks.append(table.positions)
        table.lift_racket()
        while table.time < MAX_DURATION - 1e-9 and not table.at_rest:  # pucks only
            table.step(phys.free_dt)
            puck_times.append(table.time)
            pucks.append(table.positions)
        if puck_times[-1] < table.time:
            puck_times.append(table.time)
            pucks.append(table.positions)
        puck_times = np.array(puck_times)
        pucks = np.array(pucks)
        if not np.all(np.isfinite(pucks)):
            raise SimulationFailure("non-finite puck positions in pymunk")
        arm_rows = slice(0, n_arm, every)
        signals = {
            "racket": blade[arm_rows, :4],
            "puck_times": puck_times,
            "control_puck": pucks[:, 0],
            "target_puck": pucks[:, 1],
        }
        if self.observation is not None:
            signals.update(self._observe(puck_times, pucks, rng))
        displacement = float(np.linalg.norm(pucks[-1, 1] - pucks[0, 1]))
        info = {
            "hit": table.hit_time is not None,
            "hit_time": table.hit_time,
            "racket_touched": bool(table.racket_touched),
            "displacement": displacement,
            "tau": float(omega[-1]),
            "n_saturated": int(arm["n_saturated"]),
            "blade_lowest": float(blade[:, 4].min()),
            "pucks_at_rest": bool(table.at_rest),
        }
        return Trajectory(
            times=arm["times"][arm_rows],
            states=np.hstack([arm["q"], arm["qd"]])[arm_rows],
            controls=arm["u"][arm_rows],
            signals=signals,
            info=info,
        )

    def _observe(
        self, puck_times: np.ndarray, pucks: np.ndarray, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """Noisy samples of both pucks at the observation rate (linear interpolation)."""
        obs = self.observation
        t_obs = np.arange(0.0, puck_times[-1] + 1e-12, 1.0 / obs.rate)
        out = {"observation_times": t_obs}
        for j, key in enumerate(("control_puck_observed", "target_puck_observed")):
            clean = np.column_stack([np.interp(t_obs, puck_times, pucks[:, j, i]) for i in (0, 1)])
            out[key] = clean + obs.noise * rng.standard_normal(clean.shape)
        return out

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        sig = trajectory.signals
        if self.observation is None:
            return hockey_reward(sig["control_puck"], sig["target_puck"], context)
        if "control_puck_observed" not in sig:
            raise ValueError("trajectory: the real-robot reward needs the observed puck signals")
        obs = self.observation
        smooth = functools.partial(
            butterworth_smooth, rate=obs.rate, cutoff=obs.cutoff, order=obs.order
        )
        return hockey_reward(
            smooth(sig["control_puck_observed"]), smooth(sig["target_puck_observed"]), context
        )


@register("hockey", "contextual")
def hockey(**kwargs) -> Hockey:
    """Simulated hockey of Appendix C.2: b_x ∈ [1.5, 2.5], b_y ∈ [0.5, 1], d* ∈ [0, 1] m."""
    return Hockey(**kwargs)


@register("hockey-real", "contextual")
def hockey_real(**kwargs) -> Hockey:
    """Real-robot setting of C.2: b_x ∈ [1.5, 2], b_y ∈ [0.4, 0.8], d* ∈ [0, 0.6] m, pucks
    observed at 30 Hz with 1 cm noise and Butterworth-smoothed before the reward."""
    kwargs.setdefault("context_low", REAL_CONTEXT_LOW)
    kwargs.setdefault("context_high", REAL_CONTEXT_HIGH)
    kwargs.setdefault("observation", Observation())
    kwargs.setdefault("name", "hockey-real")
    return Hockey(**kwargs)
