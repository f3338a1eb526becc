"""Conditional mean embeddings of distributions in an RKHS (thesis Secs. 2.4 and 5.1).

Training pairs (z_i, y_i), an input kernel g with Gram matrix G and λ > 0 define the
conditional embedding operator Ĉ_{y|z} = Φ_y (G + λI)⁻¹ Φ_zᵀ (Eq. 2.38); an embedding over
the targets is a weight vector β, μ_y = Φ_y β (Eq. 2.40), shape (N,) or (N, B)."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import gpytorch
import numpy as np
import torch

from skillkit._repr import number, span
from skillkit._validation import check_array, check_count, check_positive, check_type
from skillkit.models.kernels import Linear, SquaredExponential, gram

__all__ = [
    "ConditionalEmbedding",
    "conditional_weights",
    "initial_weights",
    "regularized_cholesky",
    "rollout_weights",
]

Transition = torch.Tensor | Callable[[int], torch.Tensor]


def regularized_cholesky(gram_matrix: torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Lower Cholesky factor (N, N) of :math:`G + \\lambda I`, the matrix inverted in Eq. 2.38.

    Raises ``numpy.linalg.LinAlgError`` naming ``lam`` if it is not numerically positive definite.
    """
    n = gram_matrix.shape[-1]
    eye = torch.eye(n, dtype=gram_matrix.dtype, device=gram_matrix.device)
    chol, info = torch.linalg.cholesky_ex(gram_matrix + lam * eye)
    if int(info.max()) > 0:
        lam_v = float(lam.detach()) if isinstance(lam, torch.Tensor) else float(lam)
        raise np.linalg.LinAlgError(
            f"lam: G + λI is not positive definite at λ={lam_v:.3g}; increase lam"
        )
    return chol


def conditional_weights(chol: torch.Tensor, cross: torch.Tensor) -> torch.Tensor:
    """:math:`\\beta = (G + \\lambda I)^{-1} g` (Eqs. 2.39, 5.6, 5.7) from ``chol`` and ``cross``
    (..., N, B)."""
    return torch.cholesky_solve(cross, chol)


def initial_weights(
    chol: torch.Tensor, gram_matrix: torch.Tensor, mean_cross: torch.Tensor, project: bool = True
) -> torch.Tensor:
    """Weights (N, B) of the first predicted state embedding, Eqs. (5.6) and (5.9).

    :math:`\\beta = (G + \\lambda I)^{-1} G \\alpha` with :math:`\\alpha = (G + \\lambda I)^{-1}
    \\langle g(z_l) \\rangle_l` (``mean_cross``, (N, B)); ``project=False`` returns α (Eq. 5.7)."""
    alpha = conditional_weights(chol, mean_cross)
    return conditional_weights(chol, gram_matrix @ alpha) if project else alpha


def rollout_weights(
    chol: torch.Tensor, beta1: torch.Tensor, transition: Transition, n_steps: int
) -> torch.Tensor:
    """:math:`\\beta_{t+1} = (G + \\lambda I)^{-1} \\tilde G_t \\beta_t` (Eqs. 5.11, 5.14) for
    t < ``n_steps``: Tensor (n_steps, N, B).

    ``transition`` is :math:`\\tilde G_t`, (N, N) or one per column (B, N, N), or ``t -> tensor``.
    """
    n_steps = check_count(n_steps, "n_steps")
    betas = [beta1]
    beta = beta1
    for t in range(1, n_steps):
        g_t = transition(t) if callable(transition) else transition
        if g_t.ndim == 2:
            v = g_t @ beta
        elif g_t.ndim == 3:
            v = torch.einsum("bij,jb->ib", g_t, beta)
        else:
            raise ValueError(f"transition: expected (N, N) or (B, N, N), got {tuple(g_t.shape)}")
        beta = conditional_weights(chol, v)
        betas.append(beta)
    return torch.stack(betas)


class ConditionalEmbedding:
    """Empirical conditional mean embedding :math:`\\mu_{y|z} = \\Phi_y (G+\\lambda I)^{-1} g(z)`
    (Eqs. 2.38–2.40, 5.2–5.8).

    Parameters
    ----------
    inputs : array_like, shape (N, d_z)
    targets : array_like, shape (N, d_y)
    kernel : gpytorch.kernels.Kernel
        g, the input kernel.
    lam : float, default 1e-3
        λ > 0.
    target_kernel : gpytorch.kernels.Kernel, optional
        For :meth:`preimage` (default ``kernel`` if d_y = d_z).

    Raises
    ------
    ValueError
        On mismatched rows or no data.
    numpy.linalg.LinAlgError
        If G + λI is not numerically positive definite.
    """

    def __init__(
        self,
        inputs,
        targets,
        kernel: gpytorch.kernels.Kernel,
        lam: float = 1e-3,
        target_kernel: gpytorch.kernels.Kernel | None = None,
    ):
        z = check_array(inputs, "inputs", ndim=2)
        y = check_array(targets, "targets", ndim=2)
        if y.shape[0] != z.shape[0]:
            raise ValueError(f"targets: expected {z.shape[0]} rows like inputs, got {y.shape}")
        if z.shape[0] < 1:
            raise ValueError("inputs: expected at least one training pair, got none")
        self.lam = check_positive(lam, "lam")
        self.kernel = kernel
        if target_kernel is None and y.shape[1] == z.shape[1]:
            target_kernel = kernel
        self.target_kernel = target_kernel
        self.inputs = z
        self.targets = y
        self.n, self.input_dim = z.shape
        self.target_dim = y.shape[1]
        self.gram = gram(kernel, z)
        self._z = torch.from_numpy(z)
        self.chol = regularized_cholesky(torch.from_numpy(self.gram), self.lam)

    def __repr__(self) -> str:
        kern = type(self.kernel).__name__
        ls = getattr(self.kernel, "lengthscale", None)
        if ls is not None:
            kern += f"(lengthscale={span(ls)})"
        return (
            f"ConditionalEmbedding(N={self.n}, input_dim={self.input_dim}, "
            f"target_dim={self.target_dim}, lam={number(self.lam)}, kernel={kern})"
        )

    def cross_kernel(self, points: torch.Tensor) -> torch.Tensor:
        """g(z_i, p) for ``points`` (M, d_z) or (B, M, d_z): (N, M) or (B, N, M)."""
        self._points(points, "points")
        with torch.no_grad():
            return self.kernel.forward(self._z, points.to(torch.float64))

    def _points(self, value, name: str, ndim=None):
        """``value`` (an array unless a Tensor) with ``input_dim`` columns, else ValueError."""
        arr = value if ndim is None else check_array(value, name, ndim=ndim)
        if arr.shape[-1] != self.input_dim:
            raise ValueError(f"{name}: expected {self.input_dim} columns, got {tuple(arr.shape)}")
        return arr

    def weights(self, queries) -> np.ndarray:
        """Weights (N, B) of :math:`\\mu_{y|z_*}` for queries (B, d_z), Eqs. (2.39)–(2.40)."""
        q = torch.from_numpy(self._points(queries, "queries", 2))
        return conditional_weights(self.chol, self.cross_kernel(q)).numpy()

    def weights_from_samples(self, samples) -> np.ndarray:
        """Weights :math:`(G + \\lambda I)^{-1} \\langle g(z_l^*) \\rangle_l` for sample-represented
        inputs (L, d_z) or (B, L, d_z), Eqs. (5.6)–(5.7): shape (N,) or (N, B)."""
        s = self._points(samples, "samples", (2, 3))
        single = s.ndim == 2
        st = torch.from_numpy(s[None] if single else s)  # (B, L, d)
        mean_k = self.cross_kernel(st).mean(-1).T  # (N, B)
        beta = conditional_weights(self.chol, mean_k).numpy()
        return beta[:, 0] if single else beta

    def operator(self, basis) -> np.ndarray:
        """:math:`C = (G + \\lambda I)^{-1} \\tilde G` (N, M) of Table 5.1 / Eq. (2.42), with
        :math:`\\tilde G_{ij} = g(z_i, \\text{basis}_j)` for ``basis`` (M, d_z)."""
        b = torch.from_numpy(self._points(basis, "basis", 2))
        return conditional_weights(self.chol, self.cross_kernel(b)).numpy()

    def apply(self, alpha, basis) -> np.ndarray:
        """Weights (N,) or (N, B) of :math:`\\Phi_y (G + \\lambda I)^{-1} \\tilde G \\alpha`
        (Eq. 2.42) for ``alpha`` (M,) or (M, B) over ``basis`` (M, d_z)."""
        b = self._points(basis, "basis", 2)
        a = check_array(alpha, "alpha", ndim=(1, 2))
        if a.shape[0] != b.shape[0]:
            raise ValueError(f"alpha: expected {b.shape[0]} rows like basis, got shape {a.shape}")
        g = self.cross_kernel(torch.from_numpy(b))
        at = torch.from_numpy(a.reshape(a.shape[0], -1))
        out = conditional_weights(self.chol, g @ at).numpy()
        return out[:, 0] if a.ndim == 1 else out

    def _rows(self, value, name: str) -> np.ndarray:
        """``value`` (N,) or (N, k), one row per training pair, else ValueError."""
        arr = check_array(value, name, ndim=(1, 2))
        if arr.shape[0] != self.n:
            raise ValueError(f"{name}: expected {self.n} rows (training pairs), got {arr.shape}")
        return arr

    def expected(self, values, beta) -> np.ndarray:
        """:math:`f'^\\top \\beta` for ``values`` f(y_i) (N,) or (N, k), e.g. rewards (Sec. 5.4)."""
        b = self._rows(beta, "beta")
        return b.T @ self._rows(values, "values")

    def mean(self, beta) -> np.ndarray:
        """Expected target :math:`Y^\\top \\beta`: (d_y,) or (B, d_y)."""
        return self.expected(self.targets, beta)

    def preimage(self, beta, max_iter: int = 200, tol: float = 1e-10) -> np.ndarray:
        """Most likely target y* = argmin_y k(y, y) − 2βᵀk_Y(y) for Φ_y β, Eqs. (2.44)–(2.45).

        Linear target kernel: Yᵀβ. SE kernel: the mean-shift fixed point y ← Σ_i w_i y_i / Σ_i w_i,
        w_i = β_i k(y, y_i), from the best training target; columns that stop early warn."""
        b = self._rows(beta, "beta")
        kern = self.target_kernel
        if kern is None:
            raise ValueError("target_kernel: needed for pre-images when targets and inputs differ")
        if isinstance(kern, Linear):
            return self.mean(b)
        check_type(kern, SquaredExponential, "target_kernel", "SE or Linear")
        single = b.ndim == 1
        x, ok = _se_preimage(self.targets, b.reshape(self.n, -1), kern, int(max_iter), float(tol))
        if not np.all(ok):
            bad = f"{int(np.sum(~ok))} of {ok.size}"
            msg = f"preimage: fixed-point iteration stopped early for {bad} embedding(s) "
            msg += "(weight mass ≤ 0 or no convergence); returned the best iterate"
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
        return x[0] if single else x


def _se_preimage(
    y: np.ndarray, beta: np.ndarray, kern: SquaredExponential, max_iter: int, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-point SE pre-image: (points (B, d), converged (B,))."""
    yt = torch.from_numpy(y)
    bt = torch.from_numpy(beta).T.contiguous()  # (B, N)
    with torch.no_grad():
        scores = bt @ kern.forward(yt, yt)  # (B, N): β^T k_Y(y_j)
        best_score, start = scores.max(dim=1)
        best = yt[start].clone()  # (B, d)
        converged = torch.zeros(best.shape[0], dtype=torch.bool)
        idx = torch.arange(best.shape[0])  # unfinished columns
        x = best.clone()
        for _ in range(max_iter):
            w = kern.forward(x, yt) * bt[idx]  # β_i k(y, y_i)
            mass = w.sum(dim=1)  # = score at x
            better = mass >= best_score[idx]
            best[idx[better]] = x[better]
            best_score[idx[better]] = mass[better]
            ok = mass > 0  # else: stop, keep the best
            idx, x, w, mass = idx[ok], x[ok], w[ok], mass[ok]
            if idx.numel() == 0:
                break
            step = (w @ yt - mass[:, None] * x) / mass[:, None]
            done = step.norm(dim=1) <= tol * (1.0 + x.norm(dim=1))
            converged[idx[done]] = True
            keep = ~done
            idx, x = idx[keep], (x + step)[keep]
            if idx.numel() == 0:
                break
    return best.numpy(), converged.numpy()
