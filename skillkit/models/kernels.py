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

from skillkit._validation import check_array, check_positive


def se_kernel(
    x1: torch.Tensor,
    x2: torch.Tensor,
    lengthscale: torch.Tensor,
    outputscale: torch.Tensor,
    diag: bool = False,
) -> torch.Tensor:
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
    os = torch.as_tensor(outputscale, dtype=x1.dtype, device=x1.device)
    if diag:
        d2 = (((x1 - x2) / lengthscale) ** 2).sum(-1)
        return os[..., None] * torch.exp(-0.5 * d2) if os.ndim else os * torch.exp(-0.5 * d2)
    return se_kernel_from_operands(
        se_operands(x1, lengthscale), se_operands(x2, lengthscale, os), torch.log(os)
    )


def se_operands(
    x: torch.Tensor, lengthscale: torch.Tensor, outputscale: torch.Tensor | float | None = None
) -> torch.Tensor:
    r"""Augmented operands that turn Eq. (2.25) into one matrix product.

    With a = x / w (element-wise), the query operand is ``[a, −½‖a‖², 1]`` and the support
    operand (``outputscale`` given) is ``[b, 1, −½‖b‖² + log σ_f²]``, so that

    .. math:: [a, -\tfrac12\|a\|^2, 1] \cdot [b, 1, -\tfrac12\|b\|^2 + \log\sigma_f^2]
              = -\tfrac12\|a - b\|^2 + \log\sigma_f^2 = \log k(x, x').

    Callers that evaluate the kernel against fixed support points many times (the trajectory
    sampler: training or pseudo-inputs never change between steps) build the support operand
    once and call :func:`se_kernel_from_operands` with fresh query operands.

    Parameters
    ----------
    x : Tensor, shape (..., n, d)
    lengthscale : Tensor, shape (..., 1, d) or broadcastable
    outputscale : Tensor of shape (...), float, or None
        σ_f² for a support operand; None for a query operand.

    Returns
    -------
    Tensor, shape (..., n, d + 2)
    """
    a = x / lengthscale
    half_sq = -0.5 * (a * a).sum(-1, keepdim=True)
    ones = torch.ones_like(half_sq)
    if outputscale is None:
        return torch.cat([a, half_sq, ones], dim=-1)
    log_os = torch.log(torch.as_tensor(outputscale, dtype=a.dtype, device=a.device))
    return torch.cat(
        [a, ones, half_sq + (log_os[..., None, None] if log_os.ndim else log_os)], dim=-1
    )


def se_kernel_from_operands(
    query: torch.Tensor, support: torch.Tensor, log_outputscale: torch.Tensor
) -> torch.Tensor:
    """k = exp(min(query · supportᵀ, log σ_f²)): Eq. (2.25) from :func:`se_operands`.

    The minimum is the round-off guard ‖a − b‖² ≥ 0 (k ≤ σ_f²). When no gradient is needed
    the product is exponentiated in place (one work array; this is the sampler's hot path).

    Parameters
    ----------
    query : Tensor, shape (..., n, d + 2)
    support : Tensor, shape (..., m, d + 2)
    log_outputscale : Tensor, shape (...) or ()

    Returns
    -------
    Tensor, shape (..., n, m)
    """
    lim = log_outputscale[..., None, None] if log_outputscale.ndim else log_outputscale
    e = query @ support.transpose(-1, -2)
    if torch.is_grad_enabled() and (
        query.requires_grad or support.requires_grad or lim.requires_grad
    ):
        return torch.exp(torch.minimum(e, lim))
    torch.minimum(e, lim, out=e)
    return e.exp_()


def linear_kernel(
    x1: torch.Tensor,
    x2: torch.Tensor,
    variance: torch.Tensor,
    bias: torch.Tensor | float = 0.0,
    diag: bool = False,
) -> torch.Tensor:
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
    return (var[..., None, None] if var.ndim else var) * prod + (
        c[..., None, None] if c.ndim else c
    )


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

    def __init__(
        self,
        input_dim: int,
        lengthscale=1.0,
        outputscale: float = 1.0,
        batch_shape: torch.Size | None = None,
        **kwargs,
    ):
        if int(input_dim) < 1:
            raise ValueError(f"input_dim: expected a positive integer, got {input_dim}")
        super().__init__(
            ard_num_dims=int(input_dim), batch_shape=batch_shape or torch.Size([]), **kwargs
        )
        self.register_parameter(
            "raw_outputscale", torch.nn.Parameter(torch.zeros(self.batch_shape))
        )
        self.register_constraint("raw_outputscale", Positive())
        # float64 by default (DESIGN.md); before the values are set, so they are exact
        self.double()
        try:
            ls = torch.as_tensor(
                np.broadcast_to(np.asarray(lengthscale, dtype=float), (int(input_dim),)).copy()
            )
        except (TypeError, ValueError):
            raise ValueError(
                f"lengthscale: expected a scalar or shape ({int(input_dim)},), got {lengthscale!r}"
            ) from None
        if torch.any(ls <= 0) or not torch.all(torch.isfinite(ls)):
            raise ValueError(f"lengthscale: expected positive finite values, got {lengthscale}")
        check_positive(outputscale, "outputscale")
        self.lengthscale = ls.expand(*self.batch_shape, 1, int(input_dim)).clone()
        self.outputscale = torch.full(self.batch_shape, float(outputscale), dtype=torch.float64)

    @property
    def outputscale(self) -> torch.Tensor:
        return self.raw_outputscale_constraint.transform(self.raw_outputscale)

    @outputscale.setter
    def outputscale(self, value) -> None:
        value = torch.as_tensor(
            value, dtype=self.raw_outputscale.dtype, device=self.raw_outputscale.device
        )
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

    def __init__(
        self,
        variance: float = 1.0,
        bias: float = 0.0,
        batch_shape: torch.Size | None = None,
        **kwargs,
    ):
        super().__init__(batch_shape=batch_shape or torch.Size([]), **kwargs)
        check_positive(variance, "variance")
        check_positive(bias, "bias", allow_zero=True)
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
        value = torch.as_tensor(
            value, dtype=self.raw_variance.dtype, device=self.raw_variance.device
        )
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
        d must be the kernel's input dimension (``ard_num_dims``) if it has one.
    Z : array_like, shape (m, d), optional
        Defaults to ``X``.

    Returns
    -------
    ndarray, shape (n, m)
    """
    x = check_array(X, "X", ndim=2)
    d = getattr(kernel, "ard_num_dims", None)
    if d is not None and x.shape[1] != d:
        raise ValueError(
            f"X: expected {d} columns (the kernel's input dimension), got shape {x.shape}"
        )
    z = x if Z is None else check_array(Z, "Z", ndim=2)
    if z.shape[1] != x.shape[1]:
        raise ValueError(f"Z: expected {x.shape[1]} columns like X, got shape {z.shape}")
    param = next(kernel.parameters(), torch.zeros((), dtype=torch.float64))
    with torch.no_grad():
        out = kernel.forward(
            torch.as_tensor(x, dtype=param.dtype, device=param.device),
            torch.as_tensor(z, dtype=param.dtype, device=param.device),
        )
    return out.detach().cpu().numpy().astype(np.float64)
