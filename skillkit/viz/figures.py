"""Figures of live objects (learning runs, GP fits, curves, predicted against real paths), drawn
by :func:`skillkit.viz.plots.draw_figure` with ``backend`` "plotly" or "matplotlib"."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_type
from skillkit.series import Series, trial_band
from skillkit.viz.plots import draw_figure

__all__ = [
    "gpreps_run_paths_figure",
    "line_figure",
    "model_paths_figure",
    "plot_gp_fit",
    "plot_learning",
    "prediction_figure",
]

_LEARN_KEYS = ("rollouts", "mean_reward", "explore_rollouts", "explore_reward")
#: Trajectory signals drawn as the real paths of :func:`model_paths_figure` (world x, y[, z]).
REAL_PATH_SIGNALS: tuple[str, ...] = ("control_puck", "target_puck", "ball")


def draw(title: str, series: Iterable[Series], backend: str = "plotly"):
    """:func:`~skillkit.viz.plots.draw_figure` of ``series`` under ``title``."""
    return draw_figure({"title": title, "series": list(series)}, backend)


def polyline(paths) -> tuple[list, list]:
    """x and y of paths (each (K, 2)) joined into one polyline broken by NaN gaps."""
    gap = np.full((1, 2), np.nan)
    joined = np.concatenate([np.concatenate([np.asarray(p, dtype=float), gap]) for p in paths])
    return joined[:, 0].tolist(), joined[:, 1].tolist()


def plot_learning(
    runs,
    *,
    label: str = "policy mean",
    backend: str = "plotly",
    explore: bool = True,
    title: str = "learning curve",
    ylabel: str = "reward",
):
    """The policy mean's reward against rollouts of :func:`skillkit.search.loop.learn` results:
    ``runs`` is one result, runs on one rollout grid (mean ± std band) or ``{label: result or
    runs}`` (``label`` names a single setting); ``explore`` adds the batches' mean rewards."""
    if isinstance(runs, Mapping) and "rollouts" not in runs:
        if not runs:
            raise ValueError("runs: empty mapping")
        groups = {str(k): v for k, v in runs.items()}
    else:
        groups = {label: runs}
    series, common = [], {"panel": "", "xlabel": "rollouts", "ylabel": ylabel}
    for name, group in groups.items():
        group_runs = [group] if isinstance(group, Mapping) else group
        if not isinstance(group_runs, Sequence) or isinstance(group_runs, str) or not group_runs:
            msg = f"runs[{name!r}]: expected a learn() result or a list of them, got {group!r:.30}"
            raise ValueError(msg)
        curves = [_check_learn(r, f"runs[{name!r}]") for r in group_runs]
        x, ex = curves[0]["rollouts"], curves[0]["explore_rollouts"]
        for c in curves[1:]:
            if not (np.array_equal(c["rollouts"], x) and np.array_equal(c["explore_rollouts"], ex)):
                raise ValueError(f"runs[{name!r}]: the runs have different rollout grids")
        n = len(curves)
        m, band = trial_band(np.stack([c["mean_reward"] for c in curves]), over="runs")
        label = name if n == 1 else f"{name} (mean of {n} runs)"
        mean = Series(label, x.tolist(), m, **band, **common)
        series.append({**mean.to_dict(), "_group": name})
        if explore and ex.size:
            ey = np.mean(np.stack([c["explore_reward"] for c in curves]), axis=0)
            what = f"{name}: exploration batches" + (" (mean over runs)" if n > 1 else "")
            dots = Series(what, ex.tolist(), ey.tolist(), kind="markers", **common)
            series.append({**dots.to_dict(), "_group": name})  # coloured as its curve
    return draw(title, series, backend)


def _check_learn(r, name: str) -> dict[str, np.ndarray]:
    check_type(r, Mapping, name, "a learn() result dict")
    missing = [k for k in _LEARN_KEYS if k not in r]
    if missing:
        raise ValueError(f"{name}: not a learn() result, missing keys {missing}")
    out = {k: np.asarray(r[k], dtype=float).ravel() for k in _LEARN_KEYS}
    for a, b in (("rollouts", "mean_reward"), ("explore_rollouts", "explore_reward")):
        if out[a].shape != out[b].shape:
            msg = f"{name}: {a} and {b} differ in length ({out[a].size} vs {out[b].size})"
            raise ValueError(msg)
    if out["rollouts"].size == 0:
        raise ValueError(f"{name}: empty learning curve")
    return out


def plot_gp_fit(
    model,
    x_train,
    y_train,
    x_test,
    *,
    backend: str = "plotly",
    include_noise: bool = True,
    f_true=None,
    label: str = "GP",
    title: str = "GP regression",
    xlabel: str = "x",
    ylabel: str = "y",
):
    """A 1-D GP fitted on ``x_train`` (N,) or (N, 1), ``y_train`` (N,): :func:`gp_band` of
    ``model.predict`` (Eqs 2.26–2.27) at the sorted ``x_test`` (n ≥ 2), the data and ``f_true``."""
    if not callable(getattr(model, "predict", None)):
        raise ValueError(f"model: expected a fitted GP with predict(), got {type(model).__name__}")
    xtr, ytr = _column(x_train, "x_train"), _column(y_train, "y_train")
    if ytr.size != xtr.size:
        raise ValueError(f"y_train: expected {xtr.size} values (one per x_train), got {ytr.size}")
    xte = np.sort(_column(x_test, "x_test"))
    if xte.size < 2:
        raise ValueError(f"x_test: expected at least 2 points, got {xte.size}")
    common = {"panel": "", "xlabel": xlabel, "ylabel": ylabel}
    series = [
        gp_band(model, xte, f"{label} mean", include_noise=include_noise, **common),
        Series("data", xtr.tolist(), ytr.tolist(), kind="markers", **common),
    ]
    if f_true is not None:
        f = np.asarray(f_true(xte), float).tolist()
        series.append(Series("true function", xte.tolist(), f, **common))
    return draw(title, series, backend)


def gp_band(model, x: np.ndarray, name: str, *, include_noise: bool = True, **fields) -> Series:
    """``model.predict``'s mean at ``x`` (n,) with its 95% band mean ± 1.96 σ of y
    (``include_noise``) or of f; ``fields`` go to the :class:`~skillkit.series.Series`."""
    mean, var = model.predict(x[:, None], include_noise=include_noise)
    mean, var = np.asarray(mean, dtype=float), np.asarray(var, dtype=float)
    if mean.ndim == 2 and mean.shape[1] == 1:
        mean, var = mean[:, 0], var[:, 0]
    if mean.shape != x.shape:
        msg = f"model: expected one output (predictions of shape ({x.size},)), got {mean.shape}"
        raise ValueError(msg)
    half = 1.96 * np.sqrt(np.maximum(var, 0.0))
    band = f"95% band of {'y' if include_noise else 'f'} (mean ± 1.96 σ)"
    lo, hi = (mean - half).tolist(), (mean + half).tolist()
    return Series(name, x.tolist(), mean.tolist(), lower=lo, upper=hi, band=band, **fields)


def _column(x, name: str) -> np.ndarray:
    x = check_array(x, name, ndim=(1, 2))
    if (x.ndim == 2 and x.shape[1] != 1) or x.size == 0:
        raise ValueError(f"{name}: expected a non-empty shape (n,) or (n, 1), got {x.shape}")
    return x.ravel()


def line_figure(
    curves: Mapping,
    *,
    title: str = "",
    xlabel: str = "",
    ylabel: str = "",
    log_y: bool = False,
    backend: str = "plotly",
):
    """One panel of named curves: ``curves`` maps a legend label to a pair (x, y) of 1-D arrays
    of equal length; ``log_y`` draws a logarithmic y axis."""
    if not isinstance(curves, Mapping) or not curves:
        raise ValueError("curves: expected a non-empty mapping of label to (x, y)")
    series, axis = [], {"xlabel": xlabel, "ylabel": ylabel, "log_y": log_y}
    for label, pair in curves.items():
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise ValueError(f"curves[{label!r}]: expected a pair (x, y)")
        x = check_array(pair[0], f"curves[{label!r}] x", ndim=1)
        y = check_array(pair[1], f"curves[{label!r}] y", shape=x.shape)
        series.append(Series(str(label), x.tolist(), y.tolist(), **axis))
    return draw(title, series, backend)


def prediction_figure(
    predicted,
    real,
    dim: int = 0,
    *,
    label: str = "",
    dt: float | None = None,
    backend: str = "plotly",
):
    """Predicted against real trajectories of state dimension ``dim``, a panel per (ω, s) pair:
    the predicted mean with a 5th–95th percentile band and the real one. ``predicted`` is a
    ``ModelRollouts`` or an array (B, L, T + 1, n_x) (or (B, T + 1, n_x): no band), ``real``
    the B simulated trajectories (Trajectory or (T_real, n_x)); ``label`` the y label, ``dt``
    the time step (default: x is the step index)."""
    states = np.asarray(getattr(predicted, "states", predicted), dtype=float)
    if states.ndim == 3:  # one deterministic prediction per pair (e.g. an embedding's means)
        states = states[:, None]
    if states.ndim != 4:
        msg = f"predicted: expected shape (B, L, T + 1, n_x) or (B, T + 1, n_x), got {states.shape}"
        raise ValueError(msg)
    B, L, T1, n_x = states.shape
    reals = [np.asarray(getattr(r, "states", r), dtype=float) for r in real]
    if len(reals) != B:
        msg = f"real: expected {B} trajectories (one per predicted pair), got {len(reals)}"
        raise ValueError(msg)
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or not 0 <= dim < n_x:
        raise ValueError(f"dim: expected an integer in [0, {n_x}), got {dim!r}")
    step, xlabel = (1.0, "step") if dt is None else (float(dt), "t [s]")
    series = []
    for b in range(B):
        x = (step * np.arange(T1)).tolist()
        y = states[b, :, :, dim]
        common = {"panel": f"pair {b + 1}", "xlabel": xlabel, "ylabel": label}
        band = {}
        if L > 1:
            lo, hi = np.percentile(y, [5, 95], axis=0)
            what = f"5th–95th percentile of {L} predicted trajectories"
            band = {"lower": lo.tolist(), "upper": hi.tolist(), "band": what}
        series.append(Series("predicted mean", x, y.mean(axis=0).tolist(), **band, **common))
        n = min(len(reals[b]), T1)
        series.append(Series("real", x[:n], reals[b][:n, dim].tolist(), **common))
    return draw("predicted vs real", series, backend)


def model_paths_figure(
    model,
    context,
    omega,
    real=None,
    *,
    n_samples: int = 10,
    rng=None,
    axes: tuple[int, int] = (0, 1),
    title: str = "",
    backend: str = "plotly",
):
    """A reward model's (``prediction_layers``) ``n_samples`` paths per layer for one (s, ω) over
    ``real``, the simulator's rollout (signals :data:`REAL_PATH_SIGNALS`) or named world paths
    (T, 2|3); ``axes`` the world axes drawn ((0, 1) top view, (0, 2) side view)."""
    from skillkit.viz.model_layers import model_layers

    pair = isinstance(axes, (tuple, list)) and len(axes) == 2 and axes[0] != axes[1]
    if not pair or any(isinstance(a, bool) or a not in (0, 1, 2) for a in axes):
        raise ValueError(f"axes: expected two different world axes out of 0, 1, 2, got {axes!r}")
    panel = {"xlabel": f"{'xyz'[axes[0]]} [m]", "ylabel": f"{'xyz'[axes[1]]} [m]"}
    series = []
    for layer in model_layers(model, context, omega, n_samples=n_samples, rng=rng):
        paths = layer["trajectories"][..., list(axes)]  # (L, T, 2)
        what = f"{layer['label']} ({paths.shape[0]} sampled)"
        series.append(Series(what, *polyline(paths), **panel))
    if real is not None:
        signals = getattr(real, "signals", None)
        if signals is not None:
            real = {k: signals[k] for k in REAL_PATH_SIGNALS if k in signals}
        real = check_type(real, Mapping, "real", "a Trajectory or a mapping of paths")
        for key, path in real.items():
            p = np.asarray(path, dtype=float)
            if p.ndim != 2 or p.shape[1] not in (2, 3) or max(axes) >= p.shape[1]:
                msg = f"real[{key!r}]: expected a path (T, 2|3) holding axes {axes}, got {p.shape}"
                raise ValueError(msg)
            what = f"real: {key.replace('_', ' ')}"
            series.append(Series(what, p[:, axes[0]].tolist(), p[:, axes[1]].tolist(), **panel))
    return draw(title or "predicted paths over the real ones", series, backend)


def gpreps_run_paths_figure(
    run_dir,
    trial: int = 0,
    *,
    update: int = -1,
    context=None,
    n_samples: int = 10,
    seed: int = 0,
    axes: tuple[int, int] = (0, 1),
    backend: str = "plotly",
):
    """:func:`model_paths_figure` of a stored GPREPS run's last reward model at the policy mean
    of ``update`` (-1: the last) of ``trial`` at ``context`` (default: sampled with ``seed``,
    which seeds the rollout and samples too). It unpickles the model: load only runs you trust.
    """
    from skillkit.viz.model_layers import load_gpreps_run

    history, model = load_gpreps_run(run_dir, trial)
    policies, n = history.policies, len(history.policies)
    integer = isinstance(update, (int, np.integer)) and not isinstance(update, bool)
    if not (integer and -n <= update < n):
        raise ValueError(f"update: expected an integer in [{-n}, {n}), got {update!r}")
    task = model.task
    rng = np.random.default_rng(seed)
    s = task.sample_context(rng) if context is None else task.check_context(context)
    omega = policies[update].mean_of(s)
    real = task.rollout(omega, s, rng)
    title = f"{Path(run_dir).name}, trial {trial}, update {update % n}: predicted vs real paths"
    return model_paths_figure(
        model, s, omega, real, n_samples=n_samples, rng=rng, axes=axes, title=title, backend=backend
    )
