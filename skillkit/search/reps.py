r"""Relative Entropy Policy Search: episode-based (2.12–2.15) and contextual (3.3–3.13).

The maths is in two functions, in the style of bolero's C-REPS:

* :func:`reps_dual` — the sample-based dual g(η, γ; D) of Eq. (3.9)/(A.10) and its analytic
  gradient (A.11, A.12), a pure function of its arguments;
* :func:`reps_weights` — minimises the dual with scipy's L-BFGS-B and returns the sample
  weights p_i ∝ exp((R_i − V(s_i))/η) of Eq. (3.10) with diagnostics.

:class:`ContextualREPS` only holds state (the policy and the last L batches of samples) and
runs Table 3.1: weights from the dual, then the weighted maximum-likelihood policy
(Eqs. 3.11–3.13, :meth:`~skillkit.policies.gaussian.LinearGaussianPolicy.fit`); that loop is
:class:`~skillkit.search.base.WeightedMLSearch`, shared with RWR. Episode-based REPS is the
same code path with a context-free policy (no context features, V ≡ 0).

Two choices of :class:`ContextualREPS` go beyond Table 3.1 (issue #17); both default to the
thesis's plain algorithm, with which every stored result was made
(:data:`DEFAULT_EXTRA_CONTEXT_WEIGHTING`, :data:`DEFAULT_M_STEP`):

* ``extra_context_weighting`` — rows that re-score a trajectory in an extra context (Sec. 3.4)
  are not draws of μ(s)π(ω|s). ``"importance"`` makes them so by importance weights
  (:func:`~skillkit.search.base.extra_context_importance`) that become the base distribution
  q of the dual (``base_weights`` of :func:`reps_weights`: p_i ∝ q_i exp((R_i − V(s_i))/η),
  KL(p ‖ q) ≤ ε). ``"naive"`` biases the gain towards zero (measured: 0.64 of the optimal gain
  after one update from the optimum, ``benchmarks/bench_reps_extra_context.py``).
* ``m_step`` — the weighted ML fit's KL from the old policy is about 2ε with tens of effective
  samples in 10 dimensions, and its covariance collapses. ``"trust_region"`` bounds the
  entropy loss and then the KL after the fit
  (:func:`~skillkit.policies.gaussian.trust_region_step`); the KL after the M-step is in every
  update's diagnostics (``policy_kl``, and the fit's own in ``m_step.ml_kl``).

Numerics of :func:`reps_weights`
--------------------------------
* Rewards are shifted by their maximum and divided by their standard deviation, and the
  baseline features are centred at their sample mean φ̂ and whitened. The weights are
  invariant to both transforms (g(η, γ; σR + c) = σ g(η/σ, γ/σ; R) + c, and the feature
  constraint (3.5) is the same set for any invertible linear map of φ), so the optimiser always
  sees rewards of unit spread, whatever their magnitude (1e-6 … 1e6).
* η > 0 is enforced by optimising over log η (bounded to [1e-8, 1e8] in normalised units);
  the log-sum-exp is evaluated with a max shift, so no exponential overflows.
* At the optimum ∂g/∂η = ε − KL(p ‖ uniform) (KL(p ‖ q) with base weights q), so the KL
  bound (3.4) is met with equality.
  If ε exceeds the largest KL the samples allow (ε ≥ log N for distinct rewards, less when the
  feature constraint (3.5) must hold too), η runs towards its lower bound; this is reported
  (``kl_bound_active=False``), not hidden. The flag is derived from the achieved KL
  (KL ≥ (1 − :data:`KL_TOLERANCE`) ε), not from where η stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from skillkit._validation import check_array, check_positive
from skillkit.policies.features import FeatureName, check_feature_name, context_features
from skillkit.policies.gaussian import (
    FitInfo,
    LinearGaussianPolicy,
    TrustRegionStep,
    effective_sample_size,
    trust_region_step,
)
from skillkit.search.base import Batch, Fields, WeightedMLSearch, extra_context_importance
from skillkit.search.base import SampleBuffer as SampleBuffer  # re-exported (and old pickles)
from skillkit.search.base import check_batch as check_batch  # re-exported

#: Bounds of η in normalised reward units (rewards divided by their standard deviation).
ETA_BOUNDS = (1e-8, 1e8)
#: Relative tolerance on the achieved KL: the bound (3.4) counts as active (met with equality)
#: when KL ≥ (1 − tol) ε, and a solution is successful only if KL ≤ (1 + tol) ε.
KL_TOLERANCE = 1e-3
#: η (normalised units) below which a KL short of ε means that ε is unattainable: the weights
#: are then, to within exp(−1/η) of the smallest reward gap, the η → 0 limit of Eq. (3.10).
ETA_UNATTAINABLE = 1e-5


# --------------------------------------------------------------------------- the dual
def _dual(
    params: np.ndarray,
    rewards: np.ndarray,
    features: np.ndarray,
    epsilon: float,
    log_base: np.ndarray | None = None,
):
    """Unchecked core of :func:`reps_dual`; also returns the weights p (softmax).

    ``log_base`` is log q_i of normalised base weights (``None``: uniform q_i = 1/N, computed
    without the logarithms so today's numbers are unchanged to the last bit).
    """
    eta, gamma = params[0], params[1:]
    adv = rewards - features @ gamma
    a = adv / eta
    if log_base is not None:
        a = a + log_base
    m = a.max()
    z = np.exp(a - m)
    total = z.sum()
    p = z / total
    if log_base is None:
        log_mean_z = m + np.log(total) - np.log(rewards.shape[0])
        phihat = features.mean(axis=0)
    else:
        log_mean_z = m + np.log(total)
        phihat = np.exp(log_base) @ features
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

    With base weights q (normalised to sum to one) the samples stand for the weighted
    empirical distribution Σ q_i δ_i instead of the uniform one (e.g. importance weights of
    samples not drawn from μ(s)π(ω|s), :func:`~skillkit.search.base.extra_context_importance`):
    1/N becomes q_i inside the logarithm and φ̂ = Σ q_i φ(s_i); the KL of Eq. (3.4) is then
    KL(p ‖ q). q uniform gives Eq. (3.9).

    Parameters
    ----------
    params : array_like, shape (1 + F,)
        [η, γ_1, …, γ_F] with η > 0.
    rewards : array_like, shape (N,)
        Rewards R_i.
    features : array_like, shape (N, F)
        Baseline features φ(s_i) (F = 0 for episode-based REPS).
    epsilon : float
        KL bound ε > 0.
    base_weights : array_like, shape (N,), optional
        Non-negative base weights q_i with a positive sum (normalised here); ``None``: uniform.

    Returns
    -------
    value : float
        g(η, γ).
    grad : ndarray, shape (1 + F,)
        [∂g/∂η (A.11), ∂g/∂γ (A.12)]. Note ∂g/∂η = ε − KL(p ‖ q) with the weights
        p_i ∝ q_i exp((R_i − γᵀφ(s_i))/η) of Eq. (3.10).
    """
    r, phi = _check_samples(rewards, features)
    x = check_array(params, "params", shape=(1 + phi.shape[1],))
    if not x[0] > 0:
        raise ValueError(f"params: η = params[0] must be > 0, got {x[0]!r}")
    log_q = _log_base(base_weights, r.shape[0])
    value, grad, _ = _dual(x, r, phi, check_positive(epsilon, "epsilon"), log_q)
    return float(value), grad


# --------------------------------------------------------------------------- weights
@dataclass(frozen=True)
class DualSolution:
    """What the minimiser of the REPS dual says, shared by :class:`REPSWeights` and
    :class:`REPSDiagnostics`.

    Attributes
    ----------
    eta : float
        Temperature η (in reward units); ``inf`` when all rewards are equal (uniform weights).
    gamma : ndarray, shape (F,)
        Baseline coefficients γ (in reward units per feature unit).
    baseline : ndarray, shape (N,)
        V(s_i) = γᵀφ(s_i) at the samples.
    dual : float
        g(η, γ) at the solution (reward units).
    kl : float
        KL(p ‖ uniform) = Σ p_i log(N p_i) actually achieved (KL(p ‖ q) with base weights q;
        ≤ ε up to solver tolerance).
    ess : float
        Kish effective sample size 1 / Σ p_i².
    feature_error : float
        max |Σ p_i φ(s_i) − φ̂| (constraint 3.5 residual, feature units).
    kl_bound_active : bool
        Whether the achieved KL meets the bound: KL ≥ (1 − :data:`KL_TOLERANCE`) ε. False when
        ε exceeds what the samples and the feature constraint (3.5) allow, or when all rewards
        are equal (uniform weights).
    success : bool
        The constraints hold: KL within :data:`KL_TOLERANCE` ε of ε when the bound is active,
        or, when it is not, η has run below :data:`ETA_UNATTAINABLE` (ε is unattainable);
        and the feature constraint (3.5) holds to 1e-6 of the features' spread.
    message : str
        Optimiser message.
    epsilon : float
        The KL bound ε the weights were solved for.
    """

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
        """η, achieved KL against ε, ESS and convergence, without the arrays."""
        bound = "" if self.kl_bound_active else ", bound inactive"
        return (
            f"eta={self.eta:.4g}, kl={self.kl:.4g} (epsilon={self.epsilon:.4g}{bound}), "
            f"ess={self.ess:.4g}, success={self.success}"
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._summary()})"


@dataclass(frozen=True, repr=False)
class REPSWeights(DualSolution):
    """Solution of the REPS dual on a set of samples.

    Attributes
    ----------
    eta, gamma, baseline, dual, kl, ess, feature_error, kl_bound_active, success, message, epsilon
        See :class:`DualSolution`.
    weights : ndarray, shape (N,)
        p_i of Eq. (3.10), summing to one.
    n_iterations : int
        L-BFGS-B iterations.
    """

    weights: np.ndarray
    n_iterations: int

    def __repr__(self) -> str:
        return f"REPSWeights(N={self.weights.shape[0]}, {self._summary()})"


def reps_weights(
    rewards: ArrayLike,
    features: ArrayLike | None = None,
    epsilon: float = 1.0,
    base_weights: ArrayLike | None = None,
) -> REPSWeights:
    r"""Solve the REPS dual (3.9) and return the sample weights (3.10) with diagnostics.

    Minimises g(η, γ) of :func:`reps_dual` with scipy's L-BFGS-B over (log η, γ) after
    normalising rewards and whitening features (see the module notes), then maps η, γ back to
    the original units.

    Parameters
    ----------
    rewards : array_like, shape (N,)
        Finite rewards R_i.
    features : array_like, shape (N, F), optional
        Baseline features φ(s_i); ``None`` or F = 0 gives episode-based REPS (Eq. 2.15).
    epsilon : float
        KL bound ε > 0 (Eq. 3.4).
    base_weights : array_like, shape (N,), optional
        Base weights q_i ≥ 0 (positive sum, normalised here): the samples stand for Σ q_i δ_i,
        the weights are p_i ∝ q_i exp((R_i − V(s_i))/η), the bound is KL(p ‖ q) ≤ ε and the
        feature constraint Σ p_i φ_i = Σ q_i φ_i (see :func:`reps_dual`). ``None``: uniform,
        Eq. (3.9) exactly.

    Returns
    -------
    REPSWeights
    """
    eps = check_positive(epsilon, "epsilon")
    r, phi = _check_samples(rewards, features)
    n, n_feat = phi.shape
    log_q = _log_base(base_weights, n)
    q = None if log_q is None else np.exp(log_q)
    phihat = phi.mean(axis=0) if q is None else q @ phi
    r_max, r_scale = float(r.max()), float(r.std())
    if not r_scale > 0:
        return REPSWeights(
            weights=np.full(n, 1.0 / n) if q is None else q, eta=np.inf, gamma=np.zeros(n_feat),
            baseline=np.zeros(n),
            dual=r_max, kl=0.0, ess=float(n) if q is None else effective_sample_size(q),
            feature_error=0.0, kl_bound_active=False,
            success=True, message="all rewards are equal: the base weights", epsilon=eps,
            n_iterations=0,
        )  # fmt: skip

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

    def objective(y):
        x = np.concatenate([[np.exp(y[0])], y[1:]])
        value, grad, _ = _dual(x, r_n, psi, eps, log_q)
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
        options={"maxiter": 2000, "maxcor": 30, "ftol": 1e-15, "gtol": 1e-11},
    )
    eta_n = float(np.exp(res.x[0]))
    theta = res.x[1:]
    value_n, _, p = _dual(np.concatenate([[eta_n], theta]), r_n, psi, eps, log_q)

    eta = eta_n * r_scale
    gamma = r_scale * (transform @ theta)
    kl = kl_from_uniform(p) if q is None else kl_divergence(p, q)
    feature_error = float(np.max(np.abs(p @ phi - phihat))) if n_feat else 0.0
    # The bound is active when the achieved KL meets it, whatever η did (4b of issue #17: with
    # features, an unattainable ε leaves η just above its lower bound with KL well below ε).
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
        message=str(res.message),
        epsilon=eps,
        n_iterations=int(res.nit),
    )


def kl_from_uniform(weights: np.ndarray) -> float:
    """KL(p ‖ uniform) = Σ p_i log(N p_i) of normalised weights p, shape (N,) (0 log 0 = 0)."""
    p = np.asarray(weights, dtype=np.float64)
    q = p[p > 0]
    return float(np.sum(q * np.log(p.size * q)))


def kl_divergence(weights: np.ndarray, base: np.ndarray) -> float:
    """KL(p ‖ q) = Σ p_i log(p_i / q_i) of normalised weights p and q, shape (N,) (0 log 0 = 0;
    p must vanish where q does)."""
    p, q = np.asarray(weights, dtype=np.float64), np.asarray(base, dtype=np.float64)
    pos = p > 0
    return float(np.sum(p[pos] * np.log(p[pos] / q[pos])))


def _log_base(base_weights: ArrayLike | None, n: int) -> np.ndarray | None:
    """log q of validated base weights, normalised to sum to one (``None`` stays ``None``)."""
    if base_weights is None:
        return None
    q = check_array(base_weights, "base_weights", shape=(n,))
    if np.any(q < 0) or not q.sum() > 0:
        raise ValueError("base_weights: expected non-negative weights with a positive sum")
    with np.errstate(divide="ignore"):
        return np.log(q) - np.log(q.sum())


def _check_samples(rewards, features) -> tuple[np.ndarray, np.ndarray]:
    r = check_array(rewards, "rewards", ndim=1)
    if r.shape[0] == 0:
        raise ValueError("rewards: expected at least one sample, got shape (0,)")
    if features is None:
        return r, np.zeros((r.shape[0], 0))
    phi = check_array(features, "features", ndim=2)
    if phi.shape[0] != r.shape[0]:
        raise ValueError(
            f"features: expected {r.shape[0]} rows (one per reward), got shape {phi.shape}"
        )
    return r, phi


# --------------------------------------------------------------------------- algorithm
@dataclass(frozen=True, repr=False)
class REPSDiagnostics(DualSolution):
    """What one :meth:`ContextualREPS.update` did.

    Attributes
    ----------
    eta, gamma, baseline, dual, kl, ess, feature_error, kl_bound_active, success, message, epsilon
        From :class:`REPSWeights` (``baseline`` is V(s_i) at the samples used).
    n_samples : int
        Samples used (the last L batches).
    policy_kl : float
        KL(π_new ‖ π_old) averaged over the contexts used, after the M-step (every update).
    mean_reward : float
        Mean reward of the newest batch.
    fit : FitInfo
        What the weighted maximum-likelihood fit did (effective samples, floor hits).
    m_step : TrustRegionStep or None
        With ``m_step="trust_region"``: the fit's own KL and entropy loss and what the
        entropy and KL bounds did to it (:func:`~skillkit.policies.gaussian.trust_region_step`);
        ``None`` with ``m_step="weighted_ml"`` (then ``policy_kl`` is the fit's KL).
    """

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

#: How REPS uses re-scored extra-context rows (Sec. 3.4) by default: ``"importance"``, the
#: unbiased fix of issue #17; ``"naive"`` (the behaviour before it) is kept as a named option.
DEFAULT_EXTRA_CONTEXT_WEIGHTING: ExtraContextWeighting = "importance"
#: REPS's M-step by default. ``"weighted_ml"`` (Eqs. 3.11–3.13 alone) is today's behaviour,
#: with which every stored result was made; ``"trust_region"`` is the fix of issue #17.
DEFAULT_M_STEP: MStep = "weighted_ml"


class ContextualREPS(WeightedMLSearch[REPSDiagnostics]):
    """Contextual (and, with a context-free policy, episode-based) REPS, Table 3.1.

    :meth:`update` adds a batch, solves the dual (3.9) on the last L batches for the weights
    (3.10) and refits the policy (3.11–3.13); see :class:`~skillkit.search.base.WeightedMLSearch`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy π(ω|s) (a :class:`~skillkit.policies.gaussian.GaussianPolicy`
        gives episode-based REPS).
    epsilon : float
        KL bound ε > 0 (Eq. 3.4); the thesis uses 0.5–1.
    n_reuse_batches : int or None
        L: the dual and the fit use the last L batches, the newest included (``None``: all).
        The thesis's throwing setting (25 rollouts per update, reuse the last 200) is L = 8.
    baseline_features : {"linear", "quadratic"}
        Features φ(s) of the baseline V(s) = γᵀφ(s) and of constraint (3.5). ``"quadratic"``
        matches the mean and second moments of μ(s) and captures rewards whose expectation is
        quadratic in s.
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of the weighted ML fit (:class:`~skillkit.search.base.WeightedMLSearch`).
    extra_context_weighting : {"naive", "importance", "dual_only"}
        How rows that re-score a rollout in an extra context (``Batch.n_rollouts`` < N, Sec. 3.4)
        are used. ``"naive"``: as if drawn from μ(s)π(ω|s), which biases the gain A towards
        zero (in 20 of 21 rows ω does not depend on s). ``"importance"``: every row of a batch
        carries the importance weight of
        :func:`~skillkit.search.base.extra_context_importance` under the policy that drew it
        (the current policy when the batch arrives, as in Table 3.1); the weights are the base
        distribution q of the dual (:func:`reps_weights`), so p_i ∝ q_i exp((R_i − V(s_i))/η)
        and the fit sees the extra rows weighted accordingly. ``"dual_only"``: the dual uses
        every row as ``"naive"`` does, the fit only the rollouts (their weights renormalised).
        Default :data:`DEFAULT_EXTRA_CONTEXT_WEIGHTING`. Batches without extra rows are
        unaffected.
    m_step : {"weighted_ml", "trust_region"}
        ``"weighted_ml"``: the policy is the weighted ML fit (3.11–3.13), whose KL from the
        old policy can be twice ε. ``"trust_region"``: the fit is passed through
        :func:`~skillkit.policies.gaussian.trust_region_step` (entropy loss ≤ β, then
        KL(π_new ‖ π_old) ≤ ε). Default :data:`DEFAULT_M_STEP`.
    entropy_loss_bound : float, optional
        β > 0 of ``m_step="trust_region"`` in nats per update (default ε: the entropy may fall
        by at most the KL budget per update).
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
        extra_context_weighting: ExtraContextWeighting = DEFAULT_EXTRA_CONTEXT_WEIGHTING,
        m_step: MStep = DEFAULT_M_STEP,
        entropy_loss_bound: float | None = None,
    ):
        super().__init__(
            policy, n_reuse_batches, ridge, cov_shrinkage, cov_floor, min_effective_samples
        )
        self.epsilon = check_positive(epsilon, "epsilon")
        self.baseline_features = check_feature_name(baseline_features, "baseline_features")
        self.extra_context_weighting = _check_choice(
            extra_context_weighting, "extra_context_weighting", get_args(ExtraContextWeighting)
        )
        self.m_step = _check_choice(m_step, "m_step", get_args(MStep))
        self.entropy_loss_bound = (
            self.epsilon
            if entropy_loss_bound is None
            else check_positive(entropy_loss_bound, "entropy_loss_bound")
        )

    _diagnostics = REPSDiagnostics
    # What an instance pickled before issue #17 (which has none of these attributes) ran.
    extra_context_weighting: ExtraContextWeighting = "naive"
    m_step: MStep = "weighted_ml"
    entropy_loss_bound: float | None = None

    def _settings_repr(self) -> str:
        text = f"epsilon={self.epsilon:.4g}, baseline_features={self.baseline_features!r}"
        if self.extra_context_weighting != "naive":
            text += f", extra_context_weighting={self.extra_context_weighting!r}"
        if self.m_step != "weighted_ml":
            text += f", m_step={self.m_step!r}, entropy_loss_bound={self.entropy_loss_bound:.4g}"
        return text

    def _importance(self, batch: Batch) -> np.ndarray | None:
        """Importance weights of a batch with extra-context rows (``"importance"`` only)."""
        if self.extra_context_weighting != "importance" or batch.n_rollouts == len(batch):
            return None
        return extra_context_importance(
            self._policy, batch.contexts, batch.omegas, batch.n_rollouts
        )

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights (3.10) from the dual (3.9) with baseline features φ(s) of the contexts, on
        the kept rows' importance weights (``"importance"``), or zero on extra-context rows
        after the dual (``"dual_only"``)."""
        phi = context_features(contexts, self.baseline_features) if contexts.shape[1] else None
        sol = reps_weights(rewards, phi, self.epsilon, self._buffer.importance())
        weights = sol.weights
        if self.extra_context_weighting == "dual_only":
            rollout = self._buffer.rollout_mask()
            if not rollout.all():
                weights = np.where(rollout, weights, 0.0)
                weights = weights / weights.sum()
        return weights, {f.name: getattr(sol, f.name) for f in fields(DualSolution)}

    def _m_step(
        self, old: LinearGaussianPolicy, fitted: LinearGaussianPolicy, contexts: np.ndarray
    ) -> tuple[LinearGaussianPolicy, Fields]:
        """The weighted ML fit, or its trust-region correction (``m_step="trust_region"``)."""
        if self.m_step == "weighted_ml":
            return fitted, {}
        new, step = trust_region_step(old, fitted, contexts, self.epsilon, self.entropy_loss_bound)
        return new, {"m_step": step}


def _check_choice(value: str, name: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return value
