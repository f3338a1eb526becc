"""Robot table tennis (Sec. 3.4.3, Appendix C.3): an 8-DoF arm returns balls to a target.

SI units, +z up, the regulation table centred at the origin, the net in the plane x = 0, the
robot on the −x side. The ball is served from :data:`SERVE_POSITION` (it clears the net and
bounces once in :data:`LANDING_ZONE`) and flies with drag and exact events (:mod:`.ball`); a
BioRob-like arm (two prismatic axes, six revolute joints) PD-tracks a DMP (Eqs. 2.21–2.23).
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
