"""The table-tennis scene and ball: flight with air drag, table bounces, racket impacts, net.

Free flight follows p̈ = g − k ‖ṗ‖ ṗ (App. C.3, no spin), integrated by the explicit midpoint
rule (exact for the drag-free parabola). Events are located inside a step and handled exactly:

* table bounce: v_z ← −e_t v_z (horizontal velocity kept);
* racket impact on the blade disc of normal n: v_b ← v_b − (1 + e_r)(v_rel · n) n with
  v_rel = v_b − v_p, v_p the racket's velocity at the contact point (one-way coupling; the
  rim and the rest of the robot are ignored);
* net: the centre crossing x = 0 less than one radius above the net top, within its width.

The first bounce on the table or a racket contact *arms* the ball; its next touch of the table
plane (or any touch off the table, or the net) is *terminal* and gives the landing point p.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skillkit._validation import check_array, check_count, check_positive, check_type

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
"""Fixed launch point of the incoming ball (m), behind the opponent's end line."""
VELOCITY_LOW = np.array([-5.8, -0.4, 2.0])
"""Lower corner of the launch-velocity range [v_x, v_y, v_z] (m/s)."""
VELOCITY_HIGH = np.array([-5.0, 0.4, 2.5])
"""Upper corner of the launch-velocity range (m/s); every velocity in the box clears the net
and bounces once inside :data:`LANDING_ZONE`."""
LANDING_ZONE = np.array([[-1.25, -0.35], [-0.40, 0.35]])
"""Landing zone on the robot's half, [[x_min, y_min], [x_max, y_max]] (m)."""
RETURN_LOW = np.array([0.0, -0.5 * TABLE_WIDTH])
"""Lower corner of the return zone [b_x, b_y] (m): the whole opponent's half (C.3)."""
RETURN_HIGH = np.array([0.5 * TABLE_LENGTH, 0.5 * TABLE_WIDTH])
"""Upper corner of the return zone (m): the opponent's end line and side line."""
RETURN_NEAR_LOW = np.array([0.2, -0.4])
"""Lower corner of the narrower *near* return zone of ``table-tennis-near`` (m)."""
RETURN_NEAR_HIGH = np.array([0.6, 0.4])
"""Upper corner of the near return zone (m), the front of the opponent's half."""


@dataclass(frozen=True)
class BallPhysics:
    """Constants of the ball model (Appendix C.3): ``radius`` r (m), ``mass`` m (kg), ``drag``
    k = ρ C_d π r² / (2 m) (1/m, ρ = 1.2 kg/m³, C_d = 0.5), ``gravity`` (m/s², −z), restitutions
    e_t of the table and e_r of the racket, and the blade disc's ``racket_radius`` (m)."""

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
                raise ValueError(f"{name}: expected a restitution in [0, 1], got {e!r}")


@dataclass
class RacketPath:
    """The racket's rigid motion at uniformly spaced ``times`` (K,): blade ``center``, unit
    ``normal``, ``velocity`` and world-frame ``angular_velocity``, each (K, 3), interpolated
    linearly in between; no racket outside [times[0], times[-1]]."""

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

    def near(self, t: float, p, distance: float) -> bool:
        """Whether point p is within ``distance`` of the blade centre sampled nearest to t."""
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


@dataclass
class BallEvent:
    """An event of the ball flight at ``time`` (s) and ``position`` (3,) with the velocities
    before and after it; ``kind`` ``table`` (the bounce), ``racket``, or the terminal ``net``
    and ``plane``."""

    kind: str
    time: float
    position: np.ndarray
    velocity_before: np.ndarray
    velocity_after: np.ndarray


@dataclass
class BallFlight:
    """Result of :func:`simulate_ball`: ``times`` k·dt (N,), ball ``positions`` and
    ``velocities`` (N, 3) (held at the terminal event with zero velocity after it), and the
    ``events`` in time order (at most one terminal event, the last)."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    events: list[BallEvent] = field(default_factory=list)

    @property
    def terminal(self) -> BallEvent | None:
        """The terminal event (net or table-plane touch), if one happened."""
        return self.events[-1] if self.events and self.events[-1].kind in ("net", "plane") else None

    def first(self, kind: str) -> BallEvent | None:
        """The first event of a kind, or None."""
        return next((e for e in self.events if e.kind == kind), None)


def _acceleration(vx: float, vy: float, vz: float, drag: float, gravity: float):
    """p̈ = g − k‖v‖v on plain floats."""
    kv = drag * math.sqrt(vx * vx + vy * vy + vz * vz)
    return -kv * vx, -kv * vy, -kv * vz - gravity


def _advance(p, v, h: float, drag: float, gravity: float):
    """One explicit-midpoint step of length h on float triples."""
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


def on_table(x: float, y: float) -> bool:
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
) -> BallFlight:
    """Integrate the ball from its launch state through bounces and racket impacts, in steps
    of ``dt / substeps``, each advanced to its earliest event (table, net, racket face).

    Parameters
    ----------
    position, velocity : array_like, shape (3,)
        Launch state (m, m/s).
    duration, dt : float
        Recorded span and period (s): states at k·dt, k = 0..round(duration/dt).
    physics : BallPhysics, optional
    racket : RacketPath, optional
    substeps : int
        Integration steps per recording period; after ``duration`` the ball flies on for up
        to 3 s (unrecorded, no racket) to find its terminal event.

    Returns
    -------
    BallFlight
    """
    physics = BallPhysics() if physics is None else physics
    check_type(physics, BallPhysics, "physics", "a BallPhysics")
    check_type(racket, (RacketPath, type(None)), "racket", "a RacketPath or None")
    p = tuple(check_array(position, "position", shape=(3,)).tolist())
    v = tuple(check_array(velocity, "velocity", shape=(3,)).tolist())
    duration = check_positive(duration, "duration")
    dt = check_positive(dt, "dt")
    substeps = check_count(substeps, "substeps")
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
        t_stop = t + 3.0
        while not sim.done and t < t_stop - 0.5 * h:
            p, v = sim.step(p, v, t, h)
            t += h
    return BallFlight(dt * np.arange(n_rec), positions, velocities, sim.events)


class _BallIntegrator:
    """Event-driven stepping of one ball on float triples."""

    def __init__(self, physics: BallPhysics, racket: RacketPath | None):
        self.physics = physics
        self.racket = racket
        self.events: list[BallEvent] = []
        self.armed = False
        self.done = False
        self.plane_z = TABLE_HEIGHT + physics.radius
        self.net_top = TABLE_HEIGHT + NET_HEIGHT + physics.radius
        # the exact racket test runs only within this distance (plus the ball's travel): the
        # radii, 2 cm, and how far a blade point (≤ 0.1 m from the centre) moves in a sample
        if racket is not None:
            reach = physics.racket_radius + physics.radius + 0.02
            speed = np.linalg.norm(racket.velocity, axis=1)
            max_speed = float(np.max(speed + 0.1 * np.linalg.norm(racket.angular_velocity, axis=1)))
            self._reach = reach + max_speed * (racket.times[1] - racket.times[0])

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
        """Time into the step at which the ball reaches the blade disc's face, or None."""
        rk = self.racket
        if not (rk._t0 <= t and t + h <= rk._t1):
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
            if not self.armed and on_table(p[0], p[1]):
                v[2] = -ph.table_restitution * v[2]
                self.armed = True
                self.events.append(BallEvent("table", t, p.copy(), before, v.copy()))
            else:
                self._terminate("plane", p, v, t)
            return p, v
        if kind == "net":
            p[0] = 0.0
            if abs(p[1]) <= 0.5 * TABLE_WIDTH + NET_OVERHANG and p[2] < self.net_top:
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
