"""Robot table tennis (Sec. 3.4.3, Appendix C.3): an 8-DoF arm returns balls to a target.

The scene (SI units, +z up, table centred at the origin, the robot on the −x side)
--------------------------------------------------------------------------------
* **Table** of regulation size, 2.74 × 1.525 m, surface at 0.76 m; the **net** is the plane
  x = 0, 0.1525 m high, overhanging the side lines by 0.1525 m.
* **Ball** (40 mm, 2.7 g) launched at t = 0 from the fixed serve position
  :data:`SERVE_POSITION` behind the opponent's end with the context velocity v = [v_x, v_y,
  v_z]. The ranges :data:`VELOCITY_LOW`, :data:`VELOCITY_HIGH` are chosen so that the ball
  clears the net and bounces exactly once, inside the landing zone (:data:`LANDING_ZONE`),
  before it reaches the robot.
* **Robot**: a light BioRob-like arm on a platform moved by two prismatic axes in the
  horizontal plane, plus six revolute joints (shoulder yaw and pitch, upper-arm roll, elbow,
  forearm roll, wrist), 8 DoF in all, holding a racket; built with ``dm_control.mjcf``
  (:func:`arm_mjcf`) and simulated in MuJoCo. A DMP (Eqs 2.21–2.23) generates the joint
  reference, tracked by PD control with gravity/Coriolis compensation
  (:func:`skillkit.tasks.controllers.track_reference`).
* **Return target** b = [b_x, b_y] uniform on the whole opponent's half (C.3: "varied
  uniformly on the opponent's side of the table"; :data:`RETURN_LOW`, :data:`RETURN_HIGH`).
  The registered variant ``table-tennis-near`` keeps targets in the near zone x ∈ [0.2, 0.6],
  y ∈ [−0.4, 0.4] m (:data:`RETURN_NEAR_LOW`, :data:`RETURN_NEAR_HIGH`), which is easier.
  The context is s = [v_x, v_y, v_z, b_x, b_y].

The ball
--------
The ball is integrated by :func:`simulate_ball`, not by MuJoCo contacts, so drag, impact
laws and event times are exact. Free flight follows

    p̈ = g − k ‖ṗ‖ ṗ,        k = ρ C_d A / (2 m) = 0.1396 m⁻¹

(ρ = 1.2 kg/m³, C_d = 0.5, A = π r², m = 2.7 g; :class:`BallPhysics`), integrated with the
explicit midpoint rule at 2 ms (exact for the drag-free parabola, O(h²) with drag).
Events are located inside a step and handled exactly:

* table bounce: v_z ← −e_t v_z with e_t = 0.9 (ITTF: a drop from 30.5 cm rebounds
  23–25 cm, e ∈ [0.87, 0.91]); the horizontal velocity is kept (no spin, no friction);
* racket impact: the racket is a disc of radius 8 cm with unit normal n, moving rigidly;
  with v_rel = v_b − v_p (v_p the racket's velocity at the contact point),
  v_b ← v_b − (1 + e_r)(v_rel · n) n, e_r = 0.8 (frictionless, no spin; the racket is so
  much heavier than the ball that its motion is unaffected: one-way coupling). Rim/edge
  contacts are ignored, and the ball touches no other part of the robot;
* net: the ball centre crossing x = 0 less than one radius above the net top, within the
  net's width, ends the rally there.

The arm is simulated first (its motion depends on ω only), recording the racket pose at
every control step; the ball is then integrated against that path (linear inside a step).

The landing point p (C.1)
-------------------------
p = (x, y) of the first *terminal* event after the ball was *armed*. The ball is armed by
its first bounce on the table or by a racket contact. Terminal events: the ball touching
the table plane z = 0.76 m (on the table, i.e. a bounce — on the opponent's side that is a
good return — or anywhere off the table), or the net. A missed ball is therefore scored
where it falls through the table plane behind the robot, and a ball hit into the net at
the net. Outcomes (``info["outcome"]``): ``"returned"`` (lands on the opponent's half),
``"net"``, ``"out"`` (hit, but lands elsewhere), ``"missed"`` (never touched the racket).

Reward (Eq. C.1) and its scale
------------------------------
R(τ, s) = −c₁ min_t ‖τ_b,t − τ_r,t‖ − c₂ ‖b − p‖ with c₁ = c₂ = 0.1 m⁻¹. τ_b and τ_r are the
ball and racket-centre positions at the control steps (joined by straight segments for the
minimum), over the incoming ball only (up to the first racket contact). With this scale the
levels of Sec. 3.4.3 hold: a ball hit short of the opponent's side scores R ≲ −0.1, a ball in
the net R ≈ −0.02 … −0.07 in the near zone (the thesis's [−0.05, −0.02]), and R > −0.02 is a
return within 20 cm of the target.

Modules
-------
:mod:`~skillkit.tasks.table_tennis.ball` (the scene and the ball),
:mod:`~skillkit.tasks.table_tennis.arm` (the arm model),
:mod:`~skillkit.tasks.table_tennis.demonstration` (the forehand stroke) and
:mod:`~skillkit.tasks.table_tennis.task` (the :class:`TableTennis` task). Every public name
is importable from ``skillkit.tasks.table_tennis``.
"""

from skillkit.tasks.table_tennis.arm import (
    ARMATURE,
    INITIAL_STD,
    JOINT_NAMES,
    KD,
    KP,
    LINK_LENGTHS,
    LINK_MASSES,
    PLATFORM_POSITION,
    RACKET_SITE,
    SHOULDER_HEIGHT,
    TORQUE_LIMIT,
    arm_mjcf,
    arm_model,
    racket_pose,
)
from skillkit.tasks.table_tennis.ball import (
    LANDING_ZONE,
    NET_HEIGHT,
    NET_OVERHANG,
    RETURN_HIGH,
    RETURN_LOW,
    RETURN_NEAR_HIGH,
    RETURN_NEAR_LOW,
    SERVE_POSITION,
    TABLE_HEIGHT,
    TABLE_LENGTH,
    TABLE_WIDTH,
    VELOCITY_HIGH,
    VELOCITY_LOW,
    BallEvent,
    BallFlight,
    BallPhysics,
    RacketPath,
    on_table,
    simulate_ball,
)
from skillkit.tasks.table_tennis.demonstration import (
    DEMO_PATH,
    HIT_TIME,
    PREFERRED_POSTURE,
    RETURN_FLIGHT_TIME,
    design_stroke,
    forehand_demonstration,
    load_demonstration,
    nominal_context,
    write_demonstration,
)
from skillkit.tasks.table_tennis.task import (
    TableTennis,
    min_segment_distance,
    table_tennis,
    table_tennis_near,
)

__all__ = [
    "ARMATURE",
    "BallEvent",
    "BallFlight",
    "BallPhysics",
    "DEMO_PATH",
    "HIT_TIME",
    "INITIAL_STD",
    "JOINT_NAMES",
    "KD",
    "KP",
    "LANDING_ZONE",
    "LINK_LENGTHS",
    "LINK_MASSES",
    "NET_HEIGHT",
    "NET_OVERHANG",
    "PLATFORM_POSITION",
    "PREFERRED_POSTURE",
    "RACKET_SITE",
    "RETURN_FLIGHT_TIME",
    "RETURN_HIGH",
    "RETURN_LOW",
    "RETURN_NEAR_HIGH",
    "RETURN_NEAR_LOW",
    "RacketPath",
    "SERVE_POSITION",
    "SHOULDER_HEIGHT",
    "TABLE_HEIGHT",
    "TABLE_LENGTH",
    "TABLE_WIDTH",
    "TORQUE_LIMIT",
    "TableTennis",
    "VELOCITY_HIGH",
    "VELOCITY_LOW",
    "arm_mjcf",
    "arm_model",
    "design_stroke",
    "forehand_demonstration",
    "load_demonstration",
    "min_segment_distance",
    "nominal_context",
    "on_table",
    "racket_pose",
    "simulate_ball",
    "table_tennis",
    "table_tennis_near",
    "write_demonstration",
]
