"""Upper-level Gaussian policies π(ω|s) = N(a + Aφ(s), Σ) and π(ω) = N(μ, Σ) (Secs. 2.1.1, 3.3).

Policies are immutable: :meth:`LinearGaussianPolicy.fit` returns the regularised weighted
maximum-likelihood policy of Eqs. 3.11–3.13, and :func:`trust_region_step` bounds its KL and
entropy loss. Contexts are (n, context_dim) or one (context_dim,); a context-free policy
takes ``None`` (one sample) or ``np.zeros((n, 0))``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg

from skillkit._repr import number, span, vector
from skillkit._validation import as_generator, check_array, check_positive
from skillkit.policies.features import (
    FeatureName,
    context_features,
    feature_dim,
)

_LOG_2PI = float(np.log(2.0 * np.pi))
RNG = np.random.Generator | np.random.SeedSequence | int | None


@dataclass(frozen=True)
class FitInfo:
    """What a weighted maximum-likelihood fit (Eqs. 3.11–3.13) did: samples, Kish effective sample
    size, ridge, shrinkage κ, the smallest eigenvalue of Σ_old^{-1/2} Σ Σ_old^{-1/2} before the
    floor, and how many eigenvalues the floor and the condition guard raised."""

    n_samples: int
    effective_samples: float
    ridge: float
    cov_shrinkage: float
    min_cov_ratio: float
    n_floored: int
    n_conditioned: int = 0


#: No eigenvalue of a fitted Σ is left below this fraction of its largest one.
MIN_RELATIVE_EIGENVALUE = 1e-12


def effective_sample_size(weights: np.ndarray) -> float:
    """Kish effective sample size (Σ w)² / Σ w² of non-negative weights (N,)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.max()
    return float(w.sum() ** 2 / np.dot(w, w))


def query_contexts(contexts: ArrayLike | None, context_dim: int) -> tuple[np.ndarray, bool]:
    """Contexts of shape (n, context_dim), and whether one context (or ``None``) was given."""
    if contexts is None:
        if context_dim:
            raise ValueError(f"contexts: this policy needs contexts of shape (n, {context_dim})")
        return np.zeros((1, 0)), True
    s = check_array(contexts, "contexts", ndim=(1, 2))
    if s.shape[-1] != context_dim:
        raise ValueError(f"contexts: expected shape (n, {context_dim}), got {s.shape}")
    return (s[None, :], True) if s.ndim == 1 else (s, False)


def _whitened(chol: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """L⁻¹ Σ L⁻ᵀ for the Cholesky factor L of Σ_old, symmetrised."""
    m = linalg.solve_triangular(chol, linalg.solve_triangular(chol, cov, lower=True).T, lower=True)
    return 0.5 * (m + m.T)


class LinearGaussianPolicy:
    r"""Contextual linear-Gaussian upper-level policy π(ω|s) = N(ω | a + A φ(s), Σ), Eq. (3.13).

    Parameters
    ----------
    mean, cov : array_like, shapes (d,) and (d, d)
        The offset a and Σ (symmetric positive definite).
    gain : array_like, shape (d, F), optional
        A on the context features (default zeros).
    context_dim : int, default 0
        Dimension of the context s.
    features : {"linear", "quadratic"}, default "linear"
        φ (:mod:`skillkit.policies.features`); F = ``feature_dim(context_dim, features)``.

    Raises
    ------
    ValueError
        On bad shapes, a ``cov`` that is not symmetric positive definite, or unknown features.
    """

    def __init__(
        self, mean, cov, gain=None, context_dim: int = 0, features: FeatureName = "linear"
    ):
        n_feat = feature_dim(context_dim, features)  # validates both
        self._features = features
        self._context_dim = int(context_dim)
        a = check_array(mean, "mean", ndim=1)
        d = a.shape[0]
        if d < 1:
            raise ValueError("mean: expected at least one parameter dimension, got shape (0,)")
        cov = check_array(cov, "cov", shape=(d, d))
        scale = max(float(np.max(np.abs(cov))), np.finfo(float).tiny)
        if np.max(np.abs(cov - cov.T)) > 1e-10 * scale:
            raise ValueError("cov: expected a symmetric matrix")
        cov = 0.5 * (cov + cov.T)
        try:
            self._chol = linalg.cholesky(cov, lower=True)
        except linalg.LinAlgError:
            low = np.linalg.eigvalsh(cov).min()
            raise ValueError(f"cov: expected positive definite, min eigenvalue {low:.3g}") from None
        gain = np.zeros((d, n_feat)) if gain is None else gain
        gain = check_array(gain, "gain", shape=(d, n_feat))
        self._mean, self._cov, self._gain = a.copy(), cov, gain.copy()
        for arr in (self._mean, self._cov, self._gain, self._chol):
            arr.setflags(write=False)

    @property
    def dim(self) -> int:
        return int(self._mean.shape[0])

    @property
    def context_dim(self) -> int:
        return self._context_dim

    @property
    def features(self) -> str:
        return self._features

    @property
    def n_features(self) -> int:
        return int(self._gain.shape[1])

    @property
    def mean(self) -> np.ndarray:
        return self._mean

    @property
    def cov(self) -> np.ndarray:
        return self._cov

    @property
    def gain(self) -> np.ndarray:
        return self._gain

    @property
    def coefficients(self) -> np.ndarray:
        """[a, A], shape (d, 1 + F)."""
        return np.column_stack([self._mean, self._gain])

    def phi(self, contexts: ArrayLike | None) -> tuple[np.ndarray, bool]:
        """φ of validated contexts (n, F), and whether one context was given."""
        s, single = query_contexts(contexts, self._context_dim)
        return context_features(s, self._features), single

    def mean_of(self, contexts: ArrayLike | None = None) -> np.ndarray:
        """Policy mean a + A φ(s) (Eq. 3.13) of contexts (n, context_dim) or (context_dim,), or
        ``None`` for a context-free policy: shape (n, d), or (d,) for one context."""
        phi, single = self.phi(contexts)
        mu = self._mean + phi @ self._gain.T
        return mu[0] if single else mu

    def sample(self, contexts: ArrayLike | None = None, rng: RNG = None) -> np.ndarray:
        """Draw ω ~ N(a + A φ(s), Σ), one per context (as :meth:`mean_of`; ``np.zeros((n, 0))``
        draws n from a context-free policy): shape (n, d), or (d,) for one context."""
        rng = as_generator(rng)
        phi, single = self.phi(contexts)
        z = rng.standard_normal((phi.shape[0], self.dim))
        omega = self._mean + phi @ self._gain.T + z @ self._chol.T
        return omega[0] if single else omega

    def _row_phi(self, contexts, n: int, single: bool = False) -> np.ndarray:
        """φ of one context per ω of n (``None``: zero-width contexts of a context-free policy)."""
        if contexts is None and self._context_dim == 0:
            contexts = np.zeros(0) if single else np.zeros((n, 0))
        phi, one = self.phi(contexts)
        if one != single or phi.shape[0] != n:
            raise ValueError(f"contexts: expected one per ω ({n}), got {np.shape(contexts)}")
        return phi

    def log_prob(self, omegas: ArrayLike, contexts: ArrayLike | None = None) -> np.ndarray | float:
        """log N(ω | a + A φ(s), Σ) of ``omegas`` (n, d) or (d,), one context each."""
        w = check_array(omegas, "omegas", ndim=(1, 2))
        if w.shape[-1] != self.dim:
            raise ValueError(f"omegas: expected shape (n, {self.dim}), got {w.shape}")
        single = w.ndim == 1
        w2 = w[None, :] if single else w
        diff = w2 - self._mean - self._row_phi(contexts, w2.shape[0], single) @ self._gain.T
        maha = np.sum(linalg.solve_triangular(self._chol, diff.T, lower=True) ** 2, axis=0)
        out = -0.5 * (self.dim * _LOG_2PI + self.log_det_cov() + maha)
        return float(out[0]) if single else out

    def log_det_cov(self) -> float:
        return float(2.0 * np.sum(np.log(np.diag(self._chol))))

    def entropy(self) -> float:
        """Differential entropy ½ log det(2πe Σ) (the same for every context)."""
        return 0.5 * (self.dim * (_LOG_2PI + 1.0) + self.log_det_cov())

    def kl(self, other: LinearGaussianPolicy, contexts: ArrayLike | None = None) -> float:
        r"""KL(self ‖ other) averaged over ``contexts``, in closed form.

        .. math:: \frac1n \sum_i \tfrac12\big[\mathrm{tr}(\Sigma_2^{-1}\Sigma_1)
                  + \delta_i^\top \Sigma_2^{-1} \delta_i - d
                  + \log\det\Sigma_2 - \log\det\Sigma_1\big],
                  \quad \delta_i = \mu_2(s_i) - \mu_1(s_i)
        """
        self._check_other(other, ("dim", "context_dim"))
        mu1 = np.atleast_2d(self.mean_of(contexts))
        mu2 = np.atleast_2d(other.mean_of(contexts))
        l2 = other._chol
        trace = np.sum(linalg.solve_triangular(l2, self._chol, lower=True) ** 2)
        maha = np.sum(linalg.solve_triangular(l2, (mu2 - mu1).T, lower=True) ** 2, axis=0)
        kl = 0.5 * (trace + maha - self.dim + other.log_det_cov() - self.log_det_cov())
        return float(np.mean(kl))

    def fit(self, contexts, omegas, weights, **kwargs: float | None) -> LinearGaussianPolicy:
        """Weighted maximum-likelihood policy (Eqs. 3.11–3.13); see :meth:`fit_with_info`."""
        return self.fit_with_info(contexts, omegas, weights, **kwargs)[0]

    def fit_with_info(
        self,
        contexts,
        omegas,
        weights,
        *,
        ridge: float = 1e-6,
        cov_shrinkage: float = 0.0,
        cov_floor: float = 1e-4,
        min_effective_samples: float | None = None,
    ) -> tuple[LinearGaussianPolicy, FitInfo]:
        r"""Weighted maximum-likelihood estimate of a, A, Σ (Eqs. 3.11–3.13), regularised.

        With p_i = w_i / Σ w and centred features, A = Xᵀ(C + ``ridge`` diag C)⁻¹, a = ω̄ − A φ̄
        (features without spread get a zero gain); Σ_ML = Σ p_i r_i r_iᵀ (3.12) is shrunk to
        (1 − κ) Σ_ML + κ Σ_old, the eigenvalues of Σ_old^{-1/2} Σ Σ_old^{-1/2} are floored at
        ``cov_floor`` and those of Σ at :data:`MIN_RELATIVE_EIGENVALUE` times the largest.

        Parameters
        ----------
        contexts : array_like, shape (N, context_dim), or None
        omegas : array_like, shape (N, d)
        weights : array_like, shape (N,)
            Non-negative sample weights (e.g. REPS's exp(R/η)).
        ridge, cov_shrinkage, cov_floor : float
            Relative ridge on C, κ ∈ [0, 1), eigenvalue floor ∈ (0, 1].
        min_effective_samples : float, optional
            Least Kish effective sample size (default d + 1).

        Returns
        -------
        policy, info : LinearGaussianPolicy, FitInfo
            A new policy of the same type, and what the fit did.

        Raises
        ------
        ValueError
            On wrong shapes or weights, too few effective samples, or contexts without spread.
        """
        ridge = check_positive(ridge, "ridge", allow_zero=True)
        kappa = check_positive(cov_shrinkage, "cov_shrinkage", allow_zero=True)
        if kappa >= 1.0:
            raise ValueError(f"cov_shrinkage: expected a value in [0, 1), got {cov_shrinkage!r}")
        floor = check_positive(cov_floor, "cov_floor")
        if floor > 1.0:
            raise ValueError(f"cov_floor: expected a value in (0, 1], got {cov_floor!r}")
        d = self.dim
        B = check_array(omegas, "omegas", shape=(None, d))
        n = B.shape[0]
        phi = self._row_phi(contexts, n)
        w = check_array(weights, "weights", shape=(n,))
        if np.any(w < 0) or not np.any(w > 0):
            raise ValueError("weights: expected non-negative weights with a positive sum")
        p = w / w.sum()
        ess = effective_sample_size(p)
        need = d + 1.0 if min_effective_samples is None else min_effective_samples
        need = check_positive(need, "min_effective_samples", allow_zero=True)
        if ess < need:
            raise ValueError(f"weights: effective sample size {ess:.3g} < {need:g} (N={n})")

        # 1. mean: weighted, centred ridge regression (Eq. 3.11)
        phibar, wbar = p @ phi, p @ B
        n_feat = phi.shape[1]
        if n_feat:
            pc = phi - phibar
            # Features with round-off spread are constant (their gain becomes 0).
            spread = np.sqrt(np.maximum(p @ pc**2, 0.0))
            pc[:, spread <= 1e-10 * np.max(np.abs(phi), axis=0)] = 0.0
            C = (pc * p[:, None]).T @ pc
            X = (pc * p[:, None]).T @ (B - wbar)
            tr = float(np.trace(C))
            if not tr > 0:
                raise ValueError("contexts: the weighted contexts have no spread")
            lam = ridge * np.diag(C)
            lam[np.diag(C) <= 0] = tr / n_feat  # constant features: X is 0 there, so A is 0
            try:
                A = linalg.solve(C + np.diag(lam), X, assume_a="pos").T
            except linalg.LinAlgError:
                raise ValueError("contexts: singular feature covariance; use ridge > 0") from None
            a = wbar - A @ phibar
        else:
            A, a = np.zeros((d, 0)), wbar
        # 2. covariance (Eq. 3.12)
        r = B - a - phi @ A.T
        cov = (r * p[:, None]).T @ r
        cov = 0.5 * (cov + cov.T)
        # 3. shrinkage and 4. floor, both relative to the previous Σ
        cov = (1.0 - kappa) * cov + kappa * self._cov
        lam, vec = np.linalg.eigh(_whitened(self._chol, cov))
        n_floored = int(np.sum(lam < floor))
        if n_floored:
            root = self._chol @ vec
            cov = (root * np.maximum(lam, floor)) @ root.T
            cov = 0.5 * (cov + cov.T)
        # 5. condition-number guard
        ev, evec = np.linalg.eigh(cov)
        low = MIN_RELATIVE_EIGENVALUE * ev[-1]
        n_conditioned = int(np.sum(ev < low))
        if n_conditioned:
            cov = (evec * np.maximum(ev, low)) @ evec.T
            cov = 0.5 * (cov + cov.T)
        info = FitInfo(n, ess, ridge, kappa, float(lam.min()), n_floored, n_conditioned)
        return self._new(a, cov, A), info

    def interpolate(self, other: LinearGaussianPolicy, t: float) -> LinearGaussianPolicy:
        """The policy a fraction t ∈ [0, 1] of the way to ``other`` (same dimensions and features):
        a and A linearly, Σ_t = (1 − t) Σ + t Σ'."""
        self._check_other(other, ("dim", "context_dim", "features"))
        t = check_positive(t, "t", allow_zero=True)
        if t > 1.0:
            raise ValueError(f"t: expected a value in [0, 1], got {t!r}")
        return self._new(
            self._mean + t * (other.mean - self._mean),
            (1.0 - t) * self._cov + t * other.cov,
            self._gain + t * (other.gain - self._gain),
        )

    def _check_other(self, other, keys: tuple[str, ...]) -> None:
        """``ValueError`` unless ``other`` is a policy with this one's ``keys``."""
        want = ", ".join(f"{k}={getattr(self, k)!r}" for k in keys)
        if not isinstance(other, LinearGaussianPolicy) or any(
            getattr(other, k) != getattr(self, k) for k in keys
        ):
            raise ValueError(f"other: expected a LinearGaussianPolicy with {want}, got {other!r}")

    def _new(self, mean: np.ndarray, cov: np.ndarray, gain: np.ndarray) -> LinearGaussianPolicy:
        return LinearGaussianPolicy(mean, cov, gain, self._context_dim, self._features)

    def __repr__(self) -> str:
        ev = np.linalg.eigvalsh(self._cov)
        ctx = f"context_dim={self.context_dim}, features={self.features!r}, "
        text = (
            f"{type(self).__name__}(dim={self.dim}, {ctx if self.context_dim else ''}"
            f"mean={vector(self._mean)}, std={span(np.sqrt(np.diag(self._cov)))}, "
            f"cond(cov)={number(ev[-1] / ev[0])}"
        )
        if self._gain.size:
            text += f", max|gain|={number(np.abs(self._gain).max())}"
        return text + ")"


class GaussianPolicy(LinearGaussianPolicy):
    """Context-free upper-level policy π(ω) = N(μ, Σ) (episode-based REPS, Eqs. 2.12–2.15), the
    ``context_dim=0`` case of :class:`LinearGaussianPolicy`.

    Parameters
    ----------
    mean, cov : array_like, shapes (d,) and (d, d)
        μ and Σ (symmetric positive definite).
    """

    def __init__(self, mean, cov):
        super().__init__(mean, cov, None, 0, "linear")

    def _new(self, mean: np.ndarray, cov: np.ndarray, gain: np.ndarray) -> GaussianPolicy:
        return GaussianPolicy(mean, cov)


@dataclass(frozen=True)
class TrustRegionStep:
    """What :func:`trust_region_step` did: KL and entropy loss of the ML fit (``ml_kl``,
    ``ml_entropy_loss``), the scale c ≥ 1 of Σ_ML, the interpolation step t ∈ (0, 1] and the
    new policy's ``kl`` and ``entropy_loss`` (1, 1: the bounds were inactive)."""

    ml_kl: float
    ml_entropy_loss: float
    cov_scale: float
    step: float
    kl: float
    entropy_loss: float


def interpolation_kl(
    old: LinearGaussianPolicy,
    new: LinearGaussianPolicy,
    contexts: ArrayLike | None,
    t: ArrayLike,
) -> tuple[np.ndarray, np.ndarray]:
    r"""KL(π_t ‖ π_old) of π_t = ``old.interpolate(new, t)`` and its derivative in t.

    With μ_i the eigenvalues of Σ_old⁻¹ Σ_new and M the context average of δᵀ Σ_old⁻¹ δ,
    δ = μ_new(s) − μ_old(s):

    .. math::
        \mathrm{KL}(t) = \tfrac12 \sum_i \big(\lambda_i - 1 - \log\lambda_i\big)
            + \tfrac12 t^2 M, \quad \lambda_i = 1 + t(\mu_i - 1),

    convex and increasing on [0, 1]."""
    mu = np.linalg.eigvalsh(_whitened(old._chol, new.cov))
    delta = np.atleast_2d(new.mean_of(contexts)) - np.atleast_2d(old.mean_of(contexts))
    maha = np.mean(np.sum(linalg.solve_triangular(old._chol, delta.T, lower=True) ** 2, axis=0))
    t = np.asarray(t, dtype=np.float64)
    lam = 1.0 + t[..., None] * (mu - 1.0)
    kl = 0.5 * np.sum(lam - 1.0 - np.log(lam), axis=-1) + 0.5 * t**2 * maha
    dkl = 0.5 * np.sum((mu - 1.0) * (1.0 - 1.0 / lam), axis=-1) + t * maha
    return kl, dkl


def trust_region_step(
    old: LinearGaussianPolicy,
    fitted: LinearGaussianPolicy,
    contexts: ArrayLike | None,
    epsilon: float,
    max_entropy_loss: float,
) -> tuple[LinearGaussianPolicy, TrustRegionStep]:
    r"""Make a weighted ML fit keep REPS's KL bound (Eq. 3.4) and lose entropy slowly.

    First, if H(π_old) − H(π_ML) > β = ``max_entropy_loss``, Σ_ML is scaled by
    c = exp(2 (H(π_old) − H(π_ML) − β) / d) (as in MORE, Abdolmaleki et al. 2015). Then, if
    KL(π ‖ π_old) > ε = ``epsilon`` (averaged over ``contexts``), the policy is interpolated back
    towards π_old to KL(π_t ‖ π_old) = ε (Newton's method on :func:`interpolation_kl`).
    Returns the new policy and a :class:`TrustRegionStep`."""
    eps = check_positive(epsilon, "epsilon")
    beta = check_positive(max_entropy_loss, "max_entropy_loss")
    d = old.dim
    ml_kl = fitted.kl(old, contexts)
    ml_loss = old.entropy() - fitted.entropy()
    scale = float(np.exp(2.0 * (ml_loss - beta) / d)) if ml_loss > beta else 1.0
    target = fitted if scale == 1.0 else fitted._new(fitted.mean, scale * fitted.cov, fitted.gain)
    t = 1.0
    kl1 = float(interpolation_kl(old, target, contexts, 1.0)[0])
    if kl1 > eps:
        for _ in range(100):  # Newton from the right of the root: monotone, quadratic at the end
            kl, dkl = interpolation_kl(old, target, contexts, t)
            t_next = t - (float(kl) - eps) / float(dkl)
            if not t_next < t or abs(float(kl) - eps) <= 1e-12 * eps:
                break
            t = t_next
    new = target if t == 1.0 else old.interpolate(target, t)
    step = TrustRegionStep(
        ml_kl=ml_kl,
        ml_entropy_loss=float(ml_loss),
        cov_scale=scale,
        step=float(t),
        kl=new.kl(old, contexts),
        entropy_loss=float(old.entropy() - new.entropy()),
    )
    return new, step
