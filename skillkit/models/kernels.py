"""Kernels shared by the GPs, the kernel embeddings and CrKR: pure torch functions
(:func:`se_kernel`, :func:`linear_kernel`) wrapped as GPyTorch kernels, and :func:`gram`
for numpy callers."""

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
        With ``diag``, shape (..., n, d).
    lengthscale : Tensor, shape (..., 1, d) or (d,)
        w.
    outputscale : Tensor, shape (...) or ()
        σ_f².
    diag : bool, default False
        Return only k(x1_i, x2_i).

    Returns
    -------
    Tensor, shape (..., n, m), or (..., n) with ``diag``
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
    r"""Augmented operands that turn Eq. (2.25) into one matrix product: (..., n, d + 2).

    With a = x / w the query operand is [a, −½‖a‖², 1], the support operand (``outputscale``
    given) [b, 1, −½‖b‖² + log σ_f²]; their product is −½‖a − b‖² + log σ_f² = log k(x, x′)."""
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
    """k = exp(min(query · supportᵀ, log σ_f²)): Eq. (2.25) from :func:`se_operands`, (..., n, m);
    in place when no gradient is needed."""
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
    r"""Linear kernel :math:`k(x, x') = \sigma^2 x^\top x' + c` (CrKR, reward embeddings in Ch. 5);
    ``diag`` gives only the diagonal."""
    var = torch.as_tensor(variance, dtype=x1.dtype, device=x1.device)
    c = torch.as_tensor(bias, dtype=x1.dtype, device=x1.device)
    if diag:
        prod = (x1 * x2).sum(-1)
        return (var[..., None] if var.ndim else var) * prod + (c[..., None] if c.ndim else c)
    prod = x1 @ x2.transpose(-1, -2)
    return (var[..., None, None] if var.ndim else var) * prod + (
        c[..., None, None] if c.ndim else c
    )


def _positive(name: str) -> property:
    """The parameter ``raw_<name>`` registered behind a positivity constraint, as a property."""
    raw = f"raw_{name}"

    def get(self) -> torch.Tensor:
        return getattr(self, f"{raw}_constraint").transform(getattr(self, raw))

    def set_(self, value) -> None:
        param = getattr(self, raw)
        value = torch.as_tensor(value, dtype=param.dtype, device=param.device)
        self.initialize(**{raw: getattr(self, f"{raw}_constraint").inverse_transform(value)})

    return property(get, set_)


def _register_positive(kernel: gpytorch.kernels.Kernel, name: str) -> None:
    kernel.register_parameter(f"raw_{name}", torch.nn.Parameter(torch.zeros(kernel.batch_shape)))
    kernel.register_constraint(f"raw_{name}", Positive())
    kernel.double()  # float64 by default (DESIGN.md); before the values are set, so they are exact


class SquaredExponential(gpytorch.kernels.Kernel):
    """Eq. (2.25) as a GPyTorch kernel, float64, positivity-constrained hyper-parameters.

    Parameters
    ----------
    input_dim : int
        d, the number of ARD length-scales.
    lengthscale : float or array_like, shape (d,), default 1.0
        Initial w.
    outputscale : float, default 1.0
        Initial σ_f².
    batch_shape : torch.Size, optional
        One set of hyper-parameters per batch entry (e.g. per GP output).
    **kwargs
        Passed to :class:`gpytorch.kernels.Kernel`.

    Raises
    ------
    ValueError
        On a non-positive ``input_dim``, ``lengthscale`` or ``outputscale``.
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
        d = int(input_dim)
        if d < 1:
            raise ValueError(f"input_dim: expected a positive integer, got {input_dim}")
        super().__init__(ard_num_dims=d, batch_shape=batch_shape or torch.Size([]), **kwargs)
        _register_positive(self, "outputscale")
        ls = check_array(lengthscale, "lengthscale")
        if ls.shape not in ((), (1,), (d,)) or np.any(ls <= 0):
            raise ValueError(f"lengthscale: expected a scalar or shape ({d},) > 0, got {ls}")
        check_positive(outputscale, "outputscale")
        ls = torch.as_tensor(np.broadcast_to(ls, (d,)).copy())
        self.lengthscale = ls.expand(*self.batch_shape, 1, d).clone()
        self.outputscale = torch.full(self.batch_shape, float(outputscale), dtype=torch.float64)

    outputscale = _positive("outputscale")

    def forward(self, x1, x2, diag: bool = False, **params):
        return se_kernel(x1, x2, self.lengthscale, self.outputscale, diag=diag)


class Linear(gpytorch.kernels.Kernel):
    """Linear kernel σ² xᵀx' + c as a GPyTorch kernel (σ² raw behind a positivity constraint, the
    ``bias`` c ≥ 0 fixed)."""

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
        _register_positive(self, "variance")
        self.variance = torch.full(self.batch_shape, float(variance), dtype=torch.float64)
        self.bias = float(bias)

    variance = _positive("variance")

    def forward(self, x1, x2, diag: bool = False, **params):
        return linear_kernel(x1, x2, self.variance, self.bias, diag=diag)


def gram(kernel: gpytorch.kernels.Kernel, X, Z=None) -> np.ndarray:
    """``kernel`` evaluated on numpy inputs X (n, d) and Z (m, d) (default X) in float64: (n, m)."""
    x = check_array(X, "X", ndim=2)
    d = getattr(kernel, "ard_num_dims", None)
    if d is not None and x.shape[1] != d:
        raise ValueError(f"X: expected {d} columns like the kernel, got shape {x.shape}")
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
