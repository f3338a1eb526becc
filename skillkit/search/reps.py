r"""Relative Entropy Policy Search: episode-based (Eqs. 2.12–2.15) and contextual (3.3–3.13).

:func:`reps_dual` is the sample-based dual g(η, γ) of Eq. (3.9)/(A.10) with its gradient
(A.11, A.12), :func:`reps_dual_hessian` its Hessian, and :func:`reps_weights` minimises it and
returns the weights p_i ∝ exp((R_i − V(s_i))/η) of Eq. (3.10). :class:`ContextualREPS` runs
Table 3.1 on them (:class:`~skillkit.search.base.WeightedMLSearch`); with a context-free policy
(no features, V ≡ 0) it is episode-based REPS.

:func:`reps_weights` solves the dual for standardised rewards and whitened features (the
weights are invariant to both) over log η within :data:`ETA_BOUNDS`. At the optimum
∂g/∂η = ε − KL(p ‖ q); where ε exceeds what the samples and constraint (3.5) allow, η runs to
its lower bound and ``kl_bound_active`` is False.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from skillkit._validation import check_array, check_choice, check_positive
from skillkit.policies.features import (
    FeatureName,
    check_feature_name,
    context_features,
)
from skillkit.policies.gaussian import (
    FitInfo,
    LinearGaussianPolicy,
    TrustRegionStep,
    effective_sample_size,
    trust_region_step,
)
from skillkit.search.base import Batch, Fields, WeightedMLSearch, extra_context_importance
from skillkit.search.base import SampleBuffer as SampleBuffer  # re-exported (pickles name it here)
from skillkit.search.base import check_batch as check_batch  # re-exported

#: Bounds of η in normalised reward units (rewards divided by their standard deviation).
ETA_BOUNDS = (1e-8, 1e8)
#: Relative tolerance on the achieved KL: the bound (3.4) is active when KL ≥ (1 − tol) ε,
#: and a solution succeeds only if KL ≤ (1 + tol) ε.
KL_TOLERANCE = 1e-3
#: η (normalised units) below which a KL short of ε means that ε is unattainable.
ETA_UNATTAINABLE = 1e-5
#: Projected-gradient tolerance in (log η, γ), normalised units, of both solvers.
DUAL_GTOL = 1e-11

DualSolver = Literal["lbfgsb", "newton"]
#: The dual's default solver.
DEFAULT_DUAL_SOLVER: DualSolver = "lbfgsb"


# --------------------------------------------------------------------------- the dual
def _dual(
    params: np.ndarray,
    rewards: np.ndarray,
    features: np.ndarray,
    epsilon: float,
    log_base: np.ndarray | None = None,
    phihat: np.ndarray | None = None,
):
    """Unchecked :func:`reps_dual`, also returning p; ``log_base`` is log q (``None``: uniform,
    computed without logarithms), ``phihat`` a precomputed φ̂."""
    eta, gamma = params[0], params[1:]
    adv = rewards - features @ gamma
    a = adv / eta
    if log_base is not None:
        a = a + log_base
    m = a.max()
    z = np.exp(a - m)
    total = z.sum()
    p = z / total
    if phihat is None:
        phihat = _phihat(features, log_base)
    if log_base is None:
        log_mean_z = m + np.log(total) - np.log(rewards.shape[0])
    else:
        log_mean_z = m + np.log(total)
    value = eta * log_mean_z + eta * epsilon + gamma @ phihat
    grad = np.empty_like(params)
    grad[0] = epsilon + log_mean_z - (p @ adv) / eta  # (A.11)
    grad[1:] = phihat - p @ features  # (A.12)
    return value, grad, p


def reps_dual(
    params: ArrayLike,
    rewards: ArrayLike,
    features: ArrayLike,
    epsilon: float,
    base_weights: ArrayLike | None = None,
) -> tuple[float, np.ndarray]:
    r"""Sample-based REPS dual (Eq. 3.9 / A.10) and its gradient (A.11, A.12).

    .. math::
        g(\eta, \gamma) = \eta \log\Big(\frac1N \sum_i
            \exp\Big(\frac{R_i - \gamma^\top\phi(s_i)}{\eta}\Big)\Big)
            + \eta\epsilon + \gamma^\top\hat\phi,
        \qquad \hat\phi = \frac1N \sum_i \phi(s_i)

    With base weights q the samples stand for Σ q_i δ_i: 1/N becomes q_i inside the logarithm,
    φ̂ = Σ q_i φ(s_i), and the KL of Eq. (3.4) is KL(p ‖ q).

    Parameters
    ----------
    params : array_like, shape (1 + F,)
        [η, γ_1, …, γ_F] with η > 0.
    rewards : array_like, shape (N,)
    features : array_like, shape (N, F)
        Baseline features φ(s_i) (F = 0 for episode-based REPS).
    epsilon : float
        KL bound ε > 0.
    base_weights : array_like, shape (N,), optional
        q_i ≥ 0 with a positive sum (normalised here); ``None``: uniform.

    Returns
    -------
    value : float
    grad : ndarray, shape (1 + F,)
        [∂g/∂η, ∂g/∂γ], with ∂g/∂η = ε − KL(p ‖ q) for the weights (3.10).
    """
    value, grad, _ = _dual(*_dual_args(params, rewards, features, epsilon, base_weights))
    return float(value), grad


def _dual_args(params, rewards, features, epsilon, base_weights):
    """Validated (params, rewards, features, ε, log q) of :func:`reps_dual`."""
    r, phi = check_samples(rewards, features)
    x = check_array(params, "params", shape=(1 + phi.shape[1],))
    if not x[0] > 0:
        raise ValueError(f"params: η = params[0] must be > 0, got {x[0]!r}")
    log_q = _log_base(base_weights, r.shape[0])
    return x, r, phi, check_positive(epsilon, "epsilon"), log_q


def _phihat(features: np.ndarray, log_base: np.ndarray | None) -> np.ndarray:
    """φ̂ = Σ q_i φ(s_i) (the plain mean for uniform q)."""
    return features.mean(axis=0) if log_base is None else np.exp(log_base) @ features


def _hessian_workspace(features: np.ndarray) -> np.ndarray:
    """Reusable (F + 2, N) storage of [·, φ, 1]ᵀ for :func:`_dual_hessian`."""
    n, n_feat = features.shape
    work = np.empty((n_feat + 2, n))
    work[1:-1] = features.T
    work[-1] = 1.0
    return work


def _dual_hessian(
    params: np.ndarray,
    rewards: np.ndarray,
    features: np.ndarray,
    epsilon: float,
    log_base: np.ndarray | None = None,
    phihat: np.ndarray | None = None,
    work: np.ndarray | None = None,
):
    """:func:`_dual` and the Hessian Cov_p(w)/η, from one product Wᵀ(p ∘ W) with W = [A/η − c,
    φ, 1] (c: A/η at the heaviest sample, against cancellation): value, grad, hess, p."""
    value, grad, p = _dual(params, rewards, features, epsilon, log_base, phihat)
    eta = params[0]
    Wt = _hessian_workspace(features) if work is None else work  # Wᵀ
    a = (rewards - features @ params[1:]) / eta
    Wt[0] = a - a[np.argmax(p)]
    moments = (Wt * p) @ Wt.T  # E_p[W_k W_l]
    mean = moments[:-1, -1]
    hess = (moments[:-1, :-1] - np.outer(mean, mean)) / eta
    return value, grad, 0.5 * (hess + hess.T), p


def reps_dual_hessian(
    params: ArrayLike,
    rewards: ArrayLike,
    features: ArrayLike,
    epsilon: float,
    base_weights: ArrayLike | None = None,
) -> np.ndarray:
    r"""Hessian ∇²g = Cov_p(w)/η of :func:`reps_dual` (same arguments), w_i = [A_i/η, φ(s_i)],
    A_i = R_i − γᵀφ(s_i), p the weights (3.10): positive semi-definite, shape (1 + F, 1 + F) in
    the order [η, γ]."""
    return _dual_hessian(*_dual_args(params, rewards, features, epsilon, base_weights))[2]


# --------------------------------------------------------------------------- weights
@dataclass(frozen=True)
class DualSolution:
    """The minimiser of the REPS dual for the bound ``epsilon``: η in reward units (``inf`` when
    all rewards are equal), γ and the baseline V(s_i) = γᵀφ(s_i) (N,), g(η, γ), the achieved
    KL(p ‖ q) and Kish ESS, ``feature_error`` = max |Σ p_i φ(s_i) − φ̂| (constraint 3.5),
    ``kl_bound_active`` (KL ≥ (1 − :data:`KL_TOLERANCE`) ε), and ``success``: the KL within
    :data:`KL_TOLERANCE` of ε (or, bound inactive, η below :data:`ETA_UNATTAINABLE`) and (3.5)
    holding to 1e-6 of the features' spread."""

    eta: float
    gamma: np.ndarray
    baseline: np.ndarray
    dual: float
    kl: float
    ess: float
    feature_error: float
    kl_bound_active: bool
    success: bool
    message: str
    epsilon: float

    def _summary(self) -> str:
        bound = "" if self.kl_bound_active else ", bound inactive"
        return (
            f"eta={self.eta:.4g}, kl={self.kl:.4g} (epsilon={self.epsilon:.4g}{bound}), "
            f"ess={self.ess:.4g}, success={self.success}"
        )


@dataclass(frozen=True, repr=False)
class REPSWeights(DualSolution):
    """Solution of the REPS dual (:class:`DualSolution`) with the weights p_i (N,) of Eq. (3.10)
    and the solver's ``n_iterations``."""

    weights: np.ndarray
    n_iterations: int

    def __repr__(self) -> str:
        return f"REPSWeights(N={self.weights.shape[0]}, {self._summary()})"


def reps_weights(
    rewards: ArrayLike,
    features: ArrayLike | None = None,
    epsilon: float = 1.0,
    base_weights: ArrayLike | None = None,
    solver: DualSolver = DEFAULT_DUAL_SOLVER,
) -> REPSWeights:
    """Solve the REPS dual (3.9) for the sample weights (3.10), with diagnostics.

    Parameters
    ----------
    rewards : array_like, shape (N,)
        Finite rewards R_i.
    features : array_like, shape (N, F), optional
        Baseline features φ(s_i); ``None`` or F = 0 gives episode-based REPS (Eq. 2.15).
    epsilon : float
        KL bound ε > 0 (Eq. 3.4).
    base_weights : array_like, shape (N,), optional
        q_i ≥ 0 (:func:`reps_dual`); ``None``: uniform, Eq. (3.9).
    solver : {"lbfgsb", "newton"}
        L-BFGS-B, or damped Newton with the analytic Hessian (L-BFGS-B takes over where Newton
        does not converge).

    Returns
    -------
    REPSWeights
    """
    eps = check_positive(epsilon, "epsilon")
    check_choice(solver, "solver", get_args(DualSolver))
    r, phi = check_samples(rewards, features)
    n, n_feat = phi.shape
    log_q = _log_base(base_weights, n)
    q = None if log_q is None else np.exp(log_q)
    phihat = _phihat(phi, log_q)
    r_max, r_scale = float(r.max()), float(r.std())
    if not r_scale > 0:
        return REPSWeights(
            weights=np.full(n, 1.0 / n) if q is None else q,
            eta=np.inf,
            gamma=np.zeros(n_feat),
            baseline=np.zeros(n),
            dual=r_max,
            kl=0.0,
            ess=float(n) if q is None else effective_sample_size(q),
            feature_error=0.0,
            kl_bound_active=False,
            success=True,
            message="all rewards are equal: the base weights",
            epsilon=eps,
            n_iterations=0,
        )

    # Normalise: unit-spread rewards with maximum 0; centred, whitened features.
    r_n = (r - r_max) / r_scale
    centred = phi - phihat
    if n_feat:
        root = centred / np.sqrt(n) if q is None else centred * np.sqrt(q)[:, None]
        _, sv, vt = np.linalg.svd(root, full_matrices=False)
        keep = sv > 1e-10 * sv.max() if sv.size and sv.max() > 0 else np.zeros(sv.shape, bool)
        transform = vt[keep].T / sv[keep]  # (F, k): ψ = (φ − φ̂) T has identity covariance
    else:
        transform = np.zeros((0, 0))
    psi = centred @ transform

    if solver == "newton":
        y, n_iterations, message, converged = _minimise_newton(r_n, psi, eps, log_q)
        if not converged:  # degenerate duals (ε unattainable under (3.5)): the default solver
            y, n_lbfgsb, message_lbfgsb = _minimise_lbfgsb(r_n, psi, eps, log_q)
            n_iterations += n_lbfgsb
            message = f"{message}; L-BFGS-B from the start: {message_lbfgsb}"
    else:
        y, n_iterations, message = _minimise_lbfgsb(r_n, psi, eps, log_q)
    eta_n = float(np.exp(y[0]))
    theta = y[1:]
    value_n, _, p = _dual(np.concatenate([[eta_n], theta]), r_n, psi, eps, log_q)

    eta = eta_n * r_scale
    gamma = r_scale * (transform @ theta)
    kl = kl_from_uniform(p) if q is None else _kl_log_base(p, log_q)
    feature_error = float(np.max(np.abs(p @ phi - phihat))) if n_feat else 0.0
    active = kl >= (1.0 - KL_TOLERANCE) * eps
    near_lower = eta_n <= ETA_UNATTAINABLE
    kl_ok = (active and kl <= (1.0 + KL_TOLERANCE) * eps) or (not active and near_lower)
    scale_phi = float(np.max(np.abs(centred))) if n_feat else 0.0
    features_ok = feature_error <= 1e-6 * max(scale_phi, np.finfo(float).tiny) or n_feat == 0
    return REPSWeights(
        weights=p,
        eta=eta,
        gamma=gamma,
        baseline=phi @ gamma,
        dual=float(r_scale * value_n + r_max),
        kl=kl,
        ess=effective_sample_size(p),
        feature_error=feature_error,
        kl_bound_active=bool(active),
        success=bool(kl_ok and features_ok),
        message=message,
        epsilon=eps,
        n_iterations=n_iterations,
    )


def _minimise_lbfgsb(
    r_n: np.ndarray, psi: np.ndarray, eps: float, log_q: np.ndarray | None
) -> tuple[np.ndarray, int, str]:
    """L-BFGS-B on the normalised dual, y = (log η, θ) from 0: minimiser, iterations, message."""

    phihat = _phihat(psi, log_q)  # the same numbers as _dual's own, computed once

    def objective(y):
        x = np.concatenate([[np.exp(y[0])], y[1:]])
        value, grad, _ = _dual(x, r_n, psi, eps, log_q, phihat)
        grad[0] *= x[0]  # chain rule for log η
        return value, grad

    lo, hi = np.log(ETA_BOUNDS[0]), np.log(ETA_BOUNDS[1])
    y0 = np.zeros(1 + psi.shape[1])
    res = optimize.minimize(
        objective,
        y0,
        jac=True,
        method="L-BFGS-B",
        bounds=[(lo, hi)] + [(None, None)] * psi.shape[1],
        options={"maxiter": 2000, "maxcor": 30, "ftol": 1e-15, "gtol": DUAL_GTOL},
    )
    return res.x, int(res.nit), str(res.message)


#: Newton's method: the largest change of log η in one step, and the iteration limit.
_MAX_LOG_ETA_STEP, _NEWTON_MAX_ITER = 2.0, 50


def _minimise_newton(
    r_n: np.ndarray, psi: np.ndarray, eps: float, log_q: np.ndarray | None
) -> tuple[np.ndarray, int, str, bool]:
    """Damped Newton on the normalised dual over y = (log η, θ) from the least-squares baseline:
    minimiser, iterations, message, converged (Armijo backtracking, η held at a bound whose
    gradient points outwards)."""
    lo, hi = np.log(ETA_BOUNDS[0]), np.log(ETA_BOUNDS[1])

    phihat, work = _phihat(psi, log_q), _hessian_workspace(psi)

    def evaluate(y: np.ndarray):
        x = np.concatenate([[np.exp(y[0])], y[1:]])
        return x, *_dual_hessian(x, r_n, psi, eps, log_q, phihat, work)[:3]

    # Start at the least-squares baseline θ₀ = Σ q_i ψ_i R_i (ψ is whitened under q).
    y = np.zeros(1 + psi.shape[1])
    y[1:] = (r_n / r_n.shape[0] if log_q is None else np.exp(log_q) * r_n) @ psi
    n_iterations, (x, value, grad, hess) = _warm_start_log_eta(evaluate, y, lo, hi, eps)
    while True:
        grad_y = np.concatenate([[x[0] * grad[0]], grad[1:]])
        held = (y[0] <= lo and grad_y[0] > 0) or (y[0] >= hi and grad_y[0] < 0)
        projected = np.concatenate([[0.0 if held else grad_y[0]], grad_y[1:]])
        if np.max(np.abs(projected)) <= DUAL_GTOL:
            return y, n_iterations, "Newton: projected gradient below tolerance", True
        if n_iterations == _NEWTON_MAX_ITER:
            return y, n_iterations, "Newton: iteration limit reached", False
        # H_y = J H J + diag(max(η ∂g/∂η, 0), 0), J = diag(η, 1): PSD, eigenvalues floored.
        hess_y = hess * np.concatenate([[x[0]], np.ones(y.shape[0] - 1)])
        hess_y[0] *= x[0]
        hess_y[0, 0] += max(grad_y[0], 0.0)
        free = np.ones(y.shape[0], bool)
        free[0] = not held
        step = np.zeros_like(y)
        step[free] = _newton_direction(hess_y[np.ix_(free, free)], grad_y[free])
        step *= min(1.0, _MAX_LOG_ETA_STEP / max(abs(step[0]), 1e-300))
        slope = grad_y @ step
        if not slope < 0:  # round-off in a near-singular Hessian: steepest descent
            step, slope = -projected, -(projected @ projected)
        t = 1.0
        while True:
            trial = y + t * step
            trial[0] = min(max(trial[0], lo), hi)
            x_t, value_t, grad_t, hess_t = evaluate(trial)
            if value_t <= value + 1e-4 * t * slope:
                break
            # At round-off level: accept a step that keeps g and reduces the gradient.
            grad_t_y = np.concatenate([[x_t[0] * grad_t[0]], grad_t[1:]])
            flat = value_t <= value + 4e-16 * max(1.0, abs(value))
            if flat and np.max(np.abs(grad_t_y)) < np.max(np.abs(grad_y)):
                break
            t *= 0.5
            if t < 1e-12:
                break
        if t < 1e-12:
            return y, n_iterations, "Newton: no decrease along the Newton direction", False
        y, x, value, grad, hess = trial, x_t, value_t, grad_t, hess_t
        n_iterations += 1


def _warm_start_log_eta(evaluate, y: np.ndarray, lo: float, hi: float, eps: float):
    """Set y[0] to a log η where ε − KL vanishes to 5e-2 ε (safeguarded Newton/bisection);
    returns the evaluations and the last one."""
    a, b, n = lo, hi, 0
    while True:
        n += 1
        evaluation = evaluate(y)
        x, _, grad, hess = evaluation
        h = grad[0]  # ε − KL, increasing in log η
        if h > 0:
            b = y[0]
        else:
            a = y[0]
        if abs(h) <= 0.05 * eps or b - a < 1e-3 or n == 60:
            break
        slope = x[0] * hess[0, 0]  # dh/d log η = η ∂²g/∂η²
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            u = y[0] - h / slope if slope > 0 and np.isfinite(slope) else np.nan
        u = min(max(u, y[0] - _MAX_LOG_ETA_STEP), y[0] + _MAX_LOG_ETA_STEP)
        y[0] = u if a < u < b else 0.5 * (a + b)
    return n, evaluation


def _newton_direction(hess: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """−H⁻¹g for a symmetric PSD H, eigenvalues floored at 1e-12 of the largest."""
    if grad.size == 0:
        return grad
    if not (np.isfinite(hess).all() and np.isfinite(grad).all()):
        return -grad
    lam, vec = np.linalg.eigh(hess)
    floor = 1e-12 * max(float(lam.max()), np.finfo(float).tiny)
    with np.errstate(over="ignore", invalid="ignore"):
        step = -(vec @ ((vec.T @ grad) / np.maximum(lam, floor)))
    return step if np.isfinite(step).all() else -grad


def kl_from_uniform(weights: np.ndarray) -> float:
    """KL(p ‖ uniform) = Σ p_i log(N p_i) of normalised weights p, shape (N,) (0 log 0 = 0)."""
    p = np.asarray(weights, dtype=np.float64)
    q = p[p > 0]
    return float(np.sum(q * np.log(p.size * q)))


def _kl_log_base(p: np.ndarray, log_q: np.ndarray) -> float:
    """KL(p ‖ q) from log q, finite where q underflows."""
    pos = p > 0
    return float(np.sum(p[pos] * (np.log(p[pos]) - log_q[pos])))


def _log_base(base_weights: ArrayLike | None, n: int) -> np.ndarray | None:
    """log q of validated base weights, normalised (``None`` stays ``None``)."""
    if base_weights is None:
        return None
    q = check_array(base_weights, "base_weights", shape=(n,))
    if np.any(q < 0) or not q.sum() > 0:
        raise ValueError("base_weights: expected non-negative weights with a positive sum")
    with np.errstate(divide="ignore"):
        return np.log(q) - np.log(q.sum())


def check_samples(rewards, features) -> tuple[np.ndarray, np.ndarray]:
    """Validated rewards (N,), N ≥ 1, and features (N, F) (``None``: F = 0)."""
    r = check_array(rewards, "rewards", ndim=1)
    if r.shape[0] == 0:
        raise ValueError("rewards: expected at least one sample, got shape (0,)")
    if features is None:
        return r, np.zeros((r.shape[0], 0))
    phi = check_array(features, "features", ndim=2)
    if phi.shape[0] != r.shape[0]:
        raise ValueError(f"features: expected {r.shape[0]} rows, got shape {phi.shape}")
    return r, phi


# --------------------------------------------------------------------------- algorithm
@dataclass(frozen=True, repr=False)
class REPSDiagnostics(DualSolution):
    """What one :meth:`ContextualREPS.update` did: the :class:`DualSolution`, the fields of
    :meth:`~skillkit.search.base.WeightedMLSearch.update`, and with ``m_step="trust_region"`` the
    :class:`~skillkit.policies.gaussian.TrustRegionStep`."""

    n_samples: int
    policy_kl: float
    mean_reward: float
    fit: FitInfo
    m_step: TrustRegionStep | None = None

    def __repr__(self) -> str:
        ml = "" if self.m_step is None else f", ml_kl={self.m_step.ml_kl:.4g}"
        return (
            f"REPSDiagnostics(n_samples={self.n_samples}, {self._summary()}, "
            f"policy_kl={self.policy_kl:.4g}{ml}, mean_reward={self.mean_reward:.4g})"
        )


ExtraContextWeighting = Literal["naive", "importance", "dual_only"]
MStep = Literal["weighted_ml", "trust_region"]


class ContextualREPS(WeightedMLSearch[REPSDiagnostics]):
    """Contextual (with a context-free policy: episode-based) REPS, Table 3.1: the weights (3.10)
    of the dual (3.9) in :class:`~skillkit.search.base.WeightedMLSearch`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy π(ω|s).
    epsilon : float
        KL bound ε > 0 (Eq. 3.4).
    n_reuse_batches : int or None
        L: the last L batches are used, the newest included (``None``: all).
    baseline_features : {"linear", "quadratic"}
        Features φ(s) of the baseline V(s) = γᵀφ(s) and of constraint (3.5).
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of the weighted ML fit (:class:`~skillkit.search.base.WeightedMLSearch`).
    extra_context_weighting : {"naive", "importance", "dual_only"}
        Rows re-scored in extra contexts (Sec. 3.4) count as drawn from μ(s)π(ω|s), carry
        :func:`~skillkit.search.base.extra_context_importance` as base weights q, or enter the
        dual only.
    m_step : {"weighted_ml", "trust_region"}
        The weighted ML fit, or that fit through
        :func:`~skillkit.policies.gaussian.trust_region_step`.
    entropy_loss_bound : float, optional
        β > 0 of the trust region in nats per update (default ε).
    dual_solver : {"lbfgsb", "newton"}
        ``solver`` of :func:`reps_weights`.
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        epsilon: float,
        n_reuse_batches: int | None = 1,
        baseline_features: FeatureName = "quadratic",
        ridge: float = 1e-6,
        cov_shrinkage: float = 0.0,
        cov_floor: float = 1e-4,
        min_effective_samples: float | None = None,
        *,
        extra_context_weighting: ExtraContextWeighting = "importance",
        m_step: MStep = "weighted_ml",
        entropy_loss_bound: float | None = None,
        dual_solver: DualSolver = DEFAULT_DUAL_SOLVER,
    ):
        super().__init__(
            policy, n_reuse_batches, ridge, cov_shrinkage, cov_floor, min_effective_samples
        )
        self.epsilon = check_positive(epsilon, "epsilon")
        self.baseline_features = check_feature_name(baseline_features, "baseline_features")
        self.extra_context_weighting = check_choice(
            extra_context_weighting, "extra_context_weighting", get_args(ExtraContextWeighting)
        )
        self.m_step = check_choice(m_step, "m_step", get_args(MStep))
        self.dual_solver = check_choice(dual_solver, "dual_solver", get_args(DualSolver))
        bound = self.epsilon if entropy_loss_bound is None else entropy_loss_bound
        self.entropy_loss_bound = check_positive(bound, "entropy_loss_bound")

    _diagnostics = REPSDiagnostics

    def _settings_repr(self) -> str:
        text = f"epsilon={self.epsilon:.4g}, baseline_features={self.baseline_features!r}"
        if self.extra_context_weighting != "naive":
            text += f", extra_context_weighting={self.extra_context_weighting!r}"
        if self.m_step != "weighted_ml":
            text += f", m_step={self.m_step!r}, entropy_loss_bound={self.entropy_loss_bound:.4g}"
        if self.dual_solver != "lbfgsb":
            text += f", dual_solver={self.dual_solver!r}"
        return text

    def _importance(self, batch: Batch) -> np.ndarray | None:
        """Importance weights of a batch with extra-context rows (``"importance"`` only)."""
        if self.extra_context_weighting != "importance" or batch.n_rollouts == len(batch):
            return None
        return extra_context_importance(
            self._policy, batch.contexts, batch.omegas, batch.n_rollouts
        )

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights (3.10) of the kept rows; zero on extra-context rows with ``"dual_only"``."""
        phi = context_features(contexts, self.baseline_features) if contexts.shape[1] else None
        sol = reps_weights(
            rewards, phi, self.epsilon, self._buffer.importance(), solver=self.dual_solver
        )
        weights = sol.weights
        if self.extra_context_weighting == "dual_only":
            rollout = self._buffer.rollout_mask()
            if not rollout.all():
                weights = np.where(rollout, weights, 0.0)
                total = weights.sum()
                if not total > 0:
                    raise ValueError("extra_context_weighting: with 'dual_only' no weight is left")
                weights = weights / total
        return weights, {f.name: getattr(sol, f.name) for f in fields(DualSolution)}

    def _m_step(
        self, old: LinearGaussianPolicy, fitted: LinearGaussianPolicy, contexts: np.ndarray
    ) -> tuple[LinearGaussianPolicy, Fields]:
        """The weighted ML fit, or its trust-region correction."""
        if self.m_step == "weighted_ml":
            return fitted, {}
        new, step = trust_region_step(old, fitted, contexts, self.epsilon, self.entropy_loss_bound)
        return new, {"m_step": step}
