"""Robot hockey speed: rollouts per second of ``hockey`` and ``hockey-real``, and the arm share.

Run ``python benchmarks/bench_hockey.py [--repeats N] [--rounds R]``. Each round rolls out
ω ~ π₀(ω|s) (the task's initial policy) in random contexts; the median over rounds is the figure
to quote (the machine may be shared; the load average is printed). The split into the MuJoCo
arm phase (DMP reference + PD tracking) and the pymunk puck phase is measured separately.

Set ``OPENBLAS_NUM_THREADS=1``: on a loaded machine multithreaded OpenBLAS makes the DMP's
4×4 matrix exponential ~100× slower.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from skillkit.tasks import make


def _rates(fn, n: int, rounds: int) -> list[float]:
    out = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        out.append(n / (time.perf_counter() - t0))
    return out


def bench(name: str, repeats: int, rounds: int) -> None:
    """Time full rollouts and the arm phase alone for the registered task ``name``."""
    task = make(name)
    rng = np.random.default_rng(0)
    contexts = task.sample_context(rng, n=repeats)
    omegas = task.initial_policy().sample(contexts, rng)
    traj = task.rollout(omegas[0], contexts[0], rng=0)  # warm-up
    full = _rates(lambda i: task.rollout(omegas[i], contexts[i], rng=i), repeats, rounds)
    arm = _rates(lambda i: task.simulate_arm(omegas[i]), repeats, rounds)
    med, arm_med = float(np.median(full)), float(np.median(arm))
    print(
        f"{name:12s} {med:6.1f} rollouts/s (median of {rounds} rounds of {repeats}; "
        f"min {min(full):.1f}); arm phase alone {arm_med:6.1f}/s = {100 * med / arm_med:.0f}% "
        f"of a rollout; {traj.n_steps} arm and {traj.signals['puck_times'].size} puck records"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=40, help="rollouts per timing round")
    parser.add_argument("--rounds", type=int, default=3, help="timing rounds")
    args = parser.parse_args()
    print(
        f"python {platform.python_version()} on {platform.machine()}, "
        f"load average {os.getloadavg()[0]:.2f}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}"
    )
    for name in ("hockey", "hockey-real"):
        bench(name, args.repeats, args.rounds)


if __name__ == "__main__":
    main()
