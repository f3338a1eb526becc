"""Tests of the chapter-2 experiment fig2.10 (Figs. 2.9–2.11)."""

import numpy as np
import pytest
from _tolerances import fp_tol
from numpy.polynomial import Polynomial

from skillkit.experiments import judge
from skillkit.experiments.ch2 import reach_demonstration
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials


@pytest.fixture(scope="module")
def result():
    return run_trials("fig2.10", scale="quick", seed=3, progress=False)


def test_fitted_dmp_reproduces_the_demonstration(result):
    s = result["summary"]
    assert s["n_basis"] == 10
    assert s["rmse_q_fraction_of_range"] < 0.01
    assert s["end_error_to_goal_rad"] < 0.01 * s["demo_range_rad"]
    assert s["holds"] is True  # quick is the thesis setting: judged
    # Fig. 2.10(a): without the forcing term the DMP reaches g but misses the shape
    assert s["rmse_q_fraction_without_forcing"] > 0.1
    assert s["end_error_without_forcing_rad"] < 1e-3


_GOOD = {
    "n_basis": 10,
    "demo_range_rad": 1.0,
    "rmse_q_fraction_of_range": 0.002,
    "end_error_to_goal_rad": 0.001,
    "rmse_q_fraction_without_forcing": 0.3,
    "end_error_without_forcing_rad": 0.001,
}


@pytest.mark.parametrize(
    "change, outcome",
    [
        ({}, "holds"),
        ({"rmse_q_fraction_of_range": 0.03}, "does not hold"),  # not an accurate fit
        ({"end_error_to_goal_rad": 0.05}, "does not hold"),  # the forcing term moved the end
        ({"end_error_without_forcing_rad": 0.05}, "does not hold"),  # without it g is missed
        ({"rmse_q_fraction_without_forcing": 0.004}, "does not hold"),  # same shape
    ],
)
def test_spec_decides_the_three_sentences(change, outcome):
    assert judge.judge("fig2.10", {**_GOOD, **change}, "paper").outcome == outcome


def test_stored_paper_run_is_judged_on_its_deterministic_numbers():
    """A DMP fit has no sampling noise: every part is a ``value`` whose interval is the
    stored number itself, compared with the threshold exactly."""
    run = stored_run("fig2.10")
    j = run.judgement
    assert j.outcome == "holds"
    first = j.readings[0]
    assert first.estimate == run.summary["rmse_q_fraction_of_range"]
    assert first.lower == first.upper == first.estimate and first.estimate < 0.01
    assert judge.card_lines_ok(run.card)


def test_smoke_run_is_not_judged():
    s = run_trials("fig2.10", scale="smoke", seed=0, progress=False)["summary"]
    assert s["holds"] is None and s["verdict"] == "not judged"
    assert judge.card_lines_ok(s["judgement"]["card"])


def test_series_cover_figures_2_9_to_2_11(result):
    series = result["series"]
    panels = {s["panel"] for s in series}
    assert len(panels) == 4
    names = {s["name"] for s in series}
    assert any("Fig. 2.9" in n for n in names)
    assert any("2.10a" in n for n in names)
    assert any("2.11" in n for n in names)
    n_steps = len(series[0]["x"])
    assert all(len(s["x"]) == len(s["y"]) == n_steps for s in series)
    # the demonstration series is the analytic demonstration
    times, q, _, _ = reach_demonstration()
    demo = next(s for s in series if "Fig. 2.9" in s["name"] and s["panel"].startswith("position"))
    np.testing.assert_allclose(demo["y"], q[:, 0])
    np.testing.assert_allclose(demo["x"], times)


def test_fewer_basis_functions_fit_worse(result):
    coarse = run_trials("fig2.10", scale="quick", seed=0, progress=False, n_basis=3)["summary"]
    assert coarse["rmse_q_fraction_of_range"] > 5 * result["summary"]["rmse_q_fraction_of_range"]


def test_demonstration_is_smooth_with_exact_derivatives():
    times, q, qd, qdd = reach_demonstration(duration=1.5, dt=1e-3, q_start=-0.2, q_goal=0.8)
    assert times.shape == (1501,) and q.shape == qd.shape == qdd.shape == (1501, 1)
    # Round-off of the polynomials (degree 7, Horner) at s = 1, where the coefficients cancel:
    # up to 8 additions of partial sums bounded by Σ|c_k| (227 for q, 834 / T for q̇,
    # 2594 / T² for q̈ with the bump's 0.25 / b(4/7) ≈ 30 scaling): fp_tol(8, Σ|c_k|); at s = 0
    # only the constant term is left (exact).
    s = Polynomial([0.0, 1.0])
    bump = s**4 * (1 - s) ** 3
    path = -0.2 + (10 * s**3 - 15 * s**4 + 6 * s**5) + 0.25 * bump / bump(4.0 / 7.0)
    tol = [fp_tol(8, np.abs(path.deriv(k).coef).sum() / 1.5**k) for k in range(3)]
    np.testing.assert_allclose([q[0, 0], q[-1, 0]], [-0.2, 0.8], atol=tol[0])
    np.testing.assert_allclose([qd[0, 0], qd[-1, 0]], 0.0, atol=tol[1])
    np.testing.assert_allclose([qdd[0, 0], qdd[-1, 0]], 0.0, atol=tol[2])
    assert q.max() > 0.8 + 0.03  # it overshoots the goal, so the forcing term matters
    np.testing.assert_allclose(np.gradient(q[:, 0], times, edge_order=2), qd[:, 0], atol=5e-5)
    np.testing.assert_allclose(np.gradient(qd[:, 0], times, edge_order=2), qdd[:, 0], atol=5e-4)


@pytest.mark.parametrize("kwargs, name", [({"duration": 0.0}, "duration"), ({"dt": -1e-3}, "dt")])
def test_demonstration_bad_input_raises(kwargs, name):
    with pytest.raises(ValueError, match=name):
        reach_demonstration(**kwargs)
