"""Robot table tennis (Sec. 3.4.3, Appendix C.3): an 8-DoF arm returns balls to a target.

The scene (SI units, +z up, table centred at the origin, the robot on the −x side)
--------------------------------------------------------------------------------
* **Table** of regulation size, 2.74 × 1.525 m, surface at 0.76 m; the **net** is the plane
  x = 0, 0.1525 m high, overhanging the side lines by 0.1525 m.
* **Ball** (40 mm, 2.7 g) launched at t = 0 from the fixed serve position
  :data:`SERVE_POSITION` behind the opponent's end with the context velocity v = [v_x, v_y,
  v_z]. The ranges :data:`VELOCITY_LOW`, :data:`VELOCITY_HIGH` are chosen so that the ball
  clears the net and bounces exactly once, inside the landing zone (:data:`LANDING_ZONE`),
  before it reaches the robot (checked for all corners of the range in the tests).
* **Robot**: a light BioRob-like arm on a platform moved by two prismatic axes in the
  horizontal plane, plus six revolute joints (shoulder yaw and pitch, upper-arm roll, elbow,
  forearm roll, wrist), 8 DoF in all, holding a racket; built with ``dm_control.mjcf``
  (:func:`arm_mjcf`) and simulated in MuJoCo. A DMP (Eqs 2.21–2.23) generates the joint
  reference, tracked by PD control with gravity/Coriolis compensation
  (:func:`skillkit.policies.controllers.track_reference`).
* **Return target** b = [b_x, b_y] uniform in the return zone on the opponent's half.
  The context is s = [v_x, v_y, v_z, b_x, b_y].

How the ball is simulated, and why
----------------------------------
The ball is integrated by our own code (:func:`simulate_ball`), not by MuJoCo contacts: we
want exact control of the air drag and of the impact laws, and event times found exactly
rather than through soft-contact penetration. Free flight follows

    p̈ = g − k ‖ṗ‖ ṗ,        k = ρ C_d A / (2 m) = 0.1396 m⁻¹

(ρ = 1.2 kg/m³, C_d = 0.5, A = π r², m = 2.7 g; :class:`BallPhysics`), integrated with the
explicit midpoint rule at 2 ms (two steps per control period; exact for the drag-free
parabola, O(h²) with drag: < 2e-5 m over a flight against an accurate ODE solution).
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

Because the 2.7 g ball does not change the arm's motion, the arm is simulated first (its
motion depends on ω only) and the racket pose is recorded at every control step from
MuJoCo's forward kinematics; the ball is then integrated against that racket path
(interpolated linearly inside a control step).

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
minimum), over the incoming ball only (up to the first racket contact). With this scale
the levels of Sec. 3.4.3 mean what the thesis says: a ball hit but not reaching the
opponent's side lands ≈ 1 m or more from b (R ≲ −0.1); a ball in the net is 0.2–0.6 m
short of b, plus its lateral offset (R ≈ −0.02 … −0.07, the thesis's [−0.05, −0.02]);
R > −0.02 means a return within 20 cm of the target (a centred hit costs ≈ 0.002 of it).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_positive
from skillkit.tasks.base import SimulationFailure, Task
from skillkit.tasks.registry import register
from skillkit.trajectory import Trajectory

# ----------------------------------------------------------------------------- the scene
TABLE_LENGTH = 2.74
"""Table length along x (m), regulation size."""
TABLE_WIDTH = 1.525
"""Table width along y (m)."""
TABLE_HEIGHT = 0.76
"""Height of the playing surface (m)."""
NET_HEIGHT = 0.1525
"""Height of the net above the playing surface (m)."""
NET_OVERHANG = 0.1525
"""How far the net extends beyond each side line (m)."""

SERVE_POSITION = np.array([1.6, 0.0, 1.0])
"""Fixed launch point of the incoming ball (m): 0.23 m behind the opponent's end line,
0.24 m above the table."""
VELOCITY_LOW = np.array([-5.8, -0.4, 2.0])
"""Lower corner of the launch-velocity range [v_x, v_y, v_z] (m/s)."""
VELOCITY_HIGH = np.array([-5.0, 0.4, 2.5])
"""Upper corner of the launch-velocity range (m/s). Every velocity in the box makes the ball
clear the net and bounce once inside :data:`LANDING_ZONE` (flight ≈ 0.4–0.6 s to the bounce)."""
LANDING_ZONE = np.array([[-1.25, -0.35], [-0.40, 0.35]])
"""Landing zone on the robot's half, [[x_min, y_min], [x_max, y_max]] (m)."""
RETURN_LOW = np.array([0.2, -0.4])
"""Lower corner of the return zone on the opponent's half, [b_x, b_y] (m)."""
RETURN_HIGH = np.array([0.6, 0.4])
"""Upper corner of the return zone (m): the front part of the opponent's half, so that a ball
in the net (p at x = 0) is 0.2–0.6 m short of the target, as the thesis's net band implies."""


@dataclass(frozen=True)
class BallPhysics:
    """Constants of the ball model (Appendix C.3: ballistic flight with air drag, no spin).

    Attributes
    ----------
    radius : float
        Ball radius r (m): 40 mm ball.
    mass : float
        Ball mass (kg): 2.7 g.
    drag : float
        Quadratic drag coefficient k = ρ C_d π r² / (2 m) (1/m) in p̈ = g − k‖ṗ‖ṗ, with air
        density ρ = 1.2 kg/m³ and drag coefficient C_d = 0.5: k = 0.1396 m⁻¹.
    gravity : float
        Gravitational acceleration (m/s²), along −z.
    table_restitution : float
        Coefficient of restitution e_t of a table bounce (v_z ← −e_t v_z).
    racket_restitution : float
        Coefficient of restitution e_r of the racket along its normal.
    racket_radius : float
        Radius of the (disc-shaped) racket blade (m).
    """

    radius: float = 0.02
    mass: float = 0.0027
    drag: float = 1.2 * 0.5 * np.pi * 0.02**2 / (2 * 0.0027)
    gravity: float = 9.81
    table_restitution: float = 0.9
    racket_restitution: float = 0.8
    racket_radius: float = 0.08

    def __post_init__(self) -> None:
        for name in ("radius", "mass", "gravity", "racket_radius"):
            check_positive(getattr(self, name), name)
        check_positive(self.drag, "drag", allow_zero=True)
        for name in ("table_restitution", "racket_restitution"):
            e = getattr(self, name)
            if not 0.0 <= e <= 1.0:
                raise ValueError(
                    f"{name}: expected a coefficient of restitution in [0, 1], got {e!r}"
                )


# ----------------------------------------------------------------------------- racket path
@dataclass
class RacketPath:
    """The racket's rigid motion sampled at the control steps (from MuJoCo's kinematics).

    Between samples the pose and velocities are interpolated linearly (the normal is
    re-normalised). Outside [times[0], times[-1]] there is no racket.

    Attributes
    ----------
    times : ndarray, shape (K,)
        Uniformly spaced sample times (s).
    center : ndarray, shape (K, 3)
        Blade centre (m).
    normal : ndarray, shape (K, 3)
        Unit normal of the blade.
    velocity : ndarray, shape (K, 3)
        Linear velocity of the blade centre (m/s).
    angular_velocity : ndarray, shape (K, 3)
        Angular velocity of the racket (rad/s), world frame.
    """

    times: np.ndarray
    center: np.ndarray
    normal: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray

    def __post_init__(self) -> None:
        self.times = check_array(self.times, "times", ndim=1)
        k = self.times.shape[0]
        if k < 2 or np.any(np.diff(self.times) <= 0):
            raise ValueError(f"times: expected at least 2 increasing sample times, got {k}")
        for name in ("center", "normal", "velocity", "angular_velocity"):
            setattr(self, name, check_array(getattr(self, name), name, shape=(k, 3)))
        norms = np.linalg.norm(self.normal, axis=1)
        if np.any(norms < 1e-9):
            raise ValueError("normal: expected non-zero racket normals")
        self.normal = self.normal / norms[:, None]
        self._t0 = float(self.times[0])
        self._dt = float(self.times[1] - self.times[0])
        self._t1 = float(self.times[-1])
        self._centers = [tuple(c) for c in self.center.tolist()]
        self._faces = [tuple(r) for r in np.hstack([self.center, self.normal]).tolist()]

    @property
    def max_speed(self) -> float:
        """Largest speed of a blade point over the samples: max_k ‖v_k‖ + ‖ω_k‖ R_max, with
        R_max = 0.1 m covering the blade (used to size the proximity test)."""
        return float(
            np.max(
                np.linalg.norm(self.velocity, axis=1)
                + 0.1 * np.linalg.norm(self.angular_velocity, axis=1)
            )
        )

    @classmethod
    def at_rest(cls, center, normal, t_end: float) -> RacketPath:
        """A racket held still at ``center`` with blade normal ``normal`` over [0, t_end]."""
        c = check_array(center, "center", shape=(3,))
        n = check_array(normal, "normal", shape=(3,))
        t_end = check_positive(t_end, "t_end")
        zeros = np.zeros((2, 3))
        return cls(np.array([0.0, t_end]), np.stack([c, c]), np.stack([n, n]), zeros, zeros)

    def active(self, t: float) -> bool:
        """Whether the racket exists at time t."""
        return self._t0 <= t <= self._t1

    def near(self, t: float, p, distance: float) -> bool:
        """Whether point p is within ``distance`` of the blade centre sampled nearest to t
        (a cheap float test run before the exact contact check)."""
        i = min(max(int(round((t - self._t0) / self._dt)), 0), len(self._centers) - 1)
        c = self._centers[i]
        dx, dy, dz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
        return dx * dx + dy * dy + dz * dz <= distance * distance

    def _index(self, t: float) -> tuple[int, float]:
        u = (t - self._t0) / self._dt
        i = min(max(int(math.floor(u)), 0), len(self._faces) - 2)
        return i, min(max(u - i, 0.0), 1.0)

    def face(self, t: float) -> tuple[float, ...]:
        """Blade centre and unit normal at time t as six floats (cx, cy, cz, nx, ny, nz)."""
        i, f = self._index(t)
        a, b = self._faces[i], self._faces[i + 1]
        cx, cy, cz, nx, ny, nz = (x + f * (y - x) for x, y in zip(a, b, strict=True))
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        return cx, cy, cz, nx / norm, ny / norm, nz / norm

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(centre, unit normal, velocity, angular velocity) at time t, each shape (3,)."""
        i, f = self._index(t)
        face = np.array(self.face(t))
        v = (1 - f) * self.velocity[i] + f * self.velocity[i + 1]
        w = (1 - f) * self.angular_velocity[i] + f * self.angular_velocity[i + 1]
        return face[:3], face[3:], v, w


# ----------------------------------------------------------------------------- ball flight
@dataclass
class BallEvent:
    """A discrete event of the ball flight.

    Attributes
    ----------
    kind : {"table", "racket", "net", "plane"}
        ``table``: a bounce on the table that does not end the rally (the incoming bounce);
        ``racket``: a racket impact; ``net``: the ball touches the net (terminal);
        ``plane``: a terminal touch of the table plane — by the armed ball, on or off the
        table, or by a ball that has not bounced yet, off the table.
    time : float
        Event time (s).
    position : ndarray, shape (3,)
        Ball centre at the event.
    velocity_before, velocity_after : ndarray, shape (3,)
        Ball velocity just before and just after the event (equal for terminal events).
    """

    kind: str
    time: float
    position: np.ndarray
    velocity_before: np.ndarray
    velocity_after: np.ndarray

    @property
    def terminal(self) -> bool:
        return self.kind in ("net", "plane")


@dataclass
class BallFlight:
    """Result of :func:`simulate_ball`.

    Attributes
    ----------
    times : ndarray, shape (N,)
        Recording times k·dt, k = 0..N−1 (s).
    positions, velocities : ndarray, shape (N, 3)
        Ball centre and velocity at the recording times. After the terminal event the ball
        is held at the event position with zero velocity (the rally is over).
    events : list of BallEvent
        All events in time order; at most one terminal event, the last.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    events: list[BallEvent] = field(default_factory=list)

    @property
    def terminal(self) -> BallEvent | None:
        """The terminal event (net or table-plane touch), if one happened."""
        return self.events[-1] if self.events and self.events[-1].terminal else None

    def first(self, kind: str) -> BallEvent | None:
        """The first event of a kind, or None."""
        return next((e for e in self.events if e.kind == kind), None)


def _acceleration(vx: float, vy: float, vz: float, drag: float, gravity: float):
    """p̈ = g − k‖v‖v, on plain floats (the inner loop runs ~10³ times per flight)."""
    kv = drag * math.sqrt(vx * vx + vy * vy + vz * vz)
    return -kv * vx, -kv * vy, -kv * vz - gravity


def _advance(p, v, h: float, drag: float, gravity: float):
    """One explicit-midpoint step of length h on float triples: exact when the acceleration
    is constant (the drag-free parabola), second order with drag."""
    ax, ay, az = _acceleration(v[0], v[1], v[2], drag, gravity)
    hh = 0.5 * h * h
    p_new = (p[0] + h * v[0] + hh * ax, p[1] + h * v[1] + hh * ay, p[2] + h * v[2] + hh * az)
    mx, my, mz = _acceleration(
        v[0] + 0.5 * h * ax, v[1] + 0.5 * h * ay, v[2] + 0.5 * h * az, drag, gravity
    )
    return p_new, (v[0] + h * mx, v[1] + h * my, v[2] + h * mz)


def _first_crossing(d0: float, rate: float, accel: float, h: float) -> float:
    """Smallest t in (0, h] with d0 + rate t + accel t²/2 = 0, given d0 > 0 (clipped to h)."""
    if abs(accel) < 1e-12:
        return min(-d0 / rate, h) if rate < 0 else h
    disc = rate * rate - 2.0 * accel * d0
    if disc < 0:
        return h
    q = -0.5 * (rate + math.copysign(math.sqrt(disc), rate))
    roots = [r for r in (q / (0.5 * accel), d0 / q if q != 0 else np.inf) if r > 0]
    return min(min(roots), h) if roots else h


def _net_half_width() -> float:
    return 0.5 * TABLE_WIDTH + NET_OVERHANG


def _on_table(x: float, y: float) -> bool:
    return abs(x) <= 0.5 * TABLE_LENGTH and abs(y) <= 0.5 * TABLE_WIDTH


def simulate_ball(
    position,
    velocity,
    duration: float,
    dt: float = 0.002,
    *,
    physics: BallPhysics | None = None,
    racket: RacketPath | None = None,
    substeps: int = 2,
    max_extra_time: float = 3.0,
) -> BallFlight:
    """Integrate the ball from its launch state through bounces and racket impacts.

    Free flight obeys p̈ = g − k‖ṗ‖ṗ (explicit midpoint rule, ``dt / substeps`` per step).
    Inside each step the earliest event (table plane, net plane, racket face) is located —
    exactly for a constant acceleration, by linear interpolation for the moving racket —
    the state is advanced to it, the event law applied, and the step finished (see the
    module docstring for the laws and for when a table-plane touch is terminal).

    Parameters
    ----------
    position, velocity : array_like, shape (3,)
        Launch state (m, m/s).
    duration : float
        Recorded span (s): states are returned at k·dt for k = 0..round(duration/dt).
    dt : float
        Recording period (s), usually the robot's control period.
    physics : BallPhysics, optional
        Ball constants (default :class:`BallPhysics`).
    racket : RacketPath, optional
        The racket's motion; None for a flight without racket.
    substeps : int
        Integration steps per recording period.
    max_extra_time : float
        If no terminal event happened within ``duration``, keep integrating (not recorded,
        racket ignored) for at most this long to find it.

    Returns
    -------
    BallFlight
    """
    physics = BallPhysics() if physics is None else physics
    if not isinstance(physics, BallPhysics):
        raise ValueError(f"physics: expected a BallPhysics, got {type(physics).__name__}")
    if racket is not None and not isinstance(racket, RacketPath):
        raise ValueError(f"racket: expected a RacketPath or None, got {type(racket).__name__}")
    p = tuple(check_array(position, "position", shape=(3,)).tolist())
    v = tuple(check_array(velocity, "velocity", shape=(3,)).tolist())
    duration = check_positive(duration, "duration")
    dt = check_positive(dt, "dt")
    max_extra_time = check_positive(max_extra_time, "max_extra_time", allow_zero=True)
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps: expected a positive integer, got {substeps!r}")
    substeps = int(substeps)
    n_rec = int(round(duration / dt)) + 1
    positions = np.empty((n_rec, 3))
    velocities = np.zeros((n_rec, 3))
    positions[0], velocities[0] = p, v
    sim = _BallIntegrator(physics, racket)
    h = dt / substeps
    t = 0.0
    for k in range(1, n_rec):
        for _ in range(substeps):
            p, v = sim.step(p, v, t, h)
            t += h
            if sim.done:
                break
        if sim.done:
            positions[k:] = p
            break
        positions[k], velocities[k] = p, v
    if not sim.done:
        sim.racket = None
        t_stop = t + max_extra_time
        while not sim.done and t < t_stop - 0.5 * h:
            p, v = sim.step(p, v, t, h)
            t += h
    return BallFlight(dt * np.arange(n_rec), positions, velocities, sim.events)


class _BallIntegrator:
    """Event-driven stepping of one ball (the state machine behind :func:`simulate_ball`).

    States are float triples; arrays are only built at events.
    """

    def __init__(self, physics: BallPhysics, racket: RacketPath | None):
        self.physics = physics
        self.racket = racket
        self.events: list[BallEvent] = []
        self.armed = False
        self.done = False
        self.plane_z = TABLE_HEIGHT + physics.radius
        self.net_top = TABLE_HEIGHT + NET_HEIGHT + physics.radius
        # The exact racket test runs only when the ball is within this distance (plus its
        # own travel in the step) of the nearest racket sample: blade and ball radii, the
        # racket's travel over a sample period, and 2 cm to spare.
        if racket is not None:
            self._reach = (
                physics.racket_radius
                + physics.radius
                + 0.02
                + racket.max_speed * (racket.times[1] - racket.times[0])
            )

    def step(self, p, v, t: float, h: float):
        """Advance (p, v) from time t by h, handling every event inside the step."""
        drag, gravity = self.physics.drag, self.physics.gravity
        remaining = h
        for _ in range(8):  # at most a few events can share one step
            if remaining <= 0.0 or self.done:
                break
            p1, v1 = _advance(p, v, remaining, drag, gravity)
            kind, te = None, remaining
            d0 = p[2] - self.plane_z  # table plane, from above
            if d0 > 0.0 and p1[2] - self.plane_z <= 0.0:
                az = _acceleration(v[0], v[1], v[2], drag, gravity)[2]
                kind, te = "plane", _first_crossing(d0, v[2], az, remaining)
            if p[0] != 0.0 and p[0] * p1[0] <= 0.0:  # net plane x = 0, from either side
                s = 1.0 if p[0] > 0 else -1.0
                ax = _acceleration(v[0], v[1], v[2], drag, gravity)[0]
                tn = _first_crossing(s * p[0], s * v[0], s * ax, remaining)
                if tn < te:
                    kind, te = "net", tn
            if self.racket is not None and self.racket.near(
                t, p, self._reach + remaining * (abs(v[0]) + abs(v[1]) + abs(v[2]))
            ):
                tr = self._racket_crossing(p, p1, t, remaining)
                if tr is not None and tr < te:
                    kind, te = "racket", tr
            if kind is None:
                return p1, v1
            p, v = _advance(p, v, te, drag, gravity)
            t += te
            remaining -= te
            p, v = self._apply(kind, np.array(p), np.array(v), t)
            p, v = tuple(p.tolist()), tuple(v.tolist())
        return p, v

    def _racket_crossing(self, p0, p1, t: float, h: float) -> float | None:
        """Time into the step at which the ball reaches the blade face, or None.

        The signed distance of the ball centre to the blade plane, minus the ball radius,
        is interpolated linearly over the step; a sign change from outside is a contact if
        the ball centre then projects inside the blade disc.
        """
        rk = self.racket
        if not (rk.active(t) and rk.active(t + h)):
            return None
        r = self.physics.radius
        cx, cy, cz, nx, ny, nz = rk.face(t)
        g0 = nx * (p0[0] - cx) + ny * (p0[1] - cy) + nz * (p0[2] - cz)
        side = 1.0 if g0 >= 0 else -1.0
        cx, cy, cz, nx, ny, nz = rk.face(t + h)
        g1 = nx * (p1[0] - cx) + ny * (p1[1] - cy) + nz * (p1[2] - cz)
        h0, h1 = side * g0 - r, side * g1 - r
        if not (h0 > 0.0 >= h1):
            return None
        frac = h0 / (h0 - h1)
        cx, cy, cz, nx, ny, nz = rk.face(t + frac * h)
        ox, oy, oz = (a + frac * (b - a) - c for a, b, c in zip(p0, p1, (cx, cy, cz), strict=True))
        normal_part = nx * ox + ny * oy + nz * oz
        in_plane2 = ox * ox + oy * oy + oz * oz - normal_part * normal_part
        if in_plane2 > self.physics.racket_radius**2:
            return None
        return frac * h

    def _apply(self, kind: str, p: np.ndarray, v: np.ndarray, t: float):
        ph = self.physics
        before = v.copy()
        if kind == "plane":
            p[2] = self.plane_z
            if not self.armed and _on_table(p[0], p[1]):
                v[2] = -ph.table_restitution * v[2]
                self.armed = True
                self.events.append(BallEvent("table", t, p.copy(), before, v.copy()))
            else:
                self._terminate("plane", p, v, t)
            return p, v
        if kind == "net":
            p[0] = 0.0
            if abs(p[1]) <= _net_half_width() and p[2] < self.net_top:
                self._terminate("net", p, v, t)
            return p, v
        # racket impact: reflect the normal relative velocity with restitution e_r
        c, n, vr, wr = self.racket.state(t)
        side = 1.0 if n @ (p - c) >= 0 else -1.0
        contact = p - side * ph.radius * n
        v_point = vr + np.cross(wr, contact - c)
        vn = float((v - v_point) @ n)
        if side * vn >= 0.0:  # already separating: no impulse
            return p, v
        v = v - (1.0 + ph.racket_restitution) * vn * n
        self.armed = True
        self.events.append(BallEvent("racket", t, p.copy(), before, v.copy()))
        return p, v

    def _terminate(self, kind: str, p, v, t) -> None:
        self.events.append(BallEvent(kind, t, p.copy(), v.copy(), v.copy()))
        self.done = True


# ----------------------------------------------------------------------------- the robot
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
"""Where the platform stands at q = 0 (m): 0.63 m behind the robot's end line, 0.5 m to the
left of the centre line (the ball passes on the robot's right: a forehand)."""
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
"""Exploration std of the initial policy per entry of ω = [g (8), ġ (8), τ]: platform goal
5 cm (x) and 10 cm (y, the direction in which the ball's arrival varies most, ±22 cm over
the context range), arm goals 0.08 rad (≈ 5 cm at the racket), final velocities 0.15 m/s
(platform) and 0.3 rad/s (arm), τ 0.03 (≈ ±20 ms at the hit)."""
RACKET_SITE = "racket"
"""Site at the blade centre; its local y axis is the blade normal."""


def arm_mjcf(timestep: float = 0.002):
    """The 8-DoF table-tennis arm as a ``dm_control.mjcf`` model.

    Two prismatic axes (``base_x``, ``base_y``) move a platform carrying a 1.2 m column;
    on it sits a 6-DoF arm whose links point along +x at q = 0: shoulder yaw (z) and pitch
    (y) at the shoulder, upper-arm roll (x) and elbow (y) at the elbow, forearm roll (x)
    and wrist (z) at the wrist, then a 10 cm handle and a disc blade of radius 8 cm whose
    normal is the hand's y axis. Masses (:data:`LINK_MASSES`) are BioRob-light; every joint
    has an armature (:data:`ARMATURE`) standing for the reflected drive inertia. Contacts
    are disabled: the ball is simulated outside MuJoCo and the arm does not touch the
    table in the strokes considered.

    Parameters
    ----------
    timestep : float
        Physics time step (s).

    Returns
    -------
    dm_control.mjcf.RootElement
    """
    with warnings.catch_warnings():  # dm_control probes for a display on import
        warnings.simplefilter("ignore")
        from dm_control import mjcf

    l1, l2, l3 = LINK_LENGTHS
    m_base, m_shoulder, m_upper, m_fore, m_hand = LINK_MASSES
    root = mjcf.RootElement(model="table_tennis_arm")
    root.compiler.angle = "radian"
    root.option.timestep = float(timestep)
    root.option.flag.contact = "disable"
    arm = iter(ARMATURE)

    def joint(body, name, kind, axis):
        body.add("joint", name=name, type=kind, axis=axis, armature=next(arm))

    platform = root.worldbody.add(
        "body", name="platform", pos=[PLATFORM_POSITION[0], PLATFORM_POSITION[1], 0.0]
    )
    joint(platform, "base_x", "slide", [1, 0, 0])
    joint(platform, "base_y", "slide", [0, 1, 0])
    platform.add(
        "geom",
        name="column",
        type="box",
        size=[0.12, 0.12, 0.5 * SHOULDER_HEIGHT],
        pos=[0, 0, 0.5 * SHOULDER_HEIGHT],
        mass=m_base,
        rgba=[0.4, 0.4, 0.45, 1],
    )
    shoulder = platform.add("body", name="upper_arm", pos=[0, 0, SHOULDER_HEIGHT])
    joint(shoulder, "shoulder_yaw", "hinge", [0, 0, 1])
    joint(shoulder, "shoulder_pitch", "hinge", [0, 1, 0])
    shoulder.add(
        "geom",
        name="shoulder",
        type="sphere",
        size=[0.06],
        mass=m_shoulder,
        rgba=[0.2, 0.3, 0.6, 1],
    )
    shoulder.add(
        "geom",
        name="upper_arm",
        type="capsule",
        fromto=[0, 0, 0, l1, 0, 0],
        size=[0.035],
        mass=m_upper,
        rgba=[0.2, 0.3, 0.6, 1],
    )
    forearm = shoulder.add("body", name="forearm", pos=[l1, 0, 0])
    joint(forearm, "upper_arm_roll", "hinge", [1, 0, 0])
    joint(forearm, "elbow", "hinge", [0, 1, 0])
    forearm.add(
        "geom",
        name="forearm",
        type="capsule",
        fromto=[0, 0, 0, l2, 0, 0],
        size=[0.03],
        mass=m_fore,
        rgba=[0.2, 0.3, 0.6, 1],
    )
    hand = forearm.add("body", name="hand", pos=[l2, 0, 0])
    joint(hand, "forearm_roll", "hinge", [1, 0, 0])
    joint(hand, "wrist", "hinge", [0, 0, 1])
    handle = l3 - 0.08
    hand.add(
        "geom",
        name="handle",
        type="capsule",
        fromto=[0, 0, 0, handle, 0, 0],
        size=[0.015],
        mass=0.3 * m_hand,
        rgba=[0.6, 0.4, 0.2, 1],
    )
    hand.add(
        "geom",
        name="blade",
        type="cylinder",
        fromto=[l3, -0.005, 0, l3, 0.005, 0],
        size=[0.08],
        mass=0.7 * m_hand,
        rgba=[0.8, 0.1, 0.1, 1],
    )
    hand.add("site", name=RACKET_SITE, pos=[l3, 0, 0], size=[0.01])
    return root


@lru_cache(maxsize=4)
def arm_model(timestep: float = 0.002):
    """The compiled MuJoCo model of :func:`arm_mjcf` (cached; MjModel is read-only here)."""
    import mujoco

    return mujoco.MjModel.from_xml_string(arm_mjcf(timestep).to_xml_string())


def racket_pose(model, data) -> tuple[np.ndarray, np.ndarray]:
    """Blade centre (3,) and unit normal (3,) from the current kinematics of ``data``."""
    sid = model.site(RACKET_SITE).id
    return data.site_xpos[sid].copy(), data.site_xmat[sid].reshape(3, 3)[:, 1].copy()


# ----------------------------------------------------------------------------- demonstration
DEMO_PATH = Path(__file__).resolve().parent.parent / "data" / "demonstrations" / "table_tennis.npz"
"""The shipped forehand demonstration (package data); :func:`write_demonstration` rebuilds it."""
HIT_TIME = 0.72
"""Time (s) at which the demonstrated stroke meets the ball of the nominal context."""
RETURN_FLIGHT_TIME = 0.55
"""Flight time (s) of the demonstrated return from racket to table."""
PREFERRED_POSTURE = np.array([0.0, 0.0, -0.6, 0.3, 0.0, -1.0, 0.0, 0.0])
"""A relaxed forehand posture the stroke design is pulled towards (regularises the IK)."""


def nominal_context() -> np.ndarray:
    """Centre of the context range, s₀ = [v₀, b₀], shape (5,)."""
    return np.concatenate([0.5 * (VELOCITY_LOW + VELOCITY_HIGH), 0.5 * (RETURN_LOW + RETURN_HIGH)])


def design_stroke(
    context=None, hit_time: float = HIT_TIME, flight_time: float = RETURN_FLIGHT_TIME
) -> dict:
    """The racket state that returns the ball of ``context`` to its target, and joints for it.

    1. Fly the incoming ball (no racket) to ``hit_time``: position p_h, velocity v_in.
    2. Solve (by Newton on :func:`simulate_ball`) for the outgoing velocity v_out that lands
       on b after ``flight_time``.
    3. For a frictionless impact v_out − v_in ∥ n, so the blade normal is
       n = (v_out − v_in)/‖·‖ and the racket's normal speed follows from the impact law:
       v_r·n = v_in·n + (v_out − v_in)·n / (1 + e_r); the racket velocity is taken along n.
    4. Inverse kinematics (least squares, pulled to :data:`PREFERRED_POSTURE`) for the blade
       centre at p_h with normal n; joint velocities q̇ from the site Jacobian, trading the
       racket's linear velocity (weight 100), its angular velocity (weight 3) and joint
       speeds (platform axes 200× costlier than the arm joints).

    Parameters
    ----------
    context : array_like, shape (5,), optional
        Default :func:`nominal_context`.
    hit_time, flight_time : float
        Contact time after launch and the return's flight time (s).

    Returns
    -------
    dict
        ``q`` (8,), ``qd`` (8,), ``position`` (3,), ``normal`` (3,), ``racket_velocity`` (3,),
        ``ball_velocity_in`` (3,), ``ball_velocity_out`` (3,).
    """
    import mujoco
    from scipy.optimize import fsolve, least_squares

    s = nominal_context() if context is None else check_array(context, "context", shape=(5,))
    hit_time = check_positive(hit_time, "hit_time")
    flight_time = check_positive(flight_time, "flight_time")
    dt = 0.002
    incoming = simulate_ball(SERVE_POSITION, s[:3], hit_time, dt=dt)
    p_h, v_in = incoming.positions[-1], incoming.velocities[-1]
    b = s[3:5]

    def miss(v_out):
        events = simulate_ball(p_h, v_out, 2.0, dt=dt).events
        if not events:  # an absurd trial velocity that never comes down: far off
            return [1e3, 1e3, 1e3]
        ev = events[0]
        return [ev.position[0] - b[0], ev.position[1] - b[1], ev.time - flight_time]

    # drag-free guess with 10% more horizontal speed for the drag
    guess = np.array(
        [
            1.1 * (b[0] - p_h[0]) / flight_time,
            1.1 * (b[1] - p_h[1]) / flight_time,
            (TABLE_HEIGHT + 0.02 - p_h[2]) / flight_time + 0.5 * 9.81 * flight_time,
        ]
    )
    v_out, _, ok, msg = fsolve(miss, guess, full_output=True)
    if ok != 1:
        raise RuntimeError(f"design_stroke: no return velocity found ({msg})")
    e_r = BallPhysics().racket_restitution
    n = (v_out - v_in) / np.linalg.norm(v_out - v_in)
    v_racket = (v_in @ n + (v_out - v_in) @ n / (1.0 + e_r)) * n

    model = arm_model()
    data = mujoco.MjData(model)
    sid = model.site(RACKET_SITE).id
    w_reg = np.array([3.0, 3.0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1])

    def residual(q):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        c, normal = racket_pose(model, data)
        return np.concatenate([100 * (c - p_h), 30 * (normal - n), w_reg * (q - PREFERRED_POSTURE)])

    q = least_squares(residual, PREFERRED_POSTURE, xtol=1e-12, ftol=1e-12).x
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    jacp, jacr = np.zeros((3, 8)), np.zeros((3, 8))
    mujoco.mj_jacSite(model, data, jacp, jacr, sid)
    cost = np.sqrt(np.array([200.0, 200.0, 1, 1, 1, 1, 1, 1]))
    a = np.vstack([100 * jacp, 3 * jacr, np.diag(cost)])
    y = np.concatenate([100 * v_racket, np.zeros(11)])
    qd = np.linalg.lstsq(a, y, rcond=None)[0]
    return {
        "q": q,
        "qd": qd,
        "position": p_h,
        "normal": n,
        "racket_velocity": v_racket,
        "ball_velocity_in": v_in,
        "ball_velocity_out": v_out,
    }


def _quintic(q0, qd0, q1, qd1, duration: float, t: np.ndarray):
    """Quintic from (q0, q̇0, 0) to (q1, q̇1, 0) over ``duration``; (q, q̇, q̈) at t, (len(t), n)."""
    T = duration
    m = np.array(
        [
            [1, 0, 0, 0, 0, 0],
            [0, 1, 0, 0, 0, 0],
            [0, 0, 2, 0, 0, 0],
            [1, T, T**2, T**3, T**4, T**5],
            [0, 1, 2 * T, 3 * T**2, 4 * T**3, 5 * T**4],
            [0, 0, 2, 6 * T, 12 * T**2, 20 * T**3],
        ],
        dtype=float,
    )
    zero = np.zeros_like(q0)
    coef = np.linalg.solve(m, np.stack([q0, qd0, zero, q1, qd1, zero]))  # (6, n)
    powers = np.arange(6)
    tt = t[:, None]
    pos = tt**powers
    vel = powers * tt ** np.maximum(powers - 1, 0)
    acc = powers * (powers - 1) * tt ** np.maximum(powers - 2, 0)
    return pos @ coef, vel @ coef, acc @ coef


def forehand_demonstration(dt: float = 0.002) -> dict[str, np.ndarray]:
    """The forehand stroke the DMP imitates (our stand-in for the thesis's kinesthetic
    teach-in), deterministic.

    From :func:`design_stroke` at the nominal context (hit pose q_h, joint velocity q̇_h at
    t_h = :data:`HIT_TIME`): the arm starts at rest in a ready pose q_r = q_h − 0.2 D q̇_h,
    draws back to q_b = q_h − 0.6 D q̇_h (at rest, t = 0.35 s) and swings forward to
    (q_h, q̇_h) at t_h, each segment a quintic with zero end accelerations (D = t_h − 0.35 s).

    Returns
    -------
    dict
        ``times`` (N,), ``q``, ``qd``, ``qdd`` (N, 8).
    """
    dt = check_positive(dt, "dt")
    stroke = design_stroke()
    q_h, qd_h = stroke["q"], stroke["qd"]
    t_back = 0.35
    swing = HIT_TIME - t_back
    q_ready, q_back = q_h - 0.2 * swing * qd_h, q_h - 0.6 * swing * qd_h
    n = int(round(HIT_TIME / dt))
    times = dt * np.arange(n + 1)
    first = times < t_back
    zero = np.zeros(8)
    a = _quintic(q_ready, zero, q_back, zero, t_back, times[first])
    b = _quintic(q_back, zero, q_h, qd_h, swing, times[~first] - t_back)
    q, qd, qdd = (np.concatenate([x, y]) for x, y in zip(a, b, strict=True))
    return {"times": times, "q": q, "qd": qd, "qdd": qdd}


def write_demonstration(path: str | Path = DEMO_PATH) -> Path:
    """Regenerate the shipped demonstration file::

    python -c "from skillkit.tasks.table_tennis import write_demonstration as w; w()"
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **forehand_demonstration())
    return path


def load_demonstration(path: str | Path = DEMO_PATH) -> dict[str, np.ndarray]:
    """Read a demonstration written by :func:`write_demonstration`."""
    with np.load(Path(path), allow_pickle=False) as f:
        return {k: f[k] for k in ("times", "q", "qd", "qdd")}


# ----------------------------------------------------------------------------- the task
class TableTennis(Task):
    """Return an incoming ball to a target on the opponent's side (Sec. 3.4.3, App. C.3).

    Lower-level policy: a DMP per joint (10 basis functions, shape weights fitted to the
    shipped forehand demonstration and fixed) of which ω = [g (8), ġ (8), τ] — final
    positions, final velocities and time scaling, 17 parameters — is learned
    (:class:`skillkit.policies.dmp.DMPParameters`). The reference is tracked by PD control
    with bias compensation at ``control_dt``; the episode lasts ``duration`` seconds from
    the ball's launch, and the ball is then followed (racket gone) until it lands.

    The context s = [v_x, v_y, v_z, b_x, b_y] is uniform on the box of
    :data:`VELOCITY_LOW`/:data:`VELOCITY_HIGH` × :data:`RETURN_LOW`/:data:`RETURN_HIGH`.
    The simulation is deterministic (C.3 neglects spin and measurement noise): ``rng`` is
    accepted and unused.

    Parameters
    ----------
    reward_weights : tuple of float
        (c₁, c₂) of Eq. C.1, in 1/m; the thesis uses c₁ = c₂ for model-free search.
    duration : float
        Episode length (s) of the robot simulation and of the recorded signals.
    control_dt : float
        Control period (s); also the sampling of the recorded signals.
    physics_dt : float
        MuJoCo time step (s); ``control_dt`` must be a multiple of it.
    ball : BallPhysics, optional
        Ball constants.
    demonstration : dict, optional
        ``times``, ``q``, ``qd``, ``qdd`` to imitate (default: the shipped file).
    name : str
        Registry name.

    Trajectory contents
    -------------------
    ``states`` (T, 16) = [q, q̇]; ``controls`` (T, 8) joint torques/forces;
    ``signals["ball"]`` (T, 3) ball centre, ``signals["racket"]`` (T, 3) blade centre,
    ``signals["racket_normal"]`` (T, 3); ``info``: ``hit`` (bool), ``net`` (bool: the
    returned ball ended in the net), ``landing_point`` p (2,), ``outcome``
    (returned/net/out/missed), ``hit_time`` (s or None), ``incoming_end`` (s: the end of the
    incoming ball, the first racket contact or else the landing), ``landing_time`` (s),
    ``n_saturated`` (saturated torque entries).
    """

    context_dim = 5
    parameter_dim = 17
    context_names = ("v_x", "v_y", "v_z", "b_x", "b_y")
    context_low = np.concatenate([VELOCITY_LOW, RETURN_LOW])
    context_high = np.concatenate([VELOCITY_HIGH, RETURN_HIGH])
    worst_reward = -5.0
    """Below any working rollout: the landing point is within ~15 m of the target (drag
    bounds the flight) and the racket within ~4 m of the ball, so R > −2."""
    trajectory_depends_on_context = True

    def __init__(
        self,
        reward_weights: tuple[float, float] = (0.1, 0.1),
        duration: float = 1.2,
        control_dt: float = 0.004,
        physics_dt: float = 0.002,
        ball: BallPhysics | None = None,
        demonstration: dict | None = None,
        name: str = "table-tennis",
    ):
        import mujoco

        from skillkit.policies.dmp import DMP, DMPParameters

        c = check_array(reward_weights, "reward_weights", shape=(2,))
        if np.any(c < 0):
            raise ValueError(f"reward_weights: expected non-negative (c1, c2), got {c.tolist()}")
        self.reward_weights = (float(c[0]), float(c[1]))
        self.duration = check_positive(duration, "duration")
        self.control_dt = check_positive(control_dt, "control_dt")
        self.physics_dt = check_positive(physics_dt, "physics_dt")
        self.ball = BallPhysics() if ball is None else ball
        if not isinstance(self.ball, BallPhysics):
            raise ValueError(f"ball: expected a BallPhysics, got {type(ball).__name__}")
        self.name = name
        demo = load_demonstration() if demonstration is None else demonstration
        self.dmp = DMP(len(JOINT_NAMES), n_basis=10, alpha_z=4.0, dt=self.control_dt).fit(
            demo["times"], demo["q"], demo["qd"], demo["qdd"]
        )
        self.parameters = DMPParameters(self.dmp, learn=("goal", "goal_velocity", "tau"))
        self.q0 = np.asarray(demo["q"][0], dtype=np.float64).copy()
        self.times = self.control_dt * np.arange(int(round(self.duration / self.control_dt)) + 1)
        self.model = arm_model(self.physics_dt)
        self.data = mujoco.MjData(self.model)
        self._site = self.model.site(RACKET_SITE).id

    # ------------------------------------------------------------------ parameters
    def check_omega(self, omega, name: str = "omega") -> np.ndarray:
        """Shape (17,), finite, and a positive time scaling τ = ω[16]."""
        omega = super().check_omega(omega, name)
        if omega[-1] <= 0:
            raise ValueError(f"{name}: its tau entry (index 16) must be > 0, got {omega[-1]:g}")
        return omega

    def initial_policy(self):
        """π(ω|s) = N(ω_demo, diag(σ²)) with zero context gain: the demonstrated stroke (g and ġ
        of the demonstration's end, τ = 1) with the exploration σ of :data:`INITIAL_STD`."""
        from skillkit.policies.gaussian import LinearGaussianPolicy

        return LinearGaussianPolicy(
            mean=self.parameters.to_vector(),
            cov=np.diag(INITIAL_STD**2),
            context_dim=self.context_dim,
        )

    # ------------------------------------------------------------------ simulation
    def _simulate(self, omega: np.ndarray, context: np.ndarray, rng: np.random.Generator):
        import mujoco

        from skillkit.policies.controllers import track_reference

        dmp = self.parameters.from_vector(omega)
        q_ref, qd_ref, _ = dmp.rollout(self.times, self.q0)
        model, data, sid = self.model, self.data, self._site
        T = self.times.shape[0]
        center, normal = np.empty((T, 3)), np.empty((T, 3))
        velocity, spin = np.empty((T, 3)), np.empty((T, 3))
        buf = np.empty(6)

        def record(k: int, d) -> None:
            center[k] = d.site_xpos[sid]
            normal[k] = d.site_xmat[sid, 1::3]
            mujoco.mj_objectVelocity(model, d, mujoco.mjtObj.mjOBJ_SITE, sid, buf, 0)
            spin[k], velocity[k] = buf[:3], buf[3:]

        mujoco.mj_resetData(model, data)
        data.qpos[:] = self.q0
        out = track_reference(
            model,
            data,
            q_ref,
            qd_ref,
            self.control_dt,
            KP,
            KD,
            torque_limit=TORQUE_LIMIT,
            on_step=record,
        )
        if not (np.all(np.isfinite(center)) and np.all(np.isfinite(normal))):
            raise SimulationFailure("non-finite racket pose")
        racket = RacketPath(self.times, center, normal, velocity, spin)
        flight = simulate_ball(
            SERVE_POSITION,
            context[:3],
            self.duration,
            dt=self.control_dt,
            physics=self.ball,
            racket=racket,
        )
        end = flight.terminal
        if end is None:
            raise SimulationFailure("the ball did not come down within the simulated time")
        hit = flight.first("racket")
        p = end.position[:2]
        if hit is None:
            outcome = "missed"
        elif end.kind == "net":
            outcome = "net"
        elif p[0] > 0 and _on_table(p[0], p[1]):
            outcome = "returned"
        else:
            outcome = "out"
        info = {
            "hit": hit is not None,
            "net": hit is not None and end.kind == "net",
            "landing_point": p.tolist(),
            "outcome": outcome,
            "hit_time": None if hit is None else float(hit.time),
            "incoming_end": float(end.time if hit is None else hit.time),
            "landing_time": float(end.time),
            "n_saturated": int(out["n_saturated"]),
        }
        return Trajectory(
            times=self.times.copy(),
            states=np.hstack([out["q"], out["qd"]]),
            controls=out["u"],
            signals={"ball": flight.positions, "racket": center, "racket_normal": normal},
            info=info,
        )

    def _reward(self, trajectory: Trajectory, context: np.ndarray) -> float:
        """R = −c₁ min_t ‖τ_b − τ_r‖ − c₂ ‖b − p‖ (Eq. C.1); the minimum is over the incoming
        ball — the samples up to ``incoming_end`` and the first one after it, so the segment
        across a racket contact counts — between samples along straight segments."""
        c1, c2 = self.reward_weights
        t = trajectory.times
        keep = min(
            int(np.searchsorted(t, trajectory.info["incoming_end"], side="right")) + 1, t.shape[0]
        )
        rel = trajectory.signals["ball"][:keep] - trajectory.signals["racket"][:keep]
        d_min = min_segment_distance(rel)
        p = np.asarray(trajectory.info["landing_point"], dtype=np.float64)
        return -c1 * d_min - c2 * float(np.linalg.norm(context[3:5] - p))


def min_segment_distance(relative) -> float:
    """Smallest ‖d‖ along the polyline through the rows of ``relative`` (shape (n, 3)):
    each segment d(u) = d_k + u (d_{k+1} − d_k), u ∈ [0, 1], is minimised in closed form."""
    d = check_array(relative, "relative", ndim=2)
    if d.shape[0] == 1:
        return float(np.linalg.norm(d[0]))
    a, delta = d[:-1], np.diff(d, axis=0)
    dd = np.einsum("ij,ij->i", delta, delta)
    u = np.where(dd > 0, -np.einsum("ij,ij->i", a, delta) / np.where(dd > 0, dd, 1.0), 0.0)
    closest = a + np.clip(u, 0.0, 1.0)[:, None] * delta
    return float(np.sqrt(np.einsum("ij,ij->i", closest, closest).min()))


@register("table-tennis", "contextual")
def table_tennis(**kwargs) -> TableTennis:
    """Sec. 3.4.3 / App. C.3 setting: contextual REPS's table tennis with c₁ = c₂ = 0.1."""
    return TableTennis(**kwargs)
