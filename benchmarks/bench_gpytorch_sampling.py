"""Benchmark: skillkit's trajectory sampler against the same FITC rollout through GPyTorch.

One FITC forward model, rolled out with per-step sampling (x_{t+1} ~ p(x_{t+1} | x_t, u_t),
the feedback policy u_t = G (x_t − x_up)), through

* skillkit: :func:`skillkit.models.sampling.sample_trajectories`;
* GPyTorch, in the fastest forms found (batched over the E outputs, eval mode, no grad,
  ``fast_pred_var`` and ``debug(False)`` on, float64), each set to the *same* predictive
  distribution (FITC's; the hyper-parameters, pseudo-inputs and training data of the skillkit
  model):

  - ``SGPR``: an ``ExactGP`` with an ``InducingPointKernel`` over ``ScaleKernel(RBFKernel)``
    and a ``GaussianLikelihood``, conditioned on the training targets: in eval mode its
    ``sgpr_diagonal_correction`` (on by default) adds diag(K_nn − Q_nn) to the training
    covariance, so it predicts with FITC's posterior (not VFE's); it recomputes the
    kernel between the pseudo-inputs and all N training inputs at every call;
  - ``SVGP``: an ``ApproximateGP`` with the (whitened) ``VariationalStrategy`` and a
    ``CholeskyVariationalDistribution`` whose q(u) is FITC's posterior over the pseudo-outputs
    (m = L_mᵀ β, S = I − L_mᵀ iK L_m with K_mm = L_m L_mᵀ), learn_inducing_locations off;
  - ``SVGP-LB``: the same with ``LargeBatchVariationalStrategy``, which caches
    K_mm^{-1/2} (S − I) K_mm^{-T/2} in eval mode and so saves the per-step triangular solve
    (the fastest form found).

  The plain ``UnwhitenedVariationalStrategy`` (a solve and a root decomposition every call) and
  SGPR without ``fast_pred_var`` are slower forms and are not timed.

Equivalence is checked before timing: (1) one-step predictive means and variances of every
GPyTorch form against skillkit's ``next_state_moments`` on states visited by a skillkit
rollout (max error of the mean in predictive standard deviations, max relative variance
error); (2) final-state statistics of the large-batch rollout: per state dimension, the
difference of the means in units of their Monte Carlo standard error
(sqrt(s_a²/L + s_b²/L)) and the ratio of standard deviations (its Monte Carlo standard error
≈ sqrt(1/L)), each GPyTorch form with its own noise stream; and the paired difference when a
GPyTorch form is driven by the *same* noise draws as skillkit.

Timing: each batch (trajectories × steps) is timed ``--repeats`` times, the forms interleaved
within each repeat (so load changes hit all of them alike), one thread
(``torch.set_num_threads(1)`` here), float64. Reported: the median time per form and the
median over repeats of the per-repeat ratio GPyTorch / skillkit, in wall time and in this
process's CPU time (``time.process_time``; on a shared, oversubscribed machine the wall time
includes waiting for a core and the CPU-time ratio is the steadier one), with the load
averages (``os.getloadavg``) before, during and after. Each rollout's timed work is the same:
the controls, the predictive moments, the noise draw (all noise drawn up front, as skillkit
does) and storing the states. Results of two runs: ``docs/gpytorch_sampling_comparison.md``.

The model: fig4.4's balancing FITC forward model (Δx targets, 8 states + 4 controls = 12 GP
inputs, 8 outputs), N = 1500 transitions, M = 300 pseudo-inputs, 10 optimisation steps
(timings do not depend on the hyper-parameters' values), as ``bench_sampler.py``.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_gpytorch_sampling.py [--batches 300x20 1000x100]
        [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
import warnings

import gpytorch
import numpy as np
import torch
from gpytorch.variational import (
    CholeskyVariationalDistribution,
    LargeBatchVariationalStrategy,
    VariationalStrategy,
)

from skillkit.experiments import get
from skillkit.experiments.ch4_models import _train_balancing_model
from skillkit.models.gp import GPNumericalWarning
from skillkit.models.sampling import sample_trajectories, sampler_flops_per_step
from skillkit.tasks.balancing import X_UP, feedback_policy, stable_gains

F64 = torch.float64


def load() -> str:
    return ", ".join(f"{v:.2f}" for v in os.getloadavg())


# ------------------------------------------------------------------------ the GPyTorch forms
def make_sgpr(model):
    """GPyTorch SGPR (ExactGP + InducingPointKernel, FITC in eval mode); returns predict.

    In eval mode GPyTorch's ``InducingPointKernel`` adds diag(K_nn − Q_nn) to the training
    covariance (``sgpr_diagonal_correction``, on by default), so with the Gaussian noise σ_ε²
    the prior of the training targets is FITC's, Q_nn + diag(K_nn − Q_nn) + σ_ε² I, and the
    prediction is FITC's. Its cached K_mm is set to skillkit's (with the fixed jitter
    ``jitter``·σ_f² on the diagonal), which it otherwise factorises without jitter.
    """
    p = model.predictor
    E, M, d = p.support.shape
    batch = torch.Size([E])
    X, Y = model.gp.X, model.gp.Y  # the standardised training data of the FITC model

    class SGPR(gpytorch.models.ExactGP):
        def __init__(self, x, y, likelihood):
            super().__init__(x, y, likelihood)
            self.mean_module = gpytorch.means.ZeroMean(batch_shape=batch)
            rbf = gpytorch.kernels.RBFKernel(ard_num_dims=d, batch_shape=batch)
            base = gpytorch.kernels.ScaleKernel(rbf, batch_shape=batch)
            self.covar_module = gpytorch.kernels.InducingPointKernel(
                base, p.support.clone(), likelihood
            )

        def forward(self, x):
            return gpytorch.distributions.MultivariateNormal(
                self.mean_module(x), self.covar_module(x)
            )

    likelihood = gpytorch.likelihoods.GaussianLikelihood(
        batch_shape=batch, noise_constraint=gpytorch.constraints.GreaterThan(1e-12)
    ).double()
    gp = SGPR(X.expand(E, *X.shape), Y, likelihood).double()
    gp.covar_module.base_kernel.base_kernel.lengthscale = p.lengthscale[:, None, :]
    gp.covar_module.base_kernel.outputscale = p.outputscale
    likelihood.noise = p.noise[:, None]
    gp.eval()
    likelihood.eval()
    with torch.no_grad():
        kern = gp.covar_module
        jitter = (model.gp.jitter * p.outputscale)[:, None, None] * torch.eye(M, dtype=F64)
        kern._cached_kernel_mat = kern.base_kernel(p.support).to_dense() + jitter

    def predict(z):  # z (E, n, d) -> latent mean, variance (E, n), standardised
        f = gp(z)
        return f.mean, f.variance

    return predict


def make_svgp(model, strategy_cls, jitter: float = 1e-10):
    """GPyTorch ApproximateGP whose q(u) is FITC's posterior over the pseudo-outputs."""
    p = model.predictor
    E, M, d = p.support.shape
    batch = torch.Size([E])

    class SVGP(gpytorch.models.ApproximateGP):
        def __init__(self):
            dist = CholeskyVariationalDistribution(M, batch_shape=batch)
            strategy = strategy_cls(
                self, p.support.clone(), dist, learn_inducing_locations=False, jitter_val=jitter
            )
            super().__init__(strategy)
            self.mean_module = gpytorch.means.ZeroMean(batch_shape=batch)
            rbf = gpytorch.kernels.RBFKernel(ard_num_dims=d, batch_shape=batch)
            self.covar_module = gpytorch.kernels.ScaleKernel(rbf, batch_shape=batch)

        def forward(self, x):
            return gpytorch.distributions.MultivariateNormal(
                self.mean_module(x), self.covar_module(x)
            )

    gp = SVGP().double()
    gp.covar_module.base_kernel.lengthscale = p.lengthscale[:, None, :]
    gp.covar_module.outputscale = p.outputscale
    with torch.no_grad():
        # GPyTorch's whitening factor: the Cholesky factor of its own K_mm (+ its jitter).
        Kmm = gp.covar_module(p.support).to_dense() + jitter * torch.eye(M, dtype=F64)
        L = torch.linalg.cholesky(Kmm)
        m = (L.mT @ p.beta[..., None])[..., 0]  # mean: kᵀ L⁻ᵀ m = kᵀ β
        S = torch.eye(M, dtype=F64) - L.mT @ p.iK @ L  # variance: −kᵀ L⁻ᵀ (I − S) L⁻¹ k = −kᵀ iK k
        S = 0.5 * (S + S.mT)
        w, U = torch.linalg.eigh(S)  # round-off can leave S a hair indefinite
        S = (U * w.clamp_min(1e-14)[..., None, :]) @ U.mT
        dist = gp.variational_strategy._variational_distribution
        dist.variational_mean.copy_(m)
        dist.chol_variational_covar.copy_(torch.linalg.cholesky(S))
        gp.variational_strategy.variational_params_initialized.fill_(1)
    gp.eval()

    def predict(z):
        f = gp(z)
        return f.mean, f.variance - jitter  # the strategy adds its jitter to the variance

    return predict


def gpytorch_rollout(model, predict, x0, G, eps):
    """Per-step sampling through a GPyTorch predictive (x0 (n, 8), eps (n, T, 8))."""
    p = model.predictor
    E = p.output_dim
    n, T, n_x = eps.shape
    up = torch.as_tensor(X_UP, dtype=F64)
    states = torch.empty((n, T + 1, n_x), dtype=F64)
    states[:, 0] = x0
    x = x0
    ym, ys, noise = p.y_mean, p.y_scale, p.noise
    with torch.no_grad(), gpytorch.settings.fast_pred_var(), gpytorch.settings.debug(False):
        for t in range(T):
            u = (x - up) @ G.T
            z = torch.cat([x, u], dim=-1)
            mean, var = predict(z.expand(E, *z.shape))
            mean = ym + ys * mean.T
            std = ys * (var.clamp_min(0.0) + noise[:, None]).T.sqrt()
            x = x + mean + std * eps[:, t]
            states[:, t + 1] = x
    return states


def draw_eps(seed: int, n: int, T: int, n_x: int) -> torch.Tensor:
    """The noise sample_trajectories draws for rng=seed (same generator, same order)."""
    gen = torch.Generator()
    gen.manual_seed(int(np.random.default_rng(seed).integers(2**63 - 1)))
    return torch.randn((n, T, n_x), generator=gen, dtype=F64)


# ------------------------------------------------------------------------ main
def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n-data", type=int, default=1500)
    parser.add_argument("--n-pseudo", type=int, default=300)
    parser.add_argument("--batches", nargs="+", default=["300x20", "1000x100"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    t_start = time.perf_counter()
    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, torch {torch.__version__}, gpytorch {gpytorch.__version__}, "
        f"threads {torch.get_num_threads()}, float64"
    )
    print(f"load before: {load()}")

    rng = np.random.default_rng(args.seed)
    settings = get("fig4.4").settings_for(
        "quick",
        horizon=30,
        torque_noise_std=0.5,
        n_data=args.n_data,
        n_pseudo=args.n_pseudo,
        n_opt_steps=10,
        additive_noise=1.0,
    )
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        task, model, data = _train_balancing_model(settings, rng)
    p = model.predictor
    E, M, D = p.output_dim, p.n_support, p.input_dim
    assert model.delta and model.linear_weights is None, "the GPyTorch rollout assumes Δx, 0 mean"
    print(
        f"model: FITC ({model.target} targets), N = {len(data['x'])}, M = {M}, {D} inputs, "
        f"{E} outputs, {sampler_flops_per_step(E, M, D) / 1e6:.2f} MFLOP per trajectory step "
        f"(trained in {time.perf_counter() - t0:.1f} s; K_mm jitter {model.gp.jitter:g} sigma_f^2, "
        f"extra jitter needed {model.gp.diagnostics.get('jitter', 0.0):g})"
    )
    G = stable_gains(task, 1, rng)[0].reshape(4, 8)
    Gt = torch.as_tensor(G)
    policy = feedback_policy(torch.as_tensor(G[None]))
    forms = {
        "SGPR": make_sgpr(model),
        "SVGP": make_svgp(model, VariationalStrategy),
        "SVGP-LB": make_svgp(model, LargeBatchVariationalStrategy),
    }

    def ours(x0, T, seed):
        return sample_trajectories(model, x0[None], policy, T, x0.shape[0], rng=seed).states[0]

    def theirs(name, x0, T, seed):
        return gpytorch_rollout(model, forms[name], x0, Gt, draw_eps(seed, x0.shape[0], T, 8))

    # ---------------------------------------------------------------- equivalence
    Lc, Tc = 300, 20
    xc = torch.as_tensor(X_UP + task.initial_std * rng.standard_normal((Lc, 8)))
    visited = ours(xc, Tc, 99)[:, :: Tc // 4].reshape(-1, 8)
    uc = (visited - torch.as_tensor(X_UP)) @ Gt.T
    with torch.no_grad():
        ref = model.next_state_moments(visited, uc)
    zc = torch.cat([visited, uc], -1)
    print(
        f"\none-step predictions on {len(visited)} states visited by a skillkit rollout "
        f"({Lc} x {Tc}, t = 0, 5, 10, 15, 20), against skillkit's next_state_moments:"
    )
    print(f"  {'form':>8} {'max |dmean| / std':>18} {'max |dvar| / var':>17}")
    for name, predict in forms.items():
        with torch.no_grad(), gpytorch.settings.fast_pred_var(), gpytorch.settings.debug(False):
            mean, var = predict(zc.expand(E, *zc.shape))
        mean = visited + p.y_mean + p.y_scale * mean.T
        var = p.y_scale**2 * (var.clamp_min(0.0) + p.noise[:, None]).T
        err_m = float(((mean - ref.mean).abs() / ref.var.sqrt()).max())
        err_v = float(((var - ref.var).abs() / ref.var).max())
        print(f"  {name:>8} {err_m:18.1e} {err_v:17.1e}")

    # ---------------------------------------------------------------- timing
    batches = [tuple(int(v) for v in b.split("x")) for b in args.batches]
    rows = []
    finals = {}
    for L, T in batches:
        x0 = torch.as_tensor(X_UP + task.initial_std * rng.standard_normal((L, 8)))
        print(f"\n{L} trajectories x {T} steps, {args.repeats} repeats (load {load()})")
        ours(x0, 2, 0)  # warm-up
        for name in forms:
            theirs(name, x0, 2, 0)
        times = {k: [] for k in ("skillkit", *forms)}
        cpu = {k: [] for k in times}
        for r in range(args.repeats):
            t, c = time.perf_counter(), time.process_time()
            a = ours(x0, T, 1)
            times["skillkit"].append(time.perf_counter() - t)
            cpu["skillkit"].append(time.process_time() - c)
            if r == 0:
                finals[L, T, "skillkit"] = a[:, -1]
            for i, name in enumerate(forms):
                t, c = time.perf_counter(), time.process_time()
                b = theirs(name, x0, T, 2 + i if r == 0 else 1)
                times[name].append(time.perf_counter() - t)
                cpu[name].append(time.process_time() - c)
                if r == 0:
                    finals[L, T, name] = b[:, -1]
                elif r == 1:
                    finals[L, T, name, "paired"] = b[:, -1]
            print(
                f"  repeat {r + 1}: "
                + ", ".join(f"{k} {v[-1]:.3f} s (CPU {cpu[k][-1]:.3f})" for k, v in times.items())
                + f"   (load {load()})"
            )
        for kind, tt in (("wall", times), ("CPU", cpu)):
            rate = sampler_flops_per_step(E, M, D) * L * T / statistics.median(tt["skillkit"]) / 1e9
            ratio = {
                k: statistics.median(g / s for g, s in zip(tt[k], tt["skillkit"], strict=True))
                for k in forms
            }
            med = {k: statistics.median(v) for k, v in tt.items()}
            rows.append((kind, L, T, med, ratio, rate))
        finals[L, T, "skillkit", "paired"] = a[:, -1]  # the last repeat's (seed 1)

    # ---------------------------------------------------------------- final-state statistics
    L, T = batches[-1]
    a = finals[L, T, "skillkit"].numpy()
    print(
        f"\nfinal states x_T, {L} x {T} (independent noise streams): per dimension, "
        f"|mean difference| / its MC standard error and std ratio (MC s.e. ~ {1 / np.sqrt(L):.3f})"
    )
    print(f"  skillkit std per state: {np.array2string(a.std(0), precision=3)}")
    for name in forms:
        b = finals[L, T, name].numpy()
        z = np.abs(a.mean(0) - b.mean(0)) / np.sqrt((a.var(0) + b.var(0)) / L)
        ratio_sd = b.std(0) / a.std(0)
        pa = finals[L, T, "skillkit", "paired"].numpy()
        pb = finals[L, T, name, "paired"].numpy()
        paired = np.max(np.abs(pa - pb) / pa.std(0))
        print(
            f"  {name:>8}: max |dmean|/s.e. {z.max():.2f}; std ratio "
            f"{ratio_sd.min():.3f}–{ratio_sd.max():.3f}; same noise: max |x_T diff| / std "
            f"{paired:.1e}"
        )

    # ---------------------------------------------------------------- table
    print(
        "\nmedian time [s] (wall; CPU = process time, less sensitive to other processes on a "
        "shared machine),\none thread, float64; ratio = GPyTorch / skillkit, median of the "
        "per-repeat ratios"
    )
    head = f"  {'time':>4} {'trajectories x steps':>20} {'skillkit':>9} {'GFLOP/s':>8}"
    head += "".join(f" {k:>9} {'ratio':>6}" for k in forms)
    print(head)
    for kind, L, T, med, ratio, rate in sorted(rows, key=lambda r: r[0] != "wall"):
        line = f"  {kind:>4} {f'{L} x {T}':>20} {med['skillkit']:9.3f} {rate:8.1f}"
        line += "".join(f" {med[k]:9.3f} {ratio[k]:5.1f}x" for k in forms)
        print(line)
    print(f"\nload after: {load()}   (benchmark wall time {time.perf_counter() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
