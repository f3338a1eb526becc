"""Deterministic long-term prediction: exact moment matching and linearisation (Sec. 2.1.2).

For an SE-kernel GP and z ~ N(m, S), :func:`moment_match` gives the exact moments of
y = f(z) + ε (PILCO; Deisenroth 2010, Sec. 2.3; Figs 2.6–2.7). Per output a, with
Λ_a = diag(w_a²) and ν_i = z_i − m:

.. math::
    q_{ai} &= \\sigma_{f,a}^2 |S\\Lambda_a^{-1} + I|^{-1/2}
              \\exp\\big(-\\tfrac12 \\nu_i^\\top (S + \\Lambda_a)^{-1} \\nu_i\\big), \\qquad
    \\mathbb{E}[y_a] = \\beta_a^\\top q_a, \\\\
    Q^{ab}_{ij} &= k_a(z_i, m) k_b(z_j, m) |R|^{-1/2}
                \\exp\\big(\\tfrac12 \\zeta_{ij}^\\top R^{-1} S \\zeta_{ij}\\big), \\quad
                R = S(\\Lambda_a^{-1} + \\Lambda_b^{-1}) + I, \\;
                \\zeta_{ij} = \\Lambda_a^{-1}\\nu_i + \\Lambda_b^{-1}\\nu_j, \\\\
    \\mathrm{cov}(y_a, y_b) &= \\beta_a^\\top Q^{ab} \\beta_b - \\mathbb{E}[y_a]\\mathbb{E}[y_b]
        + \\delta_{ab}\\big(\\sigma_{f,a}^2 - \\mathrm{tr}(iK_a Q^{aa})
                            + \\sigma_{\\varepsilon,a}^2\\big).

Each step bounds its own float64 round-off (:class:`RoundoffEstimate`)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.weak import WeakIdKeyDictionary

from skillkit._repr import span, vector
from skillkit._validation import check_array, check_count
from skillkit.models.gp import (
    DTYPE,
    VARIANCE_TOL,
    ForwardModel,
    GPNumericalWarning,
    GPPredictor,
    warn_if_clamped,
)

__all__ = [
    "ROUNDOFF_TOL",
    "GaussianPrediction",
    "MomentPrecisionError",
    "RoundoffEstimate",
    "check_roundoff",
    "linearize",
    "moment_match",
    "moment_matching_flops_per_step",
    "propagate",
    "with_linear_mean",
]

#: Log-domain exponents are raised to at least this before ``exp`` (no denormals).
LOG_FLOOR = -600.0

#: Entries of one cache-sized block of Q matrices in :func:`_second_moments` (1 MiB).
BLOCK_ENTRIES = 1 << 17

#: Unit round-off of float64, 2^-53.
UNIT_ROUNDOFF = float(torch.finfo(DTYPE).eps) / 2

#: Moment matching warns (``strict``: raises) when its round-off bound exceeds this.
ROUNDOFF_TOL = 1e-4


class MomentPrecisionError(RuntimeError):
    """Moment matching's round-off bound exceeded :data:`ROUNDOFF_TOL` (``strict=True``)."""


@dataclass(frozen=True)
class RoundoffEstimate:
    """A bound on the float64 round-off of one moment-matching step (predictor and input exact):
    the largest ``relative_error`` of cov(y), E[y] or cov(z, y) in predictive standard
    deviations (≥ 1: no correct digit), ``where`` it is, the ``cancellation`` ratio
    Σ_ij |β_ai| Q^{ab}_ij |β_bj| / √(V_aa V_bb) and the largest ``condition`` bound."""

    relative_error: float
    where: str
    cancellation: float
    condition: float

    def describe(self) -> str:
        return (
            f"the {self.where} may have lost up to {self.relative_error:.1e} relative precision "
            f"to float64 round-off (estimated bound); the terms of the second moments "
            f"beta_a' Q beta_b are up to {self.cancellation:.1e} times the predictive "
            f"covariance (cancellation: large |beta|, e.g. a GP near its linear limit with "
            f"sigma_f/sigma_eps and length-scales >> 1), condition of R and S/Lambda + I up to "
            f"{self.condition:.1e}"
        )

    @staticmethod
    def worst(estimates) -> RoundoffEstimate | None:
        """The estimate with the largest error (None if none; NaN skipped)."""
        estimates = [e for e in estimates if e is not None and not np.isnan(e.relative_error)]
        return max(estimates, key=lambda e: e.relative_error) if estimates else None


_IK_NORMS = WeakIdKeyDictionary()


@dataclass
class GaussianPrediction:
    """A Gaussian approximation of p(y) for z ~ N(m, S) in raw units: ``mean`` (E,), ``cov``
    (E, E), ``input_output_cov`` cov(z, y) (D, E) and the ``roundoff`` bound (None from
    :func:`linearize`)."""

    mean: torch.Tensor
    cov: torch.Tensor
    input_output_cov: torch.Tensor
    roundoff: RoundoffEstimate | None = None

    def __repr__(self) -> str:
        std = torch.diagonal(self.cov).clamp_min(0.0).sqrt()
        return (
            f"GaussianPrediction(outputs={self.mean.shape[0]}, inputs="
            f"{self.input_output_cov.shape[0]}, mean={vector(self.mean)}, std={span(std)})"
        )


def _check_gaussian(mean, cov, dim: int, name: str = "mean") -> tuple[torch.Tensor, torch.Tensor]:
    if not isinstance(mean, torch.Tensor):
        mean = torch.as_tensor(check_array(mean, name, shape=(dim,)))
    if not isinstance(cov, torch.Tensor):
        cov = torch.as_tensor(check_array(cov, "cov", shape=(dim, dim)))
    m, S = mean.to(DTYPE), cov.to(DTYPE)
    if tuple(m.shape) != (dim,):
        raise ValueError(f"{name}: expected shape ({dim},), got {tuple(m.shape)}")
    if tuple(S.shape) != (dim, dim):
        raise ValueError(f"cov: expected shape ({dim}, {dim}), got {tuple(S.shape)}")
    if not (torch.isfinite(m).all() and torch.isfinite(S).all()):
        raise ValueError(f"{name}, cov: contain non-finite values")
    scale = float(S.abs().max()) if S.numel() else 0.0
    if float((S - S.T).abs().max()) > 1e-9 * (1.0 + scale):
        raise ValueError("cov: expected a symmetric matrix")
    if dim and float(torch.linalg.eigvalsh(S).min()) < -1e-9 * (1.0 + scale):
        raise ValueError("cov: expected a positive semi-definite matrix")
    return m, 0.5 * (S + S.T)


def moment_match(
    predictor: GPPredictor, mean, cov, include_noise: bool = True, strict: bool = False
) -> GaussianPrediction:
    """Exact mean, covariance and input–output covariance of a GP's prediction at z ~ N(m, S)
    (Sec. 2.1.2; PILCO's moment matching).

    Parameters
    ----------
    predictor : GPPredictor
        A fitted SE-kernel GP (e.g. ``ForwardModel.predictor``), E outputs on D inputs.
    mean : array_like or Tensor, shape (D,)
        m.
    cov : array_like or Tensor, shape (D, D)
        S, symmetric positive semi-definite.
    include_noise : bool, default True
        Add σ_ε² (predict y rather than f).
    strict : bool, default False
        Raise instead of warning when the round-off bound exceeds :data:`ROUNDOFF_TOL`.

    Returns
    -------
    GaussianPrediction

    Raises
    ------
    ValueError
        On bad shapes, non-finite values, or a ``cov`` that is not symmetric PSD.
    MomentPrecisionError
        With ``strict``, when the round-off bound exceeds :data:`ROUNDOFF_TOL`.
    """
    pred = predictor.to("cpu", DTYPE)
    m, S = _check_gaussian(mean, cov, pred.support.shape[-1])
    g = moment_match_step(pred, m, S, include_noise)
    check_roundoff(g.roundoff, "moment_match", strict)
    return g


def check_roundoff(estimate: RoundoffEstimate | None, where: str, strict: bool = False) -> None:
    """Warn, or with ``strict`` raise :class:`MomentPrecisionError`, above :data:`ROUNDOFF_TOL`."""
    if estimate is None or not estimate.relative_error > ROUNDOFF_TOL:
        return
    text = f"{where}: {estimate.describe()}; tolerance {ROUNDOFF_TOL:g}"
    if strict:
        raise MomentPrecisionError(text)
    warnings.warn(text, GPNumericalWarning, stacklevel=3)


def moment_match_step(
    pred: GPPredictor,
    m: torch.Tensor,
    S: torch.Tensor,
    include_noise: bool = True,
    strict: bool = False,
    roundoff: bool = True,
) -> GaussianPrediction:
    """:func:`moment_match` for a CPU float64 predictor without input checks, differentiable in
    ``m`` and ``S``; ``strict`` turns a negative latent variance into NaN, ``roundoff`` bounds
    the round-off."""
    E, M, D = pred.support.shape
    iL = 1.0 / pred.lengthscale  # (E, D)
    sf2 = pred.outputscale
    eye = torch.eye(D, dtype=DTYPE)
    nu = pred.support - m  # (E, M, D)
    nut = nu * iL[:, None, :]  # Λ^{-1/2} ν
    # Mean and input-output covariance:
    # (S + Λ_a)^{-1} = Λ_a^{-1/2} (Λ_a^{-1/2} S Λ_a^{-1/2} + I)^{-1} Λ_a^{-1/2}.
    Sa = iL[:, :, None] * S * iL[:, None, :] + eye
    Lsa = torch.linalg.cholesky(Sa)
    sol = torch.cholesky_solve(nut.transpose(-1, -2), Lsa)  # (E, D, M)
    quad = (nut * sol.transpose(-1, -2)).sum(-1)
    logdet_sa = 2.0 * torch.log(Lsa.diagonal(dim1=-2, dim2=-1)).sum(-1)
    q = sf2[:, None] * torch.exp(torch.clamp_min(-0.5 * quad - 0.5 * logdet_sa[:, None], LOG_FLOOR))
    bq = pred.beta * q
    mu = bq.sum(-1)  # (E,)
    v = (sol @ bq[..., None]).squeeze(-1)  # (E, D): S̃⁻¹ Σ β q ν̃
    io = S @ (iL * v).T  # (D, E)
    extra = None
    if roundoff:
        with torch.no_grad():  # n*_ai = ‖Λ_a^{-1/2} ν_ai‖² + ‖Λ_a^{-1/2}(|z_ai| + |m|)‖², (E, M)
            shift = (pred.support.abs() + m.abs()) * iL[:, None, :]
            magnitude = (nut * nut).sum(-1) + (shift * shift).sum(-1)
        second, latent_var, extra = _second_moments(pred, S, nut, iL, magnitude=magnitude)
    else:
        second, latent_var = _second_moments(pred, S, nut, iL)
    if strict and float((latent_var / sf2).detach().min()) < -VARIANCE_TOL:
        nan = torch.full((), float("nan"), dtype=DTYPE)
        mu, second, latent_var = mu + nan, second + nan, latent_var + nan
    else:
        warn_if_clamped("moment_match", (latent_var / sf2).detach().min())
    noise = pred.noise if include_noise else 0.0
    V = second - mu[:, None] * mu[None, :]
    V = V + torch.diag(latent_var.clamp_min(0.0) + noise)
    V = 0.5 * (V + V.T)
    s = pred.y_scale
    g = GaussianPrediction(pred.y_mean + s * mu, s[:, None] * V * s[None, :], io * s[None, :])
    if extra is None:
        return g
    bound, terms, cond_r = extra
    # The round-off bound: exponent errors in the worst case, long sums by σ_n u Σ|terms|
    # (Higham & Mary, SIAM J. Sci. Comput. 41, 2019).
    with torch.no_grad():
        u, c = UNIT_ROUNDOFF, D + 4
        cond_a = 1.0 + torch.linalg.matrix_norm(Sa - eye)  # ≥ cond(S̃_a), (E,)
        alpha = torch.log(sf2).abs() + logdet_sa + D * cond_a
        delta = c * (alpha[:, None] + (1.0 + cond_a)[:, None] * magnitude)  # (E, M), units of u
        w = pred.beta.abs() * q  # (E, M)
        err_mu = u * (w * (delta + _sum_error(M))).sum(-1)  # (E,)
        err_v = u * (sol.abs() @ (w * (delta + _sum_error(M)))[..., None]).squeeze(-1)
        err_v = err_v + u * c * cond_a[:, None] * (w * (2.0 * magnitude).sqrt()).sum(-1)[:, None]
        err_io = S.abs() @ (iL * (err_v + u * (D + 2) * v.abs())).T  # (D, E)
        amu = mu.abs()
        err_cov = (
            bound
            + amu[None, :] * err_mu[:, None]
            + amu[:, None] * err_mu[None, :]
            + 3 * u * (second.abs() + amu[:, None] * amu[None, :])
            + torch.diag(2 * u * (latent_var.abs() + noise))
        )
        # V_aa at least its own error bound: a variance with no correct digit gives errors ≥ 1.
        tiny = torch.finfo(DTYPE).tiny
        sd = torch.maximum(V.diagonal(), err_cov.diagonal()).clamp_min(tiny).sqrt()
        scale = sd[:, None] * sd[None, :]
        sd_in = S.diagonal().clamp_min(0.0).sqrt()[:, None] * sd[None, :]
        rel = {
            "covariance": float((err_cov / scale).max()),
            "mean": float((err_mu / sd).max()),
            "input-output covariance": float(
                torch.where(sd_in > 0, err_io / sd_in.clamp_min(tiny), 0.0).max()
            ),
        }
        where = max(rel, key=rel.get)
        cancellation = float((terms / scale).max())
        condition = max(cond_r, float(cond_a.max()))
        g.roundoff = RoundoffEstimate(rel[where], where, cancellation, condition)
    return g


def _sum_error(n: int) -> float:
    """σ_n = 2 + 3√n, the probabilistic error factor of a sum of n terms."""
    return 2.0 + 3.0 * float(np.sqrt(n))


def _pair_indices(E: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Output pairs a ≤ b: the E diagonal pairs first, then the rest row by row."""
    ia, ib = torch.triu_indices(E, E, offset=1)
    diag = torch.arange(E)
    return torch.cat([diag, ia]), torch.cat([diag, ib])


def _second_moments(
    pred: GPPredictor,
    S: torch.Tensor,
    nut: torch.Tensor,
    iL: torch.Tensor,
    block: int = BLOCK_ENTRIES,
    magnitude: torch.Tensor | None = None,
) -> tuple[torch.Tensor, ...]:
    """β_aᵀ Q^{ab} β_b (a ≤ b) and σ_{f,a}² − tr(iK_a Q^{aa}), log Q^{ab}_{ij} = c_ai + c_bj +
    (Tζ_ai)ᵀζ_bj as [Tζ_a, c_a, 1][ζ_b, 1, c_b]ᵀ in blocks; ``magnitude``: a round-off bound."""
    E, M, D = nut.shape
    ia, ib = _pair_indices(E)
    P = len(ia)
    eye = torch.eye(D, dtype=DTYPE)
    logk = torch.log(pred.outputscale)[:, None] - 0.5 * (nut * nut).sum(-1)  # (E, M)
    zeta = nut * iL[:, None, :]  # Λ^{-1} ν, (E, M, D)
    # R = S(Λ_a⁻¹ + Λ_b⁻¹) + I is similar to P + I with P = Δ^{1/2} S Δ^{1/2}, Δ = Λ_a⁻¹ + Λ_b⁻¹.
    sd = (iL[ia] ** 2 + iL[ib] ** 2).sqrt()  # (P, D)
    Pm = sd[:, :, None] * S * sd[:, None, :]
    LR = torch.linalg.cholesky(Pm + eye)
    T = torch.cholesky_solve(Pm, LR) / (sd[:, :, None] * sd[:, None, :])  # R⁻¹ S
    T = 0.5 * (T + T.transpose(-1, -2))
    logdet_r = 2.0 * torch.log(LR.diagonal(dim1=-2, dim2=-1)).sum(-1)  # (P,)
    za, zb = zeta[ia], zeta[ib]  # (P, M, D)
    Ta = za @ T
    ca = logk[ia] + 0.5 * torch.einsum("pmd,pmd->pm", Ta, za) - 0.5 * logdet_r[:, None]
    cb = logk[ib] + 0.5 * torch.einsum("pmd,pmd->pm", zb @ T, zb)
    ones = torch.ones((P, M, 1), dtype=DTYPE)
    left = torch.cat([Ta, ca[..., None], ones], dim=-1)  # (P, M, D + 2)
    right = torch.cat([zb, ones, cb[..., None]], dim=-1).transpose(-1, -2)  # (P, D + 2, M)
    # Pairs whose exponents might fall below the floor are clamped, the others skip that pass:
    # log Q ≥ min c_a + min c_b − ‖T‖_F max‖ζ_a‖ max‖ζ_b‖ (Cauchy–Schwarz, ‖T‖₂ ≤ ‖T‖_F).
    with torch.no_grad():
        znorm = torch.linalg.vector_norm(zeta, dim=-1).amax(-1)  # (E,)
        tnorm = torch.linalg.matrix_norm(T)  # (P,)
        lower = ca.amin(-1) + cb.amin(-1) - tnorm * znorm[ia] * znorm[ib]
    clamp = (lower < LOG_FLOOR).tolist()
    iK = pred.iK.reshape(E, 1, M * M)
    in_place = not (torch.is_grad_enabled() and (left.requires_grad or right.requires_grad))
    rows = max(1, min(M, block // M))
    group = max(1, block // (M * M)) if rows == M else 1
    buffer = torch.empty(group * rows * M, dtype=DTYPE) if in_place else None
    beta_b = pred.beta[ib][..., None]  # (P, M, 1)
    q_beta, traces = [], []  # Q^{ab} β_b by blocks; tr(iK_a Q^{aa}) by blocks
    for p0 in range(0, P, group):
        p1 = min(P, p0 + group)
        n_diag = max(0, min(p1, E) - p0)  # pairs p < E are (p, p)
        floor = any(clamp[p0:p1])
        lhs, rhs, vec, iK_g = left[p0:p1], right[p0:p1], beta_b[p0:p1], iK[p0 : p0 + n_diag]
        for r0 in range(0, M, rows):
            r1 = min(M, r0 + rows)
            if buffer is not None:
                out = buffer[: (p1 - p0) * (r1 - r0) * M].view(p1 - p0, r1 - r0, M)
                Q = torch.bmm(lhs[:, r0:r1], rhs, out=out)
                Q = (Q.clamp_min_(LOG_FLOOR) if floor else Q).exp_()
            else:
                Q = torch.bmm(lhs[:, r0:r1], rhs)
                Q = torch.exp(torch.clamp_min(Q, LOG_FLOOR) if floor else Q)
            q_beta.append(torch.bmm(Q, vec))  # (g, r, 1)
            if n_diag:
                flat = Q[:n_diag].reshape(n_diag, -1, 1)
                traces.append(torch.bmm(iK_g[..., r0 * M : r1 * M], flat))
    if rows == M:
        qb = torch.cat(q_beta, dim=0)[..., 0]  # (P, M)
        trace = torch.cat(traces, dim=0)[:, 0, 0]
    else:
        n_blocks = len(q_beta) // P
        qb = torch.cat(q_beta, dim=1).reshape(P, M)
        trace = torch.cat(traces, dim=1).reshape(E, n_blocks).sum(-1)
    s = (pred.beta[ia] * qb).sum(-1)
    second = torch.zeros((E, E), dtype=DTYPE).index_put((ia, ib), s).index_put((ib, ia), s)
    if magnitude is None:
        return second, pred.outputscale - trace
    # Round-off by Cauchy–Schwarz on Q from its diagonal d: absolute bound on second −
    # diag(latent_var), Σ|β_a| Q |β_b| (+ Σ|iK_a| Q^{aa} on the diagonal), max bound on cond(R).
    with torch.no_grad():
        d = torch.exp(0.5 * torch.clamp_min(ca[:E] + cb[:E] + (Ta[:E] * za[:E]).sum(-1), LOG_FLOOR))
        u = UNIT_ROUNDOFF
        bd = pred.beta.abs() * d
        s0, s1 = bd.sum(-1), (bd * magnitude).sum(-1)  # (E,)
        terms0 = s0[ia] * s0[ib]
        terms1 = s1[ia] * s0[ib] + s0[ia] * s1[ib]
        cond_r = 1.0 + torch.linalg.matrix_norm(Pm)  # ≥ cond(R) = cond(P + I)
        log_sf2 = torch.log(pred.outputscale).abs()
        alpha = log_sf2[ia] + log_sf2[ib] + logdet_r + D * cond_r
        c = D + 4  # exponent error per unit of (α, n*): c α_ab + c (1 + κ_R)(n*_ai + n*_bj)
        pair = u * ((c * alpha + 2 * _sum_error(M)) * terms0 + c * (1.0 + cond_r) * terms1)
        norm_ik = _IK_NORMS.get(pred.iK)  # ‖iK_a‖_F, (E,)
        if norm_ik is None:
            norm_ik = _IK_NORMS[pred.iK] = torch.linalg.matrix_norm(pred.iK.detach())
        dn = torch.linalg.vector_norm(d, dim=-1)
        t0 = norm_ik * dn * dn
        t1 = norm_ik * dn * torch.linalg.vector_norm(d * magnitude, dim=-1)
        lat = u * (
            pred.outputscale
            + (c * alpha[:E] + _sum_error(M * M)) * t0
            + 2 * c * (1.0 + cond_r[:E]) * t1
        )
        sym = torch.zeros((E, E), dtype=DTYPE)
        bound = sym.index_put((ia, ib), pair).index_put((ib, ia), pair) + torch.diag(lat)
        terms = sym.index_put((ia, ib), terms0).index_put((ib, ia), terms0) + torch.diag(t0)
    return second, pred.outputscale - trace, (bound, terms, float(cond_r.max()))


def linearize(predictor: GPPredictor, mean, cov, include_noise: bool = True) -> GaussianPrediction:
    """First-order (Taylor) Gaussian approximation at z ~ N(m, S) (Fig. 2.6).

    J_a = Σ_i β_ai k_a(z_i, m) Λ_a⁻¹ (z_i − m); cov(y) = J S Jᵀ + diag σ²(m), cov(z, y) = S Jᵀ.
    Parameters and returns as :func:`moment_match`."""
    pred = predictor.to("cpu", DTYPE)
    E, M, D = pred.support.shape
    m, S = _check_gaussian(mean, cov, D)
    k = pred.kernel_vectors(m[None, :])[:, 0, :]  # (E, M)
    mom = pred.moments(m[None, :], include_noise)
    warn_if_clamped("linearize", mom.worst)
    J = ((pred.beta * k)[:, :, None] * (pred.support - m)).sum(1) / pred.lengthscale**2  # (E, D)
    J = pred.y_scale[:, None] * J
    V = J @ S @ J.T + torch.diag(mom.var[0])
    return GaussianPrediction(mom.mean[0], 0.5 * (V + V.T), S @ J.T)


def propagate(
    model: ForwardModel,
    mean0,
    cov0,
    horizon: int,
    gain,
    offset=None,
    method: str = "moment_matching",
    strict: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Long-term Gaussian prediction p(x_0) → … → p(x_T) with u_t = K_t x_t + k_t (Eq. 4.4).

    Parameters
    ----------
    model : ForwardModel
        A fitted GP forward model.
    mean0 : array_like or Tensor, shape (n_x,)
    cov0 : array_like or Tensor, shape (n_x, n_x)
        p(x_0) = N(mean0, cov0).
    horizon : int
        T.
    gain : array_like, shape (n_u, n_x) or (T, n_u, n_x)
        K_t, shared or per step.
    offset : array_like, shape (n_u,) or (T, n_u), optional
        k_t (default 0).
    method : {"moment_matching", "linearization"}
        :func:`moment_match` or :func:`linearize` (Fig. 2.6) per step.
    strict : bool, default False
        As :func:`moment_match`.

    Returns
    -------
    means : Tensor, shape (T + 1, n_x)
    covs : Tensor, shape (T + 1, n_x, n_x)

    Raises
    ------
    ValueError
        On bad shapes, an unknown ``method`` or a non-positive ``horizon``.
    """
    if method not in ("moment_matching", "linearization"):
        raise ValueError(f"method: expected 'moment_matching' or 'linearization', got {method!r}")
    step = moment_match if method == "moment_matching" else linearize
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon: expected a positive integer, got {horizon!r}")
    T, n_x, n_u = int(horizon), model.state_dim, model.control_dim
    m, S = _check_gaussian(mean0, cov0, n_x, "mean0")
    K = _per_step(gain, "gain", (n_u, n_x), T)
    k = (
        torch.zeros((T, n_u), dtype=DTYPE)
        if offset is None
        else _per_step(offset, "offset", (n_u,), T)
    )
    predictor = model.predictor.to("cpu", DTYPE)
    D = predictor.support.shape[-1]
    means = torch.empty((T + 1, n_x), dtype=DTYPE)
    covs = torch.empty((T + 1, n_x, n_x), dtype=DTYPE)
    means[0], covs[0] = m, S
    eye = torch.eye(n_x, dtype=DTYPE)
    worst = None
    with torch.no_grad():
        for t in range(T):
            A = torch.cat([eye, K[t]], dim=0)  # z = A x + [0; k_t]
            mz = A @ m + torch.cat([torch.zeros(n_x, dtype=DTYPE), k[t]])
            Sz = A @ S @ A.T
            if step is moment_match:  # moment_match, its bound checked once after the loop
                g = moment_match_step(predictor, *_check_gaussian(mz, 0.5 * (Sz + Sz.T), D))
                worst = RoundoffEstimate.worst([worst, g.roundoff])
            else:
                g = linearize(predictor, mz, 0.5 * (Sz + Sz.T))
            g = with_linear_mean(model, g, mz, Sz)
            if model.delta:
                cx = g.input_output_cov[:n_x]  # cov(x_t, Δ)
                m = m + g.mean
                S = S + g.cov + cx + cx.T
            else:
                m, S = g.mean, g.cov
            S = 0.5 * (S + S.T)
            means[t + 1], covs[t + 1] = m, S
    check_roundoff(worst, "propagate", strict)
    return means, covs


def with_linear_mean(
    model: ForwardModel, g: GaussianPrediction, mean: torch.Tensor, cov: torch.Tensor
) -> GaussianPrediction:
    """The prediction of y = Wᵀz + b + f(z) (``mean="linear"``) from ``g``, that of f, exactly:
    E[y] = Wᵀm + b + E[f], cov(y) = WᵀSW + cov(f) + WᵀC + CᵀW, cov(z, y) = SW + C, C = cov(z, f)."""
    if model.linear_weights is None:
        return g
    w = model.linear_weights.to("cpu", DTYPE)
    W = w[:-1]
    c = g.input_output_cov
    cov_y = W.T @ cov @ W + g.cov + W.T @ c + c.T @ W
    return GaussianPrediction(
        mean @ W + w[-1] + g.mean, 0.5 * (cov_y + cov_y.T), cov @ W + c, g.roundoff
    )


def _per_step(value, name: str, shape: tuple[int, ...], T: int) -> torch.Tensor:
    arr = check_array(value, name, ndim=(len(shape), len(shape) + 1))
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (T, *shape))
    elif arr.shape != (T, *shape):
        raise ValueError(f"{name}: expected shape {shape} or {(T, *shape)}, got {arr.shape}")
    return torch.as_tensor(np.array(arr, dtype=np.float64), dtype=DTYPE)


def moment_matching_flops_per_step(output_dim: int, n_support: int, input_dim: int) -> int:
    """Floating-point operations of one :func:`moment_match` step (``exp`` counts one) for E
    outputs, M support points and D inputs."""
    E = check_count(output_dim, "output_dim")
    M = check_count(n_support, "n_support")
    D = check_count(input_dim, "input_dim")
    P = E * (E + 1) // 2
    q_blocks = P * M * M * (2 * D + 5) + E * M * M * 2
    operands = P * (2 * 2 * M * D * D + 2 * 2 * M * D)
    mean_io = E * (2 * M * D * D + 2 * M * D + 2 * M * D)
    return q_blocks + operands + mean_io


def gaussian_kl(mean_p, cov_p, mean_q, cov_q) -> np.ndarray:
    """KL(N(m_p, S_p) || N(m_q, S_q)) = ½(tr(S_q⁻¹S_p) + (m_q − m_p)ᵀS_q⁻¹(m_q − m_p) − d
    + log|S_q| − log|S_p|) for broadcasting batches (numpy). Raises ValueError on mismatched
    shapes and ``numpy.linalg.LinAlgError`` for a finite covariance that is not positive definite.
    """
    mp, mq = np.asarray(mean_p, float), np.asarray(mean_q, float)
    Sp, Sq = np.asarray(cov_p, float), np.asarray(cov_q, float)
    if mp.ndim < 1:
        raise ValueError(f"mean_p: expected shape (..., d), got {mp.shape}")
    d = mp.shape[-1]
    if mq.ndim < 1 or mq.shape[-1] != d:
        raise ValueError(f"mean_q: expected shape (..., {d}) like mean_p, got {mq.shape}")
    for name, S in (("cov_p", Sp), ("cov_q", Sq)):
        if S.ndim < 2 or S.shape[-2:] != (d, d):
            raise ValueError(f"{name}: expected shape (..., {d}, {d}), got {S.shape}")
    try:
        np.broadcast_shapes(mp.shape[:-1], mq.shape[:-1], Sp.shape[:-2], Sq.shape[:-2])
    except ValueError:
        raise ValueError("mean_p, cov_p, mean_q, cov_q: batch shapes do not broadcast") from None
    Lq = np.linalg.cholesky(Sq)
    Lp = np.linalg.cholesky(Sp)
    A = np.linalg.solve(Lq, Lp)
    diff = np.linalg.solve(Lq, (mq - mp)[..., None])[..., 0]
    logdet = 2.0 * (
        np.log(np.diagonal(Lq, axis1=-2, axis2=-1)).sum(-1)
        - np.log(np.diagonal(Lp, axis1=-2, axis2=-1)).sum(-1)
    )
    return 0.5 * ((A**2).sum((-2, -1)) + (diff**2).sum(-1) - d + logdet)
