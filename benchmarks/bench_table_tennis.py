"""Table-tennis speed: rollouts per second, and where the time goes.

Run ``python benchmarks/bench_table_tennis.py [--rollouts N] [--rounds R]``. A rollout is
one :meth:`TableTennis.rollout` (DMP reference, MuJoCo PD tracking at 250 Hz over 1.2 s,
the ball integrated against the recorded racket path) with ω drawn from the initial
policy in random contexts. Prints the median and the slowest of several timing rounds (the
machine may be shared, so the median is the figure to quote) and a per-stage breakdown.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from skillkit.tasks import make
from skillkit.tasks.table_tennis import SERVE_POSITION, RacketPath, simulate_ball


def _rate(fn, n: int, rounds: int) -> tuple[float, float, float]:
    """Median and slowest wall-clock rate over the rounds, and the rate per CPU-second of
    this process (the load-independent figure on a shared machine)."""
    rates, cpu = [], []
    for _ in range(rounds):
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(n):
            fn(i)
        rates.append(n / (time.perf_counter() - t0))
        cpu.append(n / (time.process_time() - c0))
    return float(np.median(rates)), float(np.min(rates)), float(np.median(cpu))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rollouts", type=int, default=40, help="rollouts per timing round")
    parser.add_argument("--rounds", type=int, default=5, help="timing rounds")
    args = parser.parse_args()

    task = make("table-tennis")
    rng = np.random.default_rng(0)
    contexts = task.sample_context(rng, n=args.rollouts)
    omegas = task.initial_policy().sample(contexts, rng)
    print(
        f"platform: {platform.platform()}, python {platform.python_version()}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}"
    )

    med, low, cpu = _rate(
        lambda i: task.rollout(omegas[i], contexts[i]), args.rollouts, args.rounds
    )
    print(
        f"full rollout:         {med:7.1f} rollouts/s (median), {low:7.1f} (slowest round), "
        f"{cpu:7.1f} per CPU-second"
    )

    dmp = task.parameters.from_vector(omegas[0])
    med, _, cpu = _rate(lambda i: dmp.rollout(task.times, task.q0), args.rollouts, args.rounds)
    print(f"  DMP reference only: {med:7.1f} /s, {cpu:7.1f} per CPU-second")

    traj = task.rollout(omegas[0], contexts[0])
    racket = RacketPath(
        traj.times,
        traj.signals["racket"],
        traj.signals["racket_normal"],
        np.gradient(traj.signals["racket"], traj.times, axis=0),
        np.zeros_like(traj.signals["racket"]),
    )
    med, _, cpu = _rate(
        lambda i: simulate_ball(
            SERVE_POSITION, contexts[i, :3], task.duration, dt=task.control_dt, racket=racket
        ),
        args.rollouts,
        args.rounds,
    )
    print(f"  ball flight only:   {med:7.1f} /s, {cpu:7.1f} per CPU-second")


if __name__ == "__main__":
    main()
