"""Chapter 5 step by step: kernel trajectory prediction (Tables 5.1, 5.2) and model selection
(Sec. 5.3), shown with the library's own pieces.

The algorithm lives in :mod:`skillkit.models.embedding` (``ConditionalEmbedding.operator``
computes :math:`C = (K + \\lambda I)^{-1} \\tilde K`, ``weights_from_samples`` Eq. 5.6,
``apply`` Eq. 5.9), :func:`skillkit.models.embedding_prediction.predict` (the loop
:math:`\\beta_{t+1} = C \\beta_t`) and :mod:`skillkit.models.embedding_training` (Eq. 5.16).
This module tabulates and draws their inputs and outputs, and reads embeddings out against
real samples (:func:`marginal_embedding`, :func:`empirical_embedding`,
:func:`embedding_figure`, :func:`draw_embedding`). Figures are plotly
(:func:`skillkit.viz.plots.plotly_figure`).
"""

from __future__ import annotations

import io
import re
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager, redirect_stderr

import numpy as np
import pandas as pd

from skillkit._validation import check_array, check_count, check_positive
from skillkit.models.embedding import ConditionalEmbedding
from skillkit.models.embedding_prediction import predict
from skillkit.models.embedding_training import CrossValidatedLoss, FitResult
from skillkit.models.kernels import SquaredExponential, gram
from skillkit.tasks.pendulum import feedback_torque
from skillkit.viz.plots import plotly_figure
from skillkit.viz.series import Series

__all__ = [
    "agreement_table",
    "draw_embedding",
    "embedding_figure",
    "empirical_embedding",
    "fit_table",
    "loss_curve_figure",
    "marginal_embedding",
    "matrices_figure",
    "pendulum_policy",
    "prediction_table",
    "warnings_as_note",
    "weights_figure",
    "weights_table",
]

Policy = Callable[[np.ndarray, int], np.ndarray]

_WARNING_LINE = re.compile(r"^\S.*:\d+: (\w*Warning): (.*)$")
"""A line of ``warnings.formatwarning``: ``file:line: Category: message``."""


# --------------------------------------------------------------------------- tables
def weights_table(
    embedding: ConditionalEmbedding,
    beta,
    reference=None,
    names: Sequence[str] | None = None,
) -> pd.DataFrame:
    """What one embedding's weights say, Eqs. (5.7, 5.8): the mean read-out and the weights' size.

    Parameters
    ----------
    embedding : ConditionalEmbedding
        The fitted operator; its targets y_j are the points the weights sit on.
    beta : array_like, shape (N,)
        Weights of one embedding :math:`\\mu = \\Phi_y \\beta` (e.g.
        ``embedding.weights_from_samples(queries)``, Eq. 5.6).
    reference : array_like, shape (d_y,), optional
        A value to hold the read-out against (e.g. the simulator's successor).
    names : sequence of str, optional
        One name per target dimension (default ``y[0]``, ``y[1]``, …).

    Returns
    -------
    DataFrame
        Column ``value``; rows: the expected target :math:`\\mathbb E[y_d] = Y^\\top\\beta`
        per dimension, the reference per dimension (if given), :math:`\\sum_j \\beta_j` (1 when
        the queries lie where the data are, with λ small) and :math:`\\|\\beta\\|_1` (larger
        than the sum when some weights are negative).

    Raises
    ------
    ValueError
        ``beta`` not of shape (N,), ``reference`` or ``names`` not one per target dimension.
    """
    b = check_array(beta, "beta", shape=(embedding.n,))
    d = embedding.target_dim
    labels = list(names) if names is not None else [f"y[{k}]" for k in range(d)]
    if len(labels) != d:
        raise ValueError(f"names: expected {d} names (one per target dimension), got {len(labels)}")
    mean = embedding.mean(b)
    rows = {f"embedded mean {n} (Yᵀβ)": float(m) for n, m in zip(labels, mean, strict=True)}
    if reference is not None:
        ref = check_array(reference, "reference", shape=(d,))
        rows |= {f"reference {n}": float(r) for n, r in zip(labels, ref, strict=True)}
    rows["sum of β"] = float(b.sum())
    rows["‖β‖₁"] = float(np.abs(b).sum())
    return pd.DataFrame({"value": rows}).rename_axis("quantity")


def agreement_table(pairs: Mapping[str, tuple]) -> pd.DataFrame:
    """By-hand steps against the library's loop: the largest difference of each pair.

    Parameters
    ----------
    pairs : mapping of str to (array_like, array_like)
        Name → (computed by hand, computed by the library), arrays of equal shape.

    Returns
    -------
    DataFrame
        Per name: ``max |by hand − library|`` and ``max |library|`` (their ratio is the
        relative difference; round-off gives ~1e-15 times the condition of G + λI).

    Raises
    ------
    ValueError
        An empty mapping, or a pair whose arrays differ in shape.
    """
    if not isinstance(pairs, Mapping) or not pairs:
        raise ValueError("pairs: expected a non-empty mapping of name to (by hand, library)")
    rows = {}
    for name, pair in pairs.items():
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise ValueError(f"pairs[{name!r}]: expected a pair (by hand, library)")
        a = check_array(pair[0], f"pairs[{name!r}] by hand")
        b = check_array(pair[1], f"pairs[{name!r}] library", shape=a.shape)
        rows[str(name)] = {
            "max |by hand − library|": float(np.max(np.abs(a - b))),
            "max |library|": float(np.max(np.abs(b))),
        }
    return pd.DataFrame(rows).T.rename_axis("weights")


def _mean_paths(embedding: ConditionalEmbedding, betas: np.ndarray) -> np.ndarray:
    """X'ᵀβ_t for t = 1, …, T, shape (T, n_x)."""
    return np.stack([embedding.mean(b) for b in betas])


def prediction_table(
    models: Mapping[str, object],
    initial,
    real_states,
    names: Sequence[str] | None = None,
) -> pd.DataFrame:
    """How well each model's embedded mean follows the real rollouts (Table 5.1 or 5.2).

    For each model: :func:`~skillkit.models.embedding_prediction.predict` from the initial
    samples, the mean read-out :math:`\\hat x_t = X'^\\top \\beta_t` and its root mean square
    error against the mean of the real rollouts over t = 1, …, T, per state dimension.

    Parameters
    ----------
    models : mapping of str to ConditionalEmbedding or (ConditionalEmbedding, policy)
        Label → a state model (inputs x, Table 5.1), or a state-action model (inputs
        ``[x, u]``) with the policy ``policy(states, t) -> controls`` it predicts (Table 5.2,
        e.g. :func:`pendulum_policy`; time-invariant).
    initial : array_like, shape (L, n_x)
        Samples of the initial state distribution (Eq. 5.6).
    real_states : array_like, shape (L', T + 1, n_x)
        L' ≥ 2 real rollouts from that distribution (row 0: the start).
    names : sequence of str, optional
        State dimension names for the columns.

    Returns
    -------
    DataFrame
        Per model: ``RMSE <name>`` per dimension, the Monte Carlo standard error of the real
        mean averaged over t (an RMSE near it is as good as the truth is known), the largest
        :math:`\\|\\beta_t\\|_1` and the last :math:`\\sum_j \\beta_{T,j}`.

    Raises
    ------
    ValueError
        Empty ``models``, a value that is not a model or (model, policy), arrays of the wrong
        shape, or ``names`` not one per state dimension.
    """
    if not isinstance(models, Mapping) or not models:
        raise ValueError("models: expected a non-empty mapping of label to ConditionalEmbedding")
    x0 = check_array(initial, "initial", ndim=2)
    real = check_array(real_states, "real_states", ndim=3)
    n_x = real.shape[2]
    if x0.shape[1] != n_x:
        raise ValueError(f"initial: expected {n_x} columns like real_states, got shape {x0.shape}")
    if real.shape[0] < 2 or real.shape[1] < 2:
        raise ValueError(
            f"real_states: expected at least 2 rollouts of at least 2 rows, got {real.shape}"
        )
    labels = list(names) if names is not None else [f"x[{k}]" for k in range(n_x)]
    if len(labels) != n_x:
        raise ValueError(f"names: expected {n_x} names (one per state dimension)")
    real_mean = real[:, 1:].mean(axis=0)  # (T, n_x)
    se = real[:, 1:].std(axis=0, ddof=1).mean(axis=0) / np.sqrt(real.shape[0])
    rows = {}
    for label, entry in models.items():
        model, policy = entry if isinstance(entry, tuple) else (entry, None)
        if not isinstance(model, ConditionalEmbedding) or not (policy is None or callable(policy)):
            raise ValueError(
                f"models[{label!r}]: expected a ConditionalEmbedding or (ConditionalEmbedding, "
                "policy)"
            )
        traj = predict(
            model, x0[None], real.shape[1], policy=policy, time_invariant=policy is not None
        )
        betas = traj.betas[:, :, 0]
        err = np.sqrt(((_mean_paths(model, betas) - real_mean) ** 2).mean(axis=0))
        row = {f"RMSE {n}": float(e) for n, e in zip(labels, err, strict=True)}
        row |= {f"MC s.e. {n}": float(v) for n, v in zip(labels, se, strict=True)}
        row["max ‖β_t‖₁"] = float(np.abs(betas).sum(axis=1).max())
        row["sum of β_T"] = float(betas[-1].sum())
        rows[str(label)] = row
    return pd.DataFrame(rows).T.rename_axis("model")


def fit_table(initial_lengthscale, initial_lam: float, fit: FitResult) -> pd.DataFrame:
    """Hyper-parameters before and after
    :func:`~skillkit.models.embedding_training.fit_hyperparameters` (Sec. 5.3).

    Parameters
    ----------
    initial_lengthscale : array_like, shape (d,)
        The start of the fit.
    initial_lam : float
        The start λ.
    fit : FitResult

    Returns
    -------
    DataFrame
        Rows ``start`` and ``fitted``; columns the length-scales w_k, λ and the loss's
        cross-validated error per validation term (Eq. 5.16, 5.19 or 5.23).
    """
    w0 = check_array(initial_lengthscale, "initial_lengthscale", ndim=1)
    if w0.shape != fit.lengthscale.shape:
        raise ValueError(
            f"initial_lengthscale: expected shape {fit.lengthscale.shape} like the fit's, "
            f"got {w0.shape}"
        )
    lam0 = check_positive(initial_lam, "initial_lam")
    cols = [f"w[{k}]" for k in range(w0.size)]
    data = {
        "start": [*w0, lam0, fit.initial_loss],
        "fitted": [*fit.lengthscale, fit.lam, fit.loss],
    }
    return pd.DataFrame(data, index=[*cols, "λ", "CV error per term"]).T.rename_axis("θ")


# --------------------------------------------------------------------------- policies
def pendulum_policy(gains) -> Policy:
    """The pendulum's commanded feedback torque as a policy for Table 5.2's prediction.

    :math:`\\pi(x, t) = \\mathrm{clip}(K^\\top x, -3, 3)`
    (:func:`~skillkit.tasks.pendulum.feedback_torque` without noise), in the form
    :func:`~skillkit.models.embedding_prediction.predict` calls: ``policy(states, t)`` with
    states of shape (b, M, 2) returns controls of shape (b, M, 1). Time-invariant.

    Parameters
    ----------
    gains : array_like, shape (2,)
        K = [k_α, k_α̇].

    Returns
    -------
    callable
    """
    k = check_array(gains, "gains", shape=(2,))

    def policy(states: np.ndarray, t: int) -> np.ndarray:
        return feedback_torque(states, k)[..., None]

    return policy


# --------------------------------------------------------------------------- read-outs
def marginal_embedding(points, weights, grid, lengthscale: float) -> np.ndarray:
    """The embedding :math:`\\sum_j w_j\\, k_h(p_j, y)` of one coordinate, on a grid.

    For a product SE kernel :math:`k(x, x') = \\prod_d k_{h_d}(x_d, x'_d)` (Eq. 2.25),
    integrating :math:`\\mu(y) = \\sum_j \\beta_j k(x'_j, y)` over the other coordinates
    leaves :math:`c \\sum_j \\beta_j k_{h_d}(x'_{j,d}, y_d)` with
    :math:`c = \\prod_{e \\ne d} \\sqrt{2\\pi} h_e`: the embedding of coordinate d's marginal.
    With :math:`w_l = 1/L` it is the empirical embedding of samples
    (:func:`empirical_embedding`), on the same scale.

    Parameters
    ----------
    points : array_like, shape (N,)
        Coordinate d of the points the weights sit on (e.g. the observed successors x'_j).
    weights : array_like, shape (N,) or (N, B)
        β (Eq. 5.8) or 1/L.
    grid : array_like, shape (G,)
        Where to evaluate.
    lengthscale : float
        h > 0 of the 1-D SE kernel (the model's :math:`w_d` to read the thesis's μ).

    Returns
    -------
    ndarray, shape (G,) or (G, B)
    """
    p = check_array(points, "points", ndim=1)
    w = check_array(weights, "weights", ndim=(1, 2))
    if w.shape[0] != p.size:
        raise ValueError(f"weights: expected {p.size} rows (one per point), got shape {w.shape}")
    g = check_array(grid, "grid", ndim=1)
    h = check_positive(lengthscale, "lengthscale")
    return gram(SquaredExponential(1, lengthscale=h), g[:, None], p[:, None]) @ w


def empirical_embedding(samples, grid, lengthscale: float) -> tuple[np.ndarray, np.ndarray]:
    """Empirical embedding :math:`\\frac1L \\sum_l k_h(x_l, y)` of samples, and its standard error.

    Parameters
    ----------
    samples : array_like, shape (L,)
        L ≥ 2 samples of one coordinate (e.g. real states at step t).
    grid : array_like, shape (G,)
    lengthscale : float
        h > 0 (as in :func:`marginal_embedding`).

    Returns
    -------
    mean : ndarray, shape (G,)
    standard_error : ndarray, shape (G,)
        :math:`\\mathrm{sd}_l\\, k_h(x_l, y) / \\sqrt L`, the Monte Carlo error of the mean.
    """
    s = check_array(samples, "samples", ndim=1)
    if s.size < 2:
        raise ValueError(f"samples: expected at least 2 samples, got {s.size}")
    g = check_array(grid, "grid", ndim=1)
    h = check_positive(lengthscale, "lengthscale")
    k = gram(SquaredExponential(1, lengthscale=h), g[:, None], s[:, None])  # (G, L)
    return k.mean(axis=1), k.std(axis=1, ddof=1) / np.sqrt(s.size)


# --------------------------------------------------------------------------- figures
def _compact(z: np.ndarray, digits: int = 4) -> list:
    """``z`` rounded to ``digits`` significant digits of its largest entry (smaller JSON)."""
    top = float(np.max(np.abs(z))) if z.size else 0.0
    if top == 0.0 or not np.isfinite(top):
        return z.tolist()
    return np.round(z, max(0, digits - 1 - int(np.floor(np.log10(top))))).tolist()


def _diverging(fig) -> None:
    """Heatmaps with negative values get a diverging colour scale centred on 0 (blue < 0 < red)."""
    for trace in fig.data:
        if trace.type == "heatmap" and np.nanmin(np.asarray(trace.z, dtype=float)) < 0:
            trace.update(colorscale="RdBu", reversescale=True, zmid=0.0)


def matrices_figure(matrices: Mapping[str, object], *, pairs: int | None = None, title: str = ""):
    """Heatmaps of kernel matrices (K, K̃, C of Table 5.1; G, G̃^π, C^π of Table 5.2).

    Each matrix gets its own panel and a colour bar with its values (titled with the part of
    its name before " = "); row i is drawn at the top as in a printed matrix, and a matrix
    with negative entries gets a diverging colour scale centred on 0.

    Parameters
    ----------
    matrices : mapping of str to array_like, shape (n, m)
        Panel title → matrix, e.g. ``{"K = k(xᵢ, xⱼ)": embedding.gram, "C = (K + λI)⁻¹K̃":
        embedding.operator(x_next)}``.
    pairs : int, optional
        Show only the first ``pairs`` rows and columns (a block of whole trajectories reads
        better than 300 × 300 cells); default all.
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
    """
    if not isinstance(matrices, Mapping) or not matrices:
        raise ValueError("matrices: expected a non-empty mapping of title to 2-D array")
    n_show = None if pairs is None else check_count(pairs, "pairs")
    series = []
    for name, value in matrices.items():
        m = check_array(value, f"matrices[{name!r}]", ndim=2)
        if n_show is not None:
            m = m[:n_show, :n_show]
        series.append(
            Series(
                str(name).split("=")[0].strip() or str(name),
                list(range(m.shape[1])),
                list(range(m.shape[0])),
                panel=str(name),
                kind="heatmap",
                z=_compact(m),
                xlabel="column j (training pair)",
                ylabel="row i (training pair)",
            ).to_dict()
        )
    fig = plotly_figure({"title": title, "series": series})
    fig.update_yaxes(autorange="reversed")
    _diverging(fig)
    return fig


def _betas(betas) -> np.ndarray:
    b = check_array(betas, "betas", ndim=(2, 3))
    if b.ndim == 3:
        if b.shape[2] != 1:
            raise ValueError(
                f"betas: expected shape (T, N) or (T, N, 1) (one distribution), got {b.shape}"
            )
        b = b[:, :, 0]
    if b.shape[0] < 1 or b.shape[1] < 1:
        raise ValueError(f"betas: expected at least one step and one weight, got {b.shape}")
    return b


def _time_axis(n: int, dt: float | None, start: int = 1) -> tuple[list, str]:
    steps = np.arange(start, start + n, dtype=float)
    if dt is None:
        return steps.tolist(), "step t"
    return (check_positive(dt, "dt") * steps).tolist(), "t [s]"


def weights_figure(betas, *, dt: float | None = None, title: str = ""):
    """The weights β_t of every predicted step (Table 5.1's loop), as a map and as sums.

    Parameters
    ----------
    betas : array_like, shape (T, N) or (T, N, 1)
        β_1, …, β_T of one predicted distribution (``predict(...).betas[:, :, 0]``); row t − 1
        weighs the observed successors x'_j for the embedding of x_t.
    dt : float, optional
        Time step (the x axis is the step index when omitted).
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
        Left: :math:`\\beta_t[j]` over t and training pair j (trajectory-major); right:
        :math:`\\sum_j \\beta_{t,j}` (the embedded mass, 1 where the data cover the distribution)
        and :math:`\\|\\beta_t\\|_1` (above the sum when weights are negative; growth means the
        propagation amplifies).
    """
    b = _betas(betas)
    t, xlabel = _time_axis(b.shape[0], dt)
    heat = Series(
        "β_t[j]",
        t,
        list(range(b.shape[1])),
        panel="β_t[j] per training pair",
        kind="heatmap",
        z=_compact(b.T),
        xlabel=xlabel,
        ylabel="training pair j",
    )
    common = {"panel": "sum and size of β_t", "xlabel": xlabel, "ylabel": "weights"}
    lines = [
        Series("sum of β_t", t, b.sum(axis=1).tolist(), **common),
        Series("‖β_t‖₁", t, np.abs(b).sum(axis=1).tolist(), **common),
    ]
    fig = plotly_figure({"title": title, "series": [s.to_dict() for s in (heat, *lines)]})
    fig.update_yaxes(autorange="reversed", row=1, col=1)
    _diverging(fig)
    return fig


def _lengthscale(embedding: ConditionalEmbedding, dim: int) -> float:
    ls = getattr(embedding.kernel, "lengthscale", None)
    if ls is None:
        raise ValueError("bandwidth: the embedding's kernel has no length-scale; give one")
    flat = np.asarray(ls.detach().cpu().numpy(), dtype=float).ravel()
    return float(flat[dim] if flat.size > 1 else flat[0])


def _to_scale(fig) -> None:
    """Every value of every panel drawn to scale.

    :func:`~skillkit.viz.plots.plotly_figure` gives a panel a robust y range when a few
    values run away from the rest; an embedding curve is ~0 over most of its grid (the tails
    of a distribution), so its peak would be clipped as if it ran away. Its clipped-value
    markers and notes are removed and the y axes range over all values again.
    """
    fig.data = [t for t in fig.data if not str(t.name or "").endswith("(off scale)")]
    notes = ("at the top edge", "at the bottom edge")  # plots' note on clipped values
    fig.layout.annotations = [
        a for a in fig.layout.annotations if not any(n in str(a.text or "") for n in notes)
    ]
    fig.update_yaxes(range=None, autorange=True)


def embedding_figure(
    embedding: ConditionalEmbedding,
    betas,
    real_states,
    *,
    steps: Sequence[int] = (1, 10, 20),
    dim: int = 0,
    bandwidth: float | None = None,
    label: str = "α [rad]",
    dt: float | None = None,
    grid_points: int = 121,
    title: str = "",
):
    """Predicted embeddings against the empirical embeddings of real samples.

    First panel: the mean read-out :math:`X'^\\top\\beta_t` of coordinate ``dim`` over t and the
    real rollouts' mean ± 2 Monte Carlo standard errors. Then per step t in ``steps``: the
    predicted marginal embedding :math:`\\sum_j \\beta_{t,j} k_h(x'_{j,d}, y)`
    (:func:`marginal_embedding`) and the empirical one of the real states,
    :math:`\\frac1L\\sum_l k_h(x^{(l)}_{t,d}, y)`, ± 2 standard errors.

    Parameters
    ----------
    embedding : ConditionalEmbedding
        The dynamics model; its targets are the observed successor states x'_j.
    betas : array_like, shape (T, N) or (T, N, 1)
        β_1, …, β_T of one predicted distribution.
    real_states : array_like, shape (L, T + 1, n_x)
        L ≥ 2 real rollouts from the same initial distribution (row 0: the start).
    steps : sequence of int
        Steps t (1 ≤ t ≤ T) to draw the embeddings at.
    dim : int
        State coordinate d.
    bandwidth : float, optional
        h of the drawn curves; default the model's length-scale of coordinate d (the RKHS of the
        thesis's μ). A smaller h shows more of the weighted sample's shape (and its negative
        weights) at a larger sampling error.
    label : str
        Name and unit of the coordinate.
    dt : float, optional
        Time step (the x axis of the first panel and the panel titles use seconds).
    grid_points : int
        Points of the evaluation grid (≥ 2): it spans the real samples and the successors
        holding the predicted weights (|β_j| ≥ 1% of the largest), ± 3 h.
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
    """
    b = _betas(betas)
    real = check_array(real_states, "real_states", ndim=3)
    n_x = embedding.target_dim
    if b.shape[1] != embedding.n:
        raise ValueError(f"betas: expected {embedding.n} weights per step, got shape {b.shape}")
    if real.shape[2] != n_x or real.shape[1] != b.shape[0] + 1 or real.shape[0] < 2:
        raise ValueError(
            f"real_states: expected shape (L >= 2, {b.shape[0] + 1}, {n_x}) for {b.shape[0]} "
            f"predicted steps, got {real.shape}"
        )
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or not 0 <= dim < n_x:
        raise ValueError(f"dim: expected an integer in [0, {n_x}), got {dim!r}")
    if isinstance(steps, (int, np.integer)) or not steps:
        raise ValueError(f"steps: expected a non-empty sequence of steps, got {steps!r}")
    shown = [check_count(s, "steps") for s in steps]
    if max(shown) > b.shape[0]:
        raise ValueError(f"steps: expected steps in 1..{b.shape[0]}, got {list(steps)}")
    h = (
        _lengthscale(embedding, dim)
        if bandwidth is None
        else check_positive(bandwidth, "bandwidth")
    )
    n_grid = check_count(grid_points, "grid_points", minimum=2)
    pts = embedding.targets[:, dim]
    weights = b[[s - 1 for s in shown]].T  # (N, S)
    size = np.abs(weights).max(axis=1)
    held = pts[size >= 0.01 * size.max()] if size.max() > 0 else pts
    seen = np.concatenate([held, real[:, shown, dim].ravel()])
    grid = np.linspace(seen.min() - 3 * h, seen.max() + 3 * h, n_grid)

    t_pred, xlabel = _time_axis(b.shape[0], dt)
    t_real, _ = _time_axis(b.shape[0] + 1, dt, start=0)
    mean = real[:, :, dim].mean(axis=0)
    se = real[:, :, dim].std(axis=0, ddof=1) / np.sqrt(real.shape[0])
    band = f"± 2 standard errors ({real.shape[0]} real samples)"
    common = {"panel": f"mean of {label}: X′ᵀβ_t", "xlabel": xlabel, "ylabel": label}
    series = [
        Series("predicted", t_pred, _mean_paths(embedding, b)[:, dim].tolist(), **common),
        Series(
            "real samples",
            t_real,
            mean.tolist(),
            lower=(mean - 2 * se).tolist(),
            upper=(mean + 2 * se).tolist(),
            band=band,
            **common,
        ),
    ]
    predicted = marginal_embedding(pts, weights, grid, h)  # (G, S)
    for k, s in enumerate(shown):
        emp, emp_se = empirical_embedding(real[:, s, dim], grid, h)
        when = f"t = {s}" if dt is None else f"t = {s * dt:.3g} s"
        common = {"panel": f"embedding at {when}", "xlabel": label, "ylabel": f"μ (h = {h:.3g})"}
        series += [
            Series("predicted", grid.tolist(), predicted[:, k].tolist(), **common),
            Series(
                "real samples",
                grid.tolist(),
                emp.tolist(),
                lower=(emp - 2 * emp_se).tolist(),
                upper=(emp + 2 * emp_se).tolist(),
                band=band,
                **common,
            ),
        ]
    fig = plotly_figure({"title": title, "series": [s.to_dict() for s in series]})
    _to_scale(fig)
    return fig


def draw_embedding(
    inputs,
    targets,
    initial,
    real_states,
    *,
    lam: float = 1e-3,
    lengthscale_factor: float = 1.0,
    step: int = 10,
    dim: int = 0,
    bandwidth: float | None = None,
    policy: Policy | None = None,
    label: str = "α [rad]",
    dt: float | None = None,
):
    """Fit an embedding with λ and scaled length-scales, predict, draw it against real samples.

    The notebook widget's redraw: ``ConditionalEmbedding(inputs, targets,
    SE(lengthscale_factor × std(inputs)), lam)``,
    :func:`~skillkit.models.embedding_prediction.predict` from ``initial`` (Table 5.1, or 5.2 with
    ``policy``) and :func:`embedding_figure` at one step.

    Parameters
    ----------
    inputs : array_like, shape (N, d_z)
        Observed inputs (states x_i, or state-actions [x_i, u_i] with ``policy``).
    targets : array_like, shape (N, n_x)
        Observed successor states x'_i.
    initial : array_like, shape (L, n_x)
        Samples of the initial state distribution.
    real_states : array_like, shape (L', T + 1, n_x)
        Real rollouts from it.
    lam : float
        Regulariser λ > 0 (Eq. 5.3).
    lengthscale_factor : float
        The SE length-scales are this factor (> 0) times the inputs' standard deviations.
    step : int
        The step t (1 ≤ t ≤ T) whose embedding is drawn.
    dim : int
        State coordinate drawn.
    bandwidth : float, optional
        h of the drawn curves (:func:`embedding_figure`); default the model's length-scale.
    policy : callable, optional
        For a state-action model (Table 5.2), e.g. :func:`pendulum_policy`.
    label : str
    dt : float, optional

    Returns
    -------
    plotly.graph_objects.Figure
        Titled with λ, the length-scales w, the sum of β_step and the largest
        :math:`\\|\\beta_t\\|_1`.
    """
    z = check_array(inputs, "inputs", ndim=2)
    factor = check_positive(lengthscale_factor, "lengthscale_factor")
    lam = check_positive(lam, "lam")
    real = check_array(real_states, "real_states", ndim=3)
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)):
        raise ValueError(f"step: expected an integer in [1, {real.shape[1] - 1}], got {step!r}")
    if not 1 <= step <= real.shape[1] - 1:
        raise ValueError(f"step: expected an integer in [1, {real.shape[1] - 1}], got {step}")
    sd = z.std(axis=0)
    ls = factor * np.where(sd > 0, sd, 1.0)
    model = ConditionalEmbedding(z, targets, SquaredExponential(z.shape[1], lengthscale=ls), lam)
    traj = predict(
        model,
        check_array(initial, "initial", ndim=2)[None],
        real.shape[1],
        policy=policy,
        time_invariant=policy is not None,
    )
    betas = traj.betas[:, :, 0]
    widths = ", ".join(f"{v:.3g}" for v in ls)
    title = (
        f"λ = {lam:.3g}, w = [{widths}]: Σβ_{step} = {betas[step - 1].sum():.3g}, "
        f"max ‖β_t‖₁ = {np.abs(betas).sum(axis=1).max():.3g}"
    )
    return embedding_figure(
        model,
        betas,
        real,
        steps=(step,),
        dim=dim,
        bandwidth=bandwidth,
        label=label,
        dt=dt,
        title=title,
    )


def loss_curve_figure(
    loss: CrossValidatedLoss,
    lengthscale,
    *,
    lams: Sequence[float] = (1e-5, 1e-3, 1e-1),
    factors=None,
    title: str = "cross-validated embedding error (5.16)",
):
    """The cross-validated error as a function of a common length-scale factor, one curve per λ.

    Evaluates ``loss`` at θ = [log(f · w), log λ] (Sec. 5.3): the objective
    :func:`~skillkit.models.embedding_training.fit_hyperparameters` minimises, on one line
    through its search space.

    Parameters
    ----------
    loss : CrossValidatedLoss
        E.g. :func:`~skillkit.models.embedding_training.state_embedding_loss`.
    lengthscale : array_like, shape (d,)
        Reference length-scales w (e.g. the inputs' standard deviations).
    lams : sequence of float
        λ > 0 of each curve.
    factors : array_like, optional
        Factors f > 0 (default 9 values from 0.03 to 10, evenly on a log scale).
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
        Log–log axes; the error is per validation term.
    """
    w = check_array(lengthscale, "lengthscale", shape=(loss.dim,))
    if np.any(w <= 0):
        raise ValueError(f"lengthscale: expected positive values, got {w}")
    f = np.geomspace(0.03, 10.0, 9) if factors is None else check_array(factors, "factors", ndim=1)
    if f.size < 2 or np.any(f <= 0):
        raise ValueError(f"factors: expected at least 2 positive values, got {f}")
    if not lams:
        raise ValueError("lams: expected at least one λ")
    series = []
    for lam in lams:
        lam = check_positive(lam, "lams")
        values = [loss(np.append(np.log(v * w), np.log(lam))) for v in f]
        series.append(
            Series(
                f"λ = {lam:.3g}",
                f.tolist(),
                values,
                xlabel="length-scale factor f (× w)",
                ylabel="CV error per term",
                log_x=True,
                log_y=True,
            ).to_dict()
        )
    return plotly_figure({"title": title, "series": series})


# --------------------------------------------------------------------------- warnings
@contextmanager
def warnings_as_note(reason: str = "") -> Iterator[list]:
    """Catch the warnings raised inside the block and show them once, as a Markdown note.

    For library warnings a notebook cannot fix at their cause: each distinct message with its count
    and ``reason``. Caught are ``warnings.warn`` and text written to ``sys.stderr`` in the block
    (the runner's ``tqdm.write``); other stderr text is passed on, exceptions are not caught.

    Parameters
    ----------
    reason : str
        Why the warnings are expected here (shown with them).

    Yields
    ------
    list of str
        The caught messages (filled when the block ends).
    """
    found: list[str] = []
    text = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, redirect_stderr(text):
        warnings.simplefilter("always")
        yield found
    found += [f"{w.category.__name__}: {w.message}" for w in caught]
    other, after_warning = [], False
    for line in text.getvalue().splitlines():  # "file:line: Category: message", "  source"
        match = _WARNING_LINE.match(line)
        if match:
            found.append(f"{match[1]}: {match[2]}")
        elif not (after_warning and line.startswith("  ")) and line.strip():
            other.append(line)
        after_warning = bool(match)
    if other:  # not a warning: it goes where it was written to
        print("\n".join(other), file=sys.stderr)
    if not found:
        return
    counts: dict[str, int] = {}
    for message in found:
        counts[message] = counts.get(message, 0) + 1
    lines = [f"- {m}" + (f" (×{n})" if n > 1 else "") for m, n in counts.items()]
    head = "**Library warnings, caught:**" + (f" {reason}" if reason else "")
    note = head + "\n" + "\n".join(lines)
    try:
        from IPython import get_ipython
        from IPython.display import Markdown, display
    except ImportError:  # no IPython: the note goes to stdout
        get_ipython = None
    if get_ipython is not None and get_ipython() is not None:
        display(Markdown(note))
    else:
        print(note)
