"""Pathwise GP trajectory sampling: one posterior function per trajectory (Wilson et al. 2020).

Each trajectory follows one g ~ GP posterior, x_{t+1} = g(x_t, u_t) + ε_t, drawn by
Matheron's rule (Wilson et al. 2020, Eq. 6):

.. math:: g(x) = \\tilde f(x) + k(x)^\\top \\big(\\beta - iK\\, \\tilde f(Z) - \\xi\\big),
          \\qquad \\xi \\sim \\mathcal N(0, iK - iK\\, K_{ZZ}\\, iK),

with f̃ a random Fourier feature prior draw (Rahimi & Recht 2007),
f̃(x) = √(2σ_f²/F) Σ_j θ_j cos(ω_jᵀx + b_j). One-step marginals equal the per-step
sampler's (Eqs 2.26–2.27)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from skillkit._validation import check_type
from skillkit.models.gp import GPPredictor, Moments, flush_tiny
from skillkit.models.kernels import se_kernel

__all__ = ["PathwiseBasis", "PathwiseFunctions", "pathwise_flops_per_step"]


@dataclass(frozen=True)
class PathwiseFunctions:
    """n posterior function draws of a GP predictor; row i of a query batch is evaluated by draw i.

    Has the predictor's ``moments``, so it can serve a
    :class:`~skillkit.models.gp.ForwardModel`. ``frequencies`` (n or 1, d, E·F), ``phases``
    (n or 1, E, F) and ``amplitudes`` √(2σ_f²/F) θ_j (n, E, F) define f̃; ``update`` (E, n, M)
    is β − iK f̃(Z) − ξ."""

    predictor: GPPredictor
    frequencies: torch.Tensor
    phases: torch.Tensor
    amplitudes: torch.Tensor
    update: torch.Tensor

    def latent(self, x: torch.Tensor) -> torch.Tensor:
        """g_i(x_i) in standardised units, Tensor (n, E), for x (n, d)."""
        n, E, F = self.amplitudes.shape
        if self.frequencies.shape[0] == 1:  # one basis shared by all functions
            proj = (x @ self.frequencies[0]).view(n, E, F)
        else:  # a row vector times a (d × E·F) matrix per function
            proj = torch.bmm(x.unsqueeze(1), self.frequencies).view(n, E, F)
        prior = (proj.add_(self.phases).cos_() * self.amplitudes).sum(-1)  # (n, E)
        k = self.predictor.kernel_vectors(x)  # (E, n, M)
        return prior + (k * self.update).sum(-1).T

    def moments(self, x: torch.Tensor, include_noise: bool = True) -> Moments:
        """The functions' values at x (n, d) as ``mean`` and σ_ε² (or 0 without ``include_noise``)
        as ``var``: :class:`Moments` (n, E), raw units."""
        p = self.predictor
        g = self.latent(x)
        mean = p.y_mean + p.y_scale * g
        noise = p.noise if include_noise else torch.zeros_like(p.noise)
        return Moments.exact(mean, (p.y_scale**2 * noise).expand_as(mean))


class PathwiseBasis:
    """The step-invariant part of pathwise sampling for one predictor; draws functions by seed.

    ``n_features`` F per function and output; ``shared_seed`` gives all functions one basis
    (cheaper, but covariances are off by O(σ_f²/√F))."""

    def __init__(
        self,
        predictor: GPPredictor,
        n_features: int,
        dtype: torch.dtype | None = None,
        *,
        shared_seed: int | None = None,
    ):
        if isinstance(n_features, bool) or int(n_features) != n_features or n_features < 1:
            raise ValueError(f"n_features: expected a positive integer, got {n_features!r}")
        check_type(predictor, GPPredictor, "predictor", "a GPPredictor")
        self.n_features = int(n_features)
        self.dtype = predictor.dtype if dtype is None else dtype
        hi = predictor.to(dtype=torch.float64)
        self.setup = hi
        self.predictor = predictor.to(dtype=self.dtype)
        Z, ls, os = hi.support, hi.lengthscale[:, None, :], hi.outputscale
        Kzz = se_kernel(Z, Z, ls, os)
        C = hi.iK - hi.iK @ Kzz @ hi.iK
        lam, U = torch.linalg.eigh(0.5 * (C + C.transpose(-1, -2)))
        self.noise_factor = U * lam.clamp_min(0.0).sqrt()[..., None, :]  # (E, M, M): ξ = U √λ ε
        self._shared = None
        if shared_seed is not None:
            gen = torch.Generator(device=hi.device).manual_seed(int(shared_seed))
            E, M, d = hi.support.shape
            F, kw = self.n_features, {"dtype": torch.float64, "device": hi.device}
            omega, phase = self._features(
                torch.randn((1, E, F, d), generator=gen, **kw),
                torch.rand((1, E, F), generator=gen, **kw),
            )
            self._shared = (omega, phase, self._cosines(omega, phase)[:, :, 0])

    def __repr__(self) -> str:
        p = self.predictor
        return (
            f"PathwiseBasis(outputs={p.output_dim}, support={p.n_support}, inputs={p.input_dim}, "
            f"n_features={self.n_features}, {self.dtype})"
        )

    def draw(self, seeds, max_setup_bytes: int = 2**25) -> PathwiseFunctions:
        """Functions g_i, one per seed; ``max_setup_bytes`` bounds the f̃(Z) work array."""
        hi = self.setup
        E, M, d = hi.support.shape
        F, dev, f64 = self.n_features, hi.device, torch.float64
        gen = torch.Generator(device=dev)
        thetas, xis, omegas, phases = [], [], [], []
        for s in seeds:
            gen.manual_seed(int(s))
            thetas.append(torch.randn((E, F), generator=gen, dtype=f64, device=dev))
            xis.append(torch.randn((E, M), generator=gen, dtype=f64, device=dev))
            if self._shared is None:
                omegas.append(torch.randn((E, F, d), generator=gen, dtype=f64, device=dev))
                phases.append(torch.rand((E, F), generator=gen, dtype=f64, device=dev))
        n = len(thetas)
        amp = torch.sqrt(2 * hi.outputscale / F)[None, :, None] * torch.stack(thetas)  # (n, E, F)
        if self._shared is not None:
            omega, phase, phi_z = self._shared
            prior_z = torch.bmm(phi_z, amp.permute(1, 2, 0))  # (E, M, n)
        else:
            omega, phase = self._features(torch.stack(omegas), torch.stack(phases))
            rows = max(1, int(max_setup_bytes // max(E * M * F * 8, 1)))
            prior_z = torch.empty((E, M, n), dtype=f64, device=dev)
            for lo in range(0, n, rows):
                sl = slice(lo, min(lo + rows, n))
                phi = self._cosines(omega[sl], phase[sl])  # (E, M, r, F)
                prior_z[:, :, sl] = (phi * amp[sl].transpose(0, 1)[:, None]).sum(-1)
        # v = β − iK f̃(Z) − ξ with ξ ~ N(0, C): (E, n, M) (iK is symmetric)
        update = hi.beta[:, None, :] - torch.bmm(prior_z.transpose(1, 2), hi.iK)
        update -= torch.bmm(torch.stack(xis).transpose(0, 1), self.noise_factor.transpose(-1, -2))
        dt = self.dtype
        return PathwiseFunctions(
            self.predictor,
            omega.reshape(omega.shape[0], E * F, d).transpose(1, 2).to(dt).contiguous(),
            phase.to(dt).contiguous(),
            amp.to(dt).contiguous(),
            flush_tiny(update.to(dt).contiguous()),  # float32: no denormal products k·v
        )

    def _features(self, normals: torch.Tensor, uniforms: torch.Tensor):
        """ω = ε / w (r, E, F, d) and b = 2π U (r, E, F)."""
        return normals / self.setup.lengthscale[None, :, None, :], 2 * math.pi * uniforms

    def _cosines(self, omega: torch.Tensor, phase: torch.Tensor) -> torch.Tensor:
        """cos(ωᵀz + b) at the support points: Tensor (E, M, r, F)."""
        r, E, F, d = omega.shape
        M = self.setup.n_support
        arg = torch.bmm(self.setup.support, omega.permute(1, 3, 0, 2).reshape(E, d, r * F))
        arg = arg.view(E, M, r, F)
        return arg.add_(phase.transpose(0, 1)[:, None]).cos_()


def pathwise_flops_per_step(
    output_dim: int, n_support: int, input_dim: int, n_features: int
) -> int:
    """Floating-point operations of one pathwise transition of one trajectory."""
    E, M, d, F = int(output_dim), int(n_support), int(input_dim), int(n_features)
    return E * (2 * M * d + 3 * M + M + 2 * M + 2 * F * d + 4 * F)
