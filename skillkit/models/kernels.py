"""Kernels: one implementation shared by the GPs, the kernel embeddings and CrKR.

The maths lives in two pure torch functions (:func:`se_kernel`, :func:`linear_kernel`); the
classes wrap them as GPyTorch kernels, so GPyTorch's exact and sparse GPs, marginal-likelihood
training (positive hyper-parameters stored raw behind a constraint) and batching work on
them unchanged, while numpy code (CrKR, embeddings) calls :func:`gram`.
"""

from __future__ import annotations

import gpytorch
import numpy as np
import torch
from gpytorch.constraints import Positive

from skillkit._validation import check_array


def se_kernel(x1: torch.Tensor, x2: torch.Tensor, lengthscale: torch.Tensor, outputscale: torch.Tensor,
              diag: bool = False) -> torch.Tensor:
    r"""Squared-exponential kernel with ARD, Eq. (2.25).

    .. math:: k(x, x') = \sigma_f^2 \exp\big(-\tfrac12 (x - x')^\top W^{-1} (x - x')\big),
              \quad W = \mathrm{diag}(w^2)

    Parameters
    ----------
    x1 : Tensor, shape (..., n, d)
    x2 : Tensor, shape (..., m, d)
    lengthscale : Tensor, shape (..., 1, d) or broadcastable
        The ARD length-scales w.
    outputscale : Tensor, shape (...) or scalar
        The signal variance σ_f².
    diag : bool
        Return only the diagonal (requires n == m), shape (..., n).

    Returns
    -------
    Tensor, shape (..., n, m) (or (..., n) with ``diag``)
    """
    a = x1 / lengthscale
    b = x2 / lengthscale
    os = torch.as_tensor(outputscale, dtype=a.dtype, device=a.device)
    if diag:
        d2 = ((a - b) ** 2).sum(-1)
        return os[..., None] * torch.exp(-0.5 * d2) if os.ndim else os * torch.exp(-0.5 * d2)
    return se_kernel_scaled(a, b, (b * b).sum(-1), os)


def se_kernel_scaled(a: torch.Tensor, b: torch.Tensor, b_sqnorm: torch.Tensor,
                     outputscale: torch.Tensor) -> torch.Tensor:
    r"""Eq. (2.25) on inputs already divided by the length-scales (the body of :func:`se_kernel`).

    Callers that evaluate the kernel against the same second argument many times (the
    trajectory sampler: the training or pseudo-inputs never change between steps) cache
    ``b = x2 / w`` and ``b_sqnorm = ||b||²`` once and call this.

    .. math:: k = \sigma_f^2 \exp\big(-\tfrac12 (\|a\|^2 + \|b\|^2 - 2 a^\top b)\big)

    The squared distance is clamped at 0 against round-off (it is a sum of squares).

    Parameters
    ----------
    a : Tensor, shape (..., n, d)
        ``x1 / lengthscale``.
    b : Tensor, shape (..., m, d)
        ``x2 / lengthscale``.
    b_sqnorm : Tensor, shape (..., m)
        ``(b * b).sum(-1)``.
    outputscale : Tensor, shape (...) or scalar
        σ_f².

    Returns
    -------
    Tensor, shape (..., n, m)
    """
    os = torch.as_tensor(outputscale, dtype=a.dtype, device=a.device)
    # ||a||^2 + ||b||^2 - 2 a.b in one fused batched matmul.
    d2 = torch.baddbmm((a * a).sum(-1)[..., :, None] + b_sqnorm[..., None, :], a, b.transpose(-1, -2),
                       alpha=-2.0) if a.ndim == 3 and b.ndim == 3 else (
        (a * a).sum(-1)[..., :, None] + b_sqnorm[..., None, :] - 2.0 * a @ b.transpose(-1, -2))
    k = torch.exp(-0.5 * d2.clamp_min(0.0))
    return k * os[..., None, None] if os.ndim else k * os


def linear_kernel(x1: torch.Tensor, x2: torch.Tensor, variance: torch.Tensor, bias: torch.Tensor | float = 0.0,
                  diag: bool = False) -> torch.Tensor:
    r"""Linear kernel :math:`k(x, x') = \sigma^2 x^\top x' + c` (CrKR, reward embeddings in Ch. 5).

    Parameters
    ----------
    x1 : Tensor, shape (..., n, d)
    x2 : Tensor, shape (..., m, d)
    variance : Tensor or float
        σ² > 0.
    bias : Tensor or float
        c ≥ 0 (0 gives the plain inner product).
    diag : bool
        Return only the diagonal, shape (..., n).
    """
    var = torch.as_tensor(variance, dtype=x1.dtype, device=x1.device)
    c = torch.as_tensor(bias, dtype=x1.dtype, device=x1.device)
    if diag:
        prod = (x1 * x2).sum(-1)
        return (var[..., None] if var.ndim else var) * prod + (c[..., None] if c.ndim else c)
    prod = x1 @ x2.transpose(-1, -2)
    return (var[..., None, None] if var.ndim else var) * prod + (c[..., None, None] if c.ndim else c)


class SquaredExponential(gpytorch.kernels.Kernel):
    """Eq. (2.25) as a GPyTorch kernel: ARD length-scales w and signal variance σ_f² (both
    stored raw behind a positivity constraint).

    Parameters
    ----------
    input_dim : int
        Input dimension d (one length-scale per dimension).
    lengthscale : float or array_like of shape (d,)
        Initial length-scales.
    outputscale : float
        Initial σ_f².
    batch_shape : torch.Size, optional
        Independent hyper-parameters per batch entry (e.g. one GP per output dimension).
    """

    has_lengthscale = True

    def __init__(self, input_dim: int, lengthscale=1.0, outputscale: float = 1.0,
                 batch_shape: torch.Size | None = None, **kwargs):
        if int(input_dim) < 1:
            raise ValueError(f"input_dim: expected a positive integer, got {input_dim}")
        super().__init__(ard_num_dims=int(input_dim), batch_shape=batch_shape or torch.Size([]), **kwargs)
        self.register_parameter("raw_outputscale", torch.nn.Parameter(torch.zeros(self.batch_shape)))
        self.register_constraint("raw_outputscale", Positive())
        self.double()  # float64 by default (DESIGN.md); before the values are set, so they are exact
        ls = torch.as_tensor(np.broadcast_to(np.asarray(lengthscale, dtype=float), (int(input_dim),)).copy())
        if torch.any(ls <= 0) or not torch.all(torch.isfinite(ls)):
            raise ValueError(f"lengthscale: expected positive finite values, got {lengthscale}")
        if not (np.isfinite(outputscale) and outputscale > 0):
            raise ValueError(f"outputscale: expected a positive finite value, got {outputscale}")
        self.lengthscale = ls.expand(*self.batch_shape, 1, int(input_dim)).clone()
        self.outputscale = torch.full(self.batch_shape, float(outputscale), dtype=torch.float64)

    @property
    def outputscale(self) -> torch.Tensor:
        return self.raw_outputscale_constraint.transform(self.raw_outputscale)

    @outputscale.setter
    def outputscale(self, value) -> None:
        value = torch.as_tensor(value, dtype=self.raw_outputscale.dtype, device=self.raw_outputscale.device)
        self.initialize(raw_outputscale=self.raw_outputscale_constraint.inverse_transform(value))

    def forward(self, x1, x2, diag: bool = False, **params):
        return se_kernel(x1, x2, self.lengthscale, self.outputscale, diag=diag)


class Linear(gpytorch.kernels.Kernel):
    """Linear kernel σ² xᵀx' + c as a GPyTorch kernel (σ² raw behind a positivity constraint).

    Parameters
    ----------
    variance : float
        Initial σ² > 0.
    bias : float
        Constant offset c ≥ 0 (fixed, not learned).
    """

    def __init__(self, variance: float = 1.0, bias: float = 0.0, batch_shape: torch.Size | None = None, **kwargs):
        super().__init__(batch_shape=batch_shape or torch.Size([]), **kwargs)
        if not (np.isfinite(variance) and variance > 0):
            raise ValueError(f"variance: expected a positive finite value, got {variance}")
        if not (np.isfinite(bias) and bias >= 0):
            raise ValueError(f"bias: expected a finite value >= 0, got {bias}")
        self.register_parameter("raw_variance", torch.nn.Parameter(torch.zeros(self.batch_shape)))
        self.register_constraint("raw_variance", Positive())
        self.double()
        self.variance = torch.full(self.batch_shape, float(variance), dtype=torch.float64)
        self.bias = float(bias)

    @property
    def variance(self) -> torch.Tensor:
        return self.raw_variance_constraint.transform(self.raw_variance)

    @variance.setter
    def variance(self, value) -> None:
        value = torch.as_tensor(value, dtype=self.raw_variance.dtype, device=self.raw_variance.device)
        self.initialize(raw_variance=self.raw_variance_constraint.inverse_transform(value))

    def forward(self, x1, x2, diag: bool = False, **params):
        return linear_kernel(x1, x2, self.variance, self.bias, diag=diag)


def gram(kernel: gpytorch.kernels.Kernel, X, Z=None) -> np.ndarray:
    """Evaluate a kernel on numpy inputs in float64 and return a numpy Gram matrix.

    Parameters
    ----------
    kernel : gpytorch Kernel
        E.g. :class:`SquaredExponential` or :class:`Linear` (not modified).
    X : array_like, shape (n, d)
    Z : array_like, shape (m, d), optional
        Defaults to ``X``.

    Returns
    -------
    ndarray, shape (n, m)
    """
    x = check_array(X, "X", ndim=2)
    z = x if Z is None else check_array(Z, "Z", ndim=2)
    if z.shape[1] != x.shape[1]:
        raise ValueError(f"Z: expected {x.shape[1]} columns like X, got shape {z.shape}")
    param = next(kernel.parameters(), torch.zeros((), dtype=torch.float64))
    with torch.no_grad():
        out = kernel.forward(torch.as_tensor(x, dtype=param.dtype, device=param.device),
                             torch.as_tensor(z, dtype=param.dtype, device=param.device))
    return out.detach().cpu().numpy().astype(np.float64)
