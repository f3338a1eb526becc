"""The puck table: pucks sliding with Coulomb friction and colliding in pymunk (Appendix C.2)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymunk

from skillkit._validation import check_array, check_positive
from skillkit.tasks.hockey.arm import BLADE_HALF, CONTROL_DT

CONTROL_PUCK_START = np.array([0.45, -0.30])
"""Initial position of the control puck on the table, m."""
TARGET_CENTRE = np.array([2.0, 0.75])
"""Centre of the simulated target region; the demonstration shoots towards it."""


@dataclass(frozen=True)
class TablePhysics:
    """Physical constants of the puck table (pymunk).

    Attributes
    ----------
    puck_radius, puck_mass, puck_height : float
        Puck geometry (m) and mass (kg).
    friction : float
        Coulomb sliding friction μ (deceleration μ g).
    restitution_pucks, restitution_racket, friction_racket : float
        Restitution of puck–puck and racket–puck contacts; friction of the latter.
    gravity : float
    dt, free_dt : float
        Time step (s): the arm's control period; once the racket is lifted.
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
                raise ValueError(f"{name}: expected a restitution in [0, 1], got {e}")

    @property
    def deceleration(self) -> float:
        """Sliding deceleration μ g, m/s²."""
        return self.friction * self.gravity


_PUCK, _RACKET = 1, 2
_NO_COLLISION = pymunk.ShapeFilter(categories=0, mask=0)


class PuckTable:
    """The pymunk table: a control puck, a target puck and an optional kinematic racket blade.

    Parameters
    ----------
    control_start, target_start : array_like, shape (2,)
        Initial puck positions, m.
    physics : TablePhysics
    racket : bool
        Add the kinematic blade (a :data:`BLADE_HALF` box), out of play until
        :meth:`move_racket` puts it down.

    Attributes
    ----------
    hit_time : float or None
        Time of the first puck–puck contact.
    racket_touched : bool
    time : float
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
        pucks = self._set_contact(physics.restitution_pucks, 0.0)
        space.on_collision(_PUCK, _PUCK, begin=self._on_puck_contact, pre_solve=pucks)
        racket_puck = self._set_contact(physics.restitution_racket, physics.friction_racket)
        space.on_collision(_RACKET, _PUCK, begin=self._on_racket_contact, pre_solve=racket_puck)
        self.racket = None
        if racket:
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            body.position = (-10.0, -10.0)
            shape = pymunk.Poly.create_box(body, (2 * BLADE_HALF[0], 2 * BLADE_HALF[1]))
            shape.collision_type = _RACKET
            shape.filter = _NO_COLLISION
            space.add(body, shape)
            self.racket = body
            self._racket_shape = shape
            self._racket_active = False

    def _add_puck(self, position: np.ndarray) -> pymunk.Body:
        p = self.physics
        body = pymunk.Body(p.puck_mass, pymunk.moment_for_circle(p.puck_mass, 0, p.puck_radius))
        body.position = (float(position[0]), float(position[1]))
        decel = p.deceleration

        def friction(body, gravity, damping, dt):  # Coulomb: v ← v max(0, 1 − μ g Δt / ‖v‖)
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
        """Place the blade at ``pose`` [x, y, yaw] with the velocity that reaches ``next_pose``
        in dt; ``active``: the blade is down on the table (collides with the pucks)."""
        if self.racket is None:
            raise ValueError("racket: this table was built without a racket")
        dt = self.physics.dt
        self.racket.position = (float(pose[0]), float(pose[1]))
        self.racket.angle = float(pose[2])
        self.racket.velocity = ((next_pose[0] - pose[0]) / dt, (next_pose[1] - pose[1]) / dt)
        dyaw = math.remainder(float(next_pose[2]) - float(pose[2]), 2 * math.pi)
        self.racket.angular_velocity = dyaw / dt
        self._activate(active)

    def lift_racket(self) -> None:
        """Take the blade out of play for good."""
        if self.racket is not None:
            self.racket.velocity = (0.0, 0.0)
            self.racket.angular_velocity = 0.0
            self._activate(False)

    def _activate(self, active: bool) -> None:
        if active != self._racket_active:
            self._racket_active = active
            self._racket_shape.filter = pymunk.ShapeFilter() if active else _NO_COLLISION

    def step(self, dt: float | None = None) -> None:
        """Advance the table by ``dt`` (default ``physics.dt``)."""
        dt = self.physics.dt if dt is None else dt
        self.space.step(dt)
        self.time += dt

    @property
    def positions(self) -> np.ndarray:
        """Control and target puck positions, shape (2, 2)."""
        return np.array([tuple(b.position) for b in (self.control, self.target)])

    @property
    def velocities(self) -> np.ndarray:
        """Control and target puck velocities, shape (2, 2)."""
        return np.array([tuple(b.velocity) for b in (self.control, self.target)])

    @property
    def at_rest(self) -> bool:
        """Both pucks stopped."""
        return all(b.velocity.x == 0.0 and b.velocity.y == 0.0 for b in (self.control, self.target))
