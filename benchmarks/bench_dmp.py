"""DMP speed: rollouts per second of a 7-joint, 10-basis DMP over 1.5 s at 1 kHz.

Run ``python benchmarks/bench_dmp.py [--repeats N]``; prints the median of several timing
rounds (the machine may be shared, so the median is the figure to quote).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from skillkit.policies.dmp import DMP, DMPParameters


def _demo(n_joints: int, duration: float, dt: float):
    t = np.arange(int(round(duration / dt)) + 1) * dt
    w = 2 * np.pi / duration * (1 + np.arange(n_joints) / n_joints)
    q = np.sin(w * t[:, None]) * (1 - np.cos(w * t[:, None]))
    qd = np.gradient(q, t, axis=0)
    qdd = np.gradient(qd, t, axis=0)
    return t, q, qd, qdd


def _rate(fn, n: int, rounds: int) -> tuple[float, float]:
    rates = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        rates.append(n / (time.perf_counter() - t0))
    return float(np.median(rates)), float(np.min(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=200, help="rollouts per timing round")
    parser.add_argument("--rounds", type=int, default=5, help="timing rounds")
    args = parser.parse_args()

    n_joints, duration, dt = 7, 1.5, 1e-3
    t, q, qd, qdd = _demo(n_joints, duration, dt)
    dmp = DMP(n_joints, n_basis=10, dt=dt).fit(t, q, qd, qdd)
    view = DMPParameters(dmp, learn=("goal", "goal_velocity", "tau"))
    rng = np.random.default_rng(0)
    omegas = view.to_vector() + 0.01 * rng.normal(size=(args.repeats, view.dim))
    it = iter(range(10**9))

    fixed, fixed_min = _rate(lambda: dmp.rollout(duration, q[0]), args.repeats, args.rounds)
    varied, varied_min = _rate(
        lambda: view.from_vector(omegas[next(it) % args.repeats]).rollout(duration, q[0]),
        args.repeats,
        args.rounds,
    )
    fit, fit_min = _rate(
        lambda: DMP(n_joints, n_basis=10, dt=dt).fit(t, q, qd, qdd), 50, args.rounds
    )
    print(f"machine: {platform.platform()} ({platform.machine()}), numpy {np.__version__}")
    print(
        f"DMP {n_joints} joints x 10 basis, {duration} s at {1 / dt:.0f} Hz "
        f"({len(t)} steps), median (min) over {args.rounds} rounds:"
    )
    print(f"  rollout, fixed parameters     : {fixed:8.0f} ({fixed_min:.0f}) rollouts/s")
    print(f"  rollout from omega (g, gd, tau): {varied:8.0f} ({varied_min:.0f}) rollouts/s")
    print(f"  fit from a demonstration      : {fit:8.0f} ({fit_min:.0f}) fits/s")


if __name__ == "__main__":
    main()
