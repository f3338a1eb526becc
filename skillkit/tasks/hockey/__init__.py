"""Robot hockey (Appendix C.2, Sec. 3.4.2): a 7-DoF arm shoots a control puck at a target puck.

The robot base stands at the origin of the table plane z = 0 (+x forward, +y left). The control
puck starts at :data:`CONTROL_PUCK_START`, the target puck at b = [b_x, b_y]; the robot must
move the target puck by d* (C.2)::

    s = [b_x, b_y, d*],   b_x ∈ [1.5, 2.5] m,  b_y ∈ [0.5, 1] m,  d* ∈ [0, 1] m,
    R(τ, s) = −min_t ‖x_t − b‖ − |d_T − d*|,

x_t the control-puck path and d_T = ‖y_T − y_0‖ the target puck's displacement; pucks touch
at centre distance 2r, so a hit has min_t ‖x_t − b‖ ≈ 8 cm at best.

* **Arm** (MuJoCo, :func:`~.arm.build_arm_mjcf`): a KUKA-LWR-4-like chain (axes z, y, z, y, z, y,
  z) with a racket whose blade box slides on the table plane; tracked by PD control with
  gravity compensation at 250 Hz (:func:`~skillkit.tasks.controllers.track_reference`).
* **Policy**: a 7-joint DMP (Eqs. 2.21–2.23) fitted to the shipped demonstration
  (:func:`make_demonstration`), ω = [g (7), ġ (7), τ]; the stroke lasts 0.5 s / τ, then a
  follow-through with decaying velocity. τ outside :data:`~.task.TAU_RANGE` is a failed rollout.
* **Pucks** (pymunk, :class:`PuckTable`): Coulomb sliding friction μ = 0.05
  (:func:`coulomb_friction`), puck–puck restitution 0.9, racket–puck 0.6; the blade is a
  kinematic box that collides only while it is below the puck top.
* **Real-robot setting** (``hockey-real``): b_x ∈ [1.5, 2], b_y ∈ [0.4, 0.8], d* ∈ [0, 0.6]
  m; the reward reads pucks observed at 30 Hz with 1 cm noise, smoothed by a zero-phase
  Butterworth filter (:func:`butterworth_smooth`; noise and filter are our choice).

Trajectories hold the arm (``states`` [q, q̇], ``controls`` torques) at :data:`~.task.RECORD_DT`
and the signals ``racket`` (T, 4) [x, y, z, yaw], ``puck_times``, ``control_puck``,
``target_puck`` (T_p, 2) and, in the real setting, ``observation_times`` and the
``*_observed`` tracks. The submodules :mod:`.arm`, :mod:`.table`, :mod:`.reward`,
:mod:`.demonstration` and :mod:`.task` hold the constants; the main names are re-exported here.
"""

from skillkit.tasks.hockey.arm import (
    ARMATURE,
    BLADE_HALF,
    BLADE_MASS,
    BLADE_OFFSET,
    CONTROL_DT,
    JOINT_LIMITS,
    LINK_MASSES,
    LINK_OFFSETS,
    N_JOINTS,
    SHAFT_MASS,
    TIMESTEP,
    arm_forward_kinematics,
    arm_model,
    blade_pose,
)
from skillkit.tasks.hockey.demonstration import load_demonstration, make_demonstration
from skillkit.tasks.hockey.reward import (
    OBSERVATION_NOISE,
    Observation,
    butterworth_smooth,
    hockey_reward,
    hockey_reward_batch,
)
from skillkit.tasks.hockey.table import (
    CONTROL_PUCK_START,
    PuckTable,
    TablePhysics,
    coulomb_friction,
)
from skillkit.tasks.hockey.task import Hockey

__all__ = [
    "ARMATURE",
    "BLADE_HALF",
    "BLADE_MASS",
    "BLADE_OFFSET",
    "CONTROL_DT",
    "CONTROL_PUCK_START",
    "Hockey",
    "JOINT_LIMITS",
    "LINK_MASSES",
    "LINK_OFFSETS",
    "N_JOINTS",
    "OBSERVATION_NOISE",
    "Observation",
    "PuckTable",
    "SHAFT_MASS",
    "TIMESTEP",
    "TablePhysics",
    "arm_forward_kinematics",
    "arm_model",
    "blade_pose",
    "butterworth_smooth",
    "coulomb_friction",
    "hockey_reward",
    "hockey_reward_batch",
    "load_demonstration",
    "make_demonstration",
]
