"""Benchmark: the trajectory sampler's speed and accuracy, float64 / float32 / pathwise.

Prints, in one run, with the machine's load (``uptime``) before and after:

* the matmul peak (GFLOP/s of a large square product) in float64 and float32 on 1 and 2 threads;
* the per-step sampler (:func:`skillkit.models.sampling.sample_trajectories`): wall time,
  GFLOP/s (analytic count :func:`~skillkit.models.sampling.sampler_flops_per_step`) and the
  fraction of the same dtype's matmul peak, float64 and float32, 1 and 2 threads; the float32
  speed-up;
* float32's accuracy: its ``precision_error`` (one-step moments against float64 on visited
  states), the paired path difference at t = T with the same seed (float32 paths follow the
  float64 paths of a seed) and the KL divergence between Gaussian fits of the final states,
  against the Monte Carlo floor (the KL between two float64 runs with different seeds);
* the peer baseline: the same rollout written the way a GPyTorch user would write it (a
  batched ``gpytorch`` SGPR model with the same kernel hyper-parameters and inducing points,
  ``likelihood(model(z))`` in eval mode under ``fast_pred_var`` at every step), its time per
  step over ``--gpytorch-steps`` steps and our speed ratio, at ``--trajectories``. In eval
  mode GPyTorch's ``InducingPointKernel`` adds diag(K_nn − Q_nn) to the training covariance
  (``sgpr_diagonal_correction``, on by default), so this SGPR predicts with FITC's posterior;
  it factorises K_mm without FITC's jitter, so its predictions differ from ours at the 1e-4
  level. This is the slowest GPyTorch form: ``benchmarks/bench_gpytorch_sampling.py`` checks
  equivalence and times the faster ones (an ``ApproximateGP`` whose q(u) is FITC's posterior)
  at a small and a large batch — the ratios the README quotes;
* the pathwise sampler (:mod:`skillkit.models.pathwise`): set-up per function, time per step
  and GFLOP/s (:func:`~skillkit.models.pathwise.pathwise_flops_per_step`), fresh features per
  function and one shared basis; and its final-state spread against the per-step sampler's
  (KL of Gaussian fits and per-dimension std ratios, against the Monte Carlo floor).

The model is the reference size: a FITC forward model (Δx targets) of the planar
4-link robot under the balancing feedback (8 states, 4 controls: 12 GP inputs, 8 outputs),
N = 1500 transitions, M = 300 pseudo-inputs, 10 optimisation steps (timings do not depend on
the hyper-parameters' values), trained with skillkit's own data collection (the fig4.4
set-up). Start states are drawn around the upright
position; the controller is a stable feedback gain.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_sampler.py [--trajectories 300] [--horizon 30]
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import time
import warnings

import gpytorch
import numpy as np
import torch
from _machine import best_time, matmul_peak

from skillkit.experiments import get
from skillkit.experiments.ch4_models import _train_balancing_model
from skillkit.models.gp import GPNumericalWarning
from skillkit.models.pathwise import PathwiseBasis, pathwise_flops_per_step
from skillkit.models.sampling import sample_trajectories, sampler_flops_per_step
from skillkit.tasks.balancing import X_UP, feedback_policy, stable_gains

F64, F32 = torch.float64, torch.float32


def load() -> str:
    """The ``uptime`` line (load averages over 1, 5, 15 minutes)."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        import os

        return "load average: " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


class threads:
    """Context manager: run with ``n`` torch threads (benchmark only; restored afterwards)."""

    def __init__(self, n: int):
        self.n = n

    def __enter__(self):
        self.before = torch.get_num_threads()
        torch.set_num_threads(self.n)

    def __exit__(self, *exc):
        torch.set_num_threads(self.before)


def gaussian_kl(a: np.ndarray, b: np.ndarray) -> float:
    """KL(N(m_a, S_a) ‖ N(m_b, S_b)) of Gaussian fits to samples a, b of shape (L, k)."""
    ma, mb = a.mean(0), b.mean(0)
    Sa, Sb = np.cov(a.T), np.cov(b.T)
    iSb = np.linalg.inv(Sb)
    d = mb - ma
    k = a.shape[1]
    _, lda = np.linalg.slogdet(Sa)
    _, ldb = np.linalg.slogdet(Sb)
    return 0.5 * float(np.trace(iSb @ Sa) + d @ iSb @ d - k + ldb - lda)


def gpytorch_rollout(model, x0: torch.Tensor, G: torch.Tensor, horizon: int):
    """The same rollout as a GPyTorch user writes it: the predictive distribution every step.

    A batched SGPR (``InducingPointKernel`` over a ``ScaleKernel(RBFKernel)``) with the FITC
    model's length-scales, signal and noise variances and pseudo-inputs, conditioned on the
    same (standardised Δx) training targets.
    """
    p = model.predictor
    E, M, d = p.support.shape
    X = model.gp.X
    Y = model.gp.Y  # (E, N) standardised targets the FITC model was trained on
    batch = torch.Size([E])

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
    gen = torch.Generator().manual_seed(0)
    up = torch.as_tensor(X_UP)

    def rollout(T: int = horizon):
        x = x0.clone()
        with torch.no_grad(), gpytorch.settings.fast_pred_var():
            for _ in range(T):
                u = (x - up) @ G.T
                z = torch.cat([x, u], dim=-1)
                pred = likelihood(gp(z.expand(E, *z.shape)))
                mean = p.y_mean + p.y_scale * pred.mean.T
                std = p.y_scale * pred.variance.T.sqrt()
                x = x + mean + std * torch.randn(x.shape, generator=gen, dtype=x.dtype)
        return x

    return rollout


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n-data", type=int, default=1500)
    parser.add_argument("--n-pseudo", type=int, default=300)
    parser.add_argument("--trajectories", type=int, default=300)
    parser.add_argument("--horizon", type=int, default=30)
    parser.add_argument("--spread-trajectories", type=int, default=400)
    parser.add_argument("--spread-horizon", type=int, default=100)
    parser.add_argument("--gpytorch-steps", type=int, default=5)
    parser.add_argument("--features", type=int, default=256)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    t_start = time.perf_counter()
    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"torch {torch.__version__}, gpytorch {gpytorch.__version__}"
    )
    print(f"load before: {load()}")

    print("\nmatmul peak [GFLOP/s]")
    peak = {}
    for th in args.threads:
        for dt in (F64, F32):
            peak[th, dt] = matmul_peak(th, dt)
        print(f"  {th} thread(s): float64 {peak[th, F64]:6.1f}   float32 {peak[th, F32]:6.1f}")

    rng = np.random.default_rng(args.seed)
    settings = get("fig4.4").settings_for(
        "quick",
        horizon=args.horizon,
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
    print(
        f"\nmodel: FITC ({model.target} targets), N = {len(data['x'])}, M = {M}, {D} inputs, "
        f"{E} outputs (trained in {time.perf_counter() - t0:.1f} s)"
    )
    G = stable_gains(task, 1, rng)[0].reshape(4, 8)
    L, T = args.trajectories, args.horizon
    x0 = X_UP + task.initial_std * rng.standard_normal((1, L, 8))
    policy = {dt: feedback_policy(torch.as_tensor(G[None], dtype=dt)) for dt in (F64, F32)}

    def run(dt, n_traj=L, horizon=T, x_start=x0, seed=1, **kw):
        return sample_trajectories(
            model, x_start, policy[dt], horizon, n_traj, rng=seed, dtype=dt, **kw
        )

    # ---------------------------------------------------------------- per-step sampler speed
    flops = sampler_flops_per_step(E, M, D) * L * T
    print(
        f"\nper-step sampler: {L} trajectories x {T} steps "
        f"({sampler_flops_per_step(E, M, D) / 1e6:.2f} MFLOP per trajectory step), "
        f"best of {args.repeats}"
    )
    print(f"  {'threads':>7} {'dtype':>8} {'time [s]':>9} {'GFLOP/s':>8} {'% of peak':>9}")
    times = {}
    for th in args.threads:
        for dt in (F64, F32):
            with threads(th):
                times[th, dt] = best_time(lambda dt=dt: run(dt), args.repeats)
            rate = flops / times[th, dt] / 1e9
            name = str(dt).replace("torch.", "")
            print(
                f"  {th:>7} {name:>8} {times[th, dt]:9.3f} {rate:8.1f} "
                f"{100 * rate / peak[th, dt]:8.1f}%"
            )
    for th in args.threads:
        print(f"  float32 speed-up on {th} thread(s): {times[th, F64] / times[th, F32]:.2f}x")

    # ---------------------------------------------------------------- float32 accuracy
    Ls, Ts = args.spread_trajectories, args.spread_horizon
    xs = X_UP + task.initial_std * rng.standard_normal((1, Ls, 8))
    with threads(1):
        a = run(F64, Ls, Ts, xs, seed=1)
        b = run(F32, Ls, Ts, xs, seed=1)
        c = run(F64, Ls, Ts, xs, seed=2)
    fa, fb, fc = (r.states[0, :, -1].double().numpy() for r in (a, b, c))
    spread = fa.std(0)
    print(f"\nfloat32 accuracy ({Ls} trajectories x {Ts} steps, same seed as float64, 1 thread)")
    print(
        f"  precision_error (one-step moments vs float64, visited states): {b.precision_error:.2e}"
    )
    print(
        f"  paired |x32 - x64| at t = T / float64 std: max {np.max(np.abs(fb - fa) / spread):.2e}"
        f", median {np.median(np.abs(fb - fa) / spread):.2e}"
    )
    floor = gaussian_kl(fc, fa)
    print(
        f"  KL(Gaussian fits, t = T): float32 vs float64 {gaussian_kl(fb, fa):.2e}; "
        f"Monte Carlo floor (float64, other seed) {floor:.2e}"
    )

    # ---------------------------------------------------------------- GPyTorch peer baseline
    Tg = args.gpytorch_steps
    x0g = torch.as_tensor(x0[0])
    Gt = torch.as_tensor(G)
    rollout = gpytorch_rollout(model, x0g, Gt, Tg)
    print(f"\nGPyTorch peer baseline (SGPR, likelihood(model(z)) each step, {L} trajectories)")
    print(f"  {'threads':>7} {'gpytorch s/step':>15} {'ours s/step (f64)':>17} {'ratio':>6}")
    for th in args.threads:
        with threads(th):
            t_g = best_time(rollout, 1) / Tg
        ours = times[th, F64] / T
        print(f"  {th:>7} {t_g:15.4f} {ours:17.4f} {t_g / ours:5.1f}x")

    # ---------------------------------------------------------------- pathwise sampler
    F = args.features
    pw_flops = pathwise_flops_per_step(E, M, D, F)
    print(
        f"\npathwise sampler: F = {F} features, {L} trajectories x {T} steps "
        f"({pw_flops / 1e6:.3f} MFLOP per trajectory step), 1 thread; a step is one\n"
        f"  next_state_moments call on {L} states (set-up: drawing {L} functions)"
    )
    print(
        f"  {'features':>9} {'dtype':>8} {'set-up [ms/fn]':>14} {'step [s]':>9} "
        f"{'GFLOP/s':>8} {'per-step time / pathwise':>24}"
    )
    seeds = range(L)
    xq = torch.as_tensor(x0[0])
    uq = (xq - torch.as_tensor(X_UP)) @ torch.as_tensor(G).T
    with threads(1):
        for label, shared in (("fresh", None), ("shared", 0)):
            for dt in (F64, F32):
                basis = PathwiseBasis(p, F, dt, shared_seed=shared)
                t_draw = best_time(lambda b=basis: b.draw(seeds), 1)
                functions = model.with_predictor(basis.draw(seeds))
                per_step = model.to(dtype=dt)
                x, u = xq.to(dt), uq.to(dt)
                t_pw = best_time(lambda f=functions, x=x, u=u: f.next_state_moments(x, u), 5)
                t_ps = best_time(lambda m=per_step, x=x, u=u: m.next_state_moments(x, u), 5)
                name = str(dt).replace("torch.", "")
                print(
                    f"  {label:>9} {name:>8} {1e3 * t_draw / L:14.2f} {t_pw:9.4f} "
                    f"{pw_flops * L / t_pw / 1e9:8.1f} {t_ps / t_pw:10.1f}x"
                )
    with threads(1):
        pw = run(F64, Ls, Ts, xs, seed=1, method="pathwise", n_features=F)
    fp = pw.states[0, :, -1].numpy()
    print(f"  spread at t = {Ts} ({Ls} trajectories, float64, fresh features, 1 thread):")
    print(f"    per-step std per state: {np.round(spread, 3)}")
    print(f"    std ratio pathwise / per-step per state: {np.round(fp.std(0) / spread, 2)}")
    print(
        f"    KL(pathwise fit || per-step fit) {gaussian_kl(fp, fa):.3f}; Monte Carlo floor "
        f"(per-step, other seed) {floor:.3f}"
    )
    print(f"\nload after: {load()}   (benchmark wall time {time.perf_counter() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
