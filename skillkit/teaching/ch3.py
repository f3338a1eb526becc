r"""Chapter 3 step by step: one contextual REPS update (Sec. 3.3, Table 3.1) taken apart with
the library's dual, weights and ML fit: (a) the dual (3.9) along η, (b, c) the weights (3.10),
KL and ESS against ε, (d) the fit's ellipse (3.11–3.13), and tables. Samples are rewards R_i
(N,), N ≥ 2, not all equal, with baseline features φ(s_i) (N, F) or ``None`` (Eq. 2.15).
Figures take ``backend`` in {"plotly", "matplotlib"}."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from skillkit._validation import check_array, check_count, check_positive, check_type
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.reps import (
    DualSolution,
    REPSDiagnostics,
    REPSWeights,
    check_samples,
    reps_dual,
    reps_weights,
)
from skillkit.teaching._common import draw, index_pair, sig, xy
from skillkit.viz.plots import PANEL_HEIGHT
from skillkit.viz.series import Series

#: Pixels :func:`ellipse_figure`'s panel gets beyond a standard one (for equal axis scales).
ELLIPSE_EXTRA_HEIGHT = 160
#: The ε grid of :func:`weights_and_kl_figure` when none is given.
DEFAULT_EPSILONS = np.geomspace(0.01, 10.0, 19)


def _samples(rewards: ArrayLike, features: ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """Rewards (N,), N ≥ 2, and features (N, F), validated as the REPS dual does."""
    r, phi = check_samples(rewards, features)
    if r.shape[0] < 2:
        raise ValueError(f"rewards: expected at least 2 samples, got shape {r.shape}")
    return r, phi


def _solve(rewards: np.ndarray, phi: np.ndarray, epsilon: float) -> REPSWeights:
    solution = reps_weights(rewards, phi if phi.shape[1] else None, epsilon)
    if not np.isfinite(solution.eta):
        raise ValueError("rewards: all rewards are equal, so the dual (3.9) has no minimiser η")
    return solution


@dataclass(frozen=True)
class DualSlice:
    """The REPS dual (3.9) along η with γ at γ* (:func:`dual_slice`): the η grid (n,) holding
    η*, g(η, γ*), KL(p_η ‖ uniform) = ε − ∂g/∂η (A.11) and the joint minimiser (η*, γ*)."""

    eta: np.ndarray
    value: np.ndarray
    kl: np.ndarray
    solution: REPSWeights

    @property
    def value_at_minimum(self) -> float:
        """g(η*, γ*), the dual at its minimiser (a grid point)."""
        return float(self.value[int(np.argmin(np.abs(self.eta - self.solution.eta)))])


def dual_slice(
    rewards: ArrayLike,
    features: ArrayLike | None,
    epsilon: float,
    *,
    span: float = 10.0,
    n_points: int = 81,
) -> DualSlice:
    r"""The sample-based dual of Eq. (3.9) along η, with γ at its optimum γ*:

    .. math::
        g(\eta, \gamma^*) = \eta \log\Big(\frac1N \sum_i
        \exp\Big(\frac{R_i - \gamma^{*T}\phi(s_i)}{\eta}\Big)\Big) + \eta\epsilon
        + \gamma^{*T}\hat\phi

    on ``n_points`` ≥ 3 log-spaced values from η*/span to η*·span (span > 1), η* included.
    """
    r, phi = _samples(rewards, features)
    eps = check_positive(epsilon, "epsilon")
    span = check_positive(span, "span")
    if not span > 1.0:
        raise ValueError(f"span: expected a value > 1, got {span!r}")
    n_points = check_count(n_points, "n_points", 3)
    sol = _solve(r, phi, eps)
    grid = np.geomspace(sol.eta / span, sol.eta * span, n_points)
    eta = np.sort(np.append(grid[np.abs(grid / sol.eta - 1.0) > 1e-9], sol.eta))
    value, kl = np.empty_like(eta), np.empty_like(eta)
    for k, e in enumerate(eta):
        g, grad = reps_dual(np.concatenate([[e], sol.gamma]), r, phi, eps)
        value[k], kl[k] = g, eps - grad[0]
    return DualSlice(eta, value, kl, sol)


def dual_figure(
    rewards: ArrayLike,
    features: ArrayLike | None,
    epsilon: float,
    *,
    span: float = 10.0,
    backend: str = "plotly",
):
    """(a) :func:`dual_slice` over log η: g(η, γ*) and the KL with the bound ε, η* marked."""
    s = dual_slice(rewards, features, epsilon, span=span)
    sol = s.solution
    n_feat = sol.gamma.shape[0]
    held = f"the {n_feat} baseline parameters γ held at their optimum γ*" if n_feat else "no γ"
    axes = {"xlabel": "η (reward units)", "log_x": True}
    left = {"panel": f"dual g(η, γ*), {held}", "ylabel": "g(η, γ*)", **axes}
    right = {"panel": "KL of the weights along the same slice", "ylabel": "KL(p ‖ q)", **axes}
    star = f"minimiser η* = {sol.eta:.3g}"
    ends = [float(s.eta[0]), float(s.eta[-1])]
    bound = f"bound ε = {sol.epsilon:.3g} (Eq. 3.4)"
    series = [
        Series("g(η, γ*) (Eq. 3.9)", s.eta.tolist(), s.value.tolist(), **left),
        Series(star, [sol.eta], [s.value_at_minimum], kind="markers", **left),
        Series("KL(p_η ‖ q) = ε − ∂g/∂η (A.11)", s.eta.tolist(), s.kl.tolist(), **right),
        Series(bound, ends, [sol.epsilon, sol.epsilon], dash="dash", **right),
        Series(star, [sol.eta], [sol.kl], kind="markers", **right),
    ]
    title = f"(a) the REPS dual along η, N = {s.solution.weights.shape[0]} samples"
    if not sol.kl_bound_active:
        title += ": ε is above the largest KL these samples allow, η* sits at its lower bound"
    return draw(title, series, backend)


@dataclass(frozen=True)
class KLSweep:
    """Over bounds ε (:func:`kl_sweep`), each (m,): ε, KL, ESS 1/Σ p_i², η*, bound active."""

    epsilon: np.ndarray
    kl: np.ndarray
    ess: np.ndarray
    eta: np.ndarray
    active: np.ndarray


def kl_sweep(rewards: ArrayLike, features: ArrayLike | None, epsilons: ArrayLike) -> KLSweep:
    """:func:`~skillkit.search.reps.reps_weights` (3.4, 3.10) per bound ``epsilons`` (m,) > 0."""
    r, phi = _samples(rewards, features)
    eps = check_array(epsilons, "epsilons", ndim=1)
    if eps.size == 0 or np.any(eps <= 0):
        raise ValueError(f"epsilons: expected at least one bound, all > 0, got {eps!r}")
    sols = [_solve(r, phi, float(e)) for e in eps]
    return KLSweep(
        epsilon=eps,
        kl=np.array([s.kl for s in sols]),
        ess=np.array([s.ess for s in sols]),
        eta=np.array([s.eta for s in sols]),
        active=np.array([s.kl_bound_active for s in sols]),
    )


def weights_and_kl_figure(
    rewards: ArrayLike,
    features: ArrayLike | None,
    epsilon: float,
    *,
    epsilons: ArrayLike | None = None,
    backend: str = "plotly",
):
    r"""(b) N p_i (3.10) at ``epsilon`` against R_i and the advantage R_i − γᵀφ(s_i); (c) KL
    and ESS over ``epsilons`` (default :data:`DEFAULT_EPSILONS`); weights of 0 are not drawn."""
    r, phi = _samples(rewards, features)
    eps = check_positive(epsilon, "epsilon")
    sol = _solve(r, phi, eps)
    sweep = kl_sweep(r, phi, DEFAULT_EPSILONS if epsilons is None else epsilons)
    n = r.shape[0]
    scaled = n * sol.weights
    adv = r - sol.baseline
    grid = np.linspace(adv.min(), adv.max(), 200)
    z = np.exp((adv - adv.max()) / sol.eta).sum()
    curve = n * np.exp((grid - adv.max()) / sol.eta) / z
    wr = {"panel": "(b) weights against the reward", "xlabel": "reward R_i"}
    wa = {"panel": "(b) weights against the advantage", "xlabel": "advantage R_i − V(s_i)"}
    for p in (wr, wa):
        p.update(ylabel="N p_i (1 = uniform)", log_y=True)
    kp = {"panel": "(c) achieved KL against the bound ε", "xlabel": "ε", "ylabel": "KL(p ‖ q)"}
    ep = {"panel": "(c) effective sample size against ε", "xlabel": "ε", "ylabel": "1 / Σ p_i²"}
    for p in (kp, ep):
        p.update(log_x=True)
    e_ends = [float(sweep.epsilon.min()), float(sweep.epsilon.max())]
    # KL = ε through many points: a straight segment would bow on the log-ε axis
    identity = np.geomspace(e_ends[0], e_ends[1], 200).tolist()
    uniform = "uniform weights 1/N (the old samples)"
    here = f"this ε = {eps:.3g}"
    series = [
        Series("samples", r.tolist(), scaled.tolist(), kind="markers", **wr),
        Series(uniform, [float(r.min()), float(r.max())], [1.0, 1.0], dash="dash", **wr),
        Series("samples", adv.tolist(), scaled.tolist(), kind="markers", **wa),
        Series(uniform, [float(adv.min()), float(adv.max())], [1.0, 1.0], dash="dash", **wa),
        Series("N exp(A/η) / Σ exp(A_j/η) (Eq. 3.10)", grid.tolist(), curve.tolist(), **wa),
        Series("achieved KL", sweep.epsilon.tolist(), sweep.kl.tolist(), **kp),
        Series("KL = ε (the bound, Eq. 3.4)", identity, identity, dash="dash", **kp),
        Series("log N (all weight on one sample)", e_ends, [np.log(n)] * 2, dash="dot", **kp),
        Series(here, [eps], [sol.kl], kind="markers", **kp),
        Series("effective sample size", sweep.epsilon.tolist(), sweep.ess.tolist(), **ep),
        Series(here, [eps], [sol.ess], kind="markers", **ep),
    ]
    title = (
        f"(b, c) REPS weights at ε = {eps:.3g}: η = {sol.eta:.3g}, KL = {sol.kl:.3g}, "
        f"ESS = {sol.ess:.3g} of N = {n}"
    )
    if not sol.kl_bound_active:
        title += " (bound inactive: ε is above the largest KL these samples allow)"
    n_zero = int(np.sum(sol.weights == 0))
    if n_zero:
        title += f"; {n_zero} weights underflow to 0 (not drawn)"
    return draw(title, series, backend)


def _contexts(policy: LinearGaussianPolicy, contexts: ArrayLike | None, n: int | None = None):
    """Contexts (n, context_dim) for ``policy`` (``None`` allowed for a context-free one)."""
    if contexts is None:
        if policy.context_dim:
            raise ValueError("contexts: a contextual policy needs contexts, got None")
        return np.zeros((1 if n is None else n, 0))
    s = check_array(contexts, "contexts", ndim=2)
    if s.shape[1] != policy.context_dim or s.shape[0] == 0 or (n is not None and s.shape[0] != n):
        raise ValueError(f"contexts: expected ({n or 'n'}, {policy.context_dim}), got {s.shape}")
    return s


def _weights(weights: ArrayLike, n: int) -> np.ndarray:
    """Non-negative weights (n,) with a positive sum, normalised to sum to one."""
    w = check_array(weights, "weights", shape=(n,))
    if np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights: expected non-negative weights with a positive sum")
    return w / w.sum()


def policy_moments(
    policy: LinearGaussianPolicy, contexts: ArrayLike | None, weights: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray]:
    r"""Mean (d,) and covariance (d, d) of ω ~ N(a + Aφ(s), Σ) (Eq. 3.13) over contexts
    (n, context_dim) drawn with probabilities q_i (``weights``, default uniform):

    .. math::
        m = \sum_i q_i \mu(s_i), \qquad
        C = \Sigma + \sum_i q_i (\mu(s_i) - m)(\mu(s_i) - m)^T.
    """
    s = _contexts(check_type(policy, LinearGaussianPolicy, "policy"), contexts)
    mu = np.atleast_2d(policy.mean_of(s))
    q = np.full(mu.shape[0], 1.0 / mu.shape[0]) if weights is None else _weights(weights, len(mu))
    mean = q @ mu
    centred = mu - mean
    cov = policy.cov + (centred * q[:, None]).T @ centred
    return mean, 0.5 * (cov + cov.T)


def ellipse_points(
    mean: ArrayLike, cov: ArrayLike, dims: tuple[int, int] = (0, 1), n_points: int = 101
) -> np.ndarray:
    r"""The closed 1-σ ellipse m + V Λ^{1/2} [cos t, sin t]ᵀ of a Gaussian's marginal on
    ``dims`` (C = V Λ Vᵀ, ``cov`` symmetric PSD), shape (n_points, 2)."""
    m = check_array(mean, "mean", ndim=1)
    c = check_array(cov, "cov", shape=(m.shape[0], m.shape[0]))
    i, j = index_pair(dims, "dims", m.shape[0], "parameter indices")
    n_points = check_count(n_points, "n_points", 3)
    block = c[np.ix_([i, j], [i, j])]
    if abs(block[0, 1] - block[1, 0]) > 1e-10 * max(np.abs(block).max(), 1e-300):
        raise ValueError("cov: expected a symmetric matrix")
    lam, vec = np.linalg.eigh(0.5 * (block + block.T))
    if lam.min() < -1e-12 * max(lam.max(), 0.0):
        raise ValueError("cov: expected a positive semi-definite matrix")
    t = np.linspace(0.0, 2.0 * np.pi, n_points)
    circle = np.stack([np.cos(t), np.sin(t)])
    return m[[i, j]] + ((vec * np.sqrt(np.maximum(lam, 0.0))) @ circle).T


def heaviest_samples(weights: ArrayLike, mass: float = 0.5) -> np.ndarray:
    """Sorted indices of the fewest samples holding ``mass`` ∈ (0, 1] of the weight."""
    p = _weights(weights, np.size(weights))
    mass = check_positive(mass, "mass")
    if mass > 1.0:
        raise ValueError(f"mass: expected a fraction in (0, 1], got {mass!r}")
    order = np.argsort(-p, kind="stable")
    k = int(np.searchsorted(np.cumsum(p[order]), mass - 1e-12)) + 1
    return np.sort(order[: min(k, p.shape[0])])


def ellipse_figure(
    old: LinearGaussianPolicy,
    new: LinearGaussianPolicy,
    contexts: ArrayLike | None,
    omegas: ArrayLike,
    weights: ArrayLike,
    *,
    dims: tuple[int, int] = (0, 1),
    mass: float = 0.5,
    backend: str = "plotly",
):
    """(d) The old and new policies' 1-σ ellipses (:func:`policy_moments` over the contexts
    (N, context_dim), the new one also at their mean) over the samples ω_i (N, d)."""
    for name, pol in (("old", old), ("new", new)):
        check_type(pol, LinearGaussianPolicy, name)
    if (new.dim, new.context_dim) != (old.dim, old.context_dim):
        raise ValueError("new: expected the dim and context_dim of old")
    w = check_array(omegas, "omegas", shape=(None, old.dim))
    s = _contexts(old, contexts, w.shape[0])
    p = _weights(weights, w.shape[0])
    i, j = index_pair(dims, "dims", old.dim, "parameter indices")
    heavy = np.zeros(w.shape[0], bool)
    heavy[heaviest_samples(p, mass)] = True
    labels = {"xlabel": f"ω_{i + 1}", "ylabel": f"ω_{j + 1}"}
    old_curve = ellipse_points(*policy_moments(old, s), (i, j))
    new_curve = ellipse_points(*policy_moments(new, s), (i, j))
    centre = np.atleast_1d(new.mean_of(s.mean(axis=0)))
    at_mean = ellipse_points(centre, new.cov, (i, j))
    curves = {
        "old policy, 1σ over the batch's contexts": (old_curve, "dash"),
        "new policy, 1σ over the batch's contexts": (new_curve, None),
        "new policy at the mean context (Σ alone), 1σ": (at_mean, "dot"),
    }
    held = f"samples holding {mass:.0%} of the weight ({heavy.sum()} of {w.shape[0]})"
    series = [
        Series(name, w[m, i].tolist(), w[m, j].tolist(), kind="markers", **labels)
        for name, m in ((held, heavy), ("the other samples", ~heavy))
    ] + [Series(name, *xy(pts), dash=dash, **labels) for name, (pts, dash) in curves.items()]
    title = f"(d) the new policy over the re-weighted samples, parameters ω_{i + 1} and ω_{j + 1}"
    fig = draw(title, series, backend)
    if backend == "plotly":
        fig.update_xaxes(constrain="domain")
        fig.update_yaxes(scaleanchor="x", scaleratio=1, constrain="domain")
        height = fig.layout.height + ELLIPSE_EXTRA_HEIGHT
        fig.update_layout(
            height=height,
            title_y=1 - 14 / height,  # 14 px from the top, as plots.plotly_figure places it
            legend_y=-70 / (PANEL_HEIGHT + ELLIPSE_EXTRA_HEIGHT),  # 70 px below the panel
        )
    else:
        fig.axes[0].set_aspect("equal", adjustable="datalim")
    return fig


#: Columns of :func:`update_table` and :func:`diagnostics_table`.
COLUMNS = (
    "N (samples used)",
    "ε",
    "η",
    "KL(p ‖ q)",
    "bound active",
    "ESS",
    "mean reward (batch)",
    "KL(π_new ‖ π_old)",
)


def _row(sol: DualSolution, n: int, mean_reward: float, policy_kl: float) -> dict:
    """A table row: the dual's diagnostics, the batch's mean reward and the policy's KL."""
    first = [sig(v) for v in (sol.epsilon, sol.eta, sol.kl)]
    last = [sig(v) for v in (sol.ess, mean_reward, policy_kl)]
    return dict(zip(COLUMNS, (n, *first, bool(sol.kl_bound_active), *last), strict=True))


def update_table(
    solution: REPSWeights,
    rewards: ArrayLike,
    old: LinearGaussianPolicy,
    new: LinearGaussianPolicy,
    contexts: ArrayLike | None,
    optimum: ArrayLike | None = None,
) -> pd.DataFrame:
    """One REPS update (3.10–3.12) as a row of :data:`COLUMNS` (KL(π_new ‖ π_old) over
    ``contexts``); with ``optimum`` θ* (d, 1 + F) also max |θ − θ*| before and after."""
    n = check_type(solution, REPSWeights, "solution").weights.shape[0]
    r = check_array(rewards, "rewards", shape=(n,))
    for name, pol in (("old", old), ("new", new)):
        check_type(pol, LinearGaussianPolicy, name)
    s = _contexts(old, contexts, n)
    row = _row(solution, n, float(r.mean()), new.kl(old, s))
    if optimum is not None:
        theta = check_array(optimum, "optimum", shape=old.coefficients.shape)
        row["max|θ − θ*| before"] = sig(np.abs(old.coefficients - theta).max())
        row["max|θ − θ*| after"] = sig(np.abs(new.coefficients - theta).max())
    return pd.DataFrame([row], index=pd.Index(["by hand"], name="update"))


def diagnostics_table(updates: Sequence) -> pd.DataFrame:
    """Table 3.1: a row of :data:`COLUMNS` per ``ContextualREPS.update`` result."""
    if isinstance(updates, (str, bytes)) or not isinstance(updates, Sequence) or not updates:
        raise ValueError("updates: expected a non-empty list of ContextualREPS.update results")
    rows = []
    for k, d in enumerate(updates):
        check_type(d, REPSDiagnostics, f"updates[{k}]")
        rows.append(_row(d, int(d.n_samples), float(d.mean_reward), float(d.policy_kl)))
    return pd.DataFrame(rows, index=pd.RangeIndex(1, len(rows) + 1, name="update"))
