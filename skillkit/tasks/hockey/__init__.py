"""Robot hockey (Appendix C.2, Sec. 3.4.2): a 7-DoF arm shoots a control puck at a target puck.

The control puck starts at :data:`CONTROL_PUCK_START`, the target puck at b = [b_x, b_y]; the
robot must move the target puck by d* (C.2)::

    s = [b_x, b_y, d*],   b_x ∈ [1.5, 2.5] m,  b_y ∈ [0.5, 1] m,  d* ∈ [0, 1] m,
    R(τ, s) = −min_t ‖x_t − b‖ − |d_T − d*|,

x_t the control-puck path, d_T the target puck's displacement. A KUKA-LWR-4-like arm with a
racket (MuJoCo) PD-tracks a 7-joint DMP fitted to the demonstration at 250 Hz, ω = [g (7),
ġ (7), τ]; the pucks slide with Coulomb friction in pymunk (:class:`PuckTable`). Signals:
``racket`` (T, 4), ``puck_times``, ``control_puck``, ``target_puck`` (T_p, 2) and, in the
real-robot setting (``hockey-real``), ``observation_times`` and the ``*_observed`` tracks.
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
    hockey_reward_batch,
)
from skillkit.tasks.hockey.table import CONTROL_PUCK_START, PuckTable, TablePhysics
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
    "hockey_reward_batch",
    "load_demonstration",
    "make_demonstration",
]
