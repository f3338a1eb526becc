"""Batched trajectory sampler: statistics, seeding, chunking, policies, limits, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _tolerances import EPS

from skillkit.models.gp import ExactGP, ForwardModel, Moments
from skillkit.models.kernels import se_operands
from skillkit.models.sampling import sample_trajectories, sampler_flops_per_step
from skillkit.models.sparse import FITC


class LinearGaussian:
    """x' = A x + B u + N(0, diag q): closed-form reference for the sampling loop."""

    state_dim, control_dim = 2, 1

    def __init__(self):
        self.A = torch.tensor([[1.0, 0.1], [-0.2, 0.9]], dtype=torch.float64)
        self.B = torch.tensor([[0.0], [0.5]], dtype=torch.float64)
        self.q = torch.tensor([0.01, 0.04], dtype=torch.float64)

    def to(self, device=None, dtype=None):
        return self

    def next_state_moments(self, x, u):
        mean = x @ self.A.T + u @ self.B.T
        z = torch.zeros((), dtype=torch.long)
        return Moments(mean, self.q.expand_as(mean), z, torch.zeros((), dtype=x.dtype))


@pytest.fixture(scope="module")
def gp_model():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, size=(150, 2))
    u = rng.uniform(-1, 1, size=(150, 1))
    xn = (
        x
        + 0.1 * np.stack([x[:, 1], -np.sin(2 * x[:, 0]) + u[:, 0]], axis=1)
        + 0.02 * rng.standard_normal((150, 2))
    )
    return ForwardModel(ExactGP(n_steps=25)).fit(x, u, xn, rng=0)


def _feedback(t, x, pair):
    return -0.5 * x[:, :1] - 0.1 * pair[:, None].to(x.dtype)


def _rollout_roundoff_bound(model, states, policy):
    """First-order bound on the round-off of sampled GP trajectories, per trajectory and step.

    Two evaluations of the same trajectories that differ only in how rows are batched (chunk
    size, stopped rows dropped from the batch) differ in BLAS blocking, hence in round-off,
    which the dynamics then carry forward. Per step and output (standardised units, γ_n = n·ε):
    the kernel exponent (a (D + 2)-term product of operands built in ~D + 2 operations) is off
    by ≤ γ_{2D+6}·(|q|·|s|), so k_i by k_i times that; kᵀβ by ≤ γ_M Σ|k_i β_i| + Σ|β_i| δk_i;
    v = Rk by ≤ γ_M |R|k + |R| δk; ‖v‖² by ≤ 2|v|·δv + γ_M ‖v‖²; the state
    x' = y_scale·(mean + sqrt(var)·ε) therefore by y_scale·(δmean + |ε| δvar / (2 sqrt(var)))
    plus ε·|x'|. The error of x_t is carried by the step's Jacobian (mean, standard deviation
    and policy differentiated by autograd, the noise ε recovered from the states):
    b_{t+1} = ‖J_t‖_∞ b_t + local_t. Returns b, shape (B, L, T + 1); two evaluations differ by
    at most 2b (worst case: the observed differences are ~500x smaller)."""
    B, L, T1, n_x = states.shape
    xs = states.reshape(B * L, T1, n_x)
    pair = torch.arange(B).repeat_interleave(L)
    p = model.predictor
    M, D = p.support.shape[1:]
    s_abs = se_operands(p.support, p.lengthscale[:, None, :], p.outputscale).abs()
    beta_abs, R_abs = p.beta.abs()[..., None], p.var_factor.abs().transpose(-1, -2)
    sf2, ys = p.outputscale[:, None], p.y_scale[:, None]
    bound = torch.zeros(B * L, T1, dtype=states.dtype)
    for t in range(T1 - 1):
        x = xs[:, t].clone().requires_grad_(True)
        with torch.enable_grad():
            u = policy(t, x, pair)
            m = model.next_state_moments(x, u)
            sd = m.var.sqrt()
            noise = ((xs[:, t + 1] - m.mean) / sd).detach()
            y = m.mean + sd * noise
            J = torch.stack(
                [torch.autograd.grad(y[:, j].sum(), x, retain_graph=True)[0] for j in range(n_x)],
                1,
            )
        with torch.no_grad():
            z = torch.cat([x, u], -1)
            q_abs = se_operands(z.unsqueeze(0), p.lengthscale[:, None, :]).abs()
            k = p.kernel_vectors(z)  # (E, n, M)
            dk = k * ((2 * D + 6) * EPS * (q_abs @ s_abs.transpose(-1, -2)) + EPS)
            dmean = (M * EPS * k + dk) @ beta_abs
            v = (k @ p.var_factor.transpose(-1, -2)).abs()
            dv = (M * EPS * k + dk) @ R_abs
            dvar = 2 * (v * dv).sum(-1) + M * EPS * (v * v).sum(-1) + 2 * EPS * sf2
            var_std = m.var.T / ys**2
            local = ys * dmean[..., 0] + noise.abs().T * ys * dvar / (2 * var_std.sqrt())
            local = local.T + EPS * (m.mean.abs() + xs[:, t + 1].abs())
            gain = J.abs().sum(-1).amax(-1)  # ‖J_t‖_∞ per trajectory
            bound[:, t + 1] = gain * bound[:, t] + local.amax(-1)
    return bound.reshape(B, L, T1)


def test_multi_step_statistics_match_closed_form_linear_gaussian():
    model = LinearGaussian()
    K = torch.tensor([[-0.4, -0.6]], dtype=torch.float64)
    x0 = np.array([[1.0, -0.5], [0.0, 0.8]])
    T, L = 5, 40000
    res = sample_trajectories(model, x0, lambda t, x, p: x @ K.T, T, L, rng=1)
    F = (model.A + model.B @ K).numpy()
    for b in range(2):
        m, S = x0[b], np.zeros((2, 2))
        for t in range(1, T + 1):
            m, S = F @ m, F @ S @ F.T + np.diag(model.q.numpy())
            xs = res.states[b, :, t].numpy()
            se = np.sqrt(np.diag(S) / L)
            assert np.all(np.abs(xs.mean(0) - m) < 5 * se)
            # Sample covariance: standard error of entry ij ≈ sqrt((S_ii S_jj + S_ij²) / L).
            se_cov = np.sqrt((np.outer(np.diag(S), np.diag(S)) + S**2) / L)
            assert np.all(np.abs(np.cov(xs.T) - S) < 5 * se_cov)
    np.testing.assert_allclose(
        res.controls[:, :, 0].numpy(), res.states[:, :, 0].numpy() @ K.numpy().T
    )


def test_one_step_matches_gp_predictive_distribution(gp_model):
    x0 = np.array([[0.5, 0.0], [-0.3, 0.4], [0.1, -0.7]])
    L = 20000
    res = sample_trajectories(gp_model, x0, _feedback, 1, L, rng=2)
    u0 = -0.5 * x0[:, :1] - 0.1 * np.arange(3)[:, None]
    mean, var = gp_model.predict(x0, u0)
    x1 = res.states[:, :, 1].numpy()
    assert np.all(np.abs(x1.mean(1) - mean) < 5 * np.sqrt(var / L))
    # var of a sample variance of a Gaussian: 2 σ⁴ / (L - 1).
    assert np.all(np.abs(x1.var(1, ddof=1) - var) < 5 * var * np.sqrt(2.0 / (L - 1)))
    np.testing.assert_allclose(res.controls[:, 0, 0, 0].numpy(), u0[:, 0])


def test_same_seed_same_samples_and_chunking_invariance(gp_model):
    x0 = np.array([[0.5, 0.0], [0.0, 0.5]])
    a = sample_trajectories(gp_model, x0, _feedback, 8, 64, rng=3)
    b = sample_trajectories(gp_model, x0, _feedback, 8, 64, rng=3)
    c = sample_trajectories(gp_model, x0, _feedback, 8, 64, rng=4)
    d = sample_trajectories(gp_model, x0, _feedback, 8, 64, rng=3, max_chunk_bytes=5000)
    assert torch.equal(a.states, b.states) and torch.equal(a.controls, b.controls)
    assert not torch.allclose(a.states, c.states)
    # d runs one row per chunk: other BLAS blocking, so equal up to round-off carried along
    # the trajectories (~3e-11 seen; the bound is ~6e-8, against O(0.1) for a wrong noise draw).
    tol = 2 * float(_rollout_roundoff_bound(gp_model, a.states, _feedback).max())
    torch.testing.assert_close(a.states, d.states, rtol=0, atol=tol)
    assert a.states.shape == (2, 64, 9, 2) and a.controls.shape == (2, 64, 8, 1)
    assert a.states.dtype == torch.float64


def test_per_trajectory_start_states_and_sparse_model():
    rng = np.random.default_rng(5)
    x = rng.uniform(-1, 1, size=(100, 2))
    u = rng.uniform(-1, 1, size=(100, 1))
    model = ForwardModel(FITC(20, n_steps=10)).fit(x, u, 0.9 * x + 0.1 * u, rng=0)
    x0 = rng.uniform(-0.5, 0.5, size=(3, 7, 2))
    res = sample_trajectories(model, x0, _feedback, 4, 7, rng=0)
    np.testing.assert_array_equal(res.states[:, :, 0].numpy(), x0)
    assert res.n_variance_clamped == 0 and np.isfinite(res.states.numpy()).all()


def test_control_limit_saturates_and_counts(gp_model):
    x0 = np.array([[0.9, 0.9]])
    res = sample_trajectories(
        gp_model,
        x0,
        lambda t, x, p: torch.full((x.shape[0], 1), 3.0, dtype=x.dtype),
        3,
        10,
        rng=0,
        control_limit=1.0,
    )
    assert res.n_saturated == 30
    assert torch.all(res.controls == 1.0)


def test_bad_input(gp_model):
    ok = np.zeros((2, 2))
    with pytest.raises(ValueError, match="x0"):
        sample_trajectories(gp_model, np.zeros((2, 3)), _feedback, 3, 2)
    with pytest.raises(ValueError, match="x0"):
        sample_trajectories(gp_model, np.full((2, 2), np.nan), _feedback, 3, 2)
    with pytest.raises(ValueError, match="x0"):
        sample_trajectories(gp_model, np.zeros((2, 5, 2)), _feedback, 3, 2)
    with pytest.raises(ValueError, match="horizon"):
        sample_trajectories(gp_model, ok, _feedback, 0, 2)
    with pytest.raises(ValueError, match="n_trajectories"):
        sample_trajectories(gp_model, ok, _feedback, 3, 0)
    with pytest.raises(ValueError, match="policy"):
        sample_trajectories(gp_model, ok, lambda t, x, p: x, 3, 2)
    with pytest.raises(ValueError, match="policy"):
        sample_trajectories(gp_model, ok, lambda t, x, p: np.zeros((x.shape[0], 1)), 3, 2)
    with pytest.raises(ValueError, match="policy"):
        sample_trajectories(
            gp_model,
            ok,
            lambda t, x, p: torch.full((x.shape[0], 1), float("nan"), dtype=x.dtype),
            3,
            2,
        )
    with pytest.raises(ValueError, match="control_limit"):
        sample_trajectories(gp_model, ok, _feedback, 3, 2, control_limit=-1.0)


def test_flop_count():
    # E = 1, M = 2, d = 1: 2·2·1 + 3·2 + 2 + 2·2 + 2·4 + 2·2 = 28
    assert sampler_flops_per_step(1, 2, 1) == 28
    assert sampler_flops_per_step(8, 300, 12) == 8 * sampler_flops_per_step(1, 300, 12)


def _crossed(k, x):
    return x[:, 0] < 0.1


def test_stop_rule_holds_stopped_trajectories_and_keeps_the_rest(gp_model):
    """With a stop rule every trajectory is the full rollout up to its first step k ≥ 1 where
    the rule holds, then stays at x_k with zero controls; ``stopped_at`` records k (T if
    never); a rule that never holds changes nothing."""
    x0 = np.array([[0.5, 0.0], [-0.5, 0.3]])
    T, L = 12, 50
    full = sample_trajectories(gp_model, x0, _feedback, T, L, rng=7)
    cut = sample_trajectories(gp_model, x0, _feedback, T, L, rng=7, stop=_crossed)
    # cut drops stopped rows from the batch, so its products are blocked differently from
    # full's: the same trajectories up to round-off carried along them (bound ~1.6e-7 here,
    # ~3e-11 seen on AMD without AVX-512, ~1e-12 on Intel with it; a wrong noise draw or a
    # wrong row would be off by O(0.1)).
    tol = 2 * float(_rollout_roundoff_bound(gp_model, full.states, _feedback).max())
    # No state sits within round-off of the threshold, so the rule fires at the same step
    # on either path (the margin is ~1e-3 for this seed).
    assert float((full.states[..., 1:, 0] - 0.1).abs().min()) > 10 * tol
    hit = full.states[..., 1:, 0] < 0.1  # (B, L, T): rule at x_1 … x_T
    hit[..., -1] = False  # x_T is the last state: nothing to stop after it
    k = torch.where(hit.any(-1), hit.to(torch.int8).argmax(-1) + 1, T)
    assert torch.equal(cut.stopped_at, k)
    # pair 1 starts below the threshold (stops at k = 1); pair 0 crosses it late or never
    assert torch.all(k[1] == 1) and 1 < int(k[0].min()) and int(k[0].max()) == T
    t = torch.arange(T + 1)
    held = t > k[..., None]  # (B, L, T + 1): after x_k
    u_kept = (t[:-1] < k[..., None])[..., None]

    def stopped(states, controls):
        last = torch.gather(states, 2, k[..., None, None].expand(2, L, 1, 2))
        return torch.where(held[..., None], last, states), torch.where(u_kept, controls, 0.0)

    expected, expected_u = stopped(full.states, full.controls)
    torch.testing.assert_close(cut.states, expected, rtol=0, atol=tol)
    torch.testing.assert_close(cut.controls, expected_u, rtol=0, atol=tol)
    # Exactly: held states repeat x_k bit for bit and the dropped controls are 0.
    held_states, held_controls = stopped(cut.states, cut.controls)
    assert torch.equal(cut.states, held_states) and torch.equal(cut.controls, held_controls)
    never = sample_trajectories(
        gp_model, x0, _feedback, T, L, rng=7, stop=lambda k, x: torch.zeros(len(x), dtype=bool)
    )
    assert torch.equal(never.states, full.states) and torch.equal(never.controls, full.controls)
    assert torch.equal(never.stopped_at, torch.full((2, L), T)) and full.stopped_at is None
    # One row per chunk (3000 bytes < one row's 3·E·M·8 = 7200): with and without the rule,
    # the same operations on the same shapes up to x_k, so the same bits there.
    chunked = sample_trajectories(
        gp_model, x0, _feedback, T, L, rng=7, stop=_crossed, max_chunk_bytes=3000
    )
    rows = sample_trajectories(gp_model, x0, _feedback, T, L, rng=7, max_chunk_bytes=3000)
    assert torch.equal(chunked.stopped_at, cut.stopped_at)
    rows_states, rows_controls = stopped(rows.states, rows.controls)
    assert torch.equal(chunked.states, rows_states) and torch.equal(chunked.controls, rows_controls)
    torch.testing.assert_close(chunked.states, cut.states, rtol=0, atol=tol)


def test_stop_rule_bad_input(gp_model):
    x0 = np.zeros((1, 2))
    with pytest.raises(ValueError, match="stop: expected a callable"):
        sample_trajectories(gp_model, x0, _feedback, 3, 4, stop=3)
    with pytest.raises(ValueError, match="stop: supported with method='per-step' only"):
        sample_trajectories(gp_model, x0, _feedback, 3, 4, stop=_crossed, method="pathwise")
    with pytest.raises(ValueError, match=r"stop: expected a bool Tensor of shape \(4,\)"):
        sample_trajectories(gp_model, x0, _feedback, 3, 4, stop=lambda k, x: x[:, :1] > 0)
    with pytest.raises(ValueError, match=r"stop: expected a bool Tensor of shape \(4,\)"):
        sample_trajectories(gp_model, x0, _feedback, 3, 4, stop=lambda k, x: x[:, 0])


def test_control_limit_shape_and_chunk_budget_are_checked(gp_model):
    """A limit of the wrong length names ``control_limit`` (not a numpy broadcast error); a
    chunk budget that is not a positive integer is refused, not run one row at a time."""
    ok = np.zeros((2, 2))
    with pytest.raises(ValueError, match=r"control_limit: expected a scalar or shape \(1,\)"):
        sample_trajectories(gp_model, ok, _feedback, 3, 2, control_limit=[1.0, 2.0])
    for bad in (0, -5, 2.5):
        with pytest.raises(ValueError, match="max_chunk_bytes: expected an integer"):
            sample_trajectories(gp_model, ok, _feedback, 3, 2, max_chunk_bytes=bad)


@pytest.mark.parametrize("device", ["cpu:0", torch.device("cpu", 0)])
def test_an_indexed_device_samples_like_the_default(gp_model, device):
    """``device="cpu:0"`` samples like ``"cpu"``: tensors report the device without its index, so
    comparing against the requested name would reject every policy ("expected controls ... on
    cpu:0, got ... on cpu"), as ``"cuda"`` would against controls on ``cuda:0``; the device
    used is the one tensors made there report."""
    x0 = np.array([[0.5, 0.0], [0.0, 0.5]])
    ref = sample_trajectories(gp_model, x0, _feedback, 4, 8, rng=3)
    res = sample_trajectories(gp_model, x0, _feedback, 4, 8, rng=3, device=device)
    assert torch.equal(res.states, ref.states) and torch.equal(res.controls, ref.controls)
    with pytest.raises(ValueError, match="device"):
        sample_trajectories(gp_model, x0, _feedback, 4, 8, device="nonsense")
