"""Sparse GPs with M pseudo-inputs behind the :class:`~skillkit.models.gp.ExactGP` interface.

:class:`FITC` (Snelson & Ghahramani's SPGP, the thesis's sparse model) and :class:`VFE`
(Titsias's collapsed bound). With Λ = diag(K_nn − Q_nn) + σ_ε²I (FITC) or σ_ε²I (VFE) and
Σ = (K_mm + K_mn Λ⁻¹ K_nm)⁻¹ both are a :class:`~skillkit.models.gp.GPPredictor` with
β = Σ K_mn Λ⁻¹ y and iK = K_mm⁻¹ − Σ. Pseudo-inputs (E, M, d) start from k-means++ seeding
and are optimised with the hyper-parameters."""

from __future__ import annotations

import math

import numpy as np
import torch

from skillkit._validation import check_array, check_positive
from skillkit.models.gp import DTYPE, GPPredictor, GPRegression, plain_cholesky, robust_cholesky
from skillkit.models.kernels import se_kernel

__all__ = ["FITC", "VFE", "kmeans_pp"]


def kmeans_pp(X, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices (n,) of ``n`` rows of ``X`` by k-means++ seeding (D²-sampling)."""
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


def sparse_terms(ls, os, noise, Z, X, Y, jitter: float, fitc: bool, factor=plain_cholesky):
    """−log p(Y) of FITC (VFE's collapsed bound if not ``fitc``) summed over E outputs, and
    (L_m, L_A, c, V, Λ (E, N), K_mm, K_mn, mask), for ``ls`` (E, d), ``os``, ``noise`` (E,),
    ``Z`` (E, M, d), ``X`` (N, d) and standardised ``Y`` (E, N): L_m L_mᵀ = K_mm + jitter·σ_f²I,
    V = L_m⁻¹K_mn, L_A L_Aᵀ = A = I + VΛ⁻¹Vᵀ, c = L_A⁻¹VΛ⁻¹y, mask: diag(K_nn − Q_nn) ≥ 0."""
    E, N = Y.shape
    eye = torch.eye(Z.shape[1], dtype=DTYPE, device=X.device)
    Kmm = se_kernel(Z, Z, ls[:, None, :], os)
    Lm = factor(Kmm + (jitter * os)[:, None, None] * eye, "K_mm")
    Kmn = se_kernel(Z, X.expand(E, *X.shape), ls[:, None, :], os)
    V = torch.linalg.solve_triangular(Lm, Kmn, upper=False)
    gap = os[:, None] - (V * V).sum(-2)  # diag(K_nn − Q_nn)
    mask, gap = gap >= 0, gap.clamp_min(0.0)
    lam = gap + noise[:, None] if fitc else noise[:, None].expand(E, N)
    sq = lam.sqrt()
    Vs, ys = V / sq[:, None, :], Y / sq
    LA = factor(Vs @ Vs.transpose(-1, -2) + eye, "I + V inv(Lambda) V^T")
    c = torch.linalg.solve_triangular(LA, Vs @ ys.unsqueeze(-1), upper=False).squeeze(-1)
    value = (ys * ys).sum() - (c * c).sum() + torch.log(lam).sum() + N * E * math.log(2 * math.pi)
    value = 0.5 * value + torch.log(LA.diagonal(dim1=-2, dim2=-1)).sum()
    if not fitc:
        value = value + (gap.sum(-1) / (2.0 * noise)).sum()
    return value, Lm, LA, c, V, lam, Kmm, Kmn, mask


class _SparseNegLogML(torch.autograd.Function):
    """:func:`sparse_terms`'s value with its analytic gradient (Snelson & Ghahramani, 2006).

    With Σ_y = Q_nn + Λ, α = Σ_y⁻¹y, W = Σ_y⁻¹ − ααᵀ, w = diag W and G = W − diag(h) (h = w
    for FITC, 1/σ_ε² for VFE's trace term; 0 where the gap is clamped): ∂/∂V = VG =
    A⁻¹VΛ⁻¹ − (Vα)αᵀ − V diag(h), ∂/∂K_mn = L_m⁻ᵀVG, ∂/∂K_mm = −½ L_m⁻ᵀVGVᵀL_m⁻¹,
    ∂/∂σ_ε² = ½Σw (VFE: − Σ gap / 2σ_ε⁴), then the SE kernel's derivatives (App. B.1)."""

    @staticmethod
    def forward(ctx, ls, os, noise, Z, X, Y, jitter, fitc):
        value, *terms = sparse_terms(ls, os, noise, Z, X, Y, jitter, fitc)
        ctx.save_for_backward(ls, os, noise, Z, X, Y, *terms)
        ctx.fitc, ctx.jitter = fitc, jitter
        return value

    @staticmethod
    def backward(ctx, grad):
        ls, os, noise, Z, X, Y, Lm, LA, c, V, lam, Kmm, Kmn, mask = ctx.saved_tensors
        Vl = V / lam[:, None, :]
        gamma = torch.linalg.solve_triangular(LA.mT, c.unsqueeze(-1), upper=True)
        alpha = (Y - (gamma.mT @ V).squeeze(-2)) / lam  # Σ_y⁻¹y
        VG = torch.cholesky_solve(Vl, LA)  # A⁻¹VΛ⁻¹ = VΣ_y⁻¹
        w = 1.0 / lam - (Vl * VG).sum(-2) - alpha * alpha
        h = (mask * (w if ctx.fitc else 1.0 / noise[:, None])).unsqueeze(-2)
        VG.baddbmm_(V @ alpha.unsqueeze(-1), alpha.unsqueeze(-2), alpha=-1.0)
        VG.addcmul_(V, h, value=-1.0)
        S = torch.linalg.solve_triangular(Lm.mT, VG @ V.mT, upper=True)
        Kmm_bar = -0.5 * torch.linalg.solve_triangular(Lm, S, upper=False, left=False)
        Pm = 0.5 * (Kmm_bar + Kmm_bar.mT) * Kmm
        Pn = torch.linalg.solve_triangular(Lm.mT, VG, upper=True).mul_(Kmn)  # K̄_mn ∘ K_mn
        g_noise = 0.5 * w.sum(-1)
        if not ctx.fitc:
            g_noise -= (os[:, None] - (V * V).sum(-2)).clamp_min(0.0).sum(-1) / (2.0 * noise**2)
        g_os = 0.5 * h.sum((-2, -1)) + (Pn.sum((-2, -1)) + Pm.sum((-2, -1))) / os
        g_os += ctx.jitter * Kmm_bar.diagonal(dim1=-2, dim2=-1).sum(-1)
        rn, rm = Pn.sum(-1, keepdim=True), 2.0 * Pm.sum(-1, keepdim=True)  # (E, M, 1)
        PX = Pn @ X  # (E, M, d)
        T = PX + 2.0 * (Pm @ Z) - (rn + rm) * Z  # w² ∂/∂Z
        g_Z = grad * T / ls[:, None, :] ** 2 if ctx.needs_input_grad[3] else None
        g_ls = (Pn.sum(-2) @ (X * X) - (Z * (T + PX)).sum(1)) / ls**3
        return grad * g_ls, grad * g_os, grad * g_noise, g_Z, None, None, None, None


class _SparseGP(GPRegression):
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
                raise ValueError(f"inducing: expected (M, {d}) or ({E}, M, {d}), got {Z.shape}")
            Z = np.broadcast_to(Z, (E, *Z.shape[-2:])).copy()
        elif self.n_inducing >= N:
            Z = np.broadcast_to(X, (E, N, d)).copy()
        else:
            idx = kmeans_pp(X / self._input_sd, self.n_inducing, rng)
            Z = np.broadcast_to(X[idx], (E, self.n_inducing, d)).copy()
        self.diagnostics_init = {"n_inducing": Z.shape[1]}
        self.inducing = torch.nn.Parameter(
            torch.as_tensor(Z, dtype=DTYPE, device=self.device),
            requires_grad=self.optimize_inducing,
        )
        self.kernel, self.likelihood = self._hyper_modules(E, d)

    def _parameters(self) -> list[torch.nn.Parameter]:
        params = list(self.kernel.parameters()) + list(self.likelihood.parameters())
        return params + ([self.inducing] if self.optimize_inducing else [])

    def _args(self) -> tuple:
        """:func:`sparse_terms`'s arguments (hyper-parameters, Z, X, Y, jitter, FITC or not)."""
        hypers = self._hypers()
        return (*hypers, self.inducing, self.X, self.Y, self.jitter, self._method == "fitc")

    def _loss(self) -> torch.Tensor:
        return _SparseNegLogML.apply(*self._args())

    def _make_predictor(self) -> tuple[GPPredictor, dict]:
        jit: dict[str, float] = {}

        def factor(A, what):
            L, jit[what] = robust_cholesky(A, what)
            return L

        args = self._args()
        value, Lm, LA, c, _, lam, *_ = sparse_terms(*args, factor)
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
        hypers = (t.detach() for t in args[:3])
        pred = GPPredictor(self.inducing.detach().clone(), *hypers, beta, iK, R, y_mean, y_scale)
        N = self.Y.shape[1]
        objective = -float(value) - N * float(torch.log(y_scale).sum())
        return pred, {
            **self.diagnostics_init,
            "jitter": max(jit.values()),
            "log_marginal_likelihood": objective,
            "effective_noise": lam.mean(-1).cpu().numpy(),
        }


class FITC(_SparseGP):
    """FITC / SPGP sparse GP (Snelson & Ghahramani) with M optimised pseudo-inputs.

    Parameters
    ----------
    n_inducing : int, default 100
        M; all N training inputs are used if M ≥ N.
    inducing : array_like, shape (M, d) or (E, M, d), optional
        Initial pseudo-inputs (default: k-means++ seeding on the standardised inputs).
    optimize_inducing : bool, default True
        Optimise the pseudo-inputs with the hyper-parameters.
    jitter : float, default 1e-8
        Relative jitter (× σ_f²) on K_mm.
    **kwargs
        As :class:`~skillkit.models.gp.ExactGP`.

    Raises
    ------
    ValueError
        On a non-positive ``n_inducing`` or ``jitter``, or ``inducing`` of the wrong shape
        (at :meth:`fit`).
    """

    _method = "fitc"


class VFE(_SparseGP):
    """Titsias's variational sparse GP (VFE), parameters as :class:`FITC`.

    ``diagnostics["log_marginal_likelihood"]`` holds the collapsed bound, not Eq. (2.28).
    """

    _method = "vfe"
