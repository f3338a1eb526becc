"""Tests of the DMP (Eqs. 2.21–2.23): closed forms, time scaling, fitting, parameter views."""

import warnings

import numpy as np
import pytest
from _tolerances import fp_tol
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from skillkit.policies.dmp import DMP, DMPParameters


def demo(n_joints=3, duration=1.2, n=1201, end_velocity=0.0):
    """Smooth multi-joint demonstration with analytic derivatives (not the ch2 one).

    q_j(t) = a_j sin(w_j t) + b_j t^2 + c_j t, optionally ending with velocity
    ``end_velocity`` on every joint (through the c_j term).
    """
    t = np.linspace(0.0, duration, n)
    j = np.arange(n_joints)
    a, w, b = 0.3 + 0.1 * j, 2.0 + 1.5 * j, 0.4 - 0.3 * j
    c = end_velocity - (a * w * np.cos(w * duration) + 2 * b * duration)
    q = a * np.sin(w * t[:, None]) + b * t[:, None] ** 2 + c * t[:, None] + 0.1 * j
    qd = a * w * np.cos(w * t[:, None]) + 2 * b * t[:, None] + c
    qdd = -a * w**2 * np.sin(w * t[:, None]) + 2 * b + 0 * t[:, None]
    return t, q, qd, qdd


def rmse_fraction(y, ref):
    return np.sqrt(np.mean((y - ref) ** 2, axis=0)) / np.ptp(ref, axis=0)


def critically_damped(t, x0, xd0, goal, goal_velocity, t_end, omega):
    """Closed form of e'' = -omega^2 e - 2 omega e' for e = x - g_t, g_t = g + gd (t - t_end)."""
    g_t = goal + goal_velocity * (t[:, None] - t_end)
    e0 = x0 - (goal - goal_velocity * t_end)
    ed0 = xd0 - goal_velocity
    c2 = ed0 + omega * e0
    decay = np.exp(-omega * t[:, None])
    e = (e0 + c2 * t[:, None]) * decay
    ed = (c2 - omega * (e0 + c2 * t[:, None])) * decay
    edd = (-2 * omega * c2 + omega**2 * (e0 + c2 * t[:, None])) * decay
    return g_t + e, goal_velocity + ed, edd


def _rollout_tol(q, tau, h, alpha_x=25.0):
    """Round-off of one rollout: the recursion y_n = tr y_(n-1) − det y_(n-2) + r_n rounds
    a few ε |q| per step (and tr, det from the 12-term Taylor expm carry a few ε more);
    errors propagate through the critically damped double pole ρ = exp(−ω h), ω = τ α_x / 2,
    whose impulse response (k + 1) ρᵏ sums to 1 / (1 − ρ)²; absolute."""
    rho = np.exp(-tau * alpha_x / 2 * h)
    return fp_tol(6, scale=float(np.abs(q).max()), cond=1 / (1 - rho) ** 2)


# ----------------------------------------------------------------- closed forms
@pytest.mark.parametrize("tau", [1.0, 0.5, 1.7])
def test_without_forcing_is_a_critically_damped_spring(tau):
    dmp = DMP(2, alpha_x=25.0, beta_x=25.0 / 4, duration=1.3)
    q0, qd0, g, gd = np.array([0.3, -1.0]), np.array([0.5, 2.0]), np.array([1.2, 0.4]), np.zeros(2)
    t = dmp.grid(4.0)
    q, qd, qdd = dmp.rollout(4.0, q0, qd0, goal=g, tau=tau)
    ref = critically_damped(t, q0, qd0, g, gd, 1.3 / tau, omega=tau * 25.0 / 2)
    for got, want in zip((q, qd, qdd), ref, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    np.testing.assert_allclose(q[-1], g, atol=1e-6)  # reaches the attractor g


def test_goal_velocity_is_reached_at_the_nominal_end():
    dmp = DMP(2, duration=1.0)
    q0, g, gd = np.zeros(2), np.array([1.0, -0.5]), np.array([2.0, -1.0])
    t = dmp.grid(1.5)
    q, qd, _ = dmp.rollout(1.5, q0, goal=g, goal_velocity=gd)
    ref_q, ref_qd, _ = critically_damped(t, q0, np.zeros(2), g, gd, 1.0, omega=12.5)
    # u is linear in t (no forcing), so the first-order hold is exact: round-off only.
    np.testing.assert_allclose(q, ref_q, rtol=0, atol=_rollout_tol(ref_q, 1.0, dmp.dt))
    np.testing.assert_allclose(qd, ref_qd, atol=1e-9)
    end = np.searchsorted(t, 1.0)
    np.testing.assert_allclose(q[end], g, atol=1e-4)
    np.testing.assert_allclose(qd[end], gd, atol=1e-3)


def test_single_basis_forcing_matches_closed_form():
    # K = 1: phi(z) = z, so f = v exp(-tau alpha_z t) and the ODE has an exponential input.
    tau, alpha_z, v, g, x0 = 1.3, 4.0, 30.0, 0.7, -0.2
    dmp = DMP(1, n_basis=1, alpha_z=alpha_z, dt=5e-4)
    t = dmp.grid(1.5)
    q, _, _ = dmp.rollout(1.5, [x0], goal=[g], tau=tau, weights=[[v]])
    k, c, lam = tau**2 * 25 * 6.25, tau * 25.0, tau * alpha_z
    omega = c / 2
    amp = tau**2 * v / (lam**2 - c * lam + k)  # particular solution amp * exp(-lam t)
    c1 = x0 - g - amp
    c2 = 0.0 + lam * amp + omega * c1
    ref = g + amp * np.exp(-lam * t) + (c1 + c2 * t) * np.exp(-omega * t)
    np.testing.assert_allclose(q[:, 0], ref, atol=1e-7)


def test_phase_solves_eq_2_22():
    dmp = DMP(1, alpha_z=3.5)
    t = np.linspace(0, 2, 2001)
    for tau in (1.0, 0.6, 2.0):
        z = dmp.phase(t, tau)
        assert z[0] == 1.0
        dz = np.gradient(z, t, edge_order=2)
        # Truncation error of the second-order differences: h²/6 |z‴| inside, h²/3 |z‴| at
        # the ends, with z‴ = −(τα)³ z: relative (τα h)²/3 of |ż| = τα z; twice that (it was
        # rtol=2e-5 against 1.6e-5 at τ = 2).
        h = t[1] - t[0]
        np.testing.assert_allclose(dz, -tau * 3.5 * z, rtol=2 * (tau * 3.5 * h) ** 2 / 3)
        # phase() evaluates the same expression exp((−τ α_z) t): an ulp at most (SIMD exp).
        np.testing.assert_allclose(z, np.exp(-tau * 3.5 * t), rtol=fp_tol(1))


def test_basis_sums_to_phase_and_centres_span_the_duration():
    dmp = DMP(1, n_basis=7, alpha_z=2.0, duration=1.5)
    z = np.linspace(0, 1, 50)
    phi = dmp.basis(z)
    assert phi.shape == (50, 7)
    # Σ_i ψ_i / Σ_j ψ_j · z: a K-term sum, a division and a product on values ≤ z ≤ 1.
    np.testing.assert_allclose(phi.sum(axis=1), z, rtol=0, atol=fp_tol(7 + 2, scale=z.max()))
    np.testing.assert_allclose(dmp.centers[[0, -1]], [1.0, np.exp(-3.0)])
    assert np.all(dmp.widths > 0)


def test_rollout_agrees_with_an_independent_ode_solver_at_second_order():
    t, q, qd, qdd = demo(n_joints=2)
    dmp = DMP(2).fit(t, q, qd, qdd)
    tau, g, gd = dmp.tau, dmp.goal, dmp.goal_velocity
    k, c = tau**2 * 25 * 6.25, tau * 25.0

    def rhs(time, y):
        x, xd = y[:2], y[2:]
        g_t = g + gd * (time - dmp.duration / tau)
        f = dmp.forcing(np.array([time]))[0]
        return np.concatenate([xd, k * (g_t - x) + c * (gd - xd) + tau**2 * f])

    sol = solve_ivp(
        rhs,
        (0, t[-1]),
        np.concatenate([q[0], qd[0]]),
        t_eval=t[::60],
        rtol=1e-12,
        atol=1e-13,
        method="DOP853",
    )
    errors = []
    for dt in (2e-3, 1e-3):
        got, got_d, _ = _with_dt(dmp, dt).rollout(t[::60], q[0], qd[0])
        errors.append(max(np.abs(got - sol.y[:2].T).max(), np.abs(got_d - sol.y[2:].T).max()))
    assert errors[1] < 1e-5
    assert 3.5 < errors[0] / errors[1] < 4.5  # first-order hold: O(dt^2)


def _with_dt(dmp, dt):
    new = dmp.replace()
    new.dt = dt
    return new


# --------------------------------------------------------------------- fitting
def test_fitted_dmp_reproduces_demonstration_and_ends_at_goal():
    t, q, qd, qdd = demo()
    dmp = DMP(3, n_basis=10).fit(t, q, qd, qdd)
    np.testing.assert_array_equal(dmp.goal, q[-1])
    got, _, _ = dmp.rollout(t, q[0], qd[0])
    assert np.all(rmse_fraction(got, q) < 0.01)
    assert np.all(np.abs(got[-1] - dmp.goal) < 0.01 * np.ptp(q, axis=0))
    # long after the movement (z = exp(-24), so f has vanished) the DMP rests at g
    later, _, _ = dmp.rollout(8.0, q[0], qd[0])
    np.testing.assert_allclose(later[-1], dmp.goal, atol=1e-6)
    # the forcing term matters: without it the demonstration is not reproduced
    free, _, _ = dmp.rollout(t, q[0], qd[0], weights=np.zeros_like(dmp.weights))
    assert np.all(rmse_fraction(free, q) > 0.05)


def test_fit_weights_solve_eq_2_23_normal_equations():
    t, q, qd, qdd = demo(n_joints=1)
    dmp = DMP(1, n_basis=6).fit(t, q, qd, qdd)
    phi = dmp.basis(dmp.phase(t))
    y = qdd[:, 0] - 25 * (6.25 * (q[-1, 0] - q[:, 0]) - qd[:, 0])  # Eq. 2.23 at tau = 1
    v = np.linalg.solve(phi.T @ phi, phi.T @ y)
    np.testing.assert_allclose(dmp.weights[0], v, rtol=1e-8, atol=1e-8 * np.abs(v).max())


def test_multi_joint_fit_equals_per_joint_fits():
    t, q, qd, qdd = demo(n_joints=3, end_velocity=0.4)
    joint = DMP(3).fit(t, q, qd, qdd, tau=1.4, ridge=1e-6)
    q_all, _, _ = joint.rollout(t, q[0], qd[0])
    # Both fits solve min ‖A v − b‖ with the same (ridge-augmented) A and bitwise the same
    # target columns; lstsq on 3 or 1 right-hand sides rounds differently, each within the
    # least-squares forward error κ N ε (2‖v‖ + (κ + 1)‖r‖ / ‖A‖) (Higham, Thm 20.1).
    phi = joint.basis(joint.phase(t - t[0], 1.4))
    A = np.vstack([phi, np.sqrt(1e-6) * np.eye(joint.n_basis)])
    kappa, a_norm = np.linalg.cond(A), np.linalg.norm(A, 2)
    k = 1.4**2 * 25 * 6.25
    for j in range(3):
        single = DMP(1).fit(t, q[:, [j]], qd[:, [j]], qdd[:, [j]], tau=1.4, ridge=1e-6)
        v = single.weights[0]
        b = qdd[:, j] / 1.4**2 - 25 * (6.25 * (q[-1, j] + qd[-1, j] * (t - t[-1]) - q[:, j]))
        b -= 25 * (qd[-1, j] - qd[:, j]) / 1.4
        r = np.linalg.norm(np.r_[b - phi @ v, -np.sqrt(1e-6) * v])
        scale = 2 * np.linalg.norm(v) + (kappa + 1) * r / a_norm
        tol = 2 * fp_tol(len(A), scale=scale, cond=kappa)
        np.testing.assert_allclose(joint.weights[j], v, rtol=0, atol=tol)
        q_j, _, _ = single.rollout(t, q[0, [j]], qd[0, [j]])
        # The rollout is linear in v: the observed weight difference reaches q through
        # τ² φ(z)ᵀδv and the spring's static gain 1/k (a positive impulse response). Any
        # change of input also changes every rounding of the recursion: each rollout within
        # its round-off bound (with equal weights the two are bitwise equal).
        dv = joint.weights[j] - v
        tol = 1.4**2 * np.abs(phi @ dv).max() / k + 2 * _rollout_tol(q_j, 1.4, joint.dt)
        np.testing.assert_allclose(q_all[:, j], q_j[:, 0], rtol=0, atol=tol)


def test_demonstration_ending_with_velocity_reaches_goal_velocity():
    t, q, qd, qdd = demo(n_joints=2, end_velocity=1.5)
    dmp = DMP(2).fit(t, q, qd, qdd)
    # qd(T) = (a w cos wT + 2bT) + (ġ − (a w cos wT + 2bT)) in demo(): the brackets cancel,
    # 4 roundings on terms of size ≤ 2 (|a w| + 2|b| T) + ġ.
    j = np.arange(2)
    peak = float(((0.3 + 0.1 * j) * (2.0 + 1.5 * j) + 2 * np.abs(0.4 - 0.3 * j) * 1.2).max())
    tol = fp_tol(4, scale=2 * peak + 1.5)
    np.testing.assert_allclose(dmp.goal_velocity, [1.5, 1.5], rtol=0, atol=tol)
    got, got_d, _ = dmp.rollout(t, q[0], qd[0])
    assert np.all(rmse_fraction(got, q) < 0.01)
    np.testing.assert_allclose(got[-1], dmp.goal, atol=0.01 * np.ptp(q, axis=0).min())
    np.testing.assert_allclose(got_d[-1], dmp.goal_velocity, atol=0.05)


def test_doubling_tau_halves_the_duration():
    t, q, qd, qdd = demo(n_joints=2, end_velocity=0.8)
    dmp = DMP(2).fit(t, q, qd, qdd)
    slow = dmp.rollout(np.linspace(0, 2.4, 2401), q[0], qd[0])
    fast = dmp.rollout(
        np.linspace(0, 1.2, 2401), q[0], 2 * qd[0], tau=2.0, goal_velocity=2 * dmp.goal_velocity
    )
    # The same discrete system in scaled time (ω h = 12.5 · 1e-3 in both): each rollout within
    # its round-off bound.
    tol = 2 * _rollout_tol(slow[0], 1.0, 1e-3)
    np.testing.assert_allclose(fast[0], slow[0], rtol=0, atol=tol)
    np.testing.assert_allclose(fast[1], 2 * slow[1], atol=1e-9)
    np.testing.assert_allclose(fast[2], 4 * slow[2], atol=1e-7)


def test_fit_at_tau_reproduces_at_that_tau():
    t, q, qd, qdd = demo(n_joints=1)
    dmp = DMP(1).fit(t, q, qd, qdd, tau=2.0)
    assert dmp.tau == 2.0 and dmp.duration == pytest.approx(2.4)
    got, _, _ = dmp.rollout(t, q[0], qd[0])
    assert rmse_fraction(got, q)[0] < 0.01


def test_output_grid_does_not_change_the_solution():
    t, q, qd, qdd = demo(n_joints=2)
    dmp = DMP(2, dt=1e-3).fit(t, q, qd, qdd)
    fine, _, _ = dmp.rollout(t, q[0], qd[0])  # 1 ms steps
    coarse, _, _ = dmp.rollout(t[::30], q[0], qd[0])  # 30 ms output, 1 ms substeps
    # Both integrate on the same 1 ms grid (linspace(0, 1.2, 1201)) with the same inputs and
    # filter: equal by construction, output every 30th step.
    np.testing.assert_array_equal(coarse, fine[::30])
    assert dmp.rollout(t[:1], q[0])[0].shape == (1, 2)


def test_rank_deficient_fit_warns_and_ridge_fixes_it():
    t, q, qd, qdd = demo(n_joints=1, n=6)
    with pytest.warns(RuntimeWarning, match="rank"):
        DMP(1, n_basis=10).fit(t, q, qd, qdd)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        DMP(1, n_basis=10).fit(t, q, qd, qdd, ridge=1e-8)


@settings(max_examples=25, deadline=None)
@given(st.floats(-2, 2), st.floats(0.3, 3.0), st.integers(0, 2**32 - 1))
def test_rollout_is_affine_in_start_goal_and_weights(a, tau, seed):
    rng = np.random.default_rng(seed)
    dmp = DMP(2, n_basis=4, dt=5e-3)
    p = [
        (
            rng.normal(size=2),
            rng.normal(size=2),
            rng.normal(size=2),
            rng.normal(size=2),
            10 * rng.normal(size=(2, 4)),
        )
        for _ in range(2)
    ]
    mix = [a * x + (1 - a) * y for x, y in zip(*p, strict=True)]
    out = [
        dmp.rollout(0.5, q0, qd0, goal=g, goal_velocity=gd, tau=tau, weights=w)[0]
        for q0, qd0, g, gd, w in (*p, mix)
    ]
    np.testing.assert_allclose(out[2], a * out[0] + (1 - a) * out[1], atol=1e-9 * (1 + abs(a)))


# ------------------------------------------------------------ parameter vector
def test_parameter_vector_round_trip():
    t, q, qd, qdd = demo(n_joints=3)
    dmp = DMP(3, n_basis=5).fit(t, q, qd, qdd)
    view = DMPParameters(dmp, learn=("tau", "goal", "weights", "goal_velocity"))
    assert view.learn == ("weights", "goal", "goal_velocity", "tau")  # canonical order
    assert view.dim == 3 * 5 + 3 + 3 + 1 == len(view.names)
    assert view.names[0] == "w[0,0]" and view.names[5] == "w[1,0]" and view.names[-1] == "tau"
    omega = view.to_vector()
    np.testing.assert_array_equal(omega[:15], dmp.weights.ravel())
    rng = np.random.default_rng(0)
    new_omega = omega + 0.1 * rng.normal(size=view.dim)
    new = view.from_vector(new_omega)
    np.testing.assert_array_equal(view.to_vector(new), new_omega)
    np.testing.assert_array_equal(new.goal, new_omega[15:18])
    np.testing.assert_array_equal(new.goal_velocity, new_omega[18:21])
    assert new.tau == new_omega[-1]
    np.testing.assert_array_equal(view.to_vector(), omega)  # template untouched
    new.weights[0, 0] = 123.0
    assert dmp.weights[0, 0] != 123.0  # copies do not share arrays


def test_hockey_view_keeps_weights_fixed():
    """Sec. 3.4.2: 7 joints, learned g, ġ and τ: 15 parameters (table tennis: 8 joints, 17)."""
    t, q, qd, qdd = demo(n_joints=7)
    dmp = DMP(7).fit(t, q, qd, qdd)
    view = DMPParameters(dmp, learn=("goal", "goal_velocity", "tau"))
    assert view.dim == 15
    new = view.from_vector(np.concatenate([dmp.goal + 0.1, np.ones(7), [1.2]]))
    np.testing.assert_array_equal(new.weights, dmp.weights)
    np.testing.assert_allclose(new.goal, dmp.goal + 0.1)
    assert new.tau == 1.2


# ------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"n_joints": 0}, "n_joints"),
        ({"n_basis": 0}, "n_basis"),
        ({"n_basis": 2.5}, "n_basis"),
        ({"n_basis": True}, "n_basis"),
        ({"alpha_x": -1.0}, "alpha_x"),
        ({"dt": 0.0}, "dt"),
        ({"alpha_z": float("nan")}, "alpha_z"),
        ({"duration": -1.0}, "duration"),
    ],
)
def test_bad_construction_raises(kwargs, name):
    args = {"n_joints": 1, **kwargs}
    with pytest.raises(ValueError, match=name):
        DMP(**args)


def test_bad_fit_input_raises():
    t, q, qd, qdd = demo(n_joints=2)
    dmp = DMP(2)
    with pytest.raises(ValueError, match="q: expected shape"):
        dmp.fit(t, q[:, :1], qd, qdd)
    with pytest.raises(ValueError, match="qdd: expected shape"):
        dmp.fit(t, q, qd, qdd[:-1])
    bad = qd.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="qd: contains 1 non-finite"):
        dmp.fit(t, q, bad, qdd)
    with pytest.raises(ValueError, match="times: expected strictly increasing"):
        dmp.fit(t[::-1], q, qd, qdd)
    with pytest.raises(ValueError, match="tau"):
        dmp.fit(t, q, qd, qdd, tau=0.0)
    with pytest.raises(ValueError, match="ridge"):
        dmp.fit(t, q, qd, qdd, ridge=-1.0)
    assert dmp.goal is None  # nothing was changed by the failed calls


def test_bad_rollout_input_raises():
    dmp = DMP(2)
    with pytest.raises(ValueError, match="goal: the DMP has no goal"):
        dmp.rollout(1.0, np.zeros(2))
    dmp.goal = np.ones(2)
    with pytest.raises(ValueError, match="q0: expected shape"):
        dmp.rollout(1.0, np.zeros(3))
    with pytest.raises(ValueError, match="tau"):
        dmp.rollout(1.0, np.zeros(2), tau=-1.0)
    with pytest.raises(ValueError, match="weights: expected shape"):
        dmp.rollout(1.0, np.zeros(2), weights=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="times: expected uniformly spaced"):
        dmp.rollout([0.0, 0.1, 0.3], np.zeros(2))
    with pytest.raises(ValueError, match="duration"):
        dmp.rollout(0.0, np.zeros(2))
    with pytest.raises(ValueError, match="goal_velocity: contains"):
        dmp.rollout(1.0, np.zeros(2), goal_velocity=[np.inf, 0.0])


def test_bad_parameter_view_input_raises():
    with pytest.raises(ValueError, match="dmp: has no goal"):
        DMPParameters(DMP(2), learn=("goal",))
    dmp = DMP(2)
    dmp.goal = np.zeros(2)
    with pytest.raises(ValueError, match="learn"):
        DMPParameters(dmp, learn=("goal", "stiffness"))
    with pytest.raises(ValueError, match="learn"):
        DMPParameters(dmp, learn=())
    with pytest.raises(ValueError, match="dmp: expected a DMP"):
        DMPParameters("dmp")
    view = DMPParameters(dmp, learn=("goal", "tau"))
    with pytest.raises(ValueError, match="omega: expected shape"):
        view.from_vector(np.zeros(4))
    with pytest.raises(ValueError, match="omega: its tau entry"):
        view.from_vector(np.array([0.0, 0.0, -0.1]))


@pytest.mark.parametrize("scale", [1e-3, 0.3, 40.0])
def test_small_matrix_exponential_matches_scipy(scale):
    from scipy.linalg import expm, expm_cond

    from skillkit.policies.dmp import _expm_small

    m = np.random.default_rng(1).normal(size=(4, 4)) * scale
    want = expm(m)
    # Scaling and squaring: 12 Taylor terms and s squarings of 4×4 products, each n ε relative
    # to ‖exp(m)‖, times exp's relative condition number (at least 1: the Taylor sum's I);
    # two implementations, each within the bound.
    s = max(0, int(np.ceil(np.log2(np.abs(m).sum(axis=0).max() / 0.25))))
    n_ops, cond = 4 * (s + 13), max(1.0, expm_cond(m))
    tol = 2 * fp_tol(n_ops, scale=np.linalg.norm(want), cond=cond)
    np.testing.assert_allclose(_expm_small(m), want, rtol=0, atol=tol)


def test_forcing_target_needs_a_fitted_dmp_and_increasing_times():
    dmp = DMP(n_joints=1, n_basis=5)
    t = np.linspace(0.0, 1.0, 11)
    q = np.zeros((11, 1))
    with pytest.raises(ValueError, match="no goal"):
        dmp.forcing_target(t, q, q, q)
    dmp.fit(t, np.sin(t)[:, None], np.cos(t)[:, None], -np.sin(t)[:, None], ridge=1e-6)
    with pytest.raises(ValueError, match="times"):
        dmp.forcing_target(t[::-1], q, q, q)
    with pytest.raises(ValueError, match="qd"):
        dmp.forcing_target(t, q, np.zeros((11, 2)), q)
