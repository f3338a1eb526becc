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
axis. The site ``blade`` marks the blade centre. The blade box has real contact with the
table plane z = 0 in MuJoCo (friction :data:`TABLE_FRICTION` = 0.1, a stiff ``solref``
:data:`CONTACT_SOLREF`), so a stroke aimed below the surface slides the blade along it
instead of passing through; no other geom collides (the pucks live in pymunk).

Lower-level policy: a 7-joint DMP (:mod:`skillkit.policies.dmp`, Eqs. 2.21–2.23 with the
moving-goal final velocity) whose shape weights are fitted to the shipped demonstration
(:func:`make_demonstration`); ω = [g (7), ġ (7), τ] (15 parameters, Sec. 3.4.2). The stroke
lasts ``duration / τ`` (0.5 s at τ = 1), then a follow-through extends the reference
with exponentially decaying velocity (time constant :data:`FOLLOW_THROUGH_TAU`, for
:data:`FOLLOW_THROUGH` seconds), after which the racket is lifted off the table. A PD
tracker with gravity/Coriolis compensation
(:func:`skillkit.tasks.controllers.track_reference`, torque saturation at the LWR limits)
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
(lowest blade corner height in the racket phase; about −1 mm, the contact's soft
penetration).

Modules
-------
:mod:`~skillkit.tasks.hockey.arm` (the arm model and kinematics),
:mod:`~skillkit.tasks.hockey.table` (pucks in pymunk), :mod:`~skillkit.tasks.hockey.reward`
(reward, observation and smoothing), :mod:`~skillkit.tasks.hockey.demonstration` (the
demonstrated stroke), :mod:`~skillkit.tasks.hockey.task` (the :class:`Hockey` task). Every
public name is importable from ``skillkit.tasks.hockey``.
"""

from skillkit.tasks.hockey.arm import (
    ARMATURE,
    BLADE_HALF,
    BLADE_MASS,
    BLADE_OFFSET,
    CONTACT_SOLREF,
    CONTROL_DT,
    FLANGE_OFFSET,
    JOINT_AXES,
    JOINT_LIMITS,
    KD,
    KP,
    LINK_MASSES,
    LINK_OFFSETS,
    N_JOINTS,
    SHAFT_LENGTH,
    SHAFT_MASS,
    SHAFT_RADIUS,
    TABLE_FRICTION,
    TIMESTEP,
    TORQUE_LIMITS,
    arm_forward_kinematics,
    arm_model,
    blade_pose,
    build_arm_mjcf,
)
from skillkit.tasks.hockey.demonstration import (
    DEMO_BACKSWING,
    DEMO_BLADE_HEIGHT,
    DEMO_DURATION,
    DEMO_FILE,
    DEMO_HIT_SPEED,
    DEMO_POSTURE,
    demonstration_path,
    load_demonstration,
    make_demonstration,
    save_demonstration,
)
from skillkit.tasks.hockey.reward import (
    BUTTER_CUTOFF,
    BUTTER_ORDER,
    OBSERVATION_NOISE,
    OBSERVATION_RATE,
    Observation,
    butterworth_smooth,
    hockey_reward,
    hockey_reward_batch,
)
from skillkit.tasks.hockey.table import (
    CONTROL_PUCK_START,
    TARGET_CENTRE,
    PuckTable,
    TablePhysics,
    coulomb_friction,
)
from skillkit.tasks.hockey.task import (
    CONTEXT_HIGH,
    CONTEXT_LOW,
    FOLLOW_THROUGH,
    FOLLOW_THROUGH_TAU,
    MAX_DURATION,
    REAL_CONTEXT_HIGH,
    REAL_CONTEXT_LOW,
    RECORD_DT,
    TAU_RANGE,
    Hockey,
    hockey,
    hockey_real,
)

__all__ = [
    "arm_forward_kinematics",
    "arm_model",
    "ARMATURE",
    "BLADE_HALF",
    "BLADE_MASS",
    "BLADE_OFFSET",
    "blade_pose",
    "build_arm_mjcf",
    "BUTTER_CUTOFF",
    "BUTTER_ORDER",
    "butterworth_smooth",
    "CONTACT_SOLREF",
    "CONTEXT_HIGH",
    "CONTEXT_LOW",
    "CONTROL_DT",
    "CONTROL_PUCK_START",
    "coulomb_friction",
    "DEMO_BACKSWING",
    "DEMO_BLADE_HEIGHT",
    "DEMO_DURATION",
    "DEMO_FILE",
    "DEMO_HIT_SPEED",
    "DEMO_POSTURE",
    "demonstration_path",
    "FLANGE_OFFSET",
    "FOLLOW_THROUGH",
    "FOLLOW_THROUGH_TAU",
    "Hockey",
    "hockey",
    "hockey_real",
    "hockey_reward",
    "hockey_reward_batch",
    "JOINT_AXES",
    "JOINT_LIMITS",
    "KD",
    "KP",
    "LINK_MASSES",
    "LINK_OFFSETS",
    "load_demonstration",
    "make_demonstration",
    "MAX_DURATION",
    "N_JOINTS",
    "Observation",
    "OBSERVATION_NOISE",
    "OBSERVATION_RATE",
    "PuckTable",
    "REAL_CONTEXT_HIGH",
    "REAL_CONTEXT_LOW",
    "RECORD_DT",
    "save_demonstration",
    "SHAFT_LENGTH",
    "SHAFT_MASS",
    "SHAFT_RADIUS",
    "TABLE_FRICTION",
    "TablePhysics",
    "TARGET_CENTRE",
    "TAU_RANGE",
    "TIMESTEP",
    "TORQUE_LIMITS",
]
