"""Robot hockey (Appendix C.2): table physics, arm kinematics, reward, smoothing, the task.

The generic task contract (shapes, seeds, failures) runs in ``test_contract.py`` for both
``hockey`` and ``hockey-real``; here are the hockey-specific checks against closed forms and
independent computations.
"""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.tasks import hockey as hk
from skillkit.tasks import make
from skillkit.trajectory import Trajectory


@pytest.fixture(scope="module")
def task() -> hk.Hockey:
    return make("hockey")


@pytest.fixture(scope="module")
def real() -> hk.Hockey:
    return make("hockey-real")


@pytest.fixture(scope="module")
def demo_rollout(task):
    s = np.array([2.0, 0.75, 0.5])
    return s, task.rollout(task.demo_omega, s, rng=0)


# ----------------------------------------------------------------------------- pucks
def _free_table(control, target, **physics) -> hk.PuckTable:
    return hk.PuckTable(control, target, hk.TablePhysics(**physics), racket=False)


def _collision_tol(table, speed):
    """Absolute round-off of a puck velocity after one collision at ``speed``: pymunk applies
    the contact impulse ``iterations`` times a step, for at most 1 + ``collision_persistence``
    steps, each application a few (≤ 4) flops on velocities of size ``speed``; with μ = 0 the
    free sliding multiplies by 1 − 0 = 1 exactly."""
    space = table.space
    return fp_tol(4 * space.iterations * (1 + space.collision_persistence), scale=speed)


def _slide_tol(steps, distance):
    """Absolute round-off of a puck's position after ``steps`` steps of Coulomb friction
    (hypot, divide, scale: ~5 flops) and position update (2 flops): the velocity error grows by
    ~7 ε v a step, and its sum over the steps, times Δt, is ~7 ε · steps · ``distance``."""
    return fp_tol(7 * steps, scale=distance)


@pytest.mark.parametrize("offset", [0.0, 0.03, 0.06])
def test_puck_collision_conserves_momentum_with_restitution(offset):
    """Equal masses, frictionless table: total momentum is conserved, the relative velocity
    along the impulse direction is reversed and scaled by e = 0.9, the tangential one kept."""
    e = 0.9
    table = _free_table([0.0, 0.0], [0.5, offset], friction=0.0, restitution_pucks=e)
    table.control.velocity = (1.2, 0.0)
    before = table.velocities
    for _ in range(300):
        table.step()
    after = table.velocities
    assert table.hit_time is not None
    tol = _collision_tol(table, 1.2)
    np.testing.assert_allclose(after.sum(axis=0), before.sum(axis=0), atol=tol)
    impulse = after[1] - before[1]
    n = impulse / np.linalg.norm(impulse)
    rel_before, rel_after = before[0] - before[1], after[0] - after[1]
    assert rel_after @ n == pytest.approx(-e * (rel_before @ n), rel=1e-9)
    t = np.array([-n[1], n[0]])
    assert rel_after @ t == pytest.approx(rel_before @ t, abs=tol)  # n ∥ impulse: no Δ along t
    # the impulse acts along the line of centres at contact (up to one step of overlap)
    r = hk.TablePhysics().puck_radius
    analytic = np.array([math.sqrt(4 * r * r - offset**2), offset]) / (2 * r)
    assert math.degrees(math.acos(min(1.0, n @ analytic))) < 5.0
    # kinetic energy is lost exactly as restitution predicts: ΔE = (1 − e²) m v_n² / 4
    m = hk.TablePhysics().puck_mass
    lost = 0.5 * m * (np.sum(before**2) - np.sum(after**2))
    assert lost == pytest.approx((1 - e**2) * m * (rel_before @ n) ** 2 / 4, rel=1e-9)


def test_head_on_collision_closed_form():
    """Head-on, equal masses: v1' = (1 − e) v / 2, v2' = (1 + e) v / 2."""
    table = _free_table([0.0, 0.0], [0.3, 0.0], friction=0.0, restitution_pucks=0.9)
    table.control.velocity = (1.0, 0.0)
    for _ in range(200):
        table.step()
    tol = _collision_tol(table, 1.0)
    np.testing.assert_allclose(table.velocities, [[0.05, 0.0], [0.95, 0.0]], atol=tol)


@pytest.mark.parametrize("v0", [0.5, 1.5])
def test_friction_stops_puck_at_closed_form_distance(v0):
    """Coulomb friction: stopping distance v0²/(2 μ g) and time v0/(μ g), up to one step; and
    exactly the discrete sum Δt Σ v_k (pymunk moves with the velocity before friction)."""
    phys = hk.TablePhysics()
    table = hk.PuckTable([0.0, 0.0], [9.0, 9.0], phys, racket=False)
    direction = np.array([0.8, 0.6])
    table.control.velocity = tuple(v0 * direction)
    dt = phys.free_dt
    steps = 0
    while not table.at_rest:
        table.step(dt)
        steps += 1
        assert steps < 10_000
    travelled = table.positions[0] @ direction
    closed = v0**2 / (2 * phys.friction * phys.gravity)
    assert abs(travelled - closed) <= v0 * dt
    assert abs(steps * dt - v0 / phys.deceleration) <= dt
    speeds = v0 - phys.deceleration * dt * np.arange(steps)
    tol = _slide_tol(steps, travelled)
    assert travelled == pytest.approx(dt * speeds.sum(), abs=tol)
    np.testing.assert_allclose(table.positions[0], travelled * direction, atol=tol)
    np.testing.assert_array_equal(table.positions[1], [9.0, 9.0])  # the other puck never moved


def test_racket_sweep_moves_control_puck():
    """A kinematic blade moving at v along its face normal launches a resting puck at (1 + e) v
    along that normal; a lifted blade passes over it."""
    phys = hk.TablePhysics(friction=0.0)
    v = 0.8
    for down, expected in ((True, (1 + phys.restitution_racket) * v), (False, 0.0)):
        table = hk.PuckTable([0.5, 0.0], [3.0, 3.0], phys)
        x = 0.3
        for _ in range(200):
            pose = (x, 0.0, math.pi / 2)  # long side along y, face normal along x
            table.move_racket(pose, (x + v * phys.dt, 0.0, math.pi / 2), down)
            table.step()
            x += v * phys.dt
        vel = table.velocities[0]
        assert table.racket_touched == down
        # lifted: the puck is never touched and its velocity stays exactly zero (abs=0)
        assert vel[0] == pytest.approx(expected, rel=1e-6, abs=0.0)
        assert vel[1] == pytest.approx(0.0, abs=1e-9)


def test_table_bad_input():
    with pytest.raises(ValueError, match="restitution_pucks"):
        hk.TablePhysics(restitution_pucks=1.5)
    with pytest.raises(ValueError, match="friction"):
        hk.TablePhysics(friction=-0.1)
    with pytest.raises(ValueError, match="puck_radius"):
        hk.TablePhysics(puck_radius=0.0)
    with pytest.raises(ValueError, match="control_start"):
        hk.PuckTable([0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="racket"):
        hk.PuckTable([0.0, 0.0], [1.0, 1.0], racket=False).move_racket((0, 0, 0), (0, 0, 0), True)


# ----------------------------------------------------------------------------- arm
def _fk_tol(scale):
    """Absolute round-off of the blade pose, numpy FK vs MuJoCo: each of the 8 frames of the
    chain costs ~10 dependent flops on either side (a 3-term matrix product here, a quaternion
    product and its conversion to a matrix in MuJoCo); ``scale``: the arm's reach for the
    position, 1 for the rotation."""
    return fp_tol(10 * (hk.N_JOINTS + 1), scale=scale)


def test_forward_kinematics_matches_mujoco_sites():
    model = hk.arm_model()
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "blade")
    rng = np.random.default_rng(0)
    qs = rng.uniform(-hk.JOINT_LIMITS, hk.JOINT_LIMITS, size=(20, 7))
    pos, rot = hk.arm_forward_kinematics(qs)
    tol_p, tol_r = _fk_tol(sum(hk.LINK_OFFSETS) + hk.BLADE_OFFSET), _fk_tol(1.0)
    assert pos.shape == (20, 3) and rot.shape == (20, 3, 3)
    for q, p, r in zip(qs, pos, rot, strict=True):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(p, data.site_xpos[site], atol=tol_p)
        np.testing.assert_allclose(r, data.site_xmat[site].reshape(3, 3), atol=tol_r)
    # at q = 0 the arm points straight up: blade at the summed link lengths. Exactly: the
    # rotations are identities (cos 0 = 1, sin 0 = 0) and the offsets add in the same order.
    p0, r0 = hk.arm_forward_kinematics(np.zeros(7))
    np.testing.assert_array_equal(p0, [0, 0, sum(hk.LINK_OFFSETS) + hk.BLADE_OFFSET])
    np.testing.assert_array_equal(r0, np.eye(3))
    with pytest.raises(ValueError, match="q"):
        hk.arm_forward_kinematics(np.zeros(6))


def test_arm_model_constants():
    model = hk.arm_model()
    assert model.nq == 7 and model.nu == 0
    np.testing.assert_allclose(model.jnt_range[:, 1], hk.JOINT_LIMITS)
    np.testing.assert_allclose(model.dof_armature, hk.ARMATURE)
    arm_mass = sum(hk.LINK_MASSES) + hk.SHAFT_MASS + hk.BLADE_MASS
    assert model.body_mass[1:].sum() == pytest.approx(arm_mass)
    # only the blade and the table collide (see test_blade_rests_on_the_table…)
    collide = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    assert {model.geom(g).name for g in np.flatnonzero(collide)} == {"table", "blade"}


def test_blade_pose_heights():
    """An upright blade spans ±half height; tilting the shaft by 90° lays it on its side."""
    upright = np.column_stack([[1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    pose = hk.blade_pose(np.array([0.1, 0.2, 0.05]), upright)
    np.testing.assert_allclose(
        pose, [0.1, 0.2, 0.05, 0.0, 0.05 - hk.BLADE_HALF[2], 0.05 + hk.BLADE_HALF[2]]
    )
    flat = np.column_stack([[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]])  # long side vertical
    pose = hk.blade_pose(np.zeros(3), flat)
    np.testing.assert_allclose(pose[4:], [-hk.BLADE_HALF[0], hk.BLADE_HALF[0]])


# ----------------------------------------------------------------------------- reward, filter
def _reward(x, y, s) -> float:
    return float(hk.hockey_reward_batch(np.asarray(x)[None], np.asarray(y)[None], [s])[0])


def test_reward_equals_hand_computation(task):
    x = np.array([[0.45, -0.30], [1.0, 0.1], [1.9, 0.5], [2.6, 1.3]])
    y = np.array([[2.0, 0.75], [2.0, 0.75], [2.3, 1.15]])  # moves by (0.3, 0.4): d_T = 0.5
    s = np.array([2.0, 0.75, 0.2])
    # closest control-puck sample to b = (2, 0.75): (1.9, 0.5) at sqrt(0.01 + 0.0625)
    expected = -math.sqrt(0.0725) - abs(0.5 - 0.2)
    # differences of coordinates (≤ 2.6), squares, a sum, sqrt, |d_T − d*|: ~8 flops each side
    tol = fp_tol(8, scale=np.abs(np.concatenate([x.ravel(), y.ravel()])).max())
    assert _reward(x, y, s) == pytest.approx(expected, abs=tol)
    traj = Trajectory(
        np.zeros(2),
        np.zeros((2, 14)),
        np.zeros((2, 7)),
        signals={"control_puck": x, "target_puck": y, "puck_times": np.arange(4.0)},
    )
    assert task.reward(traj, s) == pytest.approx(expected, abs=tol)
    # a different context re-scores the same trajectory: b = (1.9, 0.5) is on the track (a
    # miss of exactly 0); d_T = ‖(2.3, 1.15) − (2, 0.75)‖ = 0.5 up to the same round-off
    assert task.reward(traj, [1.9, 0.5, 0.5]) == pytest.approx(0.0, abs=tol)
    with pytest.raises(ValueError, match="control_puck"):
        _reward(x[:, :1], y, s)
    with pytest.raises(ValueError, match="context"):
        _reward(x, y, s[:2])


def test_butterworth_preserves_slow_signal_and_reduces_noise():
    rate, cutoff, order = 30.0, 4.0, 2
    t = np.arange(0.0, 20.0, 1.0 / rate)
    f = 0.5
    clean = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    smooth = hk.butterworth_smooth(clean, rate, cutoff, order)
    # forward–backward filtering: gain |H(f)|² = 1 / (1 + (f / f_c)^(2 n)), zero phase
    gain = 1.0 / (1.0 + (f / cutoff) ** (2 * order))
    interior = slice(60, -60)
    np.testing.assert_allclose(smooth[interior], gain * clean[interior], atol=2e-4)
    noise = 0.01 * np.random.default_rng(0).standard_normal((t.size, 2))
    residual = hk.butterworth_smooth(clean + noise, rate, cutoff, order) - smooth
    ratio = residual[interior].var() / noise.var()
    # white noise keeps ∫|H|⁴ df / (rate / 2) of its power: about 0.19 here
    freq = np.linspace(0.0, rate / 2, 200_001)
    expected = np.trapezoid(1.0 / (1.0 + (freq / cutoff) ** (2 * order)) ** 2, freq) / (rate / 2)
    assert ratio == pytest.approx(expected, rel=0.25)
    assert ratio < 0.3


def test_butterworth_bad_input():
    x = np.zeros(50)
    with pytest.raises(ValueError, match="cutoff"):
        hk.butterworth_smooth(x, rate=30.0, cutoff=15.0)
    with pytest.raises(ValueError, match="values"):
        hk.butterworth_smooth(np.zeros(5), rate=30.0)
    with pytest.raises(ValueError, match="order"):
        hk.butterworth_smooth(x, rate=30.0, order=0)
    with pytest.raises(ValueError, match="values"):
        hk.butterworth_smooth(np.full(50, np.nan), rate=30.0)
    # an Observation that cannot be smoothed is refused when it is made, not at reward time
    with pytest.raises(ValueError, match="cutoff"):
        hk.Observation(rate=30.0, cutoff=15.0)
    for order in (0, 2.5, True):
        with pytest.raises(ValueError, match="order"):
            hk.Observation(order=order)


# ----------------------------------------------------------------------------- the task
def test_context_ranges_and_validation(task, real):
    np.testing.assert_array_equal(task.context_low, [1.5, 0.5, 0.0])
    np.testing.assert_array_equal(task.context_high, [2.5, 1.0, 1.0])
    np.testing.assert_array_equal(real.context_low, [1.5, 0.4, 0.0])
    np.testing.assert_array_equal(real.context_high, [2.0, 0.8, 0.6])
    assert task.context_dim == 3 and task.parameter_dim == 15
    assert task.trajectory_depends_on_context
    s = task.sample_context(np.random.default_rng(0), n=500)
    assert np.all(s >= task.context_low) and np.all(s <= task.context_high)
    with pytest.raises(ValueError, match="b_x"):
        real.rollout(real.demo_omega, [2.4, 0.6, 0.3])  # fine for hockey, outside hockey-real
    with pytest.raises(ValueError, match="d_star"):
        task.rollout(task.demo_omega, [2.0, 0.75, 1.2])
    with pytest.raises(ValueError, match="context_high"):
        hk.Hockey(context_low=[2, 1, 1], context_high=[1, 1, 1])
    # the table step is the arm's control period: refused when the task is made (not
    # accepted only to fail at the first rollout)
    with pytest.raises(ValueError, match="physics: dt"):
        hk.Hockey(physics=hk.TablePhysics(dt=0.003))
    with pytest.raises(ValueError, match="exploration_std"):
        hk.Hockey(exploration_std=np.ones(14))


def test_demonstration_shot_hits_the_middle_target(demo_rollout, task):
    s, traj = demo_rollout
    assert not traj.failed
    assert traj.info["racket_touched"] and traj.info["hit"]
    assert traj.info["pucks_at_rest"]
    cp, tp = traj.signals["control_puck"], traj.signals["target_puck"]
    np.testing.assert_allclose(cp[0], hk.CONTROL_PUCK_START)
    np.testing.assert_allclose(tp[0], s[:2])
    assert traj.info["displacement"] == pytest.approx(np.linalg.norm(tp[-1] - tp[0]))
    assert 0.3 < traj.info["displacement"] < 1.5
    r = task.reward(traj, s)
    assert r == pytest.approx(_reward(cp, tp, s))
    assert -1.0 < r < -2 * hk.TablePhysics().puck_radius + 1e-9
    # the racket signal is the FK of the recorded joint angles
    pos, rot = hk.arm_forward_kinematics(traj.states[:, :7])  # vs MuJoCo's site_xpos
    reach = sum(hk.LINK_OFFSETS) + hk.BLADE_OFFSET
    np.testing.assert_allclose(traj.signals["racket"][:, :3], pos, atol=_fk_tol(reach))
    assert traj.signals["racket"].shape == (traj.n_steps, 4)
    assert traj.signals["puck_times"].shape == (cp.shape[0],)


def test_a_miss_leaves_the_target_in_place(task):
    """Aiming the blade 60° away sends the control puck past the target: d_T = 0."""
    omega = task.demo_omega.copy()
    omega[6] += math.radians(60.0)  # roll the blade about the vertical shaft
    s = np.array([2.0, 0.75, 0.4])
    traj = task.rollout(omega, s, rng=0)
    assert traj.info["racket_touched"] and not traj.info["hit"]
    assert traj.info["displacement"] == 0.0
    miss = np.min(np.linalg.norm(traj.signals["control_puck"] - s[:2], axis=1))
    assert miss > 0.3
    assert task.reward(traj, s) == pytest.approx(-miss - 0.4)


def test_dmp_reproduces_demonstration(task):
    demo = hk.load_demonstration()
    times, q_ref, qd_ref = task.reference(task.demo_omega)
    n = demo["times"].shape[0]
    stride = int(round(hk.CONTROL_DT / hk.TIMESTEP))
    demo_q = demo["q"][::stride]
    np.testing.assert_allclose(q_ref[: demo_q.shape[0]], demo_q, atol=5e-3)
    assert times[demo_q.shape[0] - 1] == pytest.approx(demo["times"][n - 1])
    np.testing.assert_allclose(task.demo_omega[7:14], demo["qd"][-1])  # ġ = final demo velocity
    assert task.demo_omega[-1] == 1.0


def test_shipped_demonstration_regenerates():
    shipped = hk.load_demonstration()
    fresh = hk.make_demonstration()
    assert shipped.keys() == fresh.keys()
    for key in fresh:
        np.testing.assert_allclose(shipped[key], fresh[key], atol=1e-9, err_msg=key)
    pos, _ = hk.arm_forward_kinematics(fresh["q"])
    np.testing.assert_allclose(pos, fresh["blade"], atol=1e-9)


def test_exploration_leaves_blade_height_alone(task):
    """Σ₀'s variance along the blade-height gradient (by finite differences of the numpy FK)
    is only the small isotropic floor."""
    g = task.demo_omega[:7]
    h = 1e-6
    grad = np.array(
        [
            (
                hk.arm_forward_kinematics(g + h * e)[0][2]
                - hk.arm_forward_kinematics(g - h * e)[0][2]
            )
            / (2 * h)
            for e in np.eye(7)
        ]
    )
    n = grad / np.linalg.norm(grad)
    cov = task.initial_policy().cov
    floor = (0.1 * task.exploration_std[:7].mean()) ** 2
    assert n @ cov[:7, :7] @ n == pytest.approx(floor, rel=1e-6)
    assert n @ cov[7:14, 7:14] @ n == pytest.approx(
        (0.1 * task.exploration_std[7:14].mean()) ** 2, rel=1e-6
    )
    np.testing.assert_allclose(np.diag(cov)[6], task.exploration_std[6] ** 2 + floor, rtol=1e-3)


def test_tau_outside_range_is_a_reported_failure(task):
    omega = task.demo_omega.copy()
    omega[-1] = 0.1
    s = np.array([2.0, 0.75, 0.5])
    with pytest.warns(RuntimeWarning, match="tau"):
        traj = task.rollout(omega, s)
    assert traj.failed
    assert task.reward(traj, s) == task.worst_reward


def test_real_setting_observes_smooths_and_is_seeded(real):
    s = np.array([1.8, 0.6, 0.3])
    a = real.rollout(real.demo_omega, s, rng=1)
    b = real.rollout(real.demo_omega, s, rng=1)
    c = real.rollout(real.demo_omega, s, rng=2)
    t_obs = a.signals["observation_times"]
    np.testing.assert_allclose(np.diff(t_obs), 1.0 / 30.0)
    for key in ("control_puck_observed", "target_puck_observed"):
        np.testing.assert_array_equal(a.signals[key], b.signals[key])
        assert not np.array_equal(a.signals[key], c.signals[key])
        assert a.signals[key].shape == (t_obs.size, 2)
    np.testing.assert_array_equal(a.signals["control_puck"], c.signals["control_puck"])
    # observation noise has the documented standard deviation around the true track
    truth = np.column_stack(
        [np.interp(t_obs, a.signals["puck_times"], a.signals["control_puck"][:, i]) for i in (0, 1)]
    )
    err = a.signals["control_puck_observed"] - truth
    assert err.std() == pytest.approx(hk.OBSERVATION_NOISE, rel=0.25)
    # the smoothed-observation reward is close to the true one, closer than the raw one
    r_true = _reward(a.signals["control_puck"], a.signals["target_puck"], s)
    r_obs = real.reward(a, s)
    assert abs(r_obs - r_true) < 0.03
    # without observations the real-robot reward refuses the trajectory
    bare = Trajectory(
        a.times,
        a.states,
        a.controls,
        signals={k: v for k, v in a.signals.items() if "observ" not in k},
    )
    with pytest.raises(ValueError, match="trajectory"):
        real.reward(bare, s)


def test_noise_free_observation_matches_truth():
    quiet = make("hockey-real", observation=hk.Observation(noise=0.0))
    s = np.array([1.8, 0.6, 0.3])
    traj = quiet.rollout(quiet.demo_omega, s, rng=0)
    r_true = _reward(traj.signals["control_puck"], traj.signals["target_puck"], s)
    assert quiet.reward(traj, s) == pytest.approx(r_true, abs=0.01)


def test_same_seed_same_rollout_and_failure_free_exploration(task):
    rng = np.random.default_rng(3)
    s = task.sample_context(rng, n=4)
    omegas = task.initial_policy().sample(s, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for w, c in zip(omegas, s, strict=True):
            a, b = task.rollout(w, c, rng=9), task.rollout(w, c, rng=9)
            assert not a.failed
            for key in a.signals:
                np.testing.assert_array_equal(a.signals[key], b.signals[key])
            assert a.info == b.info


def test_blade_rests_on_the_table_instead_of_passing_through(task):
    """The blade–table contact: over exploration samples (half of which aim the blade below the
    surface, which without the contact went up to 2 cm through it) the lowest blade corner stays
    within the contact's soft penetration, and a stroke aimed 2 cm into the table is stopped."""
    rng = np.random.default_rng(0)
    policy = task.initial_policy()
    lowest = []
    for _ in range(30):
        s = task.context_low + rng.random(3) * (task.context_high - task.context_low)
        traj = task.rollout(policy.sample(s, rng=rng), s, rng=rng)
        lowest.append(traj.info["blade_lowest"])
    assert min(lowest) > -0.002
    # the table's geom collides with the blade and nothing else
    model = task.model
    table = model.geom("table").id
    blade = model.geom("blade").id
    others = [g for g in range(model.ngeom) if g not in (table, blade)]
    assert model.geom_contype[table] & model.geom_conaffinity[blade]
    for g in others:
        assert not (model.geom_contype[g] & model.geom_conaffinity[table])
        assert not (model.geom_contype[table] & model.geom_conaffinity[g])
    # aim the demonstrated goal posture 2 cm lower: the blade slides on the surface
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = task.demo_omega[: hk.N_JOINTS]
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, hk.N_JOINTS))
    mujoco.mj_jacSite(model, data, jac, None, model.site("blade").id)
    omega = task.demo_omega.copy()
    omega[: hk.N_JOINTS] -= np.linalg.pinv(jac[2:3]) @ np.array([0.02])
    assert task.rollout(omega, [2.0, 0.75, 0.5], rng=0).info["blade_lowest"] > -0.002


def test_initial_policy_hits_span_the_required_displacements(task):
    """Coverage of the initial exploration: of 100 sampled shots some hit the
    target puck, and their displacements span the context's d* ∈ [0, 1] m."""
    policy, rng = task.initial_policy(), np.random.default_rng(0)
    moved = []
    for _ in range(100):
        s = task.sample_context(rng)
        traj = task.rollout(policy.sample(s, rng), s, rng)
        assert not traj.failed
        if traj.info["hit"]:
            moved.append(np.linalg.norm(traj.info["displacement"]))
    assert 5 <= len(moved) <= 30
    lo, hi = np.percentile(moved, [5, 95])
    assert lo <= task.context_low[2] + 0.2 and hi >= task.context_high[2]
