"""Robot table tennis (Sec. 3.4.3, Appendix C.3): an 8-DoF arm returns balls to a target.

SI units, +z up, the regulation table (2.74 × 1.525 m, surface at 0.76 m) centred at the
origin, the net in the plane x = 0, the robot on the −x side. The context is
s = [v_x, v_y, v_z, b_x, b_y]: the ball is served from :data:`SERVE_POSITION` with velocity
v (ranges :data:`VELOCITY_LOW`, :data:`VELOCITY_HIGH`: it clears the net and bounces once
in :data:`LANDING_ZONE`), and b is the return target, uniform on the opponent's half
(``table-tennis-near``: the near zone ``ball.RETURN_NEAR_LOW``, ``ball.RETURN_NEAR_HIGH``).

* **Robot** (MuJoCo, :func:`~.arm.arm_mjcf`): a BioRob-like arm on two prismatic axes plus six
  revolute joints holding a racket; a DMP (Eqs. 2.21–2.23) reference tracked by PD control.
* **Ball** (:func:`simulate_ball`): free flight p̈ = g − k ‖ṗ‖ ṗ with exact event handling
  — table bounces, impacts with the racket disc, the net (see :mod:`.ball`).
* **Landing point** p: where the ball first touches the table plane (or the net) after its
  first bounce or a racket contact; outcomes ``returned``, ``net``, ``out``, ``missed``.
* **Reward** (Eq. C.1): R = −c₁ min_t ‖τ_b,t − τ_r,t‖ − c₂ ‖b − p‖, c₁ = c₂ = 0.1 m⁻¹, the
  minimum over the incoming ball only.

The submodules :mod:`.ball`, :mod:`.arm`, :mod:`.demonstration` and :mod:`.task` hold the
constants; the main names are re-exported here.
"""

from skillkit.tasks.table_tennis.arm import arm_model
from skillkit.tasks.table_tennis.ball import (
    LANDING_ZONE,
    NET_HEIGHT,
    NET_OVERHANG,
    SERVE_POSITION,
    TABLE_HEIGHT,
    TABLE_LENGTH,
    TABLE_WIDTH,
    VELOCITY_HIGH,
    VELOCITY_LOW,
    BallPhysics,
    RacketPath,
    simulate_ball,
)
from skillkit.tasks.table_tennis.demonstration import (
    DEMO_PATH,
    design_stroke,
    forehand_demonstration,
    load_demonstration,
    nominal_context,
)
from skillkit.tasks.table_tennis.task import TableTennis, min_segment_distance

__all__ = [
    "BallPhysics",
    "DEMO_PATH",
    "LANDING_ZONE",
    "NET_HEIGHT",
    "NET_OVERHANG",
    "RacketPath",
    "SERVE_POSITION",
    "TABLE_HEIGHT",
    "TABLE_LENGTH",
    "TABLE_WIDTH",
    "TableTennis",
    "VELOCITY_HIGH",
    "VELOCITY_LOW",
    "arm_model",
    "design_stroke",
    "forehand_demonstration",
    "load_demonstration",
    "min_segment_distance",
    "nominal_context",
    "simulate_ball",
]
