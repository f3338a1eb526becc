"""Benchmark: the prediction speed of the GP models, every figure in one run.

Runs, in one process and in this order, with the machine's load printed before and after each
part (other processes on a shared machine inflate every time):

1. ``bench_sampler.py``: the float64 / float32 matmul peak on 1 and 2 threads, the per-step
   sampler's GFLOP/s and fraction of peak (float64, float32), the GPyTorch user's rollout
   (its predictive distribution called every step) as the peer baseline with the speed ratio,
   and the pathwise sampler's step time;
2. ``bench_moment_matching.py``: moment matching's GFLOP/s and fraction of peak, and a 100-step
   prediction, batched and unbatched;
3. fig4.4's own measurement, run fresh into ``--out`` (``--fig44-scale``, default ``paper``:
   FITC with 1500 points and 300 pseudo-inputs, 100 steps, trained on balancing data):
   moment-matching time, sampling time per N and trajectories per moment-matching prediction,
   each with its GFLOP/s from the counted flops, as fig4.4's summary reports them
   (:func:`~skillkit.models.sampling.sampler_flops_per_step` and
   :func:`~skillkit.models.moment_matching.moment_matching_flops_per_step`);
4. ``bench_gpreps.py --task throwing``: one GPREPS throwing update at M = 500 × L = 25, split
   into training / prediction / policy, float64 and float32, 1 and 2 threads;
5. ``bench_reps.py``: one contextual REPS update at N = 10,000 (both dual solvers).

``--quick`` shrinks every part (a check that the driver runs, not a measurement).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_prediction.py [--quick] [--fig44-scale paper]
"""

from __future__ import annotations

import argparse
import os
import runpy
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _script(name: str, argv: list[str]) -> None:
    """Run ``benchmarks/<name>`` as ``__main__`` with ``argv``, between two load readings."""
    print(f"\n===== {name} {' '.join(argv)}   (load before: {_load()})", flush=True)
    t0, saved = time.perf_counter(), sys.argv
    sys.argv = [str(HERE / name), *argv]
    try:
        runpy.run_path(str(HERE / name), run_name="__main__")
    finally:
        sys.argv = saved
    print(f"===== {name}: {time.perf_counter() - t0:.0f} s (load after: {_load()})", flush=True)


def fig44_lines(summary: dict) -> list[str]:
    """Lines with fig4.4's times and each implementation's GFLOP/s (from its summary)."""
    T = summary["model"]["horizon"]
    lines = []
    for th, mm in summary["mm_time_s"].items():
        lines.append(
            f"{th} thread(s): moment matching {mm:.3f} s per {T}-step prediction = "
            f"{summary['mm_gflops'][th]:.2f} GFLOP/s; "
            f"trajectories in that time {summary['trajectories_in_mm_time'][th]:.0f}"
        )
        for n, t in summary["sampling_time_s"][th].items():
            rate = summary["sampling_gflops"][th][n]
            lines.append(f"    sampling N = {n:>6}: {t:8.3f} s = {rate:6.2f} GFLOP/s")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes (driver check)")
    parser.add_argument("--fig44-scale", choices=["smoke", "quick", "paper"], default="paper")
    parser.add_argument("--out", default="runs", help="folder of the fresh fig4.4 run")
    args = parser.parse_args()
    q = args.quick
    print(f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, load {_load()}")

    _script(
        "bench_sampler.py",
        ["--trajectories", "50", "--horizon", "5", "--spread-trajectories", "50",
         "--spread-horizon", "10", "--gpytorch-steps", "2", "--repeats", "1"] if q else [],
    )  # fmt: skip
    _script(
        "bench_moment_matching.py",
        ["--inducing", "50", "--steps", "5", "--repeats", "1"] if q else [],
    )

    from skillkit.experiments import reproduce

    scale = "smoke" if q else args.fig44_scale
    print(f"\n===== fig4.4 at scale {scale}   (load before: {_load()})", flush=True)
    run = reproduce("fig4.4", scale=scale, seed=0, out=args.out, fresh=True, html=False)
    print(f"fig4.4 result: {run.path}")
    summary = run.summary
    for line in fig44_lines(summary):
        print(line)
    print(f"===== fig4.4 (load after: {_load()})", flush=True)

    _script(
        "bench_gpreps.py",
        ["--task", "throwing"]
        + (["--artificial", "20", "--trajectories", "2", "--threads", "1"] if q else []),
    )
    _script("bench_reps.py", [])


if __name__ == "__main__":
    main()
