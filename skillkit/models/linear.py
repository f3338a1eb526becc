"""A linear-Gaussian forward model: x_{t+1} = A x_t + B u_t + c + w, w ~ N(0, Σ_w).

Least squares on [x, u, 1] with the full residual covariance Σ_w (Table 4.2's parametric
model). Sampled trajectories draw correlated noise F ε with F Fᵀ = Σ_w; PILCO's propagation
under a linear controller is exact (:func:`~skillkit.search.pilco.linear_gaussian_step`)."""

from __future__ import annotations

import numpy as np
import torch

from skillkit.models.gp import DTYPE, Moments, TransitionModel

__all__ = ["LinearGaussianModel"]


class LinearGaussianModel(TransitionModel):
    """Linear-Gaussian forward model x' = A x + B u + c + w, w ~ N(0, Σ_w).

    Parameters
    ----------
    target : {"delta", "next"}, default "delta"
        Regress x' − x or x'.
    ridge : float, default 1e-9
        λ ≥ 0 on the coefficients of [x, u], relative to the mean squared input.

    Attributes
    ----------
    A : ndarray, shape (n_x, n_x)
    B : ndarray, shape (n_x, n_u)
    c : ndarray, shape (n_x,)
    noise_cov : ndarray, shape (n_x, n_x)
        Σ_w, from the residuals.
    """

    def __init__(self, target: str = "delta", ridge: float = 1e-9):
        super().__init__(target)
        if not np.isfinite(ridge) or ridge < 0:
            raise ValueError(f"ridge: expected a finite number >= 0, got {ridge!r}")
        self.ridge = float(ridge)
        self.dtype = DTYPE
        self.A = self.B = self.c = self.noise_cov = None  # set by fit() or by hand

    @property
    def state_dim(self) -> int:
        """n_x (0 before the dynamics are set)."""
        return 0 if self.A is None else int(np.shape(self.A)[0])

    @property
    def control_dim(self) -> int:
        """n_u (0 before the dynamics are set)."""
        return 0 if self.B is None else int(np.shape(self.B)[1])

    @property
    def noise_factor(self) -> np.ndarray | None:
        """F, the symmetric square root of Σ_w (n_x, n_x), negative round-off eigenvalues as 0."""
        if self.noise_cov is None:
            return None
        lam, V = np.linalg.eigh(np.asarray(self.noise_cov, dtype=np.float64))
        return (V * np.sqrt(np.clip(lam, 0.0, None))) @ V.T

    def _fit(self, x: np.ndarray, u: np.ndarray, xn: np.ndarray, rng) -> None:
        """Least squares for A, B, c (≥ n_x + n_u + 1 transitions); Σ_w from the residuals."""
        n_x, n_u = x.shape[1], u.shape[1]
        if x.shape[0] < n_x + n_u + 1:
            raise ValueError(
                f"states: expected at least {n_x + n_u + 1} transitions, got {x.shape[0]}"
            )
        z1 = np.hstack([x, u, np.ones((x.shape[0], 1))])
        y = xn - x if self.target == "delta" else xn
        reg = self.ridge * np.mean(z1[:, :-1] ** 2) * np.diag([1.0] * (n_x + n_u) + [0.0])
        w = np.linalg.solve(z1.T @ z1 + reg, z1.T @ y)  # (D + 1, n_x)
        res = y - z1 @ w
        self.A = w[:n_x].T + (np.eye(n_x) if self.target == "delta" else 0.0)
        self.B = w[n_x : n_x + n_u].T
        self.c = w[-1]
        self.noise_cov = res.T @ res / max(x.shape[0] - n_x - n_u - 1, 1)

    def _check_fitted(self) -> None:
        if self.A is None or self.B is None or self.c is None or self.noise_cov is None:
            raise RuntimeError("LinearGaussianModel: call fit() (or set A, B, c, noise_cov) first")

    def to(self, device=None, dtype: torch.dtype | None = None) -> LinearGaussianModel:
        """Itself, with predictions in ``dtype`` (the arrays are converted per call)."""
        self.dtype = DTYPE if dtype is None else dtype
        return self

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor) -> Moments:
        """Mean A x + B u + c and variance diag Σ_w (the marginals) for x (n, n_x), u (n, n_u)."""
        self._check_fitted()
        kw = {"dtype": x.dtype, "device": x.device}
        A, B, c = (torch.as_tensor(a, **kw) for a in (self.A, self.B, self.c))
        mean = x @ A.T + u @ B.T + c
        var = torch.as_tensor(np.diag(self.noise_cov).copy(), **kw).expand_as(mean)
        return Moments.exact(mean, var)

    def noise_factor_tensor(self, device=None, dtype: torch.dtype | None = None) -> torch.Tensor:
        """F as a tensor (default dtype: the model's)."""
        self._check_fitted()
        return torch.as_tensor(
            np.array(self.noise_factor), dtype=self.dtype if dtype is None else dtype, device=device
        )

    def __repr__(self) -> str:
        if self.A is None:
            return f"LinearGaussianModel(target={self.target!r}, unfitted)"
        rho = float(np.abs(np.linalg.eigvals(self.A)).max())
        return (
            f"LinearGaussianModel(state_dim={self.state_dim}, control_dim={self.control_dim}, "
            f"spectral radius of A {rho:.3g}, noise std max "
            f"{float(np.sqrt(np.diag(self.noise_cov).max())):.3g})"
        )
