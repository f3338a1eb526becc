r"""Trajectory-KL model learning (Sec. 4.2.4, Eqs 4.5–4.16, Appendix B).

A forward model p(x′ | x, u; θ) is fitted by minimising the KL between predicted and
observed state marginals under feature-matching constraints (4.10–4.13). With M observed
trajectories the dual is (4.16)

.. math::
    g(\gamma_{1:T}, \theta) = -\sum_{t=1}^T \log \frac1M \sum_{i=1}^M
        \exp\big(\gamma_t^\top \phi(x_{i,t}) - \gamma_{t+1}^\top \psi_{i,t}(\theta)\big)
        + \gamma_1^\top \hat\phi, \qquad \gamma_{T+1} \equiv 0,

with ψ_{i,t}(θ) = E[φ(x′) | x_{i,t}, u_{i,t}; θ] (B.7). g is concave in γ, so the model is
trained by min_θ D(θ), D(θ) = max_γ g(γ, θ), ∇D = ∂g/∂θ at γ* (B.6). Infeasible constraints
give D = +∞; ``ridge`` λ > 0 subtracts (λ/2) Σ_t ‖γ_t‖² from g (soft matching)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from numpy.typing import ArrayLike
from scipy import optimize
from scipy.linalg import cho_solve

from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.models.kernels import se_kernel
from skillkit.models.sparse import kmeans_pp

__all__ = [
    "DualValue",
    "LinearGaussianTKL",
    "PseudoDataGP",
    "TKLFit",
    "fit_one_step",
    "fit_trajectory_kl",
    "gaussian_expected_features",
    "gaussian_expected_features_vjp",
    "one_step_log_likelihood",
    "state_features",
    "trajectory_kl_objective",
]


def _pairs(n: int, cross: bool) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(n) if cross else (np.arange(n), np.arange(n))


def state_features(x: ArrayLike, cross: bool = True) -> np.ndarray:
    """φ(x) = [x, (x_i x_j)_{i ≤ j}] (Sec. 4.2.4, B.7) for x (..., n): shape (..., F).

    ``cross=False`` keeps only the squares (F = 2n instead of n + n(n+1)/2)."""
    x = check_array(x, "x", ndim=(1, 2, 3))
    i, j = _pairs(x.shape[-1], cross)
    return np.concatenate([x, x[..., i] * x[..., j]], axis=-1)


def gaussian_expected_features(mean: ArrayLike, var: ArrayLike, cross: bool = True) -> np.ndarray:
    r"""ψ = E[φ(x′)] for x′ ~ N(μ, diag v) (B.7): E[x′_i x′_j] = μ_i μ_j + δ_ij v_i."""
    mu = check_array(mean, "mean", ndim=(1, 2, 3))
    v = check_array(var, "var", shape=mu.shape)
    i, j = _pairs(mu.shape[-1], cross)
    quad = mu[..., i] * mu[..., j] + np.where(i == j, v[..., i], 0.0)
    return np.concatenate([mu, quad], axis=-1)


def gaussian_expected_features_vjp(
    mean: ArrayLike, grad_features: ArrayLike, cross: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    r"""∂L/∂μ and ∂L/∂v (..., n) from ∂L/∂ψ (..., F) in closed form (B.7)."""
    mu = check_array(mean, "mean", ndim=(1, 2, 3))
    n = mu.shape[-1]
    i, j = _pairs(n, cross)
    g = check_array(grad_features, "grad_features", shape=(*mu.shape[:-1], n + len(i)))
    g_lin, g_quad = g[..., :n], g[..., n:]
    sym = np.zeros((*mu.shape[:-1], n, n))
    sym[..., i, j] += g_quad
    sym[..., j, i] += g_quad  # the diagonal gets 2 g_kk
    grad_mean = g_lin + np.einsum("...kj,...j->...k", sym, mu)
    diag = i == j
    grad_var = np.zeros_like(mu)
    grad_var[..., i[diag]] = g_quad[..., diag]
    return grad_mean, grad_var


@dataclass(frozen=True)
class DualValue:
    """The sample-based dual at γ: ``value`` g(γ, θ) (4.16) less (λ/2) Σ ‖γ_t‖²,
    ``grad_gamma`` ∂g/∂γ_t (T, F) (B.4, B.5), ``grad_predicted`` ∂g/∂ψ_{i,t} = p_{t,i} γ_{t+1}
    (T − 1, M, F) (B.6 before ∂ψ/∂θ) and ``weights`` p_t(x_{i,t}) (T, M) of (4.14)."""

    value: float
    grad_gamma: np.ndarray
    grad_predicted: np.ndarray
    weights: np.ndarray


def _dual(gammas, features, predicted, phi_hat, ridge) -> DualValue:
    """g (4.16), its gradients (B.4–B.6) and marginals (4.14) from ``gammas`` (T, F), features
    φ(x_{i,t}) (T, M, F) time-major, ψ_{i,t} (T − 1, M, F), φ̂ (F,) of (4.9) and λ ≥ 0."""
    T, M, _ = features.shape
    a = np.einsum("tf,tmf->tm", gammas, features)
    a[:-1] -= np.einsum("tf,tmf->tm", gammas[1:], predicted)
    m = a.max(axis=1, keepdims=True)
    z = np.exp(a - m)
    total = z.sum(axis=1, keepdims=True)
    p = z / total
    log_mean = m[:, 0] + np.log(total[:, 0]) - math.log(M)
    value = -log_mean.sum() + gammas[0] @ phi_hat - 0.5 * ridge * np.sum(gammas * gammas)
    e_phi = np.einsum("tm,tmf->tf", p, features)
    grad = -e_phi - ridge * gammas
    grad[0] += phi_hat  # (B.4)
    grad[1:] += np.einsum("tm,tmf->tf", p[:-1], predicted)  # (B.5)
    grad_pred = p[:-1, :, None] * gammas[1:, None, :]  # (B.6) before ∂ψ/∂θ
    return DualValue(float(value), grad, grad_pred, p)


class Model:
    """A Gaussian transition model p(x′ | x, u; θ) on ``state_dim`` states and ``control_dim``
    controls."""

    def __init__(self, state_dim: int, control_dim: int):
        self.state_dim = check_count(state_dim, "state_dim")
        self.control_dim = check_count(control_dim, "control_dim", minimum=0)

    def _inputs(self, x, u) -> tuple[np.ndarray, np.ndarray]:
        x = check_array(x, "x", shape=(None, self.state_dim))
        return x, check_array(u, "u", shape=(x.shape[0], self.control_dim))

    def __repr__(self) -> str:
        sizes = ("state_dim", "control_dim", "n_inducing")
        args = ", ".join(f"{k}={getattr(self, k)}" for k in sizes if hasattr(self, k))
        return f"{type(self).__name__}({args})"


class LinearGaussianTKL(Model):
    """x′ ~ N(A x + B u + c, diag σ²) with θ = [vec A, vec B, c, log σ²] (row-major)."""

    def __init__(self, state_dim: int, control_dim: int):
        super().__init__(state_dim, control_dim)
        n, m = self.state_dim, self.control_dim
        self.n_params = n * n + n * m + 2 * n

    def pack(self, A: ArrayLike, B: ArrayLike, c: ArrayLike, var: ArrayLike) -> np.ndarray:
        n, m = self.state_dim, self.control_dim
        A = check_array(A, "A", shape=(n, n))
        B = check_array(B, "B", shape=(n, m))
        c = check_array(c, "c", shape=(n,))
        v = check_array(var, "var", shape=(n,))
        if np.any(v <= 0):
            raise ValueError("var: expected positive noise variances")
        return np.concatenate([A.ravel(), B.ravel(), c, np.log(v)])

    def unpack(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n, m = self.state_dim, self.control_dim
        th = check_array(theta, "theta", shape=(self.n_params,))
        A = th[: n * n].reshape(n, n)
        B = th[n * n : n * n + n * m].reshape(n, m)
        c = th[n * n + n * m : n * n + n * m + n]
        return A, B, c, np.exp(th[-n:])

    def moments(self, theta: ArrayLike, x: ArrayLike, u: ArrayLike):
        """Mean and variance (N, n) at x (N, n), u (N, m), and their vector–Jacobian product."""
        A, B, c, v = self.unpack(theta)
        x, u = self._inputs(x, u)
        mean = x @ A.T + u @ B.T + c
        var = np.broadcast_to(v, mean.shape).copy()

        def vjp(g_mean: np.ndarray, g_var: np.ndarray) -> np.ndarray:
            return np.concatenate(
                [(g_mean.T @ x).ravel(), (g_mean.T @ u).ravel(), g_mean.sum(0), g_var.sum(0) * v]
            )

        return mean, var, vjp

    def init_theta(self, x, u, x_next, rng=None) -> np.ndarray:
        """Least squares on [x, u, 1] and the residual variances."""
        x, u = self._inputs(x, u)
        y = check_array(x_next, "x_next", shape=x.shape)
        z1 = np.hstack([x, u, np.ones((x.shape[0], 1))])
        w, *_ = np.linalg.lstsq(z1, y, rcond=None)
        res = y - z1 @ w
        n, m = self.state_dim, self.control_dim
        var = np.maximum(np.mean(res**2, axis=0), 1e-12)
        return self.pack(w[:n].T, w[n : n + m].T, w[-1], var)


class PseudoDataGP(Model):
    r"""A FITC GP whose pseudo-inputs Z and pseudo-targets U are parameters (Sec. 4.2.4).

    Per output e, with z = [x, u] and K_e = k_e(Z_e, Z_e) + 10⁻⁶ σ_f² I,
    μ_e(z) = m_e(z) + k_e(z, Z_e) K_e⁻¹ U_e and
    v_e(z) = σ_{f,e}² − k_e(z, Z_e) K_e⁻¹ k_e(Z_e, z) + σ_{ε,e}²; θ = [Z, U, log w, log σ_f²,
    log σ_ε²]. The prior mean m(z) = [z, 1] W (``mean_weights``, default: x persists) is fixed."""

    def __init__(
        self,
        state_dim: int,
        control_dim: int,
        n_inducing: int,
        mean_weights: ArrayLike | None = None,
    ):
        super().__init__(state_dim, control_dim)
        self.n_inducing = check_count(n_inducing, "n_inducing")
        n, d = self.state_dim, self.state_dim + self.control_dim
        if mean_weights is None:
            W = np.zeros((d + 1, n))
            W[:n] = np.eye(n)
        else:
            W = check_array(mean_weights, "mean_weights", shape=(d + 1, n))
        self.mean_weights = W
        self.jitter = 1e-6
        E, M = n, self.n_inducing
        self._sizes = (E * M * d, E * M, E * d, E, E)
        self.n_params = int(sum(self._sizes))

    def split(self, theta: ArrayLike) -> dict[str, np.ndarray]:
        """θ's parts: Z (E, M, d), U (E, M), log_w (E, d), log_sf2, log_sn2 (E,)."""
        th = check_array(theta, "theta", shape=(self.n_params,))
        E, M, d = self.state_dim, self.n_inducing, self.state_dim + self.control_dim
        parts = np.split(th, np.cumsum(self._sizes)[:-1])
        shapes = ((E, M, d), (E, M), (E, d), (E,), (E,))
        names = ("Z", "U", "log_w", "log_sf2", "log_sn2")
        return {k: p.reshape(s) for k, p, s in zip(names, parts, shapes, strict=True)}

    def _torch_moments(self, th: torch.Tensor, z: torch.Tensor):
        E, M, d = self.state_dim, self.n_inducing, self.state_dim + self.control_dim
        Z, U, log_w, log_sf2, log_sn2 = torch.split(th, self._sizes)
        Z, U, w = Z.reshape(E, M, d), U.reshape(E, M), torch.exp(log_w).reshape(E, 1, d)
        sf2, sn2 = torch.exp(log_sf2), torch.exp(log_sn2)
        eye = torch.eye(M, dtype=th.dtype)
        K = se_kernel(Z, Z, w, sf2) + (self.jitter * sf2)[:, None, None] * eye
        L = torch.linalg.cholesky(K)
        Kzm = se_kernel(z.expand(E, *z.shape), Z, w, sf2)  # (E, N, M)
        V = torch.linalg.solve_triangular(L, Kzm.transpose(1, 2), upper=False)  # (E, M, N)
        alpha = torch.cholesky_solve(U[..., None], L)  # (E, M, 1)
        W = torch.as_tensor(self.mean_weights, dtype=th.dtype)
        prior = torch.cat([z, torch.ones_like(z[:, :1])], 1) @ W  # (N, E)
        mean = prior + (Kzm @ alpha)[..., 0].T
        var = (sf2[:, None] - (V * V).sum(1)).clamp_min(0.0).T + sn2
        return mean, var

    def moments(self, theta: ArrayLike, x: ArrayLike, u: ArrayLike):
        """Mean and variance (N, n) at x (N, n), u (N, m), and their vector–Jacobian product."""
        th = torch.tensor(check_array(theta, "theta", shape=(self.n_params,)), requires_grad=True)
        x, u = self._inputs(x, u)
        z = torch.as_tensor(np.hstack([x, u]))
        mean, var = self._torch_moments(th, z)

        def vjp(g_mean: np.ndarray, g_var: np.ndarray) -> np.ndarray:
            (g,) = torch.autograd.grad(
                (mean, var),
                th,
                (torch.as_tensor(g_mean), torch.as_tensor(g_var)),
                retain_graph=True,
            )
            return g.numpy().copy()

        return mean.detach().numpy(), var.detach().numpy(), vjp

    def init_theta(self, x, u, x_next, rng=None) -> np.ndarray:
        """A starting θ: Z by k-means++, w = std(z), σ_f² the residual variance, σ_ε² = σ_f²/10, U
        by least squares."""
        x, u = self._inputs(x, u)
        y = check_array(x_next, "x_next", shape=x.shape)
        z = np.hstack([x, u])
        N, d = z.shape
        E, M = self.state_dim, self.n_inducing
        if M > N:
            raise ValueError(f"n_inducing: expected at most {N} (the transitions), got {M}")
        sd = np.where(z.std(0) > 0, z.std(0), 1.0)
        idx = kmeans_pp(z / sd, M, as_generator(rng))
        res = y - np.hstack([z, np.ones((N, 1))]) @ self.mean_weights
        sf2 = np.maximum(res.var(0), 1e-10)
        th = np.concatenate(
            [
                np.broadcast_to(z[idx], (E, M, d)).ravel(),
                np.zeros(E * M),
                np.broadcast_to(np.log(sd), (E, d)).ravel(),
                np.log(sf2),
                np.log(sf2 / 10),
            ]
        )
        # U by least squares: μ − m = Kzm K⁻¹ U is linear in U (K⁻¹U = α).
        p = self.split(th)
        w, lsf = np.exp(p["log_w"]), p["log_sf2"]
        for e in range(E):
            k = np.exp(lsf[e] - 0.5 * (((z[:, None, :] - p["Z"][e][None]) / w[e]) ** 2).sum(-1))
            Km = np.exp(
                lsf[e] - 0.5 * (((p["Z"][e][:, None] - p["Z"][e][None]) / w[e]) ** 2).sum(-1)
            ) + self.jitter * np.exp(lsf[e]) * np.eye(M)
            reg = 1e-6 * np.trace(k.T @ k) / M * np.eye(M)
            alpha = np.linalg.solve(k.T @ k + reg, k.T @ res[:, e])
            p["U"][e] = Km @ alpha
        return np.concatenate([p[k].ravel() for k in ("Z", "U", "log_w", "log_sf2", "log_sn2")])


@dataclass(frozen=True)
class TKLFit:
    """A trained ``theta`` (P,), the final ``objective`` (negative mean one-step log-likelihood,
    or D(θ) in nats summed over time), outer ``n_iterations`` and the optimiser's ``message``;
    for trajectory-KL also γ* ``gammas`` (T, F), the marginals ``weights`` (4.14) (T, M), the
    per-step ``kl`` (T,) and the ``feature_residual`` max_t ‖E_{p_t} φ − E_{p_{t−1}} ψ‖_∞ of
    (4.12) (NaN otherwise)."""

    theta: np.ndarray
    objective: float
    n_iterations: int
    message: str
    gammas: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    weights: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    kl: np.ndarray = field(default_factory=lambda: np.zeros(0))
    feature_residual: float = math.nan


def one_step_log_likelihood(model: Model, theta, x, u, x_next) -> float:
    """Mean log N(x′ | μ(x, u), diag v(x, u)) per transition (nats; −inf if a variance is 0)."""
    mean, var, _ = model.moments(theta, x, u)
    y = check_array(x_next, "x_next", shape=mean.shape)
    with np.errstate(divide="ignore", invalid="ignore"):  # a variance of 0 gives −inf
        ll = -0.5 * np.mean(np.sum(np.log(2 * np.pi * var) + (y - mean) ** 2 / var, 1))
    return float(ll) if np.isfinite(ll) else -math.inf


def _lbfgs(fun, theta0, maxiter):
    return optimize.minimize(
        fun,
        theta0,
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": int(maxiter), "maxcor": 30, "ftol": 1e-12, "gtol": 1e-8},
    )


def fit_one_step(model: Model, theta0, x, u, x_next, maxiter: int = 200) -> TKLFit:
    """One-step maximum likelihood of transitions x (N, n), u (N, m) → ``x_next`` (N, n) by
    L-BFGS from ``theta0`` (P,), P = ``model.n_params``.

    Returns
    -------
    TKLFit
        ``objective`` is the negative mean one-step log-likelihood.
    """
    th0 = check_array(theta0, "theta0", shape=(model.n_params,))
    x, u = model._inputs(x, u)
    y = check_array(x_next, "x_next", shape=x.shape)
    N = x.shape[0]

    def fun(th):
        try:
            mean, var, vjp = model.moments(th, x, u)
        except (torch.linalg.LinAlgError, ValueError, RuntimeError):
            return np.inf, np.zeros_like(th)
        r = y - mean
        value = 0.5 * np.sum(np.log(2 * np.pi * var) + r * r / var) / N
        g_mean = -r / var / N
        g_var = 0.5 * (1.0 / var - r * r / var**2) / N
        return value, vjp(g_mean, g_var)

    res = _lbfgs(fun, th0, maxiter)
    return TKLFit(res.x, float(res.fun), int(res.nit), str(res.message))


def trajectory_kl_objective(
    model: Model,
    theta: ArrayLike,
    states: ArrayLike,
    controls: ArrayLike,
    gammas0: ArrayLike | None = None,
    cross: bool = True,
    ridge: float = 0.0,
    inner_maxiter: int = 100,
) -> tuple[float, np.ndarray, DualValue, np.ndarray]:
    """D(θ) = max_γ g(γ, θ) and ∇D(θ) (B.6 at γ*) for one θ.

    ``states`` (M, T, n), ``controls`` (M, T − 1, m). Returns the value, the gradient (P,), the
    :class:`DualValue` at γ* (None, with value +inf, when infeasible) and γ* (T, F)."""
    prob = _Problem(model, states, controls, cross, ridge)
    th = check_array(theta, "theta", shape=(model.n_params,))
    g0 = None if gammas0 is None else check_array(gammas0, "gammas0", shape=prob.gamma_shape)
    return prob.evaluate(th, g0, check_count(inner_maxiter, "inner_maxiter"))


class _Infeasible(Exception):
    """g exceeds T log M: the hard constraints cannot hold (D(θ) = +∞)."""


def _newton_max(features, predicted, phi_hat, ridge, gammas0, maxiter, tol=1e-12):
    """max_γ g(γ) by damped Newton steps (block-tridiagonal Hessian) with backtracking."""
    T, M, F = features.shape
    bound = T * math.log(M)
    gam = gammas0.copy()
    d = _dual(gam, features, predicted, phi_hat, ridge)
    for _ in range(maxiter):
        if ridge == 0.0 and d.value > bound:
            raise _Infeasible
        H = np.zeros((T * F, T * F))
        for t in range(T):
            v = features[t] if t == T - 1 else np.hstack([features[t], -predicted[t]])
            p = d.weights[t]
            mean = p @ v
            cov = (v * p[:, None]).T @ v - np.outer(mean, mean)
            k = v.shape[1]
            H[t * F : t * F + k, t * F : t * F + k] += cov
        H[np.diag_indices_from(H)] += ridge
        grad = d.grad_gamma.ravel()
        scale = max(float(np.mean(np.diag(H))), 1e-300)
        damping = 1e-12 * scale
        while True:
            try:
                L = np.linalg.cholesky(H + damping * np.eye(H.shape[0]))
                break
            except np.linalg.LinAlgError:
                damping *= 100.0
                if damping > scale:
                    raise _Infeasible from None
        step = cho_solve((L, True), grad)
        decrement = float(grad @ step)
        if decrement < tol:
            break
        alpha = 1.0
        while alpha > 1e-10:
            trial = gam + alpha * step.reshape(T, F)
            new = _dual(trial, features, predicted, phi_hat, ridge)
            if new.value >= d.value + 1e-4 * alpha * decrement:
                break
            alpha *= 0.5
        else:
            break  # no ascent along the Newton direction: round-off level
        gam, d = trial, new
    if ridge == 0.0 and d.value > bound:
        raise _Infeasible
    return gam


class _Problem:
    """The standardised features of a data set and the nested evaluation of D(θ)."""

    def __init__(self, model, states, controls, cross, ridge):
        X = check_array(states, "states", shape=(None, None, model.state_dim))
        M, T, n = X.shape
        if T < 2:
            raise ValueError(f"states: expected at least 2 time steps, got {T}")
        U = check_array(controls, "controls", shape=(M, T - 1, model.control_dim))
        self.model, self.cross = model, cross
        self.ridge = check_positive(ridge, "ridge", allow_zero=True)
        self.M, self.T = M, T
        phi = state_features(X, cross)  # (M, T, F)
        self.loc = phi.reshape(-1, phi.shape[-1]).mean(0)
        sd = phi.reshape(-1, phi.shape[-1]).std(0)
        self.scale = np.where(sd > 0, sd, 1.0)
        self.features = ((phi - self.loc) / self.scale).transpose(1, 0, 2)  # (T, M, F)
        self.x = X[:, :-1].transpose(1, 0, 2).reshape(-1, n)  # (T−1)·M rows, time-major
        self.u = U.transpose(1, 0, 2).reshape(-1, U.shape[-1])
        self.gamma_shape = (T, phi.shape[-1])

    def evaluate(self, theta, gammas0, inner_maxiter):
        T, M = self.T, self.M
        mean, var, vjp = self.model.moments(theta, self.x, self.u)
        psi = gaussian_expected_features(mean, var, self.cross)
        psi = ((psi - self.loc) / self.scale).reshape(T - 1, M, -1)
        phi_hat = self.features[0].mean(0)

        zero = np.zeros(self.gamma_shape)
        args = (self.features, psi, phi_hat, self.ridge)
        try:
            gammas = _newton_max(*args, zero if gammas0 is None else gammas0, inner_maxiter)
            if gammas0 is not None and not _dual(gammas, *args).value >= 0.0:
                gammas = _newton_max(*args, zero, inner_maxiter)  # a bad warm start: from 0
        except _Infeasible:
            return math.inf, np.zeros(self.model.n_params), None, zero
        d = _dual(gammas, *args)
        g_psi = (d.grad_predicted / self.scale).reshape(-1, psi.shape[-1])
        g_mean, g_var = gaussian_expected_features_vjp(mean, g_psi, self.cross)
        return d.value, vjp(g_mean, g_var), d, gammas


def fit_trajectory_kl(
    model: Model,
    theta0: ArrayLike,
    states: ArrayLike,
    controls: ArrayLike,
    cross: bool = True,
    ridge: float = 0.0,
    maxiter: int = 100,
    inner_maxiter: int = 100,
) -> TKLFit:
    """Trajectory-KL training: min_θ max_γ g(γ, θ) of (4.16) by L-BFGS over θ.

    Parameters
    ----------
    model : Model
        E.g. :class:`LinearGaussianTKL` or :class:`PseudoDataGP`, P = ``model.n_params``.
    theta0 : array_like, shape (P,)
        Start (e.g. a :func:`fit_one_step` result).
    states : array_like, shape (M, T, n)
        M observed trajectories.
    controls : array_like, shape (M, T − 1, m)
    cross : bool, default True
        Cross products in φ (:func:`state_features`, B.7).
    ridge : float, default 0.0
        λ ≥ 0: subtracts (λ/2) Σ_t ‖γ_t‖² from g (soft feature matching).
    maxiter, inner_maxiter : int, default 100
        Outer L-BFGS iterations over θ; Newton iterations over γ per evaluation.

    Returns
    -------
    TKLFit
    """
    prob = _Problem(model, states, controls, cross, ridge)
    th0 = check_array(theta0, "theta0", shape=(model.n_params,))
    inner = check_count(inner_maxiter, "inner_maxiter")
    warm = {"gammas": None}

    def fun(y):
        th = th0 + step * y
        try:
            value, grad, _, gammas = prob.evaluate(th, warm["gammas"], inner)
        except (torch.linalg.LinAlgError, ValueError):
            return np.inf, np.zeros_like(th)
        if not (np.isfinite(value) and np.all(np.isfinite(grad))):
            return np.inf, np.zeros_like(th)
        warm["gammas"] = gammas
        return value, step * grad

    step = 1e-3  # the largest first step in θ, divided by 4 until steepest descent lowers D
    start = prob.evaluate(th0, None, inner)
    if not np.isfinite(start[0]):
        msg = (
            "infeasible at theta0: the feature constraints (4.12) "
            "cannot hold on these samples (D = +inf); theta0 returned"
        )
        uniform, kl = np.full((prob.T, prob.M), 1.0 / prob.M), np.full(prob.T, np.nan)
        return TKLFit(th0, math.inf, 0, msg, start[3], uniform, kl, math.inf)
    warm["gammas"] = start[3]
    direction = -start[1] / max(float(np.linalg.norm(start[1])), 1e-300)
    for _ in range(20):
        if prob.evaluate(th0 + step * direction, start[3], inner)[0] < start[0]:
            break
        step *= 0.25
    res = _lbfgs(fun, np.zeros_like(th0), check_count(maxiter, "maxiter"))
    theta = th0 + step * res.x
    value, _, d, gammas = prob.evaluate(theta, warm["gammas"], inner)
    if d is None:  # the optimiser ended on an infeasible point: keep θ₀ (feasible)
        theta, (value, _, d, gammas) = th0, start
    p = d.weights
    kl = np.sum(np.where(p > 0, p * np.log(np.maximum(p * prob.M, 1e-300)), 0.0), axis=1)
    resid = float(np.max(np.abs(d.grad_gamma + prob.ridge * gammas)))
    return TKLFit(theta, float(value), int(res.nit), str(res.message), gammas, p, kl, resid)
