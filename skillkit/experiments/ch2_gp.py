"""Chapter 2 GP experiments: GP regression (Fig. 2.12) and deterministic prediction (Figs 2.6–2.7).

* ``fig2.12``: GP regression (Eqs 2.26–2.27) of a 1-D function from 1, a few and many noisy
  samples with fixed hyper-parameters: mean, 95% band of y_* and samples of p(f_* | x_*, D).
* ``fig2.7``: the successor distribution p(y) = ∫ p(y | x) N(x | μ_x, σ_x²) dx of a 1-D GP
  model three ways: the truth (Monte Carlo and quadrature), exact moment matching (Fig. 2.7)
  and linearisation at μ_x (Fig. 2.6), with moment errors and KL(p ‖ Gaussian).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ExactGP, record_numerical_events, robust_cholesky
from skillkit.models.moment_matching import linearize, moment_match
from skillkit.trial import TrialContext

GP_BAND = "95% interval of y: GP mean ± 1.96 σ (noise included)"
"""``Series.band`` of the GP fits of ``fig2.12`` and ``fig2.7`` (Eqs 2.26–2.27 plus σ_n²)."""

__all__ = [
    "DeterministicPredictionSettings",
    "GPRegressionSettings",
    "fig2_7_function",
    "fig2_12_function",
    "successor_density",
]


def fig2_12_function(x: np.ndarray) -> np.ndarray:
    """The regression target of Fig. 2.12: f(x) = sin(1.5 x) + 0.2 x."""
    return np.sin(1.5 * x) + 0.2 * x


def fig2_7_function(x: np.ndarray) -> np.ndarray:
    """The nonlinear 1-D model of Figs 2.6–2.7: f(x) = sin(2 x)."""
    return np.sin(2.0 * x)


# ---------------------------------------------------------------------------- fig2.12
@dataclass(frozen=True)
class GPRegressionSettings(Settings):
    """Settings of ``fig2.12`` (Sec. 2.4, Eqs 2.26–2.27); the same at every scale."""

    n_points: tuple[int, ...] = setting(
        (1, 4, 25), "Observations of each panel, increasing (one, a few, many).", minimum=1
    )
    noise_std: float = setting(0.1, "Std σ_n of the observation noise and the GP's.", above=0)
    lengthscale: float = setting(0.8, "Fixed SE length-scale of the GP (Eq. 2.24).", above=0)
    outputscale: float = setting(1.0, "Fixed SE signal variance σ_f² (Eq. 2.24).", above=0)
    x_range: tuple[float, float] = setting((-4.0, 4.0), "Interval of inputs, grid and tests.")
    n_grid: int = setting(161, "Plot grid points.", minimum=1)
    n_function_samples: int = setting(5, "Functions drawn from p(f_* | x_*, D).", minimum=1)
    n_test: int = setting(2000, "Noisy test points of the 95% band's coverage.", minimum=1)


SCALES_2_12 = scales(GPRegressionSettings())  # seconds: every scale is the thesis setting


def _run_2_12(
    settings: GPRegressionSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    lo, hi = settings.x_range
    grid = np.linspace(lo, hi, settings.n_grid)
    test = rng.uniform(lo, hi, settings.n_test)
    test_y = fig2_12_function(test) + settings.noise_std * rng.standard_normal(settings.n_test)
    trial.reset(total=len(settings.n_points))
    out: dict = {"grid": grid}
    X = rng.uniform(lo, hi, max(settings.n_points))
    y = fig2_12_function(X) + settings.noise_std * rng.standard_normal(X.shape)
    hyper = dict(lengthscale=settings.lengthscale, outputscale=settings.outputscale)
    hyper.update(noise=settings.noise_std**2, n_steps=0, additive_noise=0.0, standardize=False)
    for n in settings.n_points:
        gp = ExactGP(**hyper).fit(X[:n, None], y[:n])
        mean, var = gp.predict(grid[:, None])
        cov = gp.predictor.latent_covariance(torch.as_tensor(grid[:, None]))[0]
        with record_numerical_events():  # the jitter is kept below (and counted by the run)
            L, jitter = robust_cholesky(cov, "posterior covariance on the grid")
        draws = rng.standard_normal((len(grid), settings.n_function_samples))
        samples = mean[None, :] + (L.numpy() @ draws).T
        tm, tv = gp.predict(test[:, None])
        inside = np.abs(test_y - tm) <= 1.96 * np.sqrt(tv)
        out[f"n{n}"] = {
            "X": X[:n],
            "y": y[:n],
            "mean": mean,
            "std": np.sqrt(var),
            "samples": samples,
            "sample_jitter": jitter,
            "rmse": float(np.sqrt(np.mean((mean - fig2_12_function(grid)) ** 2))),
            "mean_std": float(np.mean(np.sqrt(var))),
            "sample_spread": float(np.mean(samples.std(axis=0))),
            "coverage95": float(inside.mean()),
        }
        trial.update()
    return out


def _gp_band(name: str, x, mean, std, kw: dict) -> Series:
    lower, upper = (mean - 1.96 * std).tolist(), (mean + 1.96 * std).tolist()
    return Series(name, x.tolist(), mean.tolist(), lower=lower, upper=upper, band=GP_BAND, **kw)


def _points(name: str, x, y, kw: dict) -> Series:
    return Series(name, np.asarray(x).tolist(), np.asarray(y).tolist(), kind="markers", **kw)


def _summarize_2_12(
    settings: GPRegressionSettings, trials: list[dict]
) -> tuple[list[Series], dict]:
    first = trials[0]
    grid = first["grid"]
    series: list[Series] = []
    for n in settings.n_points:
        r = first[f"n{n}"]
        panel = f"{n} sample{'s' if n > 1 else ''}"
        kw = dict(panel=panel, xlabel="x", ylabel="y")
        series.append(Series("true function", grid.tolist(), fig2_12_function(grid).tolist(), **kw))
        series.append(_gp_band("GP mean, 95% band of y", grid, r["mean"], r["std"], kw))
        for i, s in enumerate(r["samples"]):
            series.append(Series(f"sample {i + 1} of p(f*|x*,D)", grid.tolist(), s.tolist(), **kw))
        series.append(_points("observations", r["X"], r["y"], kw))
    ns = settings.n_points
    keys = ("rmse", "mean_std", "sample_spread", "coverage95")
    summary = {
        "per_n_points": {
            str(n): {k: float(np.mean([t[f"n{n}"][k] for t in trials])) for k in keys} for n in ns
        },
        "hyperparameters": {
            k: getattr(settings, k) for k in ("lengthscale", "outputscale", "noise_std")
        },
        "max_sample_jitter": max(t[f"n{n}"]["sample_jitter"] for t in trials for n in ns),
    }
    return series, summary


register(
    Experiment(
        id="fig2.12",
        title="GP regression with an increasing number of samples",
        settings_class=GPRegressionSettings,
        settings=SCALES_2_12,
        run_trial=_run_2_12,
        summarize=_summarize_2_12,
    )
)


# ---------------------------------------------------------------------------- fig2.7
@dataclass(frozen=True)
class DeterministicPredictionSettings(Settings):
    """Settings of ``fig2.7`` (Sec. 2.4.1, Figs 2.6–2.7)."""

    n_train: int = setting(40, "Noisy observations of f(x) = sin(2x) that train the GP.", minimum=1)
    train_range: tuple[float, float] = setting((-2.5, 2.5), "Interval of the training inputs.")
    train_noise_std: float = setting(0.05, "Std of the training observations' noise.", minimum=0)
    n_steps: int = setting(100, "Marginal-likelihood steps of the GP (Eq. 2.28).", minimum=0)
    input_mean: float = setting(0.4, "Mean μ_x of the Gaussian input N(μ_x, σ_x²) (Fig. 2.6).")
    input_std: float = setting(0.5, "Std σ_x of the Gaussian input (Fig. 2.6).", above=0)
    n_monte_carlo: int = setting(200_000, "Monte Carlo samples of the successor.", minimum=1)
    n_bins: int = setting(80, "Bins of the Monte Carlo histogram.", minimum=1)
    n_quadrature: int = setting(2001, "Trapezoid nodes of p(y) (Eq. 4.4).", minimum=2)


SCALES_2_7 = scales(
    DeterministicPredictionSettings(),
    smoke=dict(n_monte_carlo=100_000, n_steps=40),
    paper=dict(n_monte_carlo=1_000_000),
)


def _gauss(y, mean, var):
    return np.exp(-0.5 * (y - mean) ** 2 / var) / np.sqrt(2 * np.pi * var)


def successor_density(
    predictor, mean: float, std: float, y_grid: np.ndarray, n_quadrature: int = 2001
) -> np.ndarray:
    """p(y) = ∫ N(y | μ(x), σ²(x)) N(x | mean, std²) dx by quadrature for a 1-D GP (Eq. 4.4).

    Parameters
    ----------
    predictor : GPPredictor
        One input, one output.
    mean, std : float
        The Gaussian input.
    y_grid : ndarray, shape (G,)
        Where to evaluate the density.
    n_quadrature : int
        Trapezoid nodes over mean ± 8 std.

    Returns
    -------
    ndarray, shape (G,)
    """
    x = np.linspace(mean - 8 * std, mean + 8 * std, n_quadrature)
    w = np.exp(-0.5 * ((x - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi))
    w = w * np.gradient(x)
    with torch.no_grad():
        m = predictor.moments(torch.as_tensor(x[:, None], dtype=predictor.dtype))
    mu, var = m.mean[:, 0].numpy(), m.var[:, 0].numpy()
    return _gauss(y_grid[:, None], mu, var) @ w


def _kl_to_gaussian(p: np.ndarray, y: np.ndarray, mean: float, var: float) -> float:
    """KL(p || N(mean, var)) by the trapezoid rule on the grid y."""
    logq = -0.5 * (y - mean) ** 2 / var - 0.5 * np.log(2 * np.pi * var)
    integrand = np.where(p > 0, p * (np.log(np.where(p > 0, p, 1.0)) - logq), 0.0)
    return float(np.trapezoid(integrand, y))


def _run_2_7(
    settings: DeterministicPredictionSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    trial.reset(total=3)
    lo, hi = settings.train_range
    X = rng.uniform(lo, hi, settings.n_train)
    y = fig2_7_function(X) + settings.train_noise_std * rng.standard_normal(X.shape)
    gp = ExactGP(n_steps=settings.n_steps, additive_noise=0.0).fit(X[:, None], y, rng=rng)
    pred = gp.predictor
    m, s = settings.input_mean, settings.input_std
    trial.update()
    mm = moment_match(pred, [m], [[s * s]])
    lin = linearize(pred, [m], [[s * s]])
    x_mc = rng.normal(m, s, settings.n_monte_carlo)
    mu, var = gp.predict(x_mc[:, None])
    y_mc = mu + np.sqrt(var) * rng.standard_normal(len(mu))
    trial.update()
    lo_y, hi_y = float(y_mc.min()) - 0.5, float(y_mc.max()) + 0.5
    y_grid = np.linspace(lo_y, hi_y, settings.n_quadrature)
    p = successor_density(pred, m, s, y_grid, settings.n_quadrature)
    true_mean = float(np.trapezoid(p * y_grid, y_grid))
    true_var = float(np.trapezoid(p * (y_grid - true_mean) ** 2, y_grid))
    hist, edges = np.histogram(y_mc, bins=settings.n_bins, density=True)
    x_grid = np.linspace(lo, hi, 201)
    gm, gv = gp.predict(x_grid[:, None])
    slope = float(lin.input_output_cov[0, 0]) / (s * s)  # cov(x, y) = S J
    trial.update()
    return {
        "x_grid": x_grid,
        "gp_mean": gm,
        "gp_std": np.sqrt(gv),
        "train_X": X,
        "train_y": y,
        "tangent": float(lin.mean[0]) + slope * (x_grid - m),
        "y_grid": y_grid,
        "true_density": p,
        "hist": hist,
        "hist_centres": 0.5 * (edges[1:] + edges[:-1]),
        "true_mean": true_mean,
        "true_var": true_var,
        "mc_mean": float(y_mc.mean()),
        "mc_var": float(y_mc.var()),
        "mm_mean": float(mm.mean[0]),
        "mm_var": float(mm.cov[0, 0]),
        "lin_mean": float(lin.mean[0]),
        "lin_var": float(lin.cov[0, 0]),
        "kl_mm": _kl_to_gaussian(p, y_grid, float(mm.mean[0]), float(mm.cov[0, 0])),
        "kl_lin": _kl_to_gaussian(p, y_grid, float(lin.mean[0]), float(lin.cov[0, 0])),
        "density_mass": float(np.trapezoid(p, y_grid)),
    }


def _summarize_2_7(
    settings: DeterministicPredictionSettings, trials: list[dict]
) -> tuple[list[Series], dict]:
    r = trials[0]
    m, s = settings.input_mean, settings.input_std
    xg, yg = r["x_grid"], r["y_grid"]
    model = dict(panel="model f(x) (GP) and its linearisation at the input mean", xlabel="x")
    model["ylabel"] = "y"
    inp = dict(panel="input distribution N(x | μₓ, σₓ²)", xlabel="x", ylabel="density")
    out = dict(panel="successor distribution p(y)", xlabel="y", ylabel="density")
    series = [
        _gp_band("GP model (mean, 95% band)", xg, r["gp_mean"], r["gp_std"], model),
        _points("training data", r["train_X"], r["train_y"], model),
        Series("linearisation (tangent)", xg.tolist(), r["tangent"].tolist(), **model),
        Series("input density", xg.tolist(), _gauss(xg, m, s * s).tolist(), **inp),
        _points("Monte Carlo histogram", r["hist_centres"], r["hist"], out),
        Series("true density (quadrature)", yg.tolist(), r["true_density"].tolist(), **out),
    ]
    for name, key in (("moment matching", "mm"), ("linearisation", "lin")):
        g = _gauss(yg, r[f"{key}_mean"], r[f"{key}_var"])
        series.append(Series(name, yg.tolist(), g.tolist(), **out))
    keys = (
        "true_mean true_var mc_mean mc_var mm_mean mm_var lin_mean lin_var kl_mm kl_lin "
        "density_mass"
    ).split()
    avg = {k: float(np.mean([t[k] for t in trials])) for k in keys}
    summary = {
        **avg,
        "mm_mean_error": float(np.mean([abs(t["mm_mean"] - t["true_mean"]) for t in trials])),
        "mm_var_rel_error": float(np.mean([abs(t["mm_var"] / t["true_var"] - 1) for t in trials])),
        "lin_mean_error": float(np.mean([abs(t["lin_mean"] - t["true_mean"]) for t in trials])),
        "lin_var_rel_error": float(
            np.mean([abs(t["lin_var"] / t["true_var"] - 1) for t in trials])
        ),
    }
    return series, summary


register(
    Experiment(
        id="fig2.7",
        title="Linearisation vs moment matching vs the true successor distribution",
        settings_class=DeterministicPredictionSettings,
        settings=SCALES_2_7,
        run_trial=_run_2_7,
        summarize=_summarize_2_7,
    )
)
