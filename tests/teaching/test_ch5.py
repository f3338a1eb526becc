"""The Chapter 5 step-through pieces (skillkit.teaching.ch5): tables and read-outs checked
against independent computations and closed forms, figures against the numbers they draw."""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest

from skillkit.models.embedding import ConditionalEmbedding
from skillkit.models.embedding_prediction import predict
from skillkit.models.embedding_training import (
    FitResult,
    kfold_splits,
    state_embedding_loss,
    transitions,
)
from skillkit.models.kernels import SquaredExponential, gram
from skillkit.tasks import make
from skillkit.tasks.pendulum import THESIS_GAINS
from skillkit.teaching import ch5
from tests._tolerances import fp_tol

EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def pendulum():
    """A tiny Table 5.1 problem: 4 trajectories of 8 steps, L = 12 initial samples and their
    real rollouts."""
    task = make("pendulum", horizon=8)
    rng = np.random.default_rng(0)
    runs = [task.rollout(THESIS_GAINS, s, rng) for s in task.sample_context(rng, n=4)]
    x, x_next, groups = transitions(np.stack([r.states for r in runs]))
    kernel = SquaredExponential(2, lengthscale=x.std(0))
    model = ConditionalEmbedding(x, x_next, kernel, lam=1e-3)
    x0 = np.array([1.0, 0.0]) + 0.1 * rng.standard_normal((12, 2))
    real = np.stack([task.rollout(THESIS_GAINS, s, rng).states for s in x0])
    return {"x": x, "x_next": x_next, "groups": groups, "model": model, "x0": x0, "real": real}


def _trace(fig, name: str, k: int = 0):
    return [t for t in fig.data if t.name == name][k]


def _readout_tol(betas, targets):
    """Absolute round-off of read-outs Yᵀβ_t evaluated in two orders (a matrix–vector product
    per step vs one matrix product): N-term sums whose terms can cancel, ≲ N ε Σ_j |β_j| |y_j|."""
    b = np.atleast_2d(betas)
    return fp_tol(targets.shape[0], scale=(np.abs(b) @ np.abs(targets)).max())


# --------------------------------------------------------------------------- tables
def test_weights_table_reads_out_the_mean_and_the_size_of_the_weights(pendulum):
    model = pendulum["model"]
    beta = model.weights_from_samples(pendulum["x0"])
    table = ch5.weights_table(model, beta, reference=[0.5, -1.0], names=["a", "b"])
    v = table["value"]
    mean = pendulum["x_next"].T @ beta
    tol = _readout_tol(beta, pendulum["x_next"])  # β signed: an absolute bound
    assert v["embedded mean a (Yᵀβ)"] == pytest.approx(mean[0], abs=tol)
    assert v["embedded mean b (Yᵀβ)"] == pytest.approx(mean[1], abs=tol)
    assert (v["reference a"], v["reference b"]) == (0.5, -1.0)
    # the same numpy sums of the same floats: equal exactly
    assert v["sum of β"] == beta.sum()
    assert v["‖β‖₁"] == np.abs(beta).sum()
    with pytest.raises(ValueError, match="names"):
        ch5.weights_table(model, beta, names=["a"])
    with pytest.raises(ValueError, match="beta"):
        ch5.weights_table(model, beta[:-1])
    with pytest.raises(ValueError, match="reference"):
        ch5.weights_table(model, beta, reference=[1.0])


def test_table_5_1_by_hand_agrees_with_predict(pendulum):
    """α (5.6), β₁ = (K + λI)⁻¹Kα (5.9) and β₂ = Cβ₁ computed by hand equal predict's loop
    to round-off: eps × cond(K + λI) × the weights' size, times a small factor."""
    model, x0 = pendulum["model"], pendulum["x0"]
    C = model.operator(model.targets)
    beta_1 = model.apply(model.weights_from_samples(x0), model.inputs)
    beta_2 = C @ beta_1
    betas = predict(model, x0[None], n_steps=4).betas[:, :, 0]
    table = ch5.agreement_table({"β₁": (beta_1, betas[0]), "β₂": (beta_2, betas[1])})
    cond = np.linalg.cond(model.gram + model.lam * np.eye(model.n))
    for name in ("β₁", "β₂"):
        size = table.loc[name, "max |library|"]
        assert table.loc[name, "max |by hand − library|"] <= 10 * EPS * cond * max(size, 1.0)
    with pytest.raises(ValueError, match="pairs"):
        ch5.agreement_table({})
    with pytest.raises(ValueError, match="library"):
        ch5.agreement_table({"β": (beta_1, beta_1[:-1])})


def test_prediction_table_is_the_rmse_of_the_mean_read_out(pendulum):
    model, x0, real = pendulum["model"], pendulum["x0"], pendulum["real"]
    table = ch5.prediction_table({"m": model}, x0, real, names=["a", "b"])
    betas = predict(model, x0[None], real.shape[1]).betas[:, :, 0]
    means = betas @ model.targets  # (T, 2): X'ᵀβ_t
    rmse = np.sqrt(((means - real[:, 1:].mean(axis=0)) ** 2).mean(axis=0))
    se = (real[:, 1:].std(axis=0, ddof=1) / np.sqrt(real.shape[0])).mean(axis=0)
    # the RMSE moves by at most the read-outs' largest difference, plus its own last rounding
    tol = _readout_tol(betas, model.targets) + fp_tol(2, scale=rmse.max())
    assert table.loc["m", "RMSE a"] == pytest.approx(rmse[0], abs=tol)
    assert table.loc["m", "RMSE b"] == pytest.approx(rmse[1], abs=tol)
    # ÷ √L before or after the mean over T same-sign terms: ≲ (T + 3) ε relatively
    assert table.loc["m", "MC s.e. b"] == pytest.approx(se[1], rel=fp_tol(real.shape[1] + 2))
    # the same predict() and numpy reductions on the same floats: equal exactly
    assert table.loc["m", "max ‖β_t‖₁"] == np.abs(betas).sum(1).max()
    assert table.loc["m", "sum of β_T"] == betas[-1].sum()
    with pytest.raises(ValueError, match="models"):
        ch5.prediction_table({"m": "not a model"}, x0, real)
    with pytest.raises(ValueError, match="initial"):
        ch5.prediction_table({"m": model}, x0[:, :1], real)


def test_prediction_table_with_a_policy_is_table_5_2(pendulum):
    """A state-action model with the data's own policy: the same numbers as predict with it."""
    task = make("pendulum", horizon=8, control_noise=1.0)
    rng = np.random.default_rng(3)
    runs = [task.rollout(THESIS_GAINS, s, rng) for s in task.sample_context(rng, n=4)]
    z, z_next, _ = transitions(
        np.stack([r.states for r in runs]), np.stack([r.controls for r in runs])
    )
    sa = ConditionalEmbedding(z, z_next, SquaredExponential(3, lengthscale=z.std(0)), lam=1e-3)
    policy = ch5.pendulum_policy(THESIS_GAINS)
    x0, real = pendulum["x0"], pendulum["real"]
    table = ch5.prediction_table({"sa": (sa, policy)}, x0, real)
    traj = predict(sa, x0[None], real.shape[1], policy=policy, time_invariant=True)
    means = traj.means(sa)[1:, 0]
    rmse = np.sqrt(((means - real[:, 1:].mean(axis=0)) ** 2).mean(axis=0))
    tol = _readout_tol(traj.betas[:, :, 0], sa.targets) + fp_tol(2, scale=rmse.max())
    assert table.loc["sa", "RMSE x[0]"] == pytest.approx(rmse[0], abs=tol)


def test_fit_table_rows_are_the_start_and_the_fit():
    fit = FitResult(np.array([1.0, 2.0]), 1e-4, 0.05, 0.1, 7, True, "ok")
    table = ch5.fit_table([3.0, 4.0], 1e-3, fit)
    assert table.loc["start"].tolist() == [3.0, 4.0, 1e-3, 0.1]
    assert table.loc["fitted"].tolist() == [1.0, 2.0, 1e-4, 0.05]
    with pytest.raises(ValueError, match="initial_lengthscale"):
        ch5.fit_table([3.0], 1e-3, fit)
    with pytest.raises(ValueError, match="initial_lam"):
        ch5.fit_table([3.0, 4.0], 0.0, fit)


# --------------------------------------------------------------------------- read-outs
def test_pendulum_policy_is_the_clipped_feedback_torque():
    policy = ch5.pendulum_policy([-3.0, -1.0])
    states = np.array([[[0.1, 0.2], [2.0, 0.0], [-2.0, 0.0]]])  # (1, 3, 2)
    u = policy(states, 5)
    assert u.shape == (1, 3, 1)
    assert u[0, :, 0].tolist() == pytest.approx([-0.5, -3.0, 3.0], abs=fp_tol(4, scale=3.0))
    with pytest.raises(ValueError, match="gains"):
        ch5.pendulum_policy([1.0, 2.0, 3.0])


def test_marginal_embedding_of_one_point_is_its_kernel():
    grid = np.linspace(-2, 3, 11)
    out = ch5.marginal_embedding([0.5], [1.0], grid, 0.7)
    assert out == pytest.approx(np.exp(-0.5 * (grid - 0.5) ** 2 / 0.7**2), abs=fp_tol(8))
    two = ch5.marginal_embedding([0.5, -1.0], np.array([[1.0, 0.0], [0.0, 2.0]]), grid, 0.7)
    assert two.shape == (11, 2)
    assert two[:, 1] == pytest.approx(
        2 * np.exp(-0.5 * (grid + 1) ** 2 / 0.7**2), abs=fp_tol(8, scale=2.0)
    )
    with pytest.raises(ValueError, match="weights"):
        ch5.marginal_embedding([0.5, 1.0], [1.0], grid, 0.7)
    with pytest.raises(ValueError, match="lengthscale"):
        ch5.marginal_embedding([0.5], [1.0], grid, 0.0)


def test_marginal_embedding_is_the_2d_embedding_integrated_over_the_other_coordinate():
    """∫ Σ_j β_j k((a_j, b_j), (a, b)) db = √(2π) h_b Σ_j β_j k_{h_a}(a_j, a) for a product SE
    kernel. The trapezoid rule on ±12 h_b around the points with step h_b / 8 is exact to far
    below round-off for these Gaussians, so the tolerance is round-off: the integrand's size
    Σ|β| times eps times the number of terms."""
    rng = np.random.default_rng(1)
    pts, beta = rng.standard_normal((6, 2)), rng.standard_normal(6)
    h = np.array([0.4, 0.3])
    a = np.linspace(-2, 2, 9)
    b = np.arange(pts[:, 1].min() - 12 * h[1], pts[:, 1].max() + 12 * h[1], h[1] / 8)
    grid2 = np.stack(np.meshgrid(a, b, indexing="ij"), axis=-1).reshape(-1, 2)
    mu = (gram(SquaredExponential(2, lengthscale=h), grid2, pts) @ beta).reshape(a.size, b.size)
    integral = (0.5 * (mu[:, 1:] + mu[:, :-1]) * np.diff(b)).sum(axis=1)  # trapezoid rule
    expected = np.sqrt(2 * np.pi) * h[1] * ch5.marginal_embedding(pts[:, 0], beta, a, h[0])
    tol = np.abs(beta).sum() * np.sqrt(2 * np.pi) * h[1] * EPS * b.size * 10
    assert np.max(np.abs(integral - expected)) <= tol


def test_empirical_embedding_matches_the_closed_form_within_its_standard_error():
    """Samples of N(0, s²): E[k_h(x, y)] = h / √(h² + s²) · exp(−y² / (2(h² + s²))). Five grid
    points, each within 5 standard errors (a false failure has probability < 1e-5)."""
    rng = np.random.default_rng(2)
    s, h, grid = 0.8, 0.5, np.linspace(-1.5, 1.5, 5)
    mean, se = ch5.empirical_embedding(s * rng.standard_normal(4000), grid, h)
    exact = h / np.sqrt(h**2 + s**2) * np.exp(-(grid**2) / (2 * (h**2 + s**2)))
    assert np.all(np.abs(mean - exact) <= 5 * se)
    small = np.array([0.0, 1.0])
    m2, se2 = ch5.empirical_embedding(small, grid, h)
    k = np.exp(-0.5 * (grid[:, None] - small) ** 2 / h**2)
    assert m2 == pytest.approx(k.mean(1), abs=fp_tol(8 + len(small)))
    assert se2 == pytest.approx(k.std(1, ddof=1) / np.sqrt(2), abs=fp_tol(8 + 4 * len(small)))
    with pytest.raises(ValueError, match="samples"):
        ch5.empirical_embedding([1.0], grid, h)


# --------------------------------------------------------------------------- figures
def test_matrices_figure_draws_each_matrix_with_a_valued_colour_bar():
    pos, signed = np.arange(12.0).reshape(3, 4), np.array([[1.0, -2.0], [0.5, 0.0]])
    fig = ch5.matrices_figure({"K = k(xᵢ, xⱼ)": pos, "C = (K + λI)⁻¹K̃": signed}, pairs=2)
    heat = [t for t in fig.data if t.type == "heatmap"]
    assert [t.name for t in heat] == ["K", "C"]
    assert np.asarray(heat[0].z).tolist() == [[0.0, 1.0], [4.0, 5.0]]  # the first 2 × 2 block
    assert all(t.colorbar.showticklabels for t in heat)
    assert heat[1].zmid == 0.0 and heat[0].zmid is None  # diverging only with negative entries
    assert fig.layout.yaxis.autorange == "reversed"
    with pytest.raises(ValueError, match="matrices"):
        ch5.matrices_figure({"v": np.ones(3)})
    with pytest.raises(ValueError, match="pairs"):
        ch5.matrices_figure({"K": pos}, pairs=0)


def test_weights_figure_draws_the_weights_and_their_sums(pendulum):
    betas = predict(pendulum["model"], pendulum["x0"][None], n_steps=6).betas  # (5, N, 1)
    fig = ch5.weights_figure(betas, dt=0.1)
    heat = [t for t in fig.data if t.type == "heatmap"][0]
    assert np.asarray(heat.z).shape == (betas.shape[1], 5)
    assert list(_trace(fig, "sum of β_t").x) == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5])
    # the same numpy sums of the same floats: equal exactly
    np.testing.assert_array_equal(_trace(fig, "sum of β_t").y, betas[:, :, 0].sum(1))
    l1 = np.abs(betas[:, :, 0]).sum(1)
    np.testing.assert_array_equal(_trace(fig, "‖β_t‖₁").y, l1)
    with pytest.raises(ValueError, match="betas"):
        ch5.weights_figure(np.ones((3, 4, 2)))


def test_embedding_figure_draws_the_read_out_and_the_curves(pendulum):
    model, x0, real = pendulum["model"], pendulum["x0"], pendulum["real"]
    betas = predict(model, x0[None], real.shape[1]).betas[:, :, 0]
    fig = ch5.embedding_figure(model, betas, real, steps=(1, 8), dim=1, bandwidth=0.3)
    pred = [t for t in fig.data if t.name == "predicted"]
    assert len(pred) == 3  # the mean read-out and one curve per step
    tol = _readout_tol(betas, model.targets)
    assert list(pred[0].y) == pytest.approx((betas @ model.targets)[:, 1], abs=tol)
    grid = np.asarray(pred[2].x)
    expected = ch5.marginal_embedding(model.targets[:, 1], betas[7], grid, 0.3)
    assert list(pred[2].y) == pytest.approx(expected, abs=fp_tol(8 * len(model.targets)))
    real_curve = [t for t in fig.data if t.name == "real samples"][2]
    assert list(real_curve.y) == pytest.approx(
        ch5.empirical_embedding(real[:, 8, 1], grid, 0.3)[0], abs=fp_tol(8 * len(real))
    )
    assert not any(str(t.name).endswith("(off scale)") for t in fig.data)
    with pytest.raises(ValueError, match="steps"):
        ch5.embedding_figure(model, betas, real, steps=(9,))
    with pytest.raises(ValueError, match="real_states"):
        ch5.embedding_figure(model, betas, real[:, :-1])
    with pytest.raises(ValueError, match="dim"):
        ch5.embedding_figure(model, betas, real, dim=2)


def test_draw_embedding_is_deterministic_and_names_bad_controls(pendulum):
    args = (pendulum["x"], pendulum["x_next"], pendulum["x0"], pendulum["real"])
    a = ch5.draw_embedding(*args, lam=0.1, lengthscale_factor=0.5, step=4)
    b = ch5.draw_embedding(*args, lam=0.1, lengthscale_factor=0.5, step=4)
    assert a.to_dict() == b.to_dict()
    model = ConditionalEmbedding(
        pendulum["x"],
        pendulum["x_next"],
        SquaredExponential(2, lengthscale=0.5 * pendulum["x"].std(0)),
        lam=0.1,
    )
    betas = predict(model, pendulum["x0"][None], 9).betas[:, :, 0]
    assert f"Σβ_4 = {betas[3].sum():.3g}" in a.layout.title.text
    with pytest.raises(ValueError, match="lam"):
        ch5.draw_embedding(*args, lam=0.0)
    with pytest.raises(ValueError, match="lengthscale_factor"):
        ch5.draw_embedding(*args, lengthscale_factor=-1.0)
    with pytest.raises(ValueError, match="step"):
        ch5.draw_embedding(*args, step=0)


def test_loss_curve_figure_draws_the_loss_on_a_line_through_theta(pendulum):
    x, x_next, groups = pendulum["x"], pendulum["x_next"], pendulum["groups"]
    folds = kfold_splits(len(x), 2, rng=0, groups=groups)
    loss = state_embedding_loss(x, x_next, folds, SquaredExponential(2, lengthscale=1.0))
    w = x.std(0)
    fig = ch5.loss_curve_figure(loss, w, lams=(1e-3,), factors=[0.5, 2.0])
    curve = _trace(fig, "λ = 0.001")
    expected = [loss(np.append(np.log(f * w), np.log(1e-3))) for f in (0.5, 2.0)]
    # the figure calls the same loss on the same floats (log(f w), log λ): equal exactly
    np.testing.assert_array_equal(curve.y, expected)
    with pytest.raises(ValueError, match="lengthscale"):
        ch5.loss_curve_figure(loss, [1.0, -1.0])
    with pytest.raises(ValueError, match="factors"):
        ch5.loss_curve_figure(loss, w, factors=[1.0])


# --------------------------------------------------------------------------- warnings
def test_warnings_as_note_catches_warnings_and_passes_other_stderr_on(capsys):
    with ch5.warnings_as_note("expected here") as caught:
        warnings.warn("first", RuntimeWarning, stacklevel=1)
        # what the experiment runner prints above its progress bars (tqdm.write to stderr)
        print("/x/y.py:95: RuntimeWarning: second\n  source line", file=sys.stderr)
        print("not a warning", file=sys.stderr)
    assert caught == ["RuntimeWarning: first", "RuntimeWarning: second"]
    out = capsys.readouterr()
    assert out.err == "not a warning\n"
    assert "expected here" in out.out and "RuntimeWarning: second" in out.out
    with ch5.warnings_as_note() as none:
        pass
    assert none == [] and capsys.readouterr().out == ""
