"""Sparse GPs with M pseudo-inputs behind the :class:`~skillkit.models.gp.ExactGP` interface.

Two approximations of the same shape (Sec. 2.3, 4.2.3), both O(N M²) to train and O(M²)
per predictive variance:

* :class:`FITC` — Snelson & Ghahramani's sparse GP with pseudo-inputs (SPGP), the sparse
  model used throughout the thesis. The prior covariance of the training targets is
  Q_nn + diag(K_nn − Q_nn) + σ_ε²I with Q_nn = K_nm K_mm⁻¹ K_mn, and the pseudo-inputs Z are
  hyper-parameters of the marginal likelihood.
* :class:`VFE` — Titsias's variational free energy: the collapsed bound
  log N(y; 0, Q_nn + σ_ε²I) − tr(K_nn − Q_nn)/(2σ_ε²) ≤ log p(y), maximised over θ and Z.

With Λ = diag(K_nn − Q_nn) + σ_ε²I (FITC) or σ_ε²I (VFE) and Σ = (K_mm + K_mn Λ⁻¹ K_nm)⁻¹,
both predict

.. math:: \\mu(x) = k_m(x)^\\top \\Sigma K_{mn} \\Lambda^{-1} y, \\qquad
          \\sigma^2(x) = \\sigma_f^2 - k_m(x)^\\top (K_{mm}^{-1} - \\Sigma) k_m(x)
                        + \\sigma_\\varepsilon^2,

which is a :class:`~skillkit.models.gp.GPPredictor` with ``beta = Σ K_mn Λ⁻¹ y``,
``iK = K_mm⁻¹ − Σ`` (PILCO's sparse form) and the variance factor
R = diag(√(1 − 1/a)) Uᵀ L_m⁻¹ (RᵀR = iK, from A = U diag(a) Uᵀ), so sampling and moment
matching work unchanged.
All linear algebra goes through Cholesky factors: with K_mm = L_m L_mᵀ, V = L_m⁻¹ K_mn and
A = I + V Λ⁻¹ Vᵀ = L_A L_Aᵀ, the log determinant is Σ log Λ + 2 Σ log diag L_A and the
quadratic form follows from the Woodbury identity.

Pseudo-inputs: initialised by k-means++ seeding (D²-sampling, Arthur & Vassilvitskii 2007) on
the inputs scaled by their standard deviations, drawn from ``rng``; with M ≥ N all training
inputs are used (``diagnostics["n_inducing"]`` records the M actually used). Each output has
its own pseudo-inputs (shape (E, M, d)), all optimised jointly with the kernel
hyper-parameters unless ``optimize_inducing=False``.

Numerical policy (in addition to :mod:`skillkit.models.gp`'s): K_mm always gets a fixed
jitter of ``jitter``·σ_f² (default 1e-8) on its diagonal, the usual safeguard against
coinciding pseudo-inputs; diag(K_nn − Q_nn) is a variance and is clamped at 0 against
round-off.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from skillkit._validation import check_array, check_positive
from skillkit.models.gp import DTYPE, GPNumericalError, GPPredictor, GPRegression, robust_cholesky
from skillkit.models.kernels import se_kernel

__all__ = ["FITC", "VFE", "kmeans_pp"]


def kmeans_pp(X, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n`` rows of ``X`` chosen by k-means++ seeding (D²-sampling).

    The first row is uniform; each next row is drawn with probability proportional to its
    squared distance to the nearest row already chosen (rows identical to a chosen one are
    never chosen again unless every row is).

    Parameters
    ----------
    X : ndarray, shape (N, d)
    n : int
        Number of rows, 1 ≤ n ≤ N.
    rng : Generator

    Returns
    -------
    ndarray of int, shape (n,)
    """
    N = X.shape[0]
    if not 1 <= n <= N:
        raise ValueError(f"n: expected 1 <= n <= {N}, got {n}")
    idx = [int(rng.integers(N))]
    d2 = ((X - X[idx[0]]) ** 2).sum(1)
    for _ in range(n - 1):
        total = d2.sum()
        if total > 0:
            i = int(rng.choice(N, p=d2 / total))
        else:  # every remaining row duplicates a chosen one
            free = np.setdiff1d(np.arange(N), idx)
            i = int(rng.choice(free))
        idx.append(i)
        d2 = np.minimum(d2, ((X - X[i]) ** 2).sum(1))
    return np.asarray(idx)


class _SparseGP(GPRegression):
    """Shared FITC/VFE implementation (``_method`` selects the approximation)."""

    _method = "fitc"

    def __init__(
        self,
        n_inducing: int = 100,
        *,
        inducing=None,
        optimize_inducing: bool = True,
        jitter: float = 1e-8,
        **kwargs,
    ):
        super().__init__(**kwargs)
        if int(n_inducing) != n_inducing or n_inducing < 1:
            raise ValueError(f"n_inducing: expected a positive integer, got {n_inducing!r}")
        self.n_inducing = int(n_inducing)
        self.init_inducing = (
            None if inducing is None else check_array(inducing, "inducing", ndim=(2, 3))
        )
        self.optimize_inducing = bool(optimize_inducing)
        self.jitter = check_positive(jitter, "jitter")

    def _size_repr(self) -> str:
        return f"N={self.X.shape[0]}, M={self.predictor.n_support}"

    def _build(self, rng: np.random.Generator) -> None:
        E, N = self.Y.shape
        X = self.X.cpu().numpy()
        d = X.shape[1]
        if self.init_inducing is not None:
            Z = self.init_inducing
            if Z.shape[-1] != d or (Z.ndim == 3 and Z.shape[0] != E):
                raise ValueError(
                    f"inducing: expected shape (M, {d}) or ({E}, M, {d}), got {Z.shape}"
                )
            Z = np.broadcast_to(Z, (E, *Z.shape[-2:])).copy()
        elif self.n_inducing >= N:
            Z = np.broadcast_to(X, (E, N, d)).copy()
        else:
            sd = X.std(axis=0)
            idx = kmeans_pp(X / np.where(sd > 0, sd, 1.0), self.n_inducing, rng)
            Z = np.broadcast_to(X[idx], (E, self.n_inducing, d)).copy()
        self.diagnostics_init = {"n_inducing": Z.shape[1]}
        self.inducing = torch.nn.Parameter(
            torch.as_tensor(Z, dtype=DTYPE, device=self.device),
            requires_grad=self.optimize_inducing,
        )
        self.kernel, self.likelihood = self._hyper_modules(E, d)

    def _hypers(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return (
            self.kernel.lengthscale[:, 0, :],
            self.kernel.outputscale,
            self.likelihood.noise[:, 0],
        )

    def _parameters(self) -> list[torch.nn.Parameter]:
        params = list(self.kernel.parameters()) + list(self.likelihood.parameters())
        return params + ([self.inducing] if self.optimize_inducing else [])

    def _terms(self, factor=None):
        """Objective and the factors the predictor needs.

        Returns (negative objective summed over outputs, Lm, LA, c, Λ) with the notation of
        the module docstring; ``factor`` is the Cholesky routine (plain during training, where
        a failure stops the optimiser; :func:`robust_cholesky` for the final predictor).
        """
        factor = factor or _plain_cholesky
        ls = self.kernel.lengthscale[:, 0, :]
        os = self.kernel.outputscale
        noise = self.likelihood.noise[:, 0]
        E, N = self.Y.shape
        Z = self.inducing
        M = Z.shape[1]
        eye = torch.eye(M, dtype=DTYPE, device=self.device)
        Kmm = se_kernel(Z, Z, ls[:, None, :], os) + (self.jitter * os)[:, None, None] * eye
        Lm = factor(Kmm, "K_mm")
        Kmn = se_kernel(Z, self.X.expand(E, *self.X.shape), ls[:, None, :], os)
        V = torch.linalg.solve_triangular(Lm, Kmn, upper=False)
        gap = (os[:, None] - (V * V).sum(-2)).clamp_min(0.0)  # diag(K_nn - Q_nn)
        if self._method == "fitc":
            lam = gap + noise[:, None]
            trace = torch.zeros((), dtype=DTYPE, device=self.device)
        else:
            lam = noise[:, None].expand(E, N)
            trace = (gap.sum(-1) / (2.0 * noise)).sum()
        sq = lam.sqrt()
        Vs = V / sq[:, None, :]
        A = Vs @ Vs.transpose(-1, -2) + eye
        LA = factor(A, "I + V inv(Lambda) V^T")
        ys = self.Y / sq
        c = torch.linalg.solve_triangular(LA, Vs @ ys.unsqueeze(-1), upper=False).squeeze(-1)
        value = (
            0.5 * ((ys * ys).sum() - (c * c).sum())
            + 0.5 * torch.log(lam).sum()
            + torch.log(LA.diagonal(dim1=-2, dim2=-1)).sum()
            + 0.5 * N * E * math.log(2 * math.pi)
            + trace
        )
        return value, Lm, LA, c

    def _loss(self) -> torch.Tensor:
        return self._terms()[0]

    def _make_predictor(self) -> tuple[GPPredictor, dict]:
        jit: dict[str, float] = {}

        def factor(A, what):
            L, j = robust_cholesky(A, what)
            jit[what] = j
            return L

        value, Lm, LA, c = self._terms(factor)
        M = Lm.shape[-1]
        eye = torch.eye(M, dtype=DTYPE, device=self.device)
        beta = torch.linalg.solve_triangular(
            Lm.transpose(-1, -2),
            torch.linalg.solve_triangular(LA.transpose(-1, -2), c.unsqueeze(-1), upper=True),
            upper=True,
        ).squeeze(-1)
        # iK = K_mm^-1 - Σ = Lm^-T (I - A^-1) Lm^-1 and its factor R = diag(√(1 - 1/a)) Uᵀ Lm^-1
        # from A = U diag(a) Uᵀ (a ≥ 1; 1 - 1/a is clamped at 0 against round-off).
        Lm_inv = torch.linalg.solve_triangular(Lm, eye.expand_as(Lm), upper=False)
        A = LA @ LA.transpose(-1, -2)
        a, U = torch.linalg.eigh(0.5 * (A + A.transpose(-1, -2)))
        R = (1.0 - 1.0 / a).clamp_min(0.0).sqrt()[..., :, None] * (U.transpose(-1, -2) @ Lm_inv)
        iK = Lm_inv.transpose(-1, -2) @ (eye - torch.cholesky_inverse(LA)) @ Lm_inv
        iK = 0.5 * (iK + iK.transpose(-1, -2))
        y_mean, y_scale = self._standardisation_tensors()
        pred = GPPredictor(
            self.inducing.detach().clone(),
            self.kernel.lengthscale.detach()[:, 0, :],
            self.kernel.outputscale.detach(),
            self.likelihood.noise.detach()[:, 0],
            beta,
            iK,
            R,
            y_mean,
            y_scale,
        )
        N = self.Y.shape[1]
        objective = -float(value) - N * float(torch.log(y_scale).sum())
        return pred, {
            **self.diagnostics_init,
            "jitter": max(jit.values()),
            "log_marginal_likelihood": objective,
        }


def _plain_cholesky(A: torch.Tensor, what: str) -> torch.Tensor:
    L, info = torch.linalg.cholesky_ex(A)
    if torch.any(info):
        raise GPNumericalError(
            f"{what}: not numerically positive definite at these hyper-parameters"
        )
    return L


class FITC(_SparseGP):
    """FITC / SPGP sparse GP (Snelson & Ghahramani) with M optimised pseudo-inputs.

    Parameters
    ----------
    n_inducing : int
        M, the number of pseudo-inputs (M = N/4 in Fig. 4.5; all N inputs if M ≥ N); not
        used when ``inducing`` is given (its M is).
    inducing : array_like, shape (M, d) or (E, M, d), optional
        Initial pseudo-inputs (default: k-means++ seeding on the training inputs).
    optimize_inducing : bool
        Optimise the pseudo-inputs with the hyper-parameters (default True).
    jitter : float
        Fixed relative jitter on K_mm (default 1e-8).
    **kwargs
        As :class:`~skillkit.models.gp.ExactGP` (initial values, ``noise_floor``,
        ``additive_noise``, ``n_steps``, ``optimizer``, ``learning_rate``, ``standardize``,
        ``curb``, ``device``: where the hyper-parameters and pseudo-inputs are optimised and the
        predictor lives; default CPU; float64 throughout). k-means++ seeding runs in numpy
        on the CPU, so its draws do not depend on the device.

    Notes
    -----
    ``diagnostics["log_marginal_likelihood"]`` is the FITC log marginal likelihood summed over
    outputs, in raw target units.
    """

    _method = "fitc"


class VFE(_SparseGP):
    """Titsias's variational sparse GP (collapsed VFE bound), same parameters as :class:`FITC`.

    Among them ``device``: where the hyper-parameters are optimised and the predictor lives;
    default CPU; float64 throughout.

    ``diagnostics["log_marginal_likelihood"]`` holds the bound (≤ the exact log marginal
    likelihood), summed over outputs, in raw target units.
    """

    _method = "vfe"
