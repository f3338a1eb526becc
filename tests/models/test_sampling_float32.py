"""float32 sampling: the float64 path equals the plain float64 sampler (above its kernel
floor); float32 matches it within Monte Carlo error.

The fixtures sit at an offset of 20 from the origin with length-scales of order 1: there the
augmented-operand kernel exponent −½‖a‖² + a·b − ½‖b‖² cancels badly: with the exponent in
float32 the float32 path is off by 0.35 (exact GP) and 0.10 (FITC) predictive
standard deviations in the mean; with the exponent in float64 the errors are 2.7e-3 and 6.7e-5.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from _tolerances import EPS, EPS32, fp_tol

from skillkit.models.gp import (
    FLOOR_EXPONENT_FLOAT64,
    FLUSH_EXPONENT,
    ExactGP,
    ForwardModel,
    GPNumericalWarning,
)
from skillkit.models.kernels import se_kernel_from_operands, se_operands
from skillkit.models.sampling import PRECISION_TOL, sample_trajectories
from skillkit.models.sparse import FITC

OFFSET = 20.0


def _data(n: int, seed: int, noise: float, offset: float = OFFSET):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-1, 1, size=(n, 2))
    u = rng.uniform(-1, 1, size=(n, 1))
    step = 0.3 * np.stack([np.sin(3 * c[:, 1]), -np.sin(3 * c[:, 0]) + u[:, 0]], axis=1)
    x = offset + c
    return x, u, x + step + noise * rng.standard_normal((n, 2))


@pytest.fixture(scope="module", params=["exact", "fitc"])
def model(request):
    if request.param == "exact":
        gp, data = ExactGP(n_steps=25), _data(100, 0, 0.05)
    else:
        gp, data = FITC(40, n_steps=25), _data(400, 1, 0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        return ForwardModel(gp, target="delta").fit(*data, rng=0)


def _policy(t, x, pair):
    return -0.5 * (x[:, :1] - OFFSET) + 0.1 * x[:, 1:]


def _queries(n: int, spread: float, seed: int) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    z = np.hstack([OFFSET + rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 1))])
    return torch.as_tensor(z + spread * rng.standard_normal((n, 3)))


def _reference_rollout(model, x0, T: int, L: int, seed: int) -> torch.Tensor:
    """The plain float64 sampler (no kernel floor), written out operation by operation."""
    p = model.predictor
    support = se_operands(p.support, p.lengthscale[:, None, :], p.outputscale).contiguous()
    weights = torch.cat([p.var_factor.transpose(-1, -2), p.beta[..., None]], dim=-1).contiguous()
    gen = torch.Generator()
    gen.manual_seed(int(np.random.default_rng(seed).integers(2**63 - 1)))
    B, n_x = x0.shape
    eps = torch.randn((B * L, T, n_x), generator=gen, dtype=torch.float64)
    x = torch.as_tensor(x0).repeat_interleave(L, dim=0)
    pair = torch.arange(B).repeat_interleave(L)
    out = [x]
    for t in range(T):
        z = torch.cat([x, _policy(t, x, pair)], dim=-1)
        query = se_operands(z.unsqueeze(0), p.lengthscale[:, None, :])
        k = se_kernel_from_operands(query, support, torch.log(p.outputscale))
        prod = torch.bmm(k, weights)
        quad = torch.linalg.vector_norm(prod[..., :-1], dim=-1).square()
        var = (p.outputscale[:, None] - quad).clamp_min(0.0) + p.noise[:, None]
        mean = p.y_mean[:, None] + p.y_scale[:, None] * prod[..., -1]
        var = p.y_scale[:, None] ** 2 * var
        x = (x + mean.T) + var.T.sqrt() * eps[:, t]
        out.append(x)
    return torch.stack(out, dim=1).reshape(B, L, T + 1, n_x)


def test_float64_path_is_bit_identical_to_the_pre_issue_18_sampler(model):
    x0 = np.array([[OFFSET + 0.2, OFFSET - 0.3], [OFFSET + 2.5, OFFSET + 1.0]])
    res = sample_trajectories(model, x0, _policy, 6, 50, rng=7)
    ref = _reference_rollout(model, x0, 6, 50, 7)
    assert torch.equal(res.states, ref)
    assert res.precision_error == 0.0 and res.states.dtype == torch.float64


def test_float64_moments_equal_a_direct_implementation(model):
    """μ = kᵀβ, σ² = σ_f² − kᵀ iK k + σ_ε² with k from explicit differences.

    Agreement up to the round-off of the two formulas (γ_n = n·ε, first order, worst case):
    the augmented exponent −½‖a‖² + a·b − ½‖b‖² is off by ≤ γ_{2D+6} |q|·|s| (it cancels:
    |q|·|s| ~ 5e3 at the offset of 20), the explicit one by ≤ γ_{3D} ½‖(z − s)/w‖², so each
    k_i by k_i times their sum plus ε; kᵀβ adds γ_M Σ|k_i β_i|, and both variance forms
    (kᵀ iK k and ‖Rk‖²) γ_M times their absolute-value forms plus the δk terms. The bounds are
    ~1e-7 predictive standard deviations and ~6e-7 σ_f² here; seen: 5e-10 and 5e-12 (a formula
    error would be O(1)).
    """
    p = model.predictor
    M, D = p.support.shape[1:]
    z = _queries(200, 1.0, 3)
    diff = (z[None, :, None, :] - p.support[:, None, :, :]) / p.lengthscale[:, None, None, :]
    k = p.outputscale[:, None, None] * torch.exp(-0.5 * diff.square().sum(-1))  # (E, n, M)
    mean = p.y_mean[:, None] + p.y_scale[:, None] * (k @ p.beta[..., None])[..., 0]
    quad = torch.einsum("enm,emk,enk->en", k, p.iK, k)
    var = p.y_scale[:, None] ** 2 * (p.outputscale[:, None] - quad + p.noise[:, None])
    m = p.moments(z)
    q_abs = se_operands(z.unsqueeze(0), p.lengthscale[:, None, :]).abs()
    s_abs = se_operands(p.support, p.lengthscale[:, None, :], p.outputscale).abs()
    exponent_err = (2 * D + 6) * (q_abs @ s_abs.transpose(-1, -2)) + 1.5 * D * diff.square().sum(-1)
    dk = k * EPS * (exponent_err + 4)
    dk_sum = M * EPS * k + dk  # what k's error and the M-term sums add, entry by entry
    dmean = p.y_scale[:, None] * (dk_sum @ p.beta.abs()[..., None])[..., 0]
    v = (k @ p.var_factor.transpose(-1, -2)).abs()
    dv = dk_sum @ p.var_factor.abs().transpose(-1, -2)
    dquad = (
        torch.einsum("enm,emk,enk->en", dk_sum, p.iK.abs(), k)
        + torch.einsum("enm,emk,enk->en", k, p.iK.abs(), dk)
        + 2 * (v * dv).sum(-1)
        + M * EPS * (v * v).sum(-1)
    )
    tol_mean = 2 * (dmean / var.sqrt()).amax()
    tol_var = 2 * (dquad / p.outputscale[:, None]).amax() + 4 * EPS
    assert ((m.mean - mean.T).abs() / var.T.sqrt()).max() <= tol_mean
    assert ((m.var - var.T).abs() / (p.y_scale**2 * p.outputscale)).max() <= tol_var


@pytest.mark.parametrize("spread", [0.01, 3.0], ids=["near", "far"])
def test_float32_one_step_moments_match_float64(model, spread):
    p = model.predictor
    z = _queries(500, spread, 4)
    a = p.moments(z)
    b = p.to(dtype=torch.float32).moments(z.float())
    assert b.mean.dtype == torch.float32
    err_mean = ((b.mean.double() - a.mean).abs() / a.var.sqrt()).max()
    err_var = ((b.var.double() - a.var).abs() / a.var).max()
    # Statistical float32 round-off (u = 2^-24, independent errors): each term k_i β_i of the
    # mean (and R_ji k_i of v = Rk) carries the rounding of the query to float32 (through the
    # exponent: Σ_d |z_d (z_d − s_id)| / w_d² u), of the float64 exponent to float32
    # (|log k_i| u), of exp, of the weight (u each) and its share of the float32 sum (√M u),
    # so its standard deviation is u·sqrt(Σ_i terms_i² ((c_i + 1)² + 1 + M)) with c_i the
    # exponent's share; ‖v‖²
    # gets 2 sqrt(Σ_j (v_j sd(v_j))²). Largest over the queries, in predictive standard
    # deviations (mean) or relative (variance): ~5e-3 (exact) and ~2.5e-4 (FITC); seen
    # 2.8e-3 and 7.9e-5. Five of them: a float32 exponent is off by
    # 0.35 (exact) and 0.10 (FITC).
    u = 2.0**-24
    k = p.kernel_vectors(z)  # (E, n, M), float64
    M = k.shape[-1]
    query = (z[None, :, None, :] * (z[None, :, None, :] - p.support[:, None])).abs()
    c = k.log().abs() + (query / p.lengthscale[:, None, None, :] ** 2).sum(-1)
    w = (c + 1) ** 2 + 1 + M
    sd_mean = u * ((k * p.beta[:, None, :]) ** 2 * w).sum(-1).sqrt()
    v = k @ p.var_factor.transpose(-1, -2)
    sd_v = u * ((k**2 * w) @ p.var_factor.square().transpose(-1, -2)).sqrt()
    sd_quad = 2 * ((v * sd_v) ** 2).sum(-1).sqrt()
    scale_mean = (p.y_scale[:, None] * sd_mean / a.var.T.sqrt()).max()
    scale_var = (p.y_scale[:, None] ** 2 * sd_quad / a.var.T).max()
    assert err_mean < 5 * scale_mean and err_var < 5 * scale_var


def test_float32_kernel_has_no_denormals_and_keeps_its_accuracy(model):
    p = model.predictor
    z = _queries(300, 10.0, 5).float()  # far: many kernel entries are below float32's range
    k64 = p.kernel_vectors(z.double())
    k32 = p.to(dtype=torch.float32).kernel_vectors(z)
    assert (k64 < torch.finfo(torch.float32).tiny).float().mean() > 0.2
    assert bool((k32 >= torch.finfo(torch.float32).tiny).all())  # clamped: never denormal
    # Where k ≥ e^-40 σ_f²: float32 rounding of the float64 exponent (|log k| ≤ 40 +
    # |log σ_f²|, half an ulp: ~2.6e-6 relative in k) and of exp (≤ 2 ulp); twice that (seen:
    # 1.95e-6 against an estimate of 2.85e-6).
    floor = math.exp(-FLUSH_EXPONENT) * p.outputscale[:, None, None]
    max_exponent = FLUSH_EXPONENT + float(p.outputscale.log().abs().max())
    tol = 2 * (max_exponent * EPS32 / 2 + 2 * EPS32)
    big = k64 > floor
    rel = ((k32.double() - k64).abs() / k64)[big]
    assert rel.max() < tol
    # Below: raised to the floor, e^-40 σ_f² (never denormal, never 0), with the same rounding
    low = (k32.double() / floor)[~big]
    assert low.numel() > 0 and ((low - 1).abs() < tol).all()


def test_float64_kernel_floor_changes_nothing_above_it_and_keeps_products_normal(model):
    """Float64 entries below e^-600 σ_f² (and e^-600) are raised to it (no 0, no denormal);
    those above are bit-identical to the unfloored kernel, and the moments equal the unfloored
    kernel's bit for bit, near the data and ~300 length-scales from it (the prior there)."""
    p = model.predictor
    support = se_operands(p.support, p.lengthscale[:, None, :], p.outputscale).contiguous()
    weights = torch.cat([p.var_factor.transpose(-1, -2), p.beta[..., None]], dim=-1).contiguous()
    log_floor = (torch.log(p.outputscale) - FLOOR_EXPONENT_FLOAT64).clamp_min(
        -FLOOR_EXPONENT_FLOAT64
    )
    floor = torch.exp(log_floor)[:, None, None]  # e^-600 σ_f², at least e^-600
    for spread in (1.0, 400.0):
        z = _queries(300, spread, 6)
        raw = se_kernel_from_operands(
            se_operands(z.unsqueeze(0), p.lengthscale[:, None, :]),
            support,
            torch.log(p.outputscale),
        )
        k = p.kernel_vectors(z)
        above = raw > floor
        assert torch.equal(k[above], raw[above])
        # the same clamped float64 exponent, then one exp on each side, possibly by different
        # kernels (vectorised over the library's large tensor, a scalar tail loop over the
        # (E,) floor): two evaluations of one rounding each (e^-600 σ_f² is a normal number)
        floor_tol = 2 * fp_tol(1)
        assert torch.allclose(k[~above], floor.expand_as(k)[~above], rtol=floor_tol, atol=0.0)
        assert bool((k >= torch.finfo(torch.float64).tiny).all())
        prod = torch.bmm(raw, weights)  # the moments of the unfloored kernel, as moments() does
        quad = torch.linalg.vector_norm(prod[..., :-1], dim=-1).square()
        var = (p.outputscale[:, None] - quad).clamp_min(0.0) + p.noise[:, None]
        m = p.moments(z)
        assert torch.equal(m.mean, (p.y_mean[:, None] + p.y_scale[:, None] * prod[..., -1]).T)
        assert torch.equal(m.var, (p.y_scale[:, None] ** 2 * var).T)
    assert (raw == 0).float().mean() > 0.5  # far: without the floor most entries underflow


def _z_scores(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """z of the mean and variance differences of two independent samples (L, n_x)."""
    L = a.shape[0]
    ma, mb, va, vb = a.mean(0), b.mean(0), a.var(0), b.var(0)
    z_mean = (ma - mb) / torch.sqrt((va + vb) / L)
    # var of a sample variance ≈ (m4 − s⁴)/L (fourth central moment; no Gaussian assumption)
    se_a = (((a - ma) ** 4).mean(0) - va**2) / L
    se_b = (((b - mb) ** 4).mean(0) - vb**2) / L
    return z_mean, (va - vb) / torch.sqrt(se_a + se_b)


def test_float32_sampled_moments_match_float64_within_monte_carlo_error(model):
    """Independent seeds; 2 starts x 3 times x 2 dims x 2 statistics = 24 z-scores per model.

    |z| < 4.5 for all: a false alarm has probability about 24 · 6.8e-6 ≈ 2e-4.
    """
    x0 = np.array([[OFFSET + 0.2, OFFSET - 0.3], [OFFSET + 3.0, OFFSET - 2.5]])  # near, far
    T, L = 10, 4000
    with warnings.catch_warnings():
        warnings.simplefilter("error", GPNumericalWarning)
        a = sample_trajectories(model, x0, _policy, T, L, rng=1)
        b = sample_trajectories(model, x0, _policy, T, L, rng=2, dtype=torch.float32)
    assert b.states.dtype == torch.float32 and b.controls.dtype == torch.float32
    assert 0 < b.precision_error < PRECISION_TOL
    zs = []
    for i in range(2):
        for t in (1, T // 2, T):
            zm, zv = _z_scores(a.states[i, :, t], b.states[i, :, t].double())
            zs += [zm, zv]
    z = torch.cat(zs).abs()
    assert z.max() < 4.5, z
    # The same random numbers: float32 follows float64 path by path (short horizon). Each step
    # is off by about precision_error predictive sds (~1.2e-3 exact, ~7e-6 FITC; ≤ the spread
    # at T) plus the float32 rounding of the state (u |x|, |x| ~ 23); over T steps at most T
    # times that; twice it (seen: 2.4e-3 and 4.8e-5 of the spread; it was 1e-2 of it).
    c = sample_trajectories(model, x0, _policy, T, L, rng=1, dtype=torch.float32)
    spread = a.states[:, :, T].std(1).min()
    x_max = float(a.states.abs().max())
    tol = 2 * T * (c.precision_error * spread + EPS32 / 2 * x_max)
    assert (c.states[:, :, T].double() - a.states[:, :, T]).abs().max() < tol


def test_float32_warns_on_an_ill_conditioned_model():
    """x′ targets, 200 points, little noise: σ_f²/σ_ε² ~ 1e4 and ‖β‖ large; float32 is off."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        model = ForwardModel(ExactGP(n_steps=25)).fit(*_data(200, 0, 0.02, offset=0.0), rng=0)
    x0 = np.array([[0.2, -0.3]])
    with pytest.warns(GPNumericalWarning, match="float64"):
        res = sample_trajectories(
            model, x0, lambda t, x, p: -0.5 * x[:, :1], 5, 300, rng=0, dtype=torch.float32
        )
    assert res.precision_error > PRECISION_TOL


def test_bad_dtype(model):
    x0 = np.array([[OFFSET, OFFSET]])
    for dt in (torch.float16, torch.bfloat16, torch.int64):
        with pytest.raises(ValueError, match="dtype"):
            sample_trajectories(model, x0, _policy, 2, 2, dtype=dt)
