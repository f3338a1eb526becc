"""Benchmark: trajectory sampling vs moment matching with the same GP model (Sec. 4.2.2, Fig. 4.4).

Prints, in one run, for 1 and 2 torch threads:

* this machine's float64 matmul peak (a large square matmul, best of a few),
* the wall time of one moment-matching prediction
  (:func:`skillkit.models.moment_matching.propagate`) over the horizon,
* the wall time of sampling N trajectories (:func:`skillkit.models.sampling.sample_trajectories`)
  with the same model, controller and horizon,
* how many trajectories the sampler produces in the time of one moment-matching prediction
  (thesis: about 1000 on one core; goal here: at least 10,000 on 2 cores),
* the sampler's FLOP rate (analytic count :func:`skillkit.models.sampling.sampler_flops_per_step`)
  as a fraction of the measured matmul peak.

The model is a FITC forward model of the planar 4-link robot under the balancing feedback
(8 states, 4 controls: 12 GP inputs, 8 outputs), trained on ``--n-data`` transitions with
``--n-pseudo`` pseudo-inputs (published setting 1500 / 300, horizon 100). Hyper-parameters
get only a few optimisation steps: timings do not depend on their values.

Usage::

    python benchmarks/bench_models.py [--n-data 1500] [--n-pseudo 300] [--horizon 100]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch

from skillkit.experiments import get
from skillkit.experiments.ch4_models import _train_balancing_model, time_predictions
from skillkit.models.sampling import sampler_flops_per_step
from skillkit.tasks.balancing import X_UP, stable_gains


def matmul_peak(threads: int, n: int = 2048, repeats: int = 3) -> float:
    """Best float64 GFLOP/s of an n × n matmul with ``threads`` torch threads."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        a = torch.randn(n, n, dtype=torch.float64)
        b = torch.randn(n, n, dtype=torch.float64)
        out = torch.empty(n, n, dtype=torch.float64)
        torch.matmul(a, b, out=out)  # warm-up
        best = min(_timed(lambda: torch.matmul(a, b, out=out)) for _ in range(repeats))
    finally:
        torch.set_num_threads(before)
    return 2.0 * n**3 / best / 1e9


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n-data", type=int, default=1500)
    parser.add_argument("--n-pseudo", type=int, default=300)
    parser.add_argument("--horizon", type=int, default=100)
    parser.add_argument("--n-trajectories", type=int, nargs="+", default=[100, 1000, 5000])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)

    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"torch {torch.__version__}, {torch.get_num_threads()} threads available"
    )
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
    task, model, data = _train_balancing_model(settings, rng)
    pred = model.predictor
    E, M, D = pred.output_dim, pred.n_support, pred.input_dim
    print(
        f"model: FITC, N = {len(data['x'])} transitions, M = {M} pseudo-inputs, "
        f"{D} inputs, {E} outputs, "
        f"horizon T = {args.horizon} (trained in {time.perf_counter() - t0:.1f} s)"
    )
    m0 = X_UP + task.initial_std * rng.standard_normal(8)
    G = stable_gains(task, 1, rng)[0].reshape(4, 8)
    flops_per_traj = sampler_flops_per_step(E, M, D) * args.horizon

    rows = []
    for th in args.threads:
        peak = matmul_peak(th)
        res = time_predictions(
            model, m0, 0.05**2 * np.eye(8), G, args.horizon, args.n_trajectories, [th], 2, rng
        )
        mm = res["mm_time"][str(th)]
        times = res["sampling_time"][str(th)]
        n_max, t_max = args.n_trajectories[-1], times[-1]
        rate = flops_per_traj * n_max / t_max / 1e9
        rows.append((th, peak, mm, times, res["trajectories_in_mm_time"][str(th)], rate))

    print()
    header = "  ".join(f"N={n:>6}" for n in args.n_trajectories)
    print(
        f"{'threads':>7}  {'matmul peak':>12}  {'MM time':>9}  sampling time [{header}]  "
        f"{'traj. in MM time':>16}  {'sampler GFLOP/s':>15}  {'% of peak':>9}"
    )
    for th, peak, mm, times, n_eq, rate in rows:
        ts = "  ".join(f"{t:8.3f}" for t in times)
        print(
            f"{th:>7}  {peak:9.1f} GF  {mm:8.3f}s  [{ts}]  {n_eq:16.0f}  {rate:15.1f}  "
            f"{100 * rate / peak:8.1f}%"
        )
    print()
    print(
        "thesis: ~1000 trajectories in one MM prediction's time on one CPU core; "
        "goal here: >= 10,000 on 2 cores"
    )
    print(
        f"sampler work: {sampler_flops_per_step(E, M, D) / 1e6:.2f} MFLOP per trajectory step "
        f"(dominated by the 2·E·M² variance product)"
    )


if __name__ == "__main__":
    main()
