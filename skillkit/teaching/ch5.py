"""Chapter 5 step by step: kernel trajectory prediction (Tables 5.1, 5.2, C = (K + λI)⁻¹K̃,
β_{t+1} = C β_t) and model selection (Sec. 5.3, Eq. 5.16), the library's embedding models
tabulated and drawn against real samples. Figures are plotly."""

from __future__ import annotations

import io
import re
import sys
import warnings
from collections import Counter
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
from skillkit.teaching._common import draw, index
from skillkit.viz.series import Series

Policy = Callable[[np.ndarray, int], np.ndarray]

#: A line of ``warnings.formatwarning``: ``file:line: Category: message``.
_WARNING_LINE = re.compile(r"^\S.*:\d+: (\w*Warning): (.*)$")


def weights_table(
    embedding: ConditionalEmbedding, beta, reference=None, names: Sequence[str] | None = None
) -> pd.DataFrame:
    """What one embedding μ = Φ_y β (N,) says (Eqs. 5.7, 5.8): E[y_d] = Yᵀβ per dimension
    (``names``), ``reference`` (d_y,) if given, Σ_j β_j and ‖β‖₁."""
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
    """Per name → (by hand, library) arrays: max |by hand − library| and max |library|."""
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


def _predicted(model: ConditionalEmbedding, x0: np.ndarray, n: int, policy) -> np.ndarray:
    """The weights β_t (T, N) of one distribution started at ``x0`` (L, n_x) (Table 5.1)."""
    out = predict(model, x0[None], n, policy=policy, time_invariant=policy is not None)
    return out.betas[:, :, 0]


def prediction_table(
    models: Mapping[str, object], initial, real_states, names: Sequence[str] | None = None
) -> pd.DataFrame:
    """How well each model (label → state model or (state-action model, ``policy(states,
    t)``)) follows the real rollouts from ``initial`` (L, n_x) (Table 5.1 or 5.2): per state
    dimension the RMSE of x̂_t = X'ᵀβ_t against the mean of ``real_states`` (L' ≥ 2, T + 1,
    n_x) and its Monte Carlo standard error; the largest ‖β_t‖₁ and Σ_j β_{T,j}."""
    if not isinstance(models, Mapping) or not models:
        raise ValueError("models: expected a non-empty mapping of label to ConditionalEmbedding")
    x0 = check_array(initial, "initial", ndim=2)
    real = check_array(real_states, "real_states", ndim=3)
    n_x = real.shape[2]
    if x0.shape[1] != n_x:
        raise ValueError(f"initial: expected {n_x} columns like real_states, got shape {x0.shape}")
    if real.shape[0] < 2 or real.shape[1] < 2:
        raise ValueError(f"real_states: expected at least 2 rollouts of 2 rows, got {real.shape}")
    labels = list(names) if names is not None else [f"x[{k}]" for k in range(n_x)]
    if len(labels) != n_x:
        raise ValueError(f"names: expected {n_x} names (one per state dimension)")
    real_mean = real[:, 1:].mean(axis=0)  # (T, n_x)
    se = real[:, 1:].std(axis=0, ddof=1).mean(axis=0) / np.sqrt(real.shape[0])
    rows = {}
    for label, entry in models.items():
        model, policy = entry if isinstance(entry, tuple) else (entry, None)
        if not isinstance(model, ConditionalEmbedding) or not (policy is None or callable(policy)):
            raise ValueError(f"models[{label!r}]: expected a ConditionalEmbedding or (it, policy)")
        betas = _predicted(model, x0, real.shape[1], policy)
        err = np.sqrt(((np.stack([model.mean(b) for b in betas]) - real_mean) ** 2).mean(axis=0))
        row = {f"RMSE {n}": float(e) for n, e in zip(labels, err, strict=True)}
        row |= {f"MC s.e. {n}": float(v) for n, v in zip(labels, se, strict=True)}
        row["max ‖β_t‖₁"] = float(np.abs(betas).sum(axis=1).max())
        row["sum of β_T"] = float(betas[-1].sum())
        rows[str(label)] = row
    return pd.DataFrame(rows).T.rename_axis("model")


def fit_table(initial_lengthscale, initial_lam: float, fit: FitResult) -> pd.DataFrame:
    """Length-scales w (d,), λ and the CV error per term (Eq. 5.16) before and after ``fit``."""
    w0 = check_array(initial_lengthscale, "initial_lengthscale", shape=fit.lengthscale.shape)
    lam0 = check_positive(initial_lam, "initial_lam")
    cols = [f"w[{k}]" for k in range(w0.size)]
    data = {"start": [*w0, lam0, fit.initial_loss], "fitted": [*fit.lengthscale, fit.lam, fit.loss]}
    return pd.DataFrame(data, index=[*cols, "λ", "CV error per term"]).T.rename_axis("θ")


def pendulum_policy(gains) -> Policy:
    """clip(Kᵀx, −3, 3), K = ``gains`` (2,), as ``policy(states (b, M, 2), t) -> (b, M, 1)``
    for :func:`~skillkit.models.embedding_prediction.predict` (Table 5.2)."""
    k = check_array(gains, "gains", shape=(2,))

    def policy(states: np.ndarray, t: int) -> np.ndarray:
        return feedback_torque(states, k)[..., None]

    return policy


def marginal_embedding(points, weights, grid, lengthscale: float) -> np.ndarray:
    r"""Σ_j w_j k_h(p_j, y) on ``grid`` (G,) for ``points`` (N,) with ``weights`` (N,) or
    (N, B): up to a constant, one coordinate's marginal embedding under a product SE kernel."""
    p = check_array(points, "points", ndim=1)
    w = check_array(weights, "weights", ndim=(1, 2))
    if w.shape[0] != p.size:
        raise ValueError(f"weights: expected {p.size} rows (one per point), got shape {w.shape}")
    g = check_array(grid, "grid", ndim=1)
    return gram(SquaredExponential(1, lengthscale=lengthscale), g[:, None], p[:, None]) @ w


def empirical_embedding(samples, grid, lengthscale: float) -> tuple[np.ndarray, np.ndarray]:
    """(1/L) Σ_l k_h(x_l, y) of L ≥ 2 ``samples`` on ``grid`` (G,) and its standard error."""
    s = check_array(samples, "samples", ndim=1)
    if s.size < 2:
        raise ValueError(f"samples: expected at least 2 samples, got {s.size}")
    g = check_array(grid, "grid", ndim=1)
    k = gram(SquaredExponential(1, lengthscale=lengthscale), g[:, None], s[:, None])  # (G, L)
    return k.mean(axis=1), k.std(axis=1, ddof=1) / np.sqrt(s.size)


def _compact(z: np.ndarray, digits: int = 4) -> list:
    """``z`` rounded to ``digits`` significant digits of its largest entry (smaller JSON)."""
    top = float(np.max(np.abs(z))) if z.size else 0.0
    if top == 0.0 or not np.isfinite(top):
        return z.tolist()
    return np.round(z, max(0, digits - 1 - int(np.floor(np.log10(top))))).tolist()


def _diverging(fig) -> None:
    """Heatmaps with negative values get a diverging colour scale centred on 0."""
    for trace in fig.data:
        if trace.type == "heatmap" and np.nanmin(np.asarray(trace.z, dtype=float)) < 0:
            trace.update(colorscale="RdBu", reversescale=True, zmid=0.0)


def matrices_figure(matrices: Mapping[str, object], *, pairs: int | None = None, title: str = ""):
    """Heatmaps of kernel matrices (Tables 5.1, 5.2), a panel per title → matrix (n, m), row
    i at the top; ``pairs`` shows only the first rows and columns."""
    if not isinstance(matrices, Mapping) or not matrices:
        raise ValueError("matrices: expected a non-empty mapping of title to 2-D array")
    n_show = None if pairs is None else check_count(pairs, "pairs")
    heat = {"kind": "heatmap", "xlabel": "column j (training pair)"}
    heat["ylabel"] = "row i (training pair)"
    series = []
    for name, value in matrices.items():
        m = check_array(value, f"matrices[{name!r}]", ndim=2)
        if n_show is not None:
            m = m[:n_show, :n_show]
        label = str(name).split("=")[0].strip() or str(name)
        x, y = list(range(m.shape[1])), list(range(m.shape[0]))
        series.append(Series(label, x, y, panel=str(name), z=_compact(m), **heat))
    fig = draw(title, series)
    fig.update_yaxes(autorange="reversed")
    _diverging(fig)
    return fig


def _betas(betas) -> np.ndarray:
    b = check_array(betas, "betas", ndim=(2, 3))
    if b.ndim == 3:
        if b.shape[2] != 1:
            raise ValueError(f"betas: expected shape (T, N) or (T, N, 1), got {b.shape}")
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
    """The weights β_t (T, N) or (T, N, 1) of every predicted step (Table 5.1's loop) over
    t (seconds with ``dt``), with Σ_j β_{t,j} and ‖β_t‖₁."""
    b = _betas(betas)
    t, xlabel = _time_axis(b.shape[0], dt)
    kw = {"panel": "β_t[j] per training pair", "kind": "heatmap", "ylabel": "training pair j"}
    heat = Series("β_t[j]", t, list(range(b.shape[1])), z=_compact(b.T), xlabel=xlabel, **kw)
    common = {"panel": "sum and size of β_t", "xlabel": xlabel, "ylabel": "weights"}
    lines = [
        Series("sum of β_t", t, b.sum(axis=1).tolist(), **common),
        Series("‖β_t‖₁", t, np.abs(b).sum(axis=1).tolist(), **common),
    ]
    fig = draw(title, (heat, *lines))
    fig.update_yaxes(autorange="reversed", row=1, col=1)
    _diverging(fig)
    return fig


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
    """Predicted embeddings β_t (T, N) or (T, N, 1) against real rollouts (L ≥ 2, T + 1, n_x):
    X'ᵀβ_t of coordinate ``dim`` over t against the real mean ± 2 s.e., then per step of
    ``steps`` :func:`marginal_embedding` against :func:`empirical_embedding` with bandwidth h
    (default the model's length-scale of the coordinate)."""
    b = _betas(betas)
    real = check_array(real_states, "real_states", ndim=3)
    n_x = embedding.target_dim
    if b.shape[1] != embedding.n:
        raise ValueError(f"betas: expected {embedding.n} weights per step, got shape {b.shape}")
    if real.shape[2] != n_x or real.shape[1] != b.shape[0] + 1 or real.shape[0] < 2:
        raise ValueError(f"real_states: expected (L≥2, {b.shape[0] + 1}, {n_x}), got {real.shape}")
    index(dim, "dim", n_x)
    if isinstance(steps, (int, np.integer)) or not steps:
        raise ValueError(f"steps: expected a non-empty sequence of steps, got {steps!r}")
    shown = [check_count(s, "steps") for s in steps]
    if max(shown) > b.shape[0]:
        raise ValueError(f"steps: expected steps in 1..{b.shape[0]}, got {list(steps)}")
    if bandwidth is None:
        ls = getattr(embedding.kernel, "lengthscale", None)
        if ls is None:
            raise ValueError("bandwidth: the embedding's kernel has no length-scale; give one")
        flat = np.asarray(ls.detach().cpu().numpy(), dtype=float).ravel()
        bandwidth = flat[dim] if flat.size > 1 else flat[0]
    h = check_positive(bandwidth, "bandwidth")
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

    def real_series(x, emp, emp_se, common) -> Series:
        lo, hi = (emp - 2 * emp_se).tolist(), (emp + 2 * emp_se).tolist()
        return Series("real samples", x, emp.tolist(), lower=lo, upper=hi, band=band, **common)

    common = {"panel": f"mean of {label}: X′ᵀβ_t", "xlabel": xlabel, "ylabel": label}
    series = [
        Series("predicted", t_pred, [float(embedding.mean(v)[dim]) for v in b], **common),
        real_series(t_real, mean, se, common),
    ]
    predicted = marginal_embedding(pts, weights, grid, h)  # (G, S)
    for k, s in enumerate(shown):
        emp, emp_se = empirical_embedding(real[:, s, dim], grid, h)
        when = f"t = {s}" if dt is None else f"t = {s * dt:.3g} s"
        common = {"panel": f"embedding at {when}", "xlabel": label, "ylabel": f"μ (h = {h:.3g})"}
        series += [
            Series("predicted", grid.tolist(), predicted[:, k].tolist(), **common),
            real_series(grid.tolist(), emp, emp_se, common),
        ]
    fig = draw(title, series)
    # every value to scale (an embedding is ~0 over most of its grid: no robust range)
    fig.data = [t for t in fig.data if not str(t.name or "").endswith("(off scale)")]
    notes = ("at the top edge", "at the bottom edge")  # plots' note on clipped values
    fig.layout.annotations = [
        a for a in fig.layout.annotations if not any(n in str(a.text or "") for n in notes)
    ]
    return fig.update_yaxes(range=None, autorange=True)


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
    """The widget's redraw: a ``ConditionalEmbedding`` (SE(``lengthscale_factor`` ×
    std(inputs)), ``lam``) of ``targets`` (N, n_x) on ``inputs`` (N, d_z), predicted from
    ``initial`` (L, n_x) and drawn by :func:`embedding_figure` at ``step`` (1 … T)."""
    z = check_array(inputs, "inputs", ndim=2)
    factor = check_positive(lengthscale_factor, "lengthscale_factor")
    lam = check_positive(lam, "lam")
    real = check_array(real_states, "real_states", ndim=3)
    is_int = isinstance(step, (int, np.integer)) and not isinstance(step, bool)
    if not (is_int and 1 <= step <= real.shape[1] - 1):
        raise ValueError(f"step: expected an integer in [1, {real.shape[1] - 1}], got {step!r}")
    sd = z.std(axis=0)
    ls = factor * np.where(sd > 0, sd, 1.0)
    model = ConditionalEmbedding(z, targets, SquaredExponential(z.shape[1], lengthscale=ls), lam)
    x0 = check_array(initial, "initial", ndim=2)
    betas = _predicted(model, x0, real.shape[1], policy)
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
    """The cross-validated ``loss`` at θ = [log(f · w), log λ] (Sec. 5.3) over ``factors``
    f > 0 (default 9 in 0.03 … 10) of the length-scales w (d,), a curve per λ of ``lams``."""
    w = check_array(lengthscale, "lengthscale", shape=(loss.dim,))
    if np.any(w <= 0):
        raise ValueError(f"lengthscale: expected positive values, got {w}")
    f = np.geomspace(0.03, 10.0, 9) if factors is None else check_array(factors, "factors", ndim=1)
    if f.size < 2 or np.any(f <= 0):
        raise ValueError(f"factors: expected at least 2 positive values, got {f}")
    if not lams:
        raise ValueError("lams: expected at least one λ")
    kw = {"xlabel": "length-scale factor f (× w)", "ylabel": "CV error per term"}
    series = []
    for lam in lams:
        lam = check_positive(lam, "lams")
        values = [loss(np.append(np.log(v * w), np.log(lam))) for v in f]
        series.append(Series(f"λ = {lam:.3g}", f.tolist(), values, log_x=True, log_y=True, **kw))
    return draw(title, series)


@contextmanager
def warnings_as_note(reason: str = "") -> Iterator[list]:
    """Show the block's warnings (``warnings.warn`` and warning lines on stderr) once, as a
    Markdown note with ``reason``; yields the caught messages, filled when the block ends."""
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
    counts = Counter(found)
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
