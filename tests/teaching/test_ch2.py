"""skillkit.teaching.ch2: the Chapter 2 step-through pieces agree with closed forms and
with the library computed another way."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skillkit.experiments.ch2 import reach_demonstration
from skillkit.experiments.ch2_gp import fig2_7_function, fig2_12_function
from skillkit.models.gp import ExactGP, GPNumericalWarning, record_numerical_events
from skillkit.policies.dmp import DMP
from skillkit.teaching import ch2
from tests._tolerances import fp_tol

EPS = np.finfo(float).eps


def _trace(fig, name: str):
    return next(t for t in fig.data if t.name == name)


@pytest.fixture(scope="module")
def reach():
    times, q, qd, qdd = reach_demonstration()
    return times, q, qd, qdd, DMP(n_joints=1, n_basis=10).fit(times, q, qd, qdd)


@pytest.fixture(scope="module")
def gp40():
    x, y = ch2.noisy_samples(40, noise_std=0.1, seed=26)
    return x, y, ExactGP(additive_noise=0.0).fit(x, y, rng=0)


# ------------------------------------------------------------------------------- DMPs
def test_phase_figure_marks_each_centre_where_the_phase_passes_it(reach):
    times, *_, dmp = reach
    fig = ch2.phase_figure(dmp, times)
    curve = fig.data[0]
    np.testing.assert_allclose(curve.y, np.exp(-dmp.tau * dmp.alpha_z * times), rtol=fp_tol(4))
    centres = _trace(fig, f"basis centres c_i ({dmp.n_basis})")
    np.testing.assert_allclose(centres.y, dmp.centers, rtol=fp_tol(4))
    # round trip t_c = −ln c / (τ α_z), z = exp(−τ α_z t_c): the exponent comes back off by
    # a few ε relatively, i.e. by a few ε |ln c| absolutely, which exp turns into a relative error
    cond = 1 + np.abs(np.log(dmp.centers)).max()
    np.testing.assert_allclose(
        dmp.phase(np.asarray(centres.x)), dmp.centers, rtol=fp_tol(5, cond=cond)
    )
    # evenly spaced in time over the nominal duration
    np.testing.assert_allclose(np.diff(centres.x), dmp.duration / (dmp.n_basis - 1), rtol=1e-9)


def test_basis_functions_sum_to_the_phase(reach):
    times, *_, dmp = reach
    fig = ch2.basis_figure(dmp, times)
    sums = [t for t in fig.data if t.name == "Σ_i φ_i = z"]
    assert len(sums) == 2  # one per panel, dashed
    over_z = sums[0]
    np.testing.assert_allclose(over_z.y, over_z.x, rtol=0, atol=10 * EPS)
    np.testing.assert_allclose(sums[1].y, dmp.phase(times), rtol=0, atol=10 * EPS)
    assert all(t.line.dash == "dash" for t in sums)
    assert {f"φ_{i + 1}" for i in range(dmp.n_basis)} <= {t.name for t in fig.data}


def test_forcing_target_is_eq_2_23_and_what_fit_solves(reach):
    times, q, qd, qdd, dmp = reach
    target = dmp.forcing_target(times, q, qd, qdd)
    # tau = 1 and a demonstration ending at rest: Eq. (2.23) as printed
    g = q[-1, 0]
    printed = qdd[:, 0] - dmp.alpha_x * (dmp.beta_x * (g - q[:, 0]) - qd[:, 0])
    # the demonstration's final velocity is zero up to round-off; its moving-goal terms
    # contribute at most alpha_x (beta_x T + 1) |gd|
    gd = abs(dmp.goal_velocity[0])
    tol = 100 * EPS * np.abs(printed).max() + dmp.alpha_x * (dmp.beta_x * dmp.duration + 1) * gd
    np.testing.assert_allclose(target[:, 0], printed, rtol=0, atol=tol)
    # least squares of the basis against the target gives DMP.fit's weights
    phi = dmp.basis(dmp.phase(times))
    v = np.linalg.lstsq(phi, target, rcond=None)[0]
    tol = 1e3 * EPS * np.linalg.cond(phi) * np.abs(dmp.weights).max()
    np.testing.assert_allclose(v.T, dmp.weights, rtol=0, atol=tol)


def test_forcing_target_with_moving_goal_and_time_scaling():
    times, q, qd, qdd = reach_demonstration()
    cut = slice(0, 601)  # ends moving: a non-zero goal velocity
    t, q, qd, qdd = times[cut], q[cut], qd[cut], qdd[cut]
    dmp = DMP(n_joints=1, n_basis=8).fit(t, q, qd, qdd, tau=1.5)
    assert abs(dmp.goal_velocity[0]) > 0.1
    target = dmp.forcing_target(t, q, qd, qdd)
    phi = dmp.basis(dmp.phase(t))
    v = np.linalg.lstsq(phi, target, rcond=None)[0]
    tol = 1e3 * EPS * np.linalg.cond(phi) * np.abs(dmp.weights).max()
    np.testing.assert_allclose(v.T, dmp.weights, rtol=0, atol=tol)


def test_forcing_figure_draws_the_fit_the_target_and_each_term(reach):
    times, q, qd, qdd, dmp = reach
    fig = ch2.forcing_figure(dmp, times, q, qd, qdd)
    target = _trace(fig, "target Y (Eq. 2.23)")
    assert target.line.dash == "dash"
    np.testing.assert_allclose(target.y, dmp.forcing_target(times, q, qd, qdd)[:, 0])
    fit = _trace(fig, "fitted f = φᵀv, 10 weights")
    np.testing.assert_allclose(fit.y, dmp.forcing(times)[:, 0], rtol=fp_tol(4 * dmp.n_basis))
    phi = dmp.basis(dmp.phase(times))
    for i in range(dmp.n_basis):
        y = np.asarray(_trace(fig, f"φ_{i + 1} v_{i + 1}").y, dtype=float)
        shown = np.isfinite(y)
        np.testing.assert_allclose(
            y[shown], phi[shown, i] * dmp.weights[0, i], rtol=fp_tol(4 * dmp.n_basis)
        )
        assert shown[np.argmax(phi[:, i])]  # each term is drawn where its bump peaks


def test_demonstration_is_dashed_and_the_fit_improves_with_more_weights(reach):
    times, q, *_ = reach
    fig = ch2.demonstration_figure(times, q[:, 0], {"copy": q[:, 0]})
    assert _trace(fig, "demonstration").line.dash == "dash"
    assert _trace(fig, "copy").line.dash in (None, "solid")
    rmse = []
    for k in (1, 3, 10):
        fig = ch2.dmp_fit_figure(k)
        demo = np.asarray(_trace(fig, "demonstration").y)
        fit = np.asarray(_trace(fig, f"DMP, {k} weights").y)
        rmse.append(np.sqrt(np.mean((fit - demo) ** 2)))
        assert f"RMSE {rmse[-1]:.2g} rad" in fig.layout.title.text
    assert rmse[0] > rmse[1] > rmse[2]


# -------------------------------------------------------------------------------- GPs
def test_noisy_samples_are_nested_and_reproducible():
    x8, y8 = ch2.noisy_samples(8, seed=3)
    x40, y40 = ch2.noisy_samples(40, seed=3)
    np.testing.assert_array_equal(x8, x40[:8])
    np.testing.assert_array_equal(y8, y40[:8])
    np.testing.assert_array_equal(ch2.noisy_samples(8, seed=3)[1], y8)
    x, f = ch2.noisy_samples(5, noise_std=0.0, function=fig2_7_function, low=-1, high=1)
    np.testing.assert_array_equal(f, fig2_7_function(x[:, 0]))
    assert x.shape == (5, 1) and np.all(np.abs(x) <= 1)


def test_gp_with_is_the_closed_form_posterior():
    x, y = ch2.noisy_samples(12, seed=1)
    ls, sf2, sn2 = 0.8, 0.6, 0.02
    gp = ch2.gp_with(x, y, lengthscale=ls, signal_var=sf2, noise_var=sn2)
    h = gp.hyperparameters
    # round trip through the standardisation (÷ s², × s²) and gpytorch's softplus constraint
    # raw = softplus⁻¹(v): the raw value's round-off ε |raw| comes back as a relative error of
    # at most ε |raw|; ~8 flops with condition 1 + |raw| (the noise floor is 1e-6 of v, no
    # cancellation)
    v = np.array([ls, sf2, sn2]) / np.array([1.0, *(2 * [float(gp.y_scale[0]) ** 2])])
    rel = fp_tol(8, cond=1 + np.abs(np.log(np.expm1(v))).max())
    np.testing.assert_allclose(
        [h["lengthscale"][0, 0], h["outputscale"][0], h["noise"][0]], [ls, sf2, sn2], rtol=rel
    )
    # Eqs. 2.26-2.27 with the training mean as prior mean (ExactGP standardises the targets)
    xs = np.linspace(-5, 5, 7)[:, None]
    k = lambda a, b: sf2 * np.exp(-0.5 * (a - b.T) ** 2 / ls**2)  # noqa: E731
    A = k(x, x) + sn2 * np.eye(len(x))
    m = y.mean()
    mean = m + k(xs, x) @ np.linalg.solve(A, y - m)
    var = sf2 + sn2 - np.einsum("ij,ji->i", k(xs, x), np.linalg.solve(A, k(x, xs)))
    got_mean, got_var = gp.predict(xs)
    tol = 100 * EPS * np.linalg.cond(A)
    np.testing.assert_allclose(got_mean, mean, rtol=0, atol=tol * np.abs(y).max())
    np.testing.assert_allclose(got_var, var, rtol=0, atol=tol * (sf2 + sn2))


def test_noise_profile_is_the_library_likelihood_maximised(gp40):
    x, y, gp = gp40
    grid = np.array([1e-3, 0.01, 0.1])
    prof = ch2.noise_profile(x, y, grid)
    # each value is the log ML (2.28) of an ExactGP at the maximising (l, sf2) and that noise
    for i, nv in enumerate(grid):
        at = ch2.gp_with(
            x, y, lengthscale=prof.lengthscale[i], signal_var=prof.signal_var[i], noise_var=nv
        )
        lml = float(at.diagnostics["log_marginal_likelihood"][0])
        assert abs(prof.log_ml[i] - lml) <= 1e-9 * max(1.0, abs(lml))
    # a maximum over (l, sf2): at the fit's own noise it is at least the fit's likelihood
    noise = gp.hyperparameters["noise"]
    fitted = float(gp.diagnostics["log_marginal_likelihood"][0])
    assert ch2.noise_profile(x, y, noise).log_ml[0] >= fitted - 1e-6


def test_noise_profile_peaks_near_the_true_noise_with_many_points():
    x, y = ch2.noisy_samples(100, noise_std=0.1, seed=5)
    prof = ch2.noise_profile(x, y, np.geomspace(1e-3, 0.1, 21))
    # relative standard error of a variance from 100 values: sqrt(2/100) = 14%; allow ~4 s.e.
    assert abs(np.log(prof.best / 0.01)) < np.log(1 + 4 * np.sqrt(2 / 100))


def test_noise_profile_figure_marks_each_maximum(gp40):
    x, y, _ = gp40
    x8, y8 = x[:8], y[:8]
    fig = ch2.noise_profile_figure({"8": (x8, y8), "40": (x, y)}, true_noise_var=0.01)
    curves = [t for t in fig.data if t.name == "log p(y | X, θ), maximised over ℓ and σ_f²"]
    assert len(curves) == 2
    for c in curves:
        assert max(c.y) == 0.0  # relative to its maximum
    assert all(t.line.dash == "dash" for t in fig.data if t.name == "true σ_ε² = 0.01")


def test_noise_by_size_table_counts_and_orders():
    with warnings.catch_warnings():
        warnings.simplefilter("error", GPNumericalWarning)
        t = ch2.noise_by_size_table(sizes=(8, 20), n_draws=4, seed=0)
    assert list(t.index) == [8, 20]
    assert np.all(t["10th percentile"] <= t["learned σ_ε², median"])
    assert np.all(t["learned σ_ε², median"] <= t["90th percentile"])
    assert np.all((t["at the floor (of 4)"] >= 0) & (t["at the floor (of 4)"] <= 4))
    np.testing.assert_allclose(t["median / true"], t["learned σ_ε², median"] / 0.01, rtol=5e-3)
    again = ch2.noise_by_size_table(sizes=(8, 20), n_draws=4, seed=0)
    assert t.equals(again)  # same seed, same table


def test_hyperparameter_table_and_figure(gp40):
    x, y, gp = gp40
    with record_numerical_events():
        gp8 = ExactGP(additive_noise=0.0, tolerance=0.0).fit(x[:8], y[:8], rng=0)
    t = ch2.hyperparameter_table({"8": gp8, "40": gp}, true_noise_var=0.01)
    assert t.loc["8", "noise at its floor"] == "yes" and t.loc["40", "noise at its floor"] == "no"
    # four significant digits
    np.testing.assert_allclose(
        t.loc["40", "noise variance σ_ε²"], gp.hyperparameters["noise"][0], rtol=5e-4
    )
    assert list(t["points N"]) == [8, 40]
    fig = ch2.hyperparameter_figure(x, y, gp, factor=4.0)
    panels = {a.text for a in fig.layout.annotations}
    assert any(p.startswith("length-scale") for p in panels)
    assert any(p.startswith("noise variance") for p in panels)
    learned = [t for t in fig.data if t.name == "learned θ"]
    assert len(learned) == 3
    xs = np.asarray(learned[0].x)
    # the learned-θ band is gp.predict on the same floats (xs round-trips through the trace's
    # list exactly): equal exactly
    np.testing.assert_array_equal(learned[0].y, np.ravel(gp.predict(xs[:, None])[0]))


def test_gp_posterior_widget_never_warns():
    with warnings.catch_warnings():
        warnings.simplefilter("error", GPNumericalWarning)
        fig = ch2.gp_posterior_figure(10.0, 1e-4, 100)
        ch2.gp_posterior_figure(0.1, 1.0, 1)
    assert "100 points" in fig.layout.title.text


# ------------------------------------------------------------------- moment matching
@pytest.fixture(scope="module")
def check():
    x, y = ch2.noisy_samples(40, function=fig2_7_function, noise_std=0.05, low=-2.5, high=2.5)
    gp = ExactGP(additive_noise=0.0).fit(x, y, rng=0)
    return gp, ch2.moment_matching_check(gp, 0.4, 0.25, n_samples=40_000, rng=0)


def test_moment_matching_agrees_with_samples_within_their_error(check):
    _, c = check
    se_m, se_v = c.standard_errors()
    y = c.samples
    # √(v / n) vs √v / √n (4 roundings), and the mean of n centred squares, ≲ (16 + log₂ n) ε
    # even if the two summed them in different orders (numpy's pairwise sum: blocks of 128 in
    # 8 accumulators, then a binary tree)
    rel = fp_tol(4 + 16 + np.log2(len(y)))
    np.testing.assert_allclose(se_m, y.std() / np.sqrt(len(y)), rtol=rel)
    mm_m, mm_v = float(c.moment_matched.mean[0]), float(c.moment_matched.cov[0, 0])
    assert abs(mm_m - y.mean()) < 4 * se_m
    assert abs(mm_v - y.var()) < 4 * se_v
    t = c.table()
    assert t.iloc[0]["mean − MC [s.e.]"] == 0.0
    # the table rounds the distances to 0.1 s.e.
    assert abs(t.iloc[1]["mean − MC [s.e.]"] - (mm_m - y.mean()) / se_m) <= 0.05 + 1e-12
    assert "None" not in c.summary() and "n/a" not in c.summary()


def test_narrow_input_reduces_to_the_gp_prediction(check):
    gp, _ = check
    c = ch2.moment_matching_check(gp, 0.4, 1e-10, n_samples=10, rng=1)
    mean, var = gp.predict(np.array([[0.4]]))
    for g in (c.moment_matched, c.linearised):
        np.testing.assert_allclose(float(g.mean[0]), mean[0], rtol=1e-6)
        np.testing.assert_allclose(float(g.cov[0, 0]), var[0], rtol=1e-6)


def test_same_seed_same_samples_and_a_density(check):
    gp, c = check
    again = ch2.moment_matching_check(gp, 0.4, 0.25, n_samples=40_000, rng=0)
    np.testing.assert_array_equal(again.samples, c.samples)
    mass = np.trapezoid(c.density, c.density_grid)
    assert 0.99 < mass <= 1.0 + 1e-6
    fig = c.figure(bins=30)
    assert fig.data[0].type == "bar" and len(fig.data[0].x) == 30


# ------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda d: ch2.phase_figure("dmp", [0.0, 1.0]), "dmp"),
        (lambda d: ch2.phase_figure(d, [1.0, 0.0]), "times"),
        (lambda d: ch2.forcing_figure(d, *reach_demonstration(), joint=1), "joint"),
        (lambda d: DMP(1).forcing_target(*reach_demonstration()[:4]), "no goal"),
        (lambda d: ch2.demonstration_figure([0.0, 1.0], [0.0], {}), "demonstration"),
        (lambda d: ch2.demonstration_figure([0.0, 1.0], [0.0, 1.0], {"a": [1.0]}), "curves"),
        (lambda d: ch2.dmp_fit_figure(0), "n_basis"),
        (lambda d: ch2.noisy_samples(0), "n_points"),
        (lambda d: ch2.noisy_samples(ch2.POOL + 1), "n_points"),
        (lambda d: ch2.noisy_samples(3, low=1.0, high=0.0), "low, high"),
        (
            lambda d: ch2.gp_with(
                [[0.0], [1.0]], [0.0, 1.0], lengthscale=1, signal_var=1, noise_var=-1
            ),
            "noise_var",
        ),
        (lambda d: ch2.noise_profile([[0.0], [1.0]], [0.0, 1.0], [0.0]), "noise_vars"),
        (lambda d: ch2.noise_profile([[0.0], [1.0]], [0.0], [0.1]), "y"),
        (lambda d: ch2.noise_by_size_table(n_draws=1), "n_draws"),
        (lambda d: ch2.hyperparameter_table({"a": "gp"}), "gps"),
    ],
)
def test_bad_input_is_named(reach, call, name):
    with pytest.raises(ValueError, match=name):
        call(reach[-1])


def test_bad_moment_matching_input_is_named(check):
    gp, c = check
    with pytest.raises(ValueError, match="var"):
        ch2.moment_matching_check(gp, 0.4, 0.0)
    with pytest.raises(ValueError, match="n_samples"):
        ch2.moment_matching_check(gp, 0.4, 0.1, n_samples=1)
    with pytest.raises(ValueError, match="gp"):
        ch2.moment_matching_check("gp", 0.4, 0.1)
    with pytest.raises(ValueError, match="bins"):
        c.figure(bins=1)
    with pytest.raises(ValueError, match="factor"):
        ch2.hyperparameter_figure(gp.X.numpy(), gp.Y.numpy()[0], gp, factor=1.0)


def test_fig2_12_function_is_the_example_target():
    x, y = ch2.noisy_samples(4, noise_std=0.0)
    np.testing.assert_array_equal(y, fig2_12_function(x[:, 0]))
