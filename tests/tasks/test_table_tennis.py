"""Table tennis (Sec. 3.4.3, App. C.3): ball physics against closed forms, the racket impact
law against hand computations, the context range, the reward, determinism and bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from _tolerances import fp_tol
from scipy.integrate import solve_ivp

from skillkit.tasks import make, names
from skillkit.tasks import table_tennis as tt
from skillkit.tasks.table_tennis import (
    DEMO_PATH,
    LANDING_ZONE,
    NET_HEIGHT,
    SERVE_POSITION,
    TABLE_HEIGHT,
    TABLE_LENGTH,
    VELOCITY_HIGH,
    VELOCITY_LOW,
    BallPhysics,
    RacketPath,
    TableTennis,
    arm_model,
    forehand_demonstration,
    load_demonstration,
    min_segment_distance,
    nominal_context,
    simulate_ball,
)
from skillkit.trajectory import Trajectory

G = 9.81
R_BALL = 0.02
PLANE = TABLE_HEIGHT + R_BALL  # height of the ball centre when it touches the table plane


@pytest.fixture(scope="module")
def task() -> TableTennis:
    return make("table-tennis")


# ----------------------------------------------------------------------------- ball flight
def _flight_tols(p0, v0, t_end, h, vz_end):
    """Absolute round-off of a drag-free flight of N = t_end / h midpoint steps (a constant
    acceleration makes each step exact but for rounding): (position, velocity, event time).

    Each step rounds the velocity by ~2 ε v (v ≤ ‖v₀‖ + g t_end) and the position by ~4 ε of
    its size; the velocity errors k·2ε v integrate to N ε v t_end, so the position is off by
    ≲ 6 N ε (|p|, v t_end). An event time is the accumulated t (N additions) plus the
    crossing of a plane from a height off by the position's error at speed |v_z|.
    """
    n = int(np.ceil(t_end / h))
    speed = np.linalg.norm(v0) + G * t_end
    tol_v = fp_tol(2 * n, scale=speed)
    tol_p = fp_tol(6 * n, scale=np.abs(p0).max() + speed * t_end)
    tol_t = fp_tol(n, scale=t_end) + tol_p / abs(vz_end)
    return tol_p, tol_v, tol_t


def test_drag_free_flight_is_the_closed_form_parabola():
    p0, v0 = np.array([3.0, 0.5, 2.0]), np.array([1.5, -0.3, 2.0])  # off the table: no bounce
    flight = simulate_ball(p0, v0, 1.0, dt=0.01, physics=BallPhysics(drag=0.0))
    t_land = (v0[2] + np.sqrt(v0[2] ** 2 + 2 * G * (p0[2] - PLANE))) / G
    before = flight.times < t_land
    t = flight.times[before, None]
    vz_land = v0[2] - G * t_land
    tol_p, tol_v, tol_t = _flight_tols(p0, v0, t_land, 0.01 / 2, vz_land)  # 2 substeps
    expected = p0 + v0 * t + 0.5 * np.array([0.0, 0.0, -G]) * t**2
    np.testing.assert_allclose(flight.positions[before], expected, rtol=0, atol=tol_p)
    np.testing.assert_allclose(flight.velocities[before], v0 + np.array([0, 0, -G]) * t, atol=tol_v)
    end = flight.terminal
    assert end.kind == "plane" and len(flight.events) == 1  # off the table: terminal at once
    assert end.time == pytest.approx(t_land, abs=tol_t)
    # the position at the event: its own error and the time's, at the landing speed
    tol_end = tol_p + np.linalg.norm(v0 + [0, 0, -G * t_land]) * tol_t
    np.testing.assert_allclose(
        end.position, p0 + v0 * t_land + [0, 0, -0.5 * G * t_land**2], atol=tol_end
    )


def test_drag_matches_an_accurate_ode_solution_and_falls_short():
    physics = BallPhysics()
    assert physics.drag == pytest.approx(1.2 * 0.5 * np.pi * 0.02**2 / (2 * 0.0027))
    p0, v0 = np.array([3.0, 0.0, 2.0]), np.array([6.0, 1.0, 3.0])
    flight = simulate_ball(p0, v0, 0.8, dt=0.01, physics=physics)

    def rhs(_, y):
        v = y[3:]
        return np.concatenate([v, -physics.drag * np.linalg.norm(v) * v - [0, 0, G]])

    ref = solve_ivp(
        rhs,
        (0, 0.8),
        np.concatenate([p0, v0]),
        t_eval=flight.times,
        rtol=1e-12,
        atol=1e-12,
        method="DOP853",
    )
    alive = flight.times < flight.terminal.time
    assert alive.sum() > 50
    # The integrator is second order: the step-halving (Richardson) estimate of its error is
    # 4/3 |x_h − x_{h/2}| (same output times, twice the substeps); allow twice that (the DOP853
    # reference is good to ~1e-12). It was atol=2e-5 against an error of 1.3e-5.
    fine = simulate_ball(p0, v0, 0.8, dt=0.01, physics=physics, substeps=4)
    estimate = 4 / 3 * np.abs(flight.positions[alive] - fine.positions[alive]).max()
    np.testing.assert_allclose(flight.positions[alive], ref.y[:3, alive].T, atol=2 * estimate)
    free = simulate_ball(p0, v0, 0.8, dt=0.01, physics=BallPhysics(drag=0.0))
    x_drag, x_free = flight.terminal.position[0], free.terminal.position[0]
    assert x_drag < x_free - 0.2  # several metres of flight lose > 20 cm to drag
    assert flight.terminal.time < free.terminal.time


def test_table_bounce_reverses_vz_with_the_restitution():
    h, e = 0.3, 0.9
    physics = BallPhysics(drag=0.0, table_restitution=e)
    flight = simulate_ball([-0.5, 0.2, PLANE + h], [0.4, 0.0, 0.0], 1.0, dt=0.005, physics=physics)
    bounce, land = flight.events
    assert bounce.kind == "table" and land.kind == "plane"  # second touch ends the rally
    vz = np.sqrt(2 * G * h)
    p0, v0, t_end = np.array([-0.5, 0.2, PLANE + h]), np.array([0.4, 0.0, 0.0]), land.time
    # bounds over the whole flight (5 ms, 2 substeps); the landing is slower than the bounce
    tol_p, tol_v, tol_t = _flight_tols(p0, v0, t_end, 0.005 / 2, e * vz)
    assert bounce.time == pytest.approx(np.sqrt(2 * h / G), abs=tol_t)
    # the velocity at the touch: its own error and g times the touch time's
    tol_bounce = tol_v + G * tol_t
    np.testing.assert_allclose(bounce.velocity_before, [0.4, 0.0, -vz], atol=tol_bounce)
    np.testing.assert_allclose(bounce.velocity_after, [0.4, 0.0, e * vz], atol=tol_bounce)
    assert bounce.position[2] == pytest.approx(PLANE)
    assert land.time - bounce.time == pytest.approx(2 * e * vz / G, abs=2 * tol_t)
    apex = flight.positions[(flight.times > bounce.time) & (flight.times < land.time), 2].max()
    assert apex == pytest.approx(PLANE + e**2 * h, abs=1e-4)


CORNERS = list(itertools.product(*zip(VELOCITY_LOW, VELOCITY_HIGH, strict=True)))


@pytest.mark.parametrize("velocity", CORNERS)
def test_corners_of_the_context_range_bounce_once_in_the_landing_zone(velocity):
    flight = simulate_ball(SERVE_POSITION, velocity, 1.5)
    kinds = [e.kind for e in flight.events]
    assert kinds == ["table", "plane"], kinds  # over the net, one bounce, then off the table
    bounce, end = flight.events
    (x_lo, y_lo), (x_hi, y_hi) = LANDING_ZONE
    assert x_lo <= bounce.position[0] <= x_hi and y_lo <= bounce.position[1] <= y_hi
    assert end.position[0] < -0.5 * TABLE_LENGTH  # the unhit ball leaves past the robot's end
    crossing = np.flatnonzero(np.diff(np.sign(flight.positions[:, 0])))[0]
    assert flight.positions[crossing, 2] > TABLE_HEIGHT + NET_HEIGHT + R_BALL  # clears the net


def test_net_stops_a_low_ball_and_lets_a_high_one_pass():
    straight = BallPhysics(drag=0.0, gravity=1e-9)  # (almost) straight lines
    low = simulate_ball([-1.0, 0.3, TABLE_HEIGHT + 0.1], [4.0, 0.0, 0.0], 1.0, physics=straight)
    assert [e.kind for e in low.events] == ["net"]
    assert low.terminal.time == pytest.approx(0.25, abs=1e-9)
    np.testing.assert_allclose(low.terminal.position, [0.0, 0.3, TABLE_HEIGHT + 0.1], atol=1e-9)
    high = simulate_ball(
        [-1.0, 0.3, TABLE_HEIGHT + NET_HEIGHT + 0.03], [4.0, 0.0, 0.0], 0.5, physics=straight
    )
    assert high.events == []


# ----------------------------------------------------------------------------- racket impact
def _resting(center, normal) -> RacketPath:
    """A racket held still at ``center`` with blade normal ``normal`` over [0, 1] s."""
    c, n, zeros = np.asarray(center, float), np.asarray(normal, float), np.zeros((2, 3))
    return RacketPath(np.array([0.0, 1.0]), np.stack([c, c]), np.stack([n, n]), zeros, zeros)


@pytest.mark.parametrize("tilt", [0.0, 0.35])
def test_racket_at_rest_returns_the_ball_by_the_impact_law(tilt):
    e_r = 0.8
    physics = BallPhysics(drag=0.0, racket_restitution=e_r)
    n = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    center = np.array([-1.5, 0.0, 1.3])
    racket = _resting(center, n)
    v0 = np.array([-4.0, 0.0, 0.0])
    flight = simulate_ball(
        center + [0.4, 0.0, 0.0], v0, 0.5, dt=0.002, physics=physics, racket=racket
    )
    hit = flight.first("racket")
    assert hit is not None
    # hand computation: the ball falls freely until contact, then v' = v − (1 + e)(v·n) n
    t = hit.time
    v_in = v0 + [0.0, 0.0, -G * t]
    # N = t / h steps (1 ms): the velocity and the accumulated time each ~N ε off; the impact
    # law (the racket at rest: v_point = 0 exactly) adds ~8 flops on (2 + e) |v|
    n_steps = int(np.ceil(t / 0.001))
    tol = fp_tol(2 * n_steps, scale=np.linalg.norm(v_in)) + G * fp_tol(n_steps, scale=t)
    np.testing.assert_allclose(hit.velocity_before, v_in, atol=tol)
    tol_after = (2 + e_r) * tol + fp_tol(8, scale=(2 + e_r) * np.linalg.norm(v_in))
    v_out = v_in - (1 + e_r) * (v_in @ n) * n
    np.testing.assert_allclose(hit.velocity_after, v_out, atol=tol_after)
    # touching the face (the gap is interpolated linearly over a 1 ms step: error ≤ g h²/8)
    assert (hit.position - center) @ n == pytest.approx(R_BALL, abs=2e-6)
    assert hit.velocity_after[0] > 0  # returned towards the opponent
    assert flight.velocities[-1, 0] >= 0  # and it stays returned


def test_moving_racket_adds_its_normal_velocity():
    e_r, u = 0.8, 1.5  # racket moving at u m/s along its normal (+x)
    physics = BallPhysics(drag=0.0, gravity=1e-9, racket_restitution=e_r)
    times = np.linspace(0.0, 0.5, 126)
    center = np.column_stack([-1.5 + u * times, np.zeros_like(times), np.full_like(times, 1.2)])
    n = np.tile([1.0, 0.0, 0.0], (times.size, 1))
    racket = RacketPath(
        times, center, n, np.tile([u, 0.0, 0.0], (times.size, 1)), np.zeros((times.size, 3))
    )
    flight = simulate_ball(
        [-0.5, 0.03, 1.2], [-3.0, 0.0, 0.0], 0.5, dt=0.004, physics=physics, racket=racket
    )
    hit = flight.first("racket")
    # relative normal speed −3 − 1.5 = −4.5 reflects to +3.6, plus the racket's 1.5
    assert hit.velocity_after[0] == pytest.approx(u + e_r * (3.0 + u), abs=1e-6)
    # exactly: no y velocity, no drag, and the normal (1, 0, 0) has an exact zero y component
    assert hit.velocity_after[1] == 0.0
    # contact when the gap closes: 1.0 m − r at a closing speed of 4.5 m/s
    assert hit.time == pytest.approx((1.0 - R_BALL) / 4.5, abs=1e-9)


def test_ball_passing_beside_the_blade_is_not_hit():
    racket = _resting([-1.5, 0.0, 1.3], [1, 0, 0])
    flight = simulate_ball(
        [-0.9, 0.15, 1.3],
        [-4.0, 0.0, 0.0],
        0.5,
        physics=BallPhysics(drag=0.0, gravity=1e-9),
        racket=racket,
    )
    assert flight.first("racket") is None  # 15 cm off-centre > 8 cm blade radius


# ----------------------------------------------------------------------------- the task
def test_registered_with_thesis_dimensions(task):
    assert "table-tennis" in names("contextual")
    assert task.context_dim == 5 and task.parameter_dim == 17
    assert task.trajectory_depends_on_context
    model = arm_model()
    assert model.nq == model.nv == 8
    kinds = [int(model.jnt_type[j]) for j in range(8)]
    assert kinds == [2, 2, 3, 3, 3, 3, 3, 3]  # two slides, six hinges (mjtJoint)
    assert model.body_mass.sum() < 12.0  # light arm on an 8 kg platform


def test_demonstration_file_is_the_deterministic_design():
    shipped = load_demonstration(DEMO_PATH)
    fresh = forehand_demonstration()
    for key in ("times", "q", "qd", "qdd"):
        # design_stroke's iterative solve converges to ~1e-7 and its last digits depend on the
        # CPU's floating-point kernels (measured: 6.7e-8 absolute on another x86-64 machine).
        np.testing.assert_allclose(shipped[key], fresh[key], rtol=1e-6, atol=1e-6)


def test_initial_policy_mean_returns_the_nominal_ball(task):
    s = nominal_context()
    omega = task.initial_policy().mean_of(s)
    r, traj = task.evaluate(omega, s)
    assert traj.info["hit"] and traj.info["outcome"] == "returned", traj.info
    assert r > -0.02  # within 20 cm of the target: the demonstration is a good stroke
    assert traj.signals["ball"].shape == traj.signals["racket"].shape == (traj.n_steps, 3)
    assert traj.states.shape == (traj.n_steps, 16) and traj.controls.shape == (traj.n_steps, 8)


def test_reward_is_the_hand_computed_eq_c1(task):
    times = np.array([0.0, 0.1, 0.2, 0.3])
    ball = np.array([[2.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 1.0]])
    racket = np.array([[0.5, 0.3, 1.0], [0.5, 0.3, 1.0], [0.5, 0.3, 1.0], [0.5, 0.3, 1.0]])
    traj = Trajectory(
        times,
        np.zeros((4, 16)),
        np.zeros((4, 8)),
        signals={"ball": ball, "racket": racket},
        info={"incoming_end": 0.25, "landing_point": [0.7, -0.1]},
    )
    s = np.array([-5.4, 0.0, 2.25, 0.5, 0.2])
    # the ball passes the racket at 0.3 m between the 2nd and 3rd samples (x = 0.5)
    expected = -0.1 * 0.3 - 0.1 * np.hypot(0.5 - 0.7, 0.2 + 0.1)
    # the closest approach (differences, 3-term dots, a ratio, a + u δ, a norm: ~15 flops on
    # ball − racket of size ≤ 1.6) and the landing distance (~4 flops on ≤ 0.7), each × 0.1
    rel_max = np.abs(ball - racket).max()
    tol = 0.1 * (fp_tol(15, scale=rel_max) + fp_tol(4, scale=0.7))
    assert task.reward(traj, s) == pytest.approx(expected, abs=tol)
    # only the incoming ball counts (samples up to the end and one after): ending at 0.05 s
    # keeps the first segment only, whose closest point is its end
    traj.info["incoming_end"] = 0.05
    expected = -0.1 * np.hypot(0.5, 0.3) - 0.1 * np.hypot(0.5 - 0.7, 0.2 + 0.1)
    assert task.reward(traj, s) == pytest.approx(expected, abs=tol)


def test_reward_batch_rejects_mismatched_signals_and_contexts(task):
    """Shapes are checked, not broadcast: extra context rows are not ignored silently."""
    ball = np.zeros((2, 4, 3))
    good = {
        "ball": ball,
        "racket": ball + [0.0, 0.3, 0.0],
        "landing_point": np.zeros((2, 2)),
        "incoming_steps": np.array([4, 2]),
    }
    s = np.tile(nominal_context(), (2, 1))
    expected = -0.1 * 0.3 - 0.1 * np.linalg.norm(s[0, 3:])  # racket 0.3 m beside the ball
    # the same floats but ‖(0, −0.3, 0)‖ = √(0.3²), 0.3 up to an ulp; same-sign terms
    np.testing.assert_allclose(task.reward_batch(None, None, good, s), expected, rtol=fp_tol(4))
    with pytest.raises(ValueError, match="contexts: expected shape"):
        task.reward_batch(None, None, good, np.tile(nominal_context(), (3, 1)))
    for key, value, message in [
        ("racket", np.zeros((2, 3, 3)), "racket"),
        ("landing_point", np.zeros((1, 2)), "landing_point"),
        ("incoming_steps", np.array([4, 0]), "incoming_steps"),
        ("incoming_steps", np.array([4, 5]), "incoming_steps"),
        ("incoming_steps", np.array([4, 1.5]), "incoming_steps"),
    ]:
        with pytest.raises(ValueError, match=message):
            task.reward_batch(None, None, {**good, key: value}, s)


def test_reward_of_a_rollout_matches_a_dense_recomputation(task):
    s = task.sample_context(3)
    omega = task.initial_policy().sample(s, np.random.default_rng(3))
    r, traj = task.evaluate(omega, s)
    keep = np.count_nonzero(traj.times <= traj.info["incoming_end"]) + 1  # and one after
    rel = traj.signals["ball"][:keep] - traj.signals["racket"][:keep]
    u = np.linspace(0, 1, 2001)[:, None, None]
    dense = rel[:-1] + u * np.diff(rel, axis=0)  # straight segments between samples
    d_min = np.linalg.norm(dense, axis=-1).min()
    p = np.array(traj.info["landing_point"])
    assert r == pytest.approx(-0.1 * d_min - 0.1 * np.linalg.norm(s[3:] - p), abs=1e-9)


def test_min_segment_distance_brute_force():
    rng = np.random.default_rng(0)
    rel = rng.normal(size=(7, 3))
    u = np.linspace(0, 1, 100001)[:, None, None]
    brute = np.linalg.norm(rel[:-1] + u * np.diff(rel, axis=0), axis=-1).min()
    assert min_segment_distance(rel) == pytest.approx(brute, abs=1e-8)
    assert min_segment_distance(rel[:1]) == pytest.approx(np.linalg.norm(rel[0]))


def test_same_seed_same_trajectory(task):
    s = task.sample_context(5)
    omega = task.initial_policy().sample(s, np.random.default_rng(5))
    a, b = task.rollout(omega, s, rng=1), task.rollout(omega, s, rng=1)
    np.testing.assert_array_equal(a.states, b.states)
    for key in ("ball", "racket", "racket_normal"):
        np.testing.assert_array_equal(a.signals[key], b.signals[key])
    assert a.info == b.info


def test_bad_omega_and_context_raise(task):
    s = nominal_context()
    omega = task.initial_policy().mean_of(s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(omega[:16], s)
    with pytest.raises(ValueError, match="omega"):
        task.rollout(np.where(np.arange(17) == 3, np.nan, omega), s)
    bad_tau = omega.copy()
    bad_tau[16] = 0.0
    with pytest.raises(ValueError, match="tau"):
        task.rollout(bad_tau, s)
    with pytest.raises(ValueError, match="context"):
        task.rollout(omega, s[:4])
    too_fast = s.copy()
    too_fast[0] = VELOCITY_LOW[0] - 1.0
    with pytest.raises(ValueError, match="v_x"):
        task.rollout(omega, too_fast)


def test_bad_timing_is_refused_when_the_task_is_made():
    """Both are refused at once, not accepted only to fail (with other argument names) at the
    first rollout."""
    with pytest.raises(ValueError, match="control_dt: expected a whole multiple"):
        TableTennis(control_dt=0.003, physics_dt=0.002)
    with pytest.raises(ValueError, match="duration: expected at least one control period"):
        TableTennis(duration=0.001)


def test_bad_ball_inputs_raise():
    with pytest.raises(ValueError, match="velocity"):
        simulate_ball(SERVE_POSITION, [1.0, 2.0], 1.0)
    with pytest.raises(ValueError, match="duration"):
        simulate_ball(SERVE_POSITION, [1.0, 2.0, 3.0], -1.0)
    with pytest.raises(ValueError, match="table_restitution"):
        BallPhysics(table_restitution=1.5)
    with pytest.raises(ValueError, match="normal"):
        _resting([0, 0, 1], [0, 0, 0])


def test_return_zone_is_the_opponents_half_and_near_is_a_variant(task):
    """C.3: b uniform on the whole opponent's half; ``table-tennis-near`` keeps the narrower zone;
    a zone off the opponent's half is refused."""
    np.testing.assert_allclose(task.context_low[3:], [0.0, -tt.TABLE_WIDTH / 2])
    np.testing.assert_allclose(task.context_high[3:], [tt.TABLE_LENGTH / 2, tt.TABLE_WIDTH / 2])
    near = make("table-tennis-near")
    assert near.name == "table-tennis-near"
    np.testing.assert_allclose(near.context_low[3:], [0.2, -0.4])
    np.testing.assert_allclose(near.context_high[3:], [0.6, 0.4])
    np.testing.assert_allclose(near.context_low[:3], task.context_low[:3])
    samples = task.sample_context(0, n=2000)
    assert samples[:, 3].max() > 1.3 and samples[:, 4].min() < -0.7 and samples[:, 4].max() > 0.7
    bad = (([-0.1, 0.0], [0.5, 0.3]), ([0.5, 0.0], [0.2, 0.3]), ([0.2, 0.0], [1.5, 0.3]))
    for low, high in bad:
        with pytest.raises(ValueError, match="return_low, return_high"):
            make("table-tennis", return_low=low, return_high=high)
    # the demonstration was designed for the near zone's centre, and still is
    np.testing.assert_allclose(tt.nominal_context()[3:], [0.4, 0.0])


def test_initial_policy_samples_hit_return_and_net_balls(task):
    """Coverage of the initial exploration: 100 strokes on random contexts reach
    every outcome, and the returned balls land on the opponent's half near its targets."""
    policy, rng = task.initial_policy(), np.random.default_rng(0)
    outcomes, landing = [], []
    for _ in range(100):
        s = task.sample_context(rng)
        traj = task.rollout(policy.sample(s, rng), s, rng)
        assert not traj.failed
        outcomes.append(traj.info["outcome"])
        if traj.info["outcome"] == "returned":
            landing.append(traj.info["landing_point"])
    counts = {o: outcomes.count(o) for o in ("returned", "net", "out", "missed")}
    assert counts["returned"] >= 5 and counts["net"] >= 1 and counts["out"] >= 1
    assert 10 <= 100 - counts["missed"] <= 50  # hits are a minority, but not rare
    landing = np.array(landing)
    assert np.all(landing[:, 0] >= 0.0)  # returned: on the opponent's half
    assert np.ptp(landing[:, 1]) > 0.5  # spread across the table's width (1.525 m)
