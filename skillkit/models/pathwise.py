"""Pathwise GP trajectory sampling: one posterior function per trajectory (Wilson et al. 2020).

The thesis's sampler (Sec. 4.2.1, :func:`~skillkit.models.sampling.sample_trajectories`) draws
every transition independently from the one-step predictive p(x_{t+1} | x_t, u_t): a
trajectory that revisits a state gets a fresh draw of the model there. The pathwise
alternative draws one function g ~ GP posterior per trajectory and follows it,

.. math:: x_{t+1} = g(x_t, u_t) + \\varepsilon_t, \\qquad
          \\varepsilon_t \\sim \\mathcal N(0, \\sigma_\\varepsilon^2),

so the model's uncertainty is temporally consistent (the same function all along the
trajectory). Each g is "prior function plus data update" (Matheron's rule; Wilson, Borovitskiy,
Terenin, Mostowski & Deisenroth 2020, *Efficiently sampling functions from Gaussian process
posteriors*, Eq. 6 / Sec. 4), per output a:

.. math:: g(x) = \\tilde f(x) + k(x)^\\top \\big(\\beta - iK\\, \\tilde f(Z) - \\xi\\big),
          \\qquad \\xi \\sim \\mathcal N(0, C), \\quad C = iK - iK\\, K_{ZZ}\\, iK,

with Z, β, iK the :class:`~skillkit.models.gp.GPPredictor`'s support points, mean weights and
variance matrix, K_ZZ the noise-free kernel matrix of Z and the prior draw f̃ a random Fourier
feature expansion of the SE kernel (Rahimi & Recht 2007),

.. math:: \\tilde f(x) = \\sqrt{2\\sigma_f^2 / F}\\, \\sum_{j=1}^F \\theta_j
          \\cos(\\omega_j^\\top x + b_j), \\quad \\omega_j \\sim \\mathcal N(0, W^{-1}),\\;
          b_j \\sim U[0, 2\\pi),\\; \\theta_j \\sim \\mathcal N(0, 1).

With C as above the covariance of g is k(x, x′) − k(x)ᵀ iK k(x′), the predictor's posterior
covariance (:meth:`~skillkit.models.gp.GPPredictor.latent_covariance`), so one-step marginals
equal the per-step sampler's (Eqs 2.26–2.27). Exact GP: iK = (K + σ_ε²I)⁻¹, C = σ_ε² iK²
(Wilson et al.'s exact update). FITC / VFE (iK = K_mm⁻¹ − Σ): C = Σ − Σ K_mm Σ, their sparse
update from q(u) = N(K_mm β, K_mm Σ K_mm); g is then a draw of the sparse model's *predictive*
process (DTC / VFE form, no FITC diagonal correction at new inputs).

* **Features.** By default every function draws its own ω, b, θ, ξ: over trajectories the
  prior covariance is exactly the SE kernel (each f̃ has excess kurtosis O(1/F), means and
  covariances are unbiased). A shared basis (:class:`PathwiseBasis` ``shared_seed``) is
  cheaper but biases every covariance by O(1/√F).
* **Randomness.** Function i depends only on its seed ``seeds[i]``, not on the chunk size.
* **Precision.** The set-up (K_ZZ, C and its square root, f̃(Z), the update vector) is done
  in float64 and cast once; evaluation runs in the predictor's dtype via
  :meth:`~skillkit.models.gp.GPPredictor.kernel_vectors`.
* **Cost** (:func:`pathwise_flops_per_step`). Per step and output 2Md + 4M + 2M + 2Fd + 4F
  (no M² term); set-up per function 2MFd + 2M² + MF. Fresh features are memory-bound (each
  function reads its own (d × E·F) frequencies) and no faster than the per-step sampler; a
  shared basis is faster. Timings: ``benchmarks/bench_sampler.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from skillkit._validation import as_generator, check_count
from skillkit.models.gp import GPPredictor, Moments, flush_tiny
from skillkit.models.kernels import se_kernel

__all__ = ["PathwiseBasis", "PathwiseFunctions", "draw_functions", "pathwise_flops_per_step"]


@dataclass(frozen=True)
class PathwiseFunctions:
    """n posterior function draws of a GP predictor, row i of a query batch evaluated by draw i.

    Implements the predictor interface the forward model needs (``moments``), so a
    :class:`~skillkit.models.gp.ForwardModel` with these functions as its predictor adds its
    linear mean, Δx target and standardisation unchanged.

    Attributes
    ----------
    predictor : GPPredictor
        The GP the functions are drawn from (evaluation dtype and device).
    frequencies : Tensor, shape (n, d, E·F) or (1, d, E·F)
        ω_j of every function and output (output-major: column a·F + j); one leading entry
        when all functions share one basis.
    phases : Tensor, shape (n, E, F) or (1, E, F)
        b_j.
    amplitudes : Tensor, shape (n, E, F)
        √(2σ_f²/F) θ_j.
    update : Tensor, shape (E, n, M)
        β − iK f̃(Z) − ξ per output and function.
    """

    predictor: GPPredictor
    frequencies: torch.Tensor
    phases: torch.Tensor
    amplitudes: torch.Tensor
    update: torch.Tensor

    def __len__(self) -> int:
        return int(self.amplitudes.shape[0])

    def latent(self, x: torch.Tensor) -> torch.Tensor:
        """g_i(x_i), standardised units: Tensor (n, E), row i by function i (x of shape (n, d))."""
        n, E, F = self.amplitudes.shape
        if self.frequencies.shape[0] == 1:  # one basis shared by all functions
            proj = (x @ self.frequencies[0]).view(n, E, F)
        else:  # a row vector times a (d × E·F) matrix per function
            proj = torch.bmm(x.unsqueeze(1), self.frequencies).view(n, E, F)
        prior = (proj.add_(self.phases).cos_() * self.amplitudes).sum(-1)  # (n, E)
        k = self.predictor.kernel_vectors(x)  # (E, n, M)
        return prior + (k * self.update).sum(-1).T

    def moments(self, x: torch.Tensor, include_noise: bool = True) -> Moments:
        """The functions' values (as ``mean``) and the observation noise σ_ε² (as ``var``).

        Parameters
        ----------
        x : Tensor, shape (n, d)
            One query per function (not validated: hot path).
        include_noise : bool
            ``var`` = σ_ε² (a noisy transition) or 0 (the latent function).

        Returns
        -------
        Moments
            ``mean`` = y_mean + y_scale · g(x) and ``var`` of shape (n, E), raw target units.
        """
        p = self.predictor
        g = self.latent(x)
        mean = p.y_mean + p.y_scale * g
        noise = p.noise if include_noise else torch.zeros_like(p.noise)
        var = (p.y_scale**2 * noise).expand_as(mean)
        zero = torch.zeros((), dtype=x.dtype, device=x.device)
        return Moments(mean, var, torch.zeros((), dtype=torch.long, device=x.device), zero)


class PathwiseBasis:
    """The step-invariant part of pathwise sampling for one predictor; draws functions by seed.

    Parameters
    ----------
    predictor : GPPredictor
        The trained GP (any dtype; the set-up is done in float64 from its fields).
    n_features : int
        F, random Fourier features per function and output.
    dtype : torch.dtype, optional
        Evaluation dtype (default: the predictor's).
    shared_seed : int, optional
        None (default): every function draws its own features ω, b (unbiased covariances).
        An int: one feature basis, drawn from this seed, shared by all functions (only θ and
        ξ differ): cheaper, but every function then has the covariance φ(x)ᵀφ(x′) of the
        same F features, off the SE kernel by O(σ_f²/√F) (about 1/√(2F) relative in the
        prior variance), a bias that does not average out over trajectories.

    Attributes
    ----------
    psd_clamp : float
        The most negative eigenvalue of C relative to its largest, set to 0 (round-off; 0.0 if
        none).
    """

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
        if not isinstance(predictor, GPPredictor):
            raise ValueError(f"predictor: expected a GPPredictor, got {type(predictor).__name__}")
        self.n_features = int(n_features)
        self.dtype = predictor.dtype if dtype is None else dtype
        hi = predictor.to(dtype=torch.float64)
        self.setup = hi
        self.predictor = predictor.to(dtype=self.dtype)
        Z, ls, os = hi.support, hi.lengthscale[:, None, :], hi.outputscale
        Kzz = se_kernel(Z, Z, ls, os)
        C = hi.iK - hi.iK @ Kzz @ hi.iK
        lam, U = torch.linalg.eigh(0.5 * (C + C.transpose(-1, -2)))
        top = lam.abs().amax(-1, keepdim=True).clamp_min(torch.finfo(lam.dtype).tiny)
        self.psd_clamp = float((lam / top).min().clamp_max(0.0))
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
        """Functions g_i, one per seed (function i depends on ``seeds[i]`` only).

        Parameters
        ----------
        seeds : sequence of int
            One seed per function.
        max_setup_bytes : int
            Bound on the (E, M, r·F) work array of f̃(Z) (functions are set up r at a time).

        Returns
        -------
        PathwiseFunctions
        """
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
        """ω = ε / w ~ N(0, diag(1/w²)) of shape (r, E, F, d) and b = 2π U of shape (r, E, F)."""
        return normals / self.setup.lengthscale[None, :, None, :], 2 * math.pi * uniforms

    def _cosines(self, omega: torch.Tensor, phase: torch.Tensor) -> torch.Tensor:
        """cos(ωᵀz + b) at the support points z for r feature sets: Tensor (E, M, r, F)."""
        r, E, F, d = omega.shape
        M = self.setup.n_support
        arg = torch.bmm(self.setup.support, omega.permute(1, 3, 0, 2).reshape(E, d, r * F))
        arg = arg.view(E, M, r, F)
        return arg.add_(phase.transpose(0, 1)[:, None]).cos_()


def draw_functions(
    predictor: GPPredictor,
    n: int,
    n_features: int = 256,
    rng=None,
    *,
    dtype: torch.dtype | None = None,
) -> PathwiseFunctions:
    """Draw n functions from a GP predictor's posterior (pathwise: RFF prior + exact update).

    Parameters
    ----------
    predictor : GPPredictor
    n : int
        Number of functions.
    n_features : int
        F, random Fourier features per function and output.
    rng : Generator, int, SeedSequence or None
        Randomness (n seeds are drawn from it).
    dtype : torch.dtype, optional
        Evaluation dtype (default: the predictor's).

    Returns
    -------
    PathwiseFunctions
        Evaluate with ``functions.moments(x)`` or ``functions.latent(x)``, x of shape (n, d).
    """
    n = check_count(n, "n")
    seeds = as_generator(rng).integers(2**63 - 1, size=n)
    return PathwiseBasis(predictor, n_features, dtype).draw(seeds)


def pathwise_flops_per_step(
    output_dim: int, n_support: int, input_dim: int, n_features: int
) -> int:
    """Floating-point operations of one pathwise transition of one trajectory.

    Per output: the kernel vector as in
    :func:`~skillkit.models.sampling.sampler_flops_per_step` (2Md + 3M + M), the update
    kᵀv (2M), the feature projections ωᵀx (2Fd), phase, cosine (counted 1), amplitude and
    sum (4F).
    """
    E, M, d, F = int(output_dim), int(n_support), int(input_dim), int(n_features)
    return E * (2 * M * d + 3 * M + M + 2 * M + 2 * F * d + 4 * F)
