"""Rollouts per second of the planar 4-link robot tasks (throwing, balancing).

Plain script (not a test): ``python benchmarks/bench_planar.py [--n N]``. Prints wall-clock and
process-CPU rates; on a shared machine the CPU rate is the more stable figure. Set
``OPENBLAS_NUM_THREADS=1`` for single-core numbers (BLAS threads only add overhead to the
small matrix operations here).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skillkit.tasks import make


def bench(name: str, n: int, seed: int = 0) -> dict[str, float]:
    """Roll out ``n`` samples of the task's initial policy; return rates and the failure count."""
    task = make(name)
    rng = np.random.default_rng(seed)
    policy = task.initial_policy()
    contexts = task.sample_context(rng, n=n) if task.context_dim else np.zeros((n, 0))
    omegas = np.atleast_2d(policy.sample(contexts, rng))
    task.rollout(omegas[0], contexts[0] if task.context_dim else None, rng)  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    failed = 0
    for w, s in zip(omegas, contexts, strict=True):
        traj = task.rollout(w, s if task.context_dim else None, rng)
        failed += traj.failed
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"wall_per_s": n / wall, "cpu_per_s": n / cpu, "ms_cpu": 1e3 * cpu / n, "failed": failed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=200, help="rollouts per task")
    args = parser.parse_args()
    for name in ("throwing", "balancing", "balancing-noisy"):
        r = bench(name, args.n)
        print(
            f"{name:16s} {r['wall_per_s']:7.1f} rollouts/s wall  "
            f"{r['cpu_per_s']:7.1f} rollouts/s CPU "
            f"({r['ms_cpu']:.2f} ms CPU each, {r['failed']} failed of {args.n})"
        )


if __name__ == "__main__":
    main()
