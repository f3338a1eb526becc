r"""Chapter 2 step by step with the library's DMP, ExactGP and moment matching: DMPs
(Sec. 2.2.1, Eqs. 2.21–2.23), GP noise and hyper-parameters (Sec. 2.3, Eqs. 2.25–2.28) and one
moment-matching step against Monte Carlo (Sec. 2.1.2, Fig. 2.7). Handled GP events are counted
in tables and titles, not warned about. Figures take ``backend`` in {"plotly", "matplotlib"}."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial

import numpy as np
import pandas as pd
import torch
from numpy.typing import ArrayLike
from scipy.optimize import minimize

from skillkit._validation import as_generator, check_array, check_count, check_positive, check_type
from skillkit.experiments.ch2 import FORCING_LABEL, reach_demonstration
from skillkit.experiments.ch2_gp import fig2_12_function, successor_density
from skillkit.models.gp import DTYPE, ExactGP, neg_log_marginal_likelihood, record_numerical_events
from skillkit.models.moment_matching import GaussianPrediction, linearize, moment_match
from skillkit.policies.dmp import DMP
from skillkit.teaching._common import draw, index, sig
from skillkit.viz.figures import gp_band, plot_gp_fit
from skillkit.viz.series import Series

#: Inputs drawn by :func:`noisy_samples` before the first ``n_points`` are kept, so the data
#: sets of one seed are nested.
POOL = 200
_EVENT_WORDS = {
    "noise_at_floor": "noise at its floor",
    "jitter_increased": "jitter added",
    "restored_iterate": "optimiser restored an iterate",
    "negative_variance_clipped": "negative variances clipped",
}


def _times(times: ArrayLike) -> np.ndarray:
    t = check_array(times, "times", ndim=1)
    if t.shape[0] < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("times: expected at least 2 strictly increasing time stamps")
    return t


def _fitted(gp, name: str = "gp") -> ExactGP:
    if not isinstance(gp, ExactGP) or gp.predictor is None:
        raise ValueError(f"{name}: expected a fitted ExactGP")
    return gp


def phase_figure(dmp: DMP, times: ArrayLike, *, backend: str = "plotly"):
    """The phase z_t = exp(−τ α_z t) (Eq. 2.22) over ``times`` (s), the basis centres c_i
    marked where it passes them."""
    centres = check_type(dmp, DMP, "dmp", "a DMP").centers
    t = _times(times)
    t_c = -np.log(centres) / (dmp.tau * dmp.alpha_z)
    kw = {"xlabel": "t [s]", "ylabel": "phase z"}
    z = f"z(t) = exp(−τ α_z t), α_z = {dmp.alpha_z:g}"
    centre_label = f"basis centres c_i ({dmp.n_basis})"
    series = [
        Series(z, t.tolist(), dmp.phase(t).tolist(), **kw),
        Series(centre_label, t_c.tolist(), centres.tolist(), kind="markers", **kw),
    ]
    return draw("The phase z(t) (Eq. 2.22) runs from 1 towards 0", series, backend)


def basis_figure(dmp: DMP, times: ArrayLike, *, backend: str = "plotly"):
    """The basis φ_i(z) = z ψ_i(z) / Σ_j ψ_j(z) of f(z) = φ(z)ᵀv (Sec. 2.2.1) and their sum z,
    over the phase z(times) and over ``times``."""
    check_type(dmp, DMP, "dmp", "a DMP")
    t = _times(times)
    z_t = dmp.phase(t)
    z = np.linspace(float(z_t.min()), 1.0, t.shape[0])
    series = []
    for label, x, zz in (("over the phase z", z, z), ("over time t", t, z_t)):
        phi = dmp.basis(zz)
        kw = {"panel": label, "xlabel": "phase z" if x is z else "t [s]", "ylabel": "φ_i"}
        series += [
            Series(f"φ_{i + 1}", x.tolist(), phi[:, i].tolist(), **kw) for i in range(dmp.n_basis)
        ]
        series.append(
            Series("Σ_i φ_i = z", x.tolist(), phi.sum(axis=1).tolist(), dash="dash", **kw)
        )
    title = f"{dmp.n_basis} basis functions: normalised Gaussians times z (Sec. 2.2.1)"
    return draw(title, series, backend)


def forcing_figure(
    dmp: DMP,
    times: ArrayLike,
    q: ArrayLike,
    qd: ArrayLike,
    qdd: ArrayLike,
    *,
    joint: int = 0,
    backend: str = "plotly",
):
    """The fitted forcing term f(z_t; v) = φ(z_t)ᵀv against its target Y (Eq. 2.23), and its
    terms φ_i(z_t) v_i.

    Parameters
    ----------
    dmp : DMP
        Fitted on the demonstration ``times`` (N,), ``q``, ``qd``, ``qdd`` (N, n_joints).
    joint : int
        The joint drawn.
    """
    check_type(dmp, DMP, "dmp", "a DMP")
    joint = index(joint, "joint", dmp.n_joints)
    t = _times(times)
    target = dmp.forcing_target(t, q, qd, qdd)[:, joint]
    f = dmp.forcing(t - t[0])[:, joint]
    phi = dmp.basis(dmp.phase(t - t[0]))
    # each term only where its basis function is above 1% of its peak
    parts = np.where(phi >= 0.01 * phi.max(axis=0), phi * dmp.weights[joint], np.nan)
    left = {"panel": "forcing term f(z_t; v)", "xlabel": "t [s]", "ylabel": FORCING_LABEL}
    right = {"panel": "its terms φ_i(z_t) v_i", "xlabel": "t [s]", "ylabel": FORCING_LABEL}
    series = [
        Series("target Y (Eq. 2.23)", t.tolist(), target.tolist(), dash="dash", **left),
        Series(f"fitted f = φᵀv, {dmp.n_basis} weights", t.tolist(), f.tolist(), **left),
    ]
    series += [
        Series(f"φ_{i + 1} v_{i + 1}", t.tolist(), parts[:, i].tolist(), **right)
        for i in range(dmp.n_basis)
    ]
    rmse = float(np.sqrt(np.mean((f - target) ** 2)))
    title = f"The forcing term fitted by least squares (Eq. 2.23): RMSE {rmse:.3g} rad/s²"
    return draw(title, series, backend)


def demonstration_figure(
    times: ArrayLike,
    demonstration: ArrayLike,
    curves: Mapping[str, ArrayLike],
    *,
    title: str = "",
    ylabel: str = "q [rad]",
    backend: str = "plotly",
):
    """Curves (label → values (T,) at ``times``) under the demonstration (T,), as Fig. 2.11."""
    t = _times(times)
    demo = check_array(demonstration, "demonstration", shape=t.shape)
    check_type(curves, Mapping, "curves", "a mapping of label to values")
    kw = {"xlabel": "t [s]", "ylabel": ylabel}
    series = [Series("demonstration", t.tolist(), demo.tolist(), dash="dash", **kw)]
    for label, y in curves.items():
        y = check_array(y, f"curves[{label!r}]", shape=t.shape)
        series.append(Series(str(label), t.tolist(), y.tolist(), **kw))
    return draw(title, series, backend)


def dmp_fit_figure(n_basis: int, *, backend: str = "plotly", **dmp_options):
    """A DMP with ``n_basis`` weights (``dmp_options`` to :class:`DMP`) fitted to the reach of
    Fig. 2.9: its rollout over the demonstration and its RMSE."""
    times, q, qd, qdd = reach_demonstration()
    dmp = DMP(n_joints=1, n_basis=n_basis, **dmp_options).fit(times, q, qd, qdd)
    q_dmp = dmp.rollout(times, q0=q[0])[0][:, 0]
    rmse = float(np.sqrt(np.mean((q_dmp - q[:, 0]) ** 2)))
    title = f"DMP with {n_basis} basis function{'s' if n_basis > 1 else ''}: RMSE {rmse:.2g} rad"
    curves = {f"DMP, {n_basis} weights": q_dmp}
    return demonstration_figure(times, q[:, 0], curves, title=title, backend=backend)


def noisy_samples(
    n_points: int,
    *,
    noise_std: float = 0.1,
    seed: int = 0,
    low: float = -4.0,
    high: float = 4.0,
    function: Callable[[np.ndarray], np.ndarray] = fig2_12_function,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy observations y = f(x) + ε, ε ~ N(0, noise_std²), x ~ U(low, high): the first
    ``n_points`` of :data:`POOL` draws (nested per seed); ``function`` is vectorised (default
    Fig. 2.12's sin(1.5x) + 0.2x).

    Returns
    -------
    x : ndarray, shape (n_points, 1)
    y : ndarray, shape (n_points,)
    """
    n = check_count(n_points, "n_points")
    if n > POOL:
        raise ValueError(f"n_points: expected at most {POOL}, got {n}")
    noise_std = check_positive(noise_std, "noise_std", allow_zero=True)
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise ValueError(f"low, high: expected finite low < high, got {low!r}, {high!r}")
    rng = np.random.default_rng(seed)
    x = rng.uniform(low, high, POOL)[:n]
    eps = rng.standard_normal(POOL)[:n]
    return x[:, None], np.asarray(function(x), dtype=float) + noise_std * eps


def gp_with(
    x: ArrayLike, y: ArrayLike, *, lengthscale: float, signal_var: float, noise_var: float
) -> ExactGP:
    """An untrained :class:`ExactGP` on x (N, 1), y (N,) at ℓ, σ_f², σ_ε² (> 0, raw units):
    the posterior (2.26–2.27) of kernel (2.25), σ_ε² at least 1.5 × its floor."""
    check_positive(lengthscale, "lengthscale")
    check_positive(signal_var, "signal_var")
    check_positive(noise_var, "noise_var")
    theta = {"lengthscale": lengthscale, "outputscale": signal_var, "noise": noise_var}
    with record_numerical_events():
        return ExactGP(**theta, n_steps=0, additive_noise=0.0).fit(x, y, rng=0)


def _data(x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    x = check_array(x, "x", ndim=2)
    y = check_array(y, "y", ndim=1)
    if x.shape[1] != 1:
        raise ValueError(f"x: expected one input column, shape (N, 1), got {x.shape}")
    if y.shape[0] != x.shape[0]:
        raise ValueError(f"y: expected {x.shape[0]} values (one per row of x), got {y.shape[0]}")
    if x.shape[0] < 2:
        raise ValueError(f"x: expected at least 2 points, got {x.shape[0]}")
    return x, y


@dataclass(frozen=True)
class NoiseProfile:
    """The log marginal likelihood (2.28) along σ_ε² (:func:`noise_profile`), raw units: per
    σ_ε² (G,) its maximum over ℓ and σ_f², and the maximising ℓ, σ_f²."""

    noise_vars: np.ndarray
    log_ml: np.ndarray
    lengthscale: np.ndarray
    signal_var: np.ndarray

    @property
    def best(self) -> float:
        """The σ_ε² of the grid with the largest log marginal likelihood."""
        return float(self.noise_vars[int(np.argmax(self.log_ml))])


def noise_profile(x: ArrayLike, y: ArrayLike, noise_vars: ArrayLike) -> NoiseProfile:
    """The profile log marginal likelihood (2.28) of the noise variances (G,) > 0 (units y²):
    maximised over ℓ ∈ [1e-3, 1e3] std(x), σ_f² ∈ [1e-4, 1e4] var(y) by L-BFGS-B from three
    starts, on standardised targets, reported in raw units as :class:`ExactGP` does."""
    x, y = _data(x, y)
    nv = check_array(noise_vars, "noise_vars", ndim=1)
    if nv.size == 0 or np.any(nv <= 0):
        raise ValueError("noise_vars: expected a non-empty array of positive variances")
    m, s = float(y.mean()), float(y.std())
    if s <= 0:
        raise ValueError("y: constant targets have no noise to estimate")
    N, G = x.shape[0], nv.shape[0]
    X = torch.as_tensor(x, dtype=DTYPE)
    Y = torch.as_tensor((y - m) / s, dtype=DTYPE).expand(G, N)
    noise = torch.as_tensor(nv / s**2, dtype=DTYPE)
    sd = float(x.std()) or 1.0

    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        t = torch.tensor(theta, dtype=DTYPE, requires_grad=True)
        value = neg_log_marginal_likelihood(X, Y, t[:G].exp()[:, None], t[G:].exp(), noise)
        value.backward()
        return float(value.detach()), t.grad.numpy().copy()

    def each(ls: np.ndarray, os_: np.ndarray) -> np.ndarray:
        """Every output's own term."""
        T = partial(torch.tensor, dtype=DTYPE)
        with torch.no_grad():
            terms = [(Y[g : g + 1], T([[ls[g]]]), T([os_[g]]), noise[g : g + 1]) for g in range(G)]
            return np.array([float(neg_log_marginal_likelihood(X, *a)) for a in terms])

    bounds = [(np.log(1e-3 * sd), np.log(1e3 * sd))] * G + [(np.log(1e-4), np.log(1e4))] * G
    best = np.full(G, np.inf)
    ls_best, os_best = np.zeros(G), np.zeros(G)
    for start in (0.3, 1.0, 3.0):
        theta0 = np.concatenate([np.full(G, np.log(start * sd)), np.zeros(G)])
        res = minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=bounds)
        ls, os_ = np.exp(res.x[:G]), np.exp(res.x[G:])
        value = each(ls, os_)
        better = value < best
        best = np.where(better, value, best)
        ls_best, os_best = np.where(better, ls, ls_best), np.where(better, os_, os_best)
    return NoiseProfile(nv.copy(), -best - N * np.log(s), ls_best, os_best * s**2)


def noise_profile_figure(
    datasets: Mapping[str, tuple[ArrayLike, ArrayLike]],
    *,
    true_noise_var: float | None = None,
    noise_vars: ArrayLike | None = None,
    backend: str = "plotly",
):
    """:func:`noise_profile` minus its maximum, a panel per data set (title → (x, y)), over
    ``noise_vars`` (default 25 log-spaced in 1e-6 … 1); ``true_noise_var`` dashed."""
    if not isinstance(datasets, Mapping) or not datasets:
        raise ValueError("datasets: expected a non-empty mapping of label to (x, y)")
    default = np.geomspace(1e-6, 1.0, 25)
    grid = default if noise_vars is None else check_array(noise_vars, "noise_vars", ndim=1)
    v = None if true_noise_var is None else check_positive(true_noise_var, "true_noise_var")
    series = []
    for label, pair in datasets.items():
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise ValueError(f"datasets[{label!r}]: expected a pair (x, y)")
        prof = noise_profile(pair[0], pair[1], grid)
        rel = prof.log_ml - prof.log_ml.max()
        kw = {
            "panel": f"{label}: maximum at σ_ε² = {prof.best:.2g}"
            + (" (the grid's lowest value)" if prof.best == grid.min() else ""),
            "xlabel": "noise variance σ_ε²",
            "ylabel": "log p(y | X, θ) − its maximum",
            "log_x": True,
        }
        series += [
            Series("log p(y | X, θ), maximised over ℓ and σ_f²", grid.tolist(), rel.tolist(), **kw),
            Series("its maximum", [prof.best], [0.0], kind="markers", **kw),
        ]
        if v is not None:
            series.append(
                Series(f"true σ_ε² = {v:g}", [v, v], [float(rel.min()), 0.0], dash="dash", **kw)
            )
    return draw("Profile likelihood of the noise variance (Eq. 2.28)", series, backend)


def noise_by_size_table(
    sizes=(8, 20, 40), *, n_draws: int = 20, noise_std: float = 0.1, seed: int = 0
) -> pd.DataFrame:
    """The noise variance ML learns per data size N (2 … :data:`POOL`), over ``n_draws``
    noise vectors on :func:`noisy_samples`' inputs: true σ_ε², the learned median and 10th /
    90th percentiles, median / true and the fits at the noise floor."""
    n_draws = check_count(n_draws, "n_draws", minimum=2)
    noise_std = check_positive(noise_std, "noise_std")
    sizes = [check_count(n, "sizes", minimum=2) for n in sizes]
    if not sizes:
        raise ValueError("sizes: expected at least one size")
    rows = []
    for n in sizes:
        x, f = noisy_samples(n, noise_std=0.0, seed=seed)
        eps = np.random.default_rng([seed, n]).standard_normal((n, n_draws))
        with record_numerical_events():
            gp = ExactGP(additive_noise=0.0).fit(x, f[:, None] + noise_std * eps, rng=0)
        learned = gp.hyperparameters["noise"]
        lo, med, hi = np.percentile(learned, [10, 50, 90])
        rows.append(
            {
                "points N": n,
                "true σ_ε²": sig(noise_std**2),
                "learned σ_ε², median": sig(med),
                "10th percentile": sig(lo),
                "90th percentile": sig(hi),
                "median / true": sig(med / noise_std**2, 3),
                f"at the floor (of {n_draws})": len(gp.diagnostics["noise_at_floor"]),
            }
        )
    return pd.DataFrame(rows).set_index("points N")


def hyperparameter_table(
    gps: Mapping[str, ExactGP], *, true_noise_var: float | None = None
) -> pd.DataFrame:
    """A row per fitted 1-D GP (label → GP): N, ℓ, σ_f², σ_ε² (raw units), ``true σ_ε²`` if
    given, the log marginal likelihood (2.28) and whether the noise is at its floor."""
    if not isinstance(gps, Mapping) or not gps:
        raise ValueError("gps: expected a non-empty mapping of label to fitted ExactGP")
    rows = {}
    for label, gp in gps.items():
        h = _fitted(gp, f"gps[{label!r}]").hyperparameters
        row = {
            "points N": int(gp.diagnostics["n_data"]),
            "length-scale ℓ": sig(h["lengthscale"][0, 0]),
            "signal variance σ_f²": sig(h["outputscale"][0]),
            "noise variance σ_ε²": sig(h["noise"][0]),
        }
        if true_noise_var is not None:
            row["true σ_ε²"] = check_positive(true_noise_var, "true_noise_var")
        row["log marginal likelihood"] = sig(np.sum(gp.diagnostics["log_marginal_likelihood"]), 5)
        row["noise at its floor"] = "yes" if gp.diagnostics["noise_at_floor"] else "no"
        rows[str(label)] = row
    return pd.DataFrame.from_dict(rows, orient="index")


def hyperparameter_figure(
    x: ArrayLike,
    y: ArrayLike,
    gp: ExactGP,
    *,
    factor: float = 4.0,
    x_test: ArrayLike | None = None,
    backend: str = "plotly",
):
    """A panel per hyper-parameter of a GP fitted on x (N, 1), y (N,): the posterior
    (2.26–2.27) at the learned θ and with that value ÷ and × ``factor`` > 1, at ``x_test``
    (n,) (default the data's range widened by a quarter each side)."""
    x, y = _data(x, y)
    _fitted(gp)
    factor = check_positive(factor, "factor")
    if factor <= 1:
        raise ValueError(f"factor: expected a number > 1, got {factor!r}")
    if x_test is None:
        lo, hi = float(x.min()), float(x.max())
        xs = np.linspace(lo - 0.25 * (hi - lo), hi + 0.25 * (hi - lo), 161)
    else:
        xs = np.sort(check_array(x_test, "x_test", ndim=1))
    h = gp.hyperparameters
    params = (
        ("lengthscale", "length-scale ℓ", h["lengthscale"][0, 0]),
        ("signal_var", "signal variance σ_f²", h["outputscale"][0]),
        ("noise_var", "noise variance σ_ε²", h["noise"][0]),
    )
    theta = {key: float(v) for key, _, v in params}
    series = []
    for key, label, _ in params:
        v = theta[key]
        kw = {"panel": f"{label}: {v / factor:.2g} / {v:.2g} / {v * factor:.2g}"}
        kw |= {"xlabel": "x", "ylabel": "y"}
        scales = ((f"÷ {factor:g}", 1 / factor), ("learned θ", 1.0), (f"× {factor:g}", factor))
        for name, scale in scales:
            model = gp if scale == 1.0 else gp_with(x, y, **{**theta, key: v * scale})
            series.append(gp_band(model, xs, name, **kw))
        series.append(Series("data", x[:, 0].tolist(), y.tolist(), kind="markers", **kw))
    title = f"One hyper-parameter at a time ÷ {factor:g} and × {factor:g}, the others as learned"
    return draw(title, series, backend)


def gp_posterior_figure(
    lengthscale: float,
    noise_var: float,
    n_points: int,
    *,
    signal_var: float = 1.0,
    noise_std: float = 0.1,
    seed: int = 0,
    backend: str = "plotly",
):
    """The slider's redraw: :func:`gp_with` on :func:`noisy_samples` with the true function,
    over x ∈ [−6, 6]."""
    x, y = noisy_samples(n_points, noise_std=noise_std, seed=seed)
    xs = np.linspace(-6.0, 6.0, 241)
    with record_numerical_events() as events:
        gp = gp_with(x, y, lengthscale=lengthscale, signal_var=signal_var, noise_var=noise_var)
        gp.predict(xs[:, None])  # counts what plot_gp_fit's prediction will meet
    seen = [f"{_EVENT_WORDS.get(k, k)} ×{n}" for k, n in events.counts.items() if n]
    title = (
        f"GP posterior, {n_points} point{'s' if n_points > 1 else ''}: ℓ = {lengthscale:.3g}, "
        f"σ_ε² = {noise_var:.3g}, σ_f² = {signal_var:.3g}"
        + (f" (handled: {', '.join(seen)})" if seen else "")
    )
    with record_numerical_events():
        return plot_gp_fit(gp, x, y, xs, f_true=fig2_12_function, backend=backend, title=title)


@dataclass(frozen=True)
class MomentMatchingCheck:
    """One step p(x) = N(m, s²) → p(y) through a 1-D GP, three ways (Sec. 2.1.2, Fig. 2.7):
    the exact moments of p(y), the linearisation at m, Monte Carlo draws y_j = μ(x_j) +
    σ(x_j) ε_j (n,), and p(y) by quadrature on a grid (G,)."""

    input_mean: float
    input_var: float
    moment_matched: GaussianPrediction
    linearised: GaussianPrediction
    samples: np.ndarray
    density_grid: np.ndarray
    density: np.ndarray

    def standard_errors(self) -> tuple[float, float]:
        """Standard errors √(v/n) of the sample mean and √((μ₄ − v²)/n) of the sample variance."""
        c = self.samples - self.samples.mean()
        n = c.shape[0]
        v = float(np.mean(c**2))
        m4 = float(np.mean(c**4))
        return float(np.sqrt(v / n)), float(np.sqrt(max(m4 - v * v, 0.0) / n))

    def table(self) -> pd.DataFrame:
        """Mean, variance and standard errors of each method, and distances from Monte Carlo."""
        se_m, se_v = self.standard_errors()
        mc_m, mc_v = float(self.samples.mean()), float(self.samples.var())
        rows = {f"Monte Carlo ({self.samples.shape[0]:,} samples)": (mc_m, mc_v, se_m, se_v)}
        for label, g in (
            ("moment matching (exact moments)", self.moment_matched),
            ("linearisation at the input mean", self.linearised),
        ):
            rows[label] = (float(g.mean[0]), float(g.cov[0, 0]), 0.0, 0.0)
        out = {
            label: {
                "mean": sig(m, 5),
                "variance": sig(v, 5),
                "s.e. of mean": sig(sm, 2),
                "s.e. of variance": sig(sv, 2),
                "mean − MC [s.e.]": round((m - mc_m) / se_m, 1),
                "variance − MC [s.e.]": round((v - mc_v) / se_v, 1),
            }
            for label, (m, v, sm, sv) in rows.items()
        }
        return pd.DataFrame.from_dict(out, orient="index")

    def summary(self) -> str:
        """One sentence: how far each Gaussian's mean and variance lie from the samples'."""
        t = self.table()
        words = []
        for label in t.index[1:]:
            dm, dv = t.loc[label, "mean − MC [s.e.]"], t.loc[label, "variance − MC [s.e.]"]
            name = label.split(" (")[0].split(" at ")[0]
            words.append(f"{name}: mean {dm:+.1f} s.e., variance {dv:+.1f} s.e.")
        return (
            f"Input N({self.input_mean:g}, {self.input_var:g}); distance from the Monte Carlo "
            f"moments in standard errors — " + "; ".join(words)
        )

    def figure(self, *, bins: int = 80, backend: str = "plotly"):
        """Density histogram of the samples (``bins`` ≥ 2) with p(y) and both Gaussians."""
        bins = check_count(bins, "bins", minimum=2)
        hist, edges = np.histogram(self.samples, bins=bins, density=True)
        centres = 0.5 * (edges[1:] + edges[:-1])
        g = self.density_grid
        kw = {"xlabel": "y", "ylabel": "density p(y)"}
        mc = f"Monte Carlo histogram ({self.samples.shape[0]:,} samples)"
        series = [
            Series(mc, centres.tolist(), hist.tolist(), kind="bar", **kw),
            Series("p(y) by quadrature", g.tolist(), self.density.tolist(), dash="dash", **kw),
        ]
        for label, pred in (
            ("moment matching", self.moment_matched),
            ("linearisation", self.linearised),
        ):
            m, v = float(pred.mean[0]), float(pred.cov[0, 0])
            dens = np.exp(-0.5 * (g - m) ** 2 / v) / np.sqrt(2 * np.pi * v)
            series.append(Series(f"{label}: N({m:.3f}, {v:.3f})", g.tolist(), dens.tolist(), **kw))
        title = (
            f"One step of x ~ N({self.input_mean:g}, {self.input_var:g}) through the GP "
            "(Sec. 2.1.2, Fig. 2.7)"
        )
        return draw(title, series, backend)


def moment_matching_check(
    gp: ExactGP, mean: float, var: float, *, n_samples: int = 100_000, rng=0, n_grid: int = 401
) -> MomentMatchingCheck:
    """One step of N(mean, var) through a fitted 1-D GP: moment matching, linearisation,
    ``n_samples`` Monte Carlo draws and the quadrature density on ``n_grid`` points."""
    _fitted(gp)
    if gp.predictor.input_dim != 1 or gp.predictor.output_dim != 1:
        raise ValueError("gp: expected one input and one output")
    m = float(check_array(mean, "mean", ndim=0))
    v = check_positive(var, "var")
    n = check_count(n_samples, "n_samples", minimum=2)
    n_grid = check_count(n_grid, "n_grid", minimum=2)
    rng = as_generator(rng)
    mm = moment_match(gp.predictor, [m], [[v]])
    lin = linearize(gp.predictor, [m], [[v]])
    x = rng.normal(m, np.sqrt(v), size=(n, 1))
    y = np.asarray(gp.sample(x, 1, rng), dtype=float).reshape(n)
    grid = np.linspace(float(y.min()), float(y.max()), n_grid)
    dens = successor_density(gp.predictor, m, float(np.sqrt(v)), grid)
    return MomentMatchingCheck(m, v, mm, lin, y, grid, dens)
