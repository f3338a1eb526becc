"""Time contextual BO's proposals on the throwing task: one batch of UCB proposals searched
row by row (one ``optimize_acqf`` call per context, as before the batched search) against one
batched call (:meth:`~skillkit.search.cbo.CBOPolicy.sample`), and the policy mean on the
evaluation contexts (searched context by context).

Setting: throwing (ω ∈ R^41, s ∈ R^2, so the GP is over 43 inputs), the default
:class:`~skillkit.search.cbo.CBOSettings` (10 restarts from 512 Sobol points, β = 0.2), a GP
fitted on the ``N`` rollouts of a Sobol batch and ``UPDATES − 1`` UCB batches of 10; then a
batch of 10 proposals timed both ways with the same seeds, and the UCB value each reaches.
CPU time of this process (``time.process_time``) and wall time, load average before and
after. Run::

    OMP_NUM_THREADS=1 python benchmarks/bench_cbo.py [--updates 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch
from botorch.acquisition import UpperConfidenceBound

from skillkit.search.cbo import ContextualBO
from skillkit.search.loop import collect
from skillkit.tasks import make


def _timed(f):
    c0, w0 = time.process_time(), time.perf_counter()
    out = f()
    return out, time.process_time() - c0, time.perf_counter() - w0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--updates", type=int, default=3, help="batches of 10 before timing")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    task = make("throwing")
    alg = ContextualBO.for_task(task, rng=0)
    rng = np.random.default_rng(1)
    for _ in range(args.updates):
        alg.update(collect(task, alg.policy, alg.rollouts_per_update, rng=rng))
    policy = alg.policy
    contexts = task.sample_context(rng, n=10)
    seeds = rng.integers(2**31, size=10)
    acqf = UpperConfidenceBound(policy.model, beta=policy.settings.beta)
    rows, c_rows, w_rows = _timed(
        lambda: np.stack(
            [policy._argmax(acqf, s, int(k)) for s, k in zip(contexts, seeds, strict=True)]
        )
    )
    batched, c_batch, w_batch = _timed(lambda: policy._argmax_rows(acqf, contexts, seeds))
    _, c_mean, w_mean = _timed(lambda: policy.mean_of(contexts[:8]))

    def ucb(omega):
        z = torch.as_tensor(np.hstack([contexts, omega]), dtype=torch.float64)[:, None, :]
        with torch.no_grad():
            return acqf(z).numpy()

    n = policy.model.train_targets.shape[-1]
    print(f"N = {n} samples, d = {task.parameter_dim} + {task.context_dim}")
    print(f"10 proposals row by row: CPU {c_rows:.1f} s, wall {w_rows:.1f} s")
    print(f"10 proposals batched:    CPU {c_batch:.1f} s, wall {w_batch:.1f} s "
          f"(ratio {c_rows / c_batch:.1f}x CPU)")  # fmt: skip
    print(f"policy mean, 8 contexts: CPU {c_mean:.1f} s, wall {w_mean:.1f} s")
    gap = ucb(batched) - ucb(rows)
    print(f"UCB batched − row by row: min {gap.min():.2e}, max {gap.max():.2e}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
