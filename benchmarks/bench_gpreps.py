"""Benchmark: wall time of ONE GPREPS policy update (Table 4.1) at the thesis's M × L.

Measures :meth:`skillkit.search.gpreps.GPREPS.update` with a
:class:`~skillkit.search.gpreps.TrajectoryRewardModel` (a FITC sparse-GP forward model,
``--inducing`` pseudo-inputs, default 100) at M = ``--artificial`` artificial samples (500) ×
L = ``--trajectories`` predicted trajectories per sample (25), the thesis's setting
(Sec. 4.3.1), split as GPREPS's own diagnostics split it:

* **training** (``time_training``): refitting the forward model on all real transitions,
  hyper-parameter optimisation included (step 1 of Table 4.1),
* **prediction** (``time_prediction``): drawing the M artificial (s, ω) and sampling the
  M · L model trajectories over the task's horizon (Eq. 4.1, step 2); also reported as the
  sampler throughput in trajectory-steps per second, M · L · T / time,
* **policy** (``time_policy``): the REPS dual (3.9) and weighted ML fit (3.11–3.13) on the
  M artificial samples (step 3),

for each ``--threads`` count (``torch.set_num_threads``, set inside this script only and
restored afterwards; OpenMP/BLAS threads outside torch follow ``OMP_NUM_THREADS``, so run with
``OMP_NUM_THREADS=1`` for a clean 1-vs-2 comparison of torch's own threading), and prints the
2-thread / 1-thread ratios measured in the same run, the torch version and the machine's load
average before and after (other processes on a shared machine inflate the times).

**Task** (``--task``). ``throwing`` (the thesis's timing, Sec. 4.3.2): the decomposed model of
Fig. 4.2 (:class:`~skillkit.search.throwing_model.ThrowingRewardModel`: FITC robot dynamics with
``--inducing`` pseudo-inputs (default 50) on at most 1000 transitions, the exact-GP release
model on 300 hand states, the FITC flight model), trained on N₀ = 10 throws of the imitation
policy (1240 transitions, so every data cap is already reached and later updates cost the
same), 125 control steps per throw and 250 flight steps. ``balancing`` (4-link planar robot,
32 gains, horizon T = 40 control steps) with a
:class:`~skillkit.search.gpreps.TrajectoryRewardModel` (FITC, default 100 pseudo-inputs).

**Real data (balancing).** N₀ = ``--initial-rollouts`` (default 20) real rollouts of robustly
balancing gains drawn from the task's initial policy by
:func:`skillkit.tasks.balancing.stable_gains`
(closed-loop spectral radius ≤ 0.98; rollouts that fall are replaced,
:func:`~skillkit.tasks.balancing.collect_balancing`), so the model is trained on N₀ · T
transitions. The update timed is the *first* GPREPS update on that batch (no prediction of an
earlier model on it); each repeat builds a fresh GPREPS with the same seed, and the table
reports, per thread count, the repeat with the smallest total (and each part of that repeat).
Below M = 100 the policy fit's effective-sample-size check (d + 1 = 33) is relaxed to 1 so that
tiny runs complete; the thesis setting M = 500 uses the library default.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_gpreps.py [--task throwing|balancing]
        [--artificial 500] [--trajectories 25] [--initial-rollouts 10|20] [--inducing 50|100]
        [--threads 1 2] [--dtype float64 float32] [--flight full stop] [--device cpu|cuda]
        [--repeats 1]

Throwing, measured on the 2-CPU x86_64 VM (Linux 6.18, torch 2.13.0+cpu, ``OMP_NUM_THREADS=1``,
nothing else running), load average 0.40 before, 1.18 after,
``OMP_NUM_THREADS=1 python benchmarks/bench_gpreps.py --task throwing --repeats 2`` (M = 500,
L = 25, 124 predicted transitions, N₀ = 10 throws, FITC robot GP with 50 pseudo-inputs on 1000
transitions, 150 optimiser iterations per GP)::

    threads   training  prediction    policy     total  traj-steps/s
          1      8.57s      15.59s    0.005s    24.16s      9.94e+04
          2      7.04s       9.31s    0.005s    16.36s      1.67e+05
    totals of all repeats: 1 thread 24.48, 24.16 s; 2 threads 17.75, 16.36 s
    ratio 2 / 1 threads (time): training 0.82, prediction 0.60, policy 0.99, total 0.68

With the x′ robot model, a run beside another job (load 2.9) took
38.1 s (float64) / 29.3 s (float32) on one thread; the quiet-machine runs below supersede it.

With the flight stopped at the ground (``--flight stop``, ``stop_flight_at_ground=True``; the
same predictions to round-off) and the torques of all steps computed in one call, float64,
the other job paused (SIGSTOP) so nothing else ran (load average 1.62 before, 1.60 after,
decaying from the paused job), ``--dtype float64 --threads 1 2 --flight full stop``::

    threads    dtype  flight   training  prediction    policy     total  traj-steps/s  GP iters
          1  float64    full     11.71s      19.59s    0.005s    31.31s      7.91e+04       150
          1  float64    stop      9.55s      17.89s    0.006s    27.45s      8.66e+04       150
          2  float64    full      7.56s      14.16s    0.005s    21.73s      1.09e+05       150
          2  float64    stop      7.70s      11.27s    0.005s    18.97s      1.38e+05       150

The same, all variants, in the one-run benchmark ``bench_prediction.py`` on a quiet machine
(load average 1.78 before, 1.57 after; nothing else ran)::

    threads    dtype  flight   training  prediction    policy     total  traj-steps/s  GP iters
          1  float64    full      9.44s      19.23s    0.006s    28.68s      8.06e+04       150
          1  float64    stop     11.51s      16.21s    0.006s    27.73s      9.56e+04       150
          1  float32    full     10.69s      14.98s    0.004s    25.67s      1.03e+05       150
          1  float32    stop      9.71s      12.24s    0.006s    21.96s      1.27e+05       150
          2  float64    full      7.37s      15.13s    0.006s    22.51s      1.02e+05       150
          2  float64    stop      7.69s      12.56s    0.005s    20.26s      1.23e+05       150
          2  float32    full      7.76s      10.59s    0.005s    18.35s      1.46e+05       150
          2  float32    stop      7.11s       8.05s    0.004s    15.17s      1.92e+05       150

Two threads, float64, quiet machine (load average 0.40 before, 1.59 after),
``--dtype float64 --threads 2 --flight full stop --repeats 3``, totals of the three repeats:
flight stopped 18.01, 19.46, 19.70 s (best: training 7.41, prediction 10.60); full flight 22.37,
20.17, 19.74 s. So the float64 update on two threads takes 18.0–20.3 s with the flight stopped
(5 updates in three runs, 4 under 20 s) and 19.7–22.5 s without: at the 20 s target.
Stopping the flight saves 0.80 (2 threads) / 0.91 (1 thread) of the prediction time; the
training times of the 1-thread rows differ by 2 s although they do the same work (one repeat:
timing noise of this VM). Not done: stopping the arm's rollout at the release (the reward's
torque and joint-limit terms run to the end of the movement, so they would need a model of
their own).

After the float64 kernel floor (``gp.FLOOR_EXPONENT_FLOAT64``: kernel entries below
e^−600 σ_f² raised to it) and the throwing reward's batch parts in cache-sized blocks of rows
(torques, path distances, joint-limit penalties: ``planar._by_rows``; ``land`` without
fancy-indexed copies), all with the same predictions bit for bit (measured on 500 × 25
throws), nothing else running: ``--dtype float64 --threads 2 --flight stop full --repeats 5``
(load average 1.96 after)::

    threads    dtype  flight   training  prediction    policy     total  traj-steps/s  GP iters
          2  float64    stop      8.04s       8.73s    0.007s    16.78s      1.78e+05       150
          2  float64    full      6.36s       9.46s    0.004s    15.82s      1.64e+05       150
    2 thread(s), float64, flight stop, totals of all repeats: 18.42s, 16.78s, 17.24s, 17.51s, 17.60s
    2 thread(s), float64, flight full, totals of all repeats: 17.16s, 19.56s, 15.82s, 16.63s, 18.17s

Just before it, ``--threads 1 2 --flight stop --repeats 3``: 2 threads 18.02, 15.47, 19.20 s;
1 thread 27.10, 21.48, 24.67 s; and after it the one-run benchmark ``bench_prediction.py`` (one
repeat each): 2 threads 16.12 s stopped, 21.14 s full (whose training alone took 9.58 s against
7.96 s in the stopped row: the same work, this VM's noise). So on two threads in float64, with
the flight stopped at the ground (the default) all 9 updates took 15.5–19.2 s, under the
20 s target; with the full flight 5 of 6 did (15.8–21.1 s); without the floor and the blocks
18.0–20.3 s (stopped) and 19.7–22.5 s (full), with the floor alone 17.0–23.6 s (stopped).
One-thread predictions of the same 500 × 25 throws: 18.6–24.2 s without either, 16.0–18.8 with
the floor, 10.7–13.2 with the blocks too. This VM's speed varies by ±15% between runs minutes
apart (its 1-thread float64 matmul peak: 57–76 GFLOP/s this week).

float32 is not usable on these models: the sampler's precision check warns (robot 3–5% of a
predictive std, flight 19–26%, and ~3.8e5 negative flight variances clamped).

The thesis reports up to half an hour per throwing update on a CPU (under a minute on a GPU).
The prediction includes the 250-step ball flight of all 12,500 throws.

Balancing, measured on a shared 2-CPU x86_64 VM (Linux 6.18, torch 2.13.0+cpu,
``OMP_NUM_THREADS=1``, 4 other jobs on the machine), load average 2.01 before, 1.63 after, with
``--repeats 3`` at the defaults (M = 500, L = 25, T = 40, N₀ = 20 → 800 transitions, FITC
100 pseudo-inputs, 150 GP optimiser iterations)::

    threads   training  prediction    policy     total  traj-steps/s
          1      7.94s       3.05s    0.002s    10.99s      1.64e+05
          2      4.74s       1.99s    0.003s     6.73s      2.51e+05
    totals of all repeats: 1 thread 12.64, 11.13, 10.99 s; 2 threads 7.05, 6.73, 8.24 s
    ratio 2 / 1 threads (time): training 0.60, prediction 0.65, policy 1.06, total 0.61

A single-repeat run while the load rose to 3.5 gave 108 s of training on 2 threads (10 s on
1): with both cores busy elsewhere, torch's two threads wait on each other at every one of the
many small ops of the hyper-parameter optimisation. Use ``--repeats`` ≥ 3 and read the spread.

**On a GPU** (``--device cuda``; one lease of an NVIDIA H200 on a 16-core host, torch
2.11.0+cu130, Python 3.12, 2026-12-04; ``OMP_NUM_THREADS=1`` and ``--threads 1``, so the
``cpu`` rows are one core of the same host, measured in the same command; load average < 1).
Balancing at Table 4.2's setting, ``--task balancing --artificial 500 --trajectories 10
--dtype float64`` (N₀ = 20 → 800 transitions, FITC 100 pseudo-inputs), two commands (the
second with two repeats: the faster shown, both totals in brackets)::

    command  device   training  prediction    policy     total  traj-steps/s
      1 (×1)    cpu     10.55s       1.05s    0.003s    11.60s       1.9e+05
      1 (×1)   cuda     10.28s       0.52s    0.003s    10.80s      3.86e+05
      2 (×2)    cpu     12.09s       1.82s    0.004s    13.92s       1.1e+05  (18.12, 13.92)
      2 (×2)   cuda     10.79s       0.16s    0.003s    10.95s      1.27e+06  (15.78, 10.95)

Throwing at Table 4.1's setting, ``--task throwing --flight stop`` (M = 500, L = 25)::

     device    dtype   training  prediction    policy     total  traj-steps/s
        cpu  float64     12.56s       8.14s    0.005s    20.71s       1.9e+05
       cuda  float64     11.59s       3.57s    0.005s    15.17s      4.34e+05
       cuda  float32      9.84s       2.86s    0.004s    12.70s      5.41e+05

The GPU samples the trajectories 2.3–11× faster (more with a warm device: the second command's
0.16 s), but the forward model's training — 150 optimiser iterations of a FITC GP with 50–100
pseudo-inputs on 800–1240 transitions, each iteration a chain of small kernels (not profiled;
launch latency is the likely bound) — takes as long as on one CPU core, and it is most of the
update: the whole update is only 1.07–1.37× faster
(balancing 10.8–11.0 s against 11.6–13.9 s, throwing 15.2 s against 20.7 s). The thesis's
"up to half an hour" per throwing update on a CPU and "under a minute" on a GPU are both far
above ours. In the same lease ``tests/models/test_gp.py`` and ``tests/models/test_sparse.py``
ran their CUDA tests (fit on ``cuda`` equals fit on ``cpu``): the sparse ones failed first,
on the row signs of ``var_factor`` (an eigendecomposition's eigenvectors: LAPACK and cuSOLVER
choose different signs), and pass since the test compares RᵀR = iK, the invariant the
predictions use.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

from skillkit.models.gp import ForwardModel
from skillkit.models.sparse import FITC
from skillkit.search.base import Batch
from skillkit.search.gpreps import GPREPS, GPREPSSettings, TrajectoryRewardModel
from skillkit.search.throwing_model import ThrowingRewardModel
from skillkit.tasks import make
from skillkit.tasks.balancing import Balancing, collect_balancing

#: Below this M the policy fit's effective-sample-size check (default d + 1 = 33) is relaxed to
#: 1, so that tiny timing runs do not stop there (the floor keeps Σ positive definite).
SMALL_M = 100


class _FITCForwardModel:
    """``make_model()`` for the reward model: a fresh FITC forward model with M_ind inputs."""

    def __init__(self, n_inducing: int):
        self.n_inducing = n_inducing

    def __call__(self) -> ForwardModel:
        return ForwardModel(FITC(n_inducing=self.n_inducing))


def real_batch(task: Balancing, n: int, seed: int) -> tuple[Batch, int]:
    """N₀ real rollouts of robustly balancing gains; returns the batch and failed rollouts."""
    data = collect_balancing(task, n, np.random.default_rng(seed))
    trajs = data["trajectories"]
    rewards = np.array([task.reward(t) for t in trajs])
    return Batch(None, data["omegas"], rewards, trajs), data["n_failed"]


def real_throws(task, n: int, seed: int) -> Batch:
    """N₀ throws of the imitation policy at random targets."""
    rng = np.random.default_rng(seed)
    s = task.sample_context(rng, n=n)
    w = task.initial_policy().sample(s, rng)
    trajs = [task.rollout(wi, si, rng) for wi, si in zip(w, s, strict=True)]
    rewards = np.array([task.reward(t, si) for t, si in zip(trajs, s, strict=True)])
    return Batch(s, w, rewards, trajs)


def one_update(
    task, batch: Batch, args: argparse.Namespace, dtype: torch.dtype, flight: str = "full"
) -> dict:
    """Wall times of one GPREPS update from a fresh GPREPS (seeded by ``args.seed``), its
    trajectories sampled in ``dtype``; throwing: ``flight`` "stop" stops each predicted ball
    at the ground (``stop_flight_at_ground``), "full" flies every ball for 2.5 s."""
    if args.task == "throwing":
        model = ThrowingRewardModel(
            task,
            make_robot_model=_FITCForwardModel(args.inducing),
            max_robot_points=1000,
            device=args.device,
            dtype=dtype,
            stop_flight_at_ground=flight == "stop",
        )
    else:
        model = TrajectoryRewardModel(
            task, make_model=_FITCForwardModel(args.inducing), device=args.device, dtype=dtype
        )
    settings = GPREPSSettings(
        n_artificial=args.artificial,
        n_trajectories=args.trajectories,
        context_model="uniform",
        min_effective_samples=1.0 if args.artificial < SMALL_M else None,
        cov_floor=0.1 if args.task == "throwing" else 1e-4,
    )
    gpreps = GPREPS(task.initial_policy(), model, settings, rng=args.seed + 1)
    t0 = time.perf_counter()
    diag = gpreps.update(batch)
    total = time.perf_counter() - t0
    return {
        "training": diag.time_training,
        "prediction": diag.time_prediction,
        "policy": diag.time_policy,
        "total": total,
        "eta": diag.reps.eta,
        "iterations": diag.model_fit.get(
            "iterations", diag.model_fit.get("robot", {}).get("iterations")
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--artificial", type=int, default=500, help="M artificial samples")
    parser.add_argument("--trajectories", type=int, default=25, help="L trajectories per sample")
    parser.add_argument("--task", choices=["throwing", "balancing"], default="throwing")
    parser.add_argument(
        "--initial-rollouts", type=int, default=None, help="N0 real rollouts (10 / 20)"
    )
    parser.add_argument(
        "--inducing", type=int, default=None, help="FITC pseudo-inputs M_ind (50 / 100)"
    )
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument(
        "--dtype",
        choices=["float64", "float32"],
        nargs="+",
        default=["float64", "float32"],
        help="precision of the sampled trajectories (float32: the sampler's faster path)",
    )
    parser.add_argument(
        "--flight",
        choices=["full", "stop"],
        nargs="+",
        default=["full", "stop"],
        help="throwing: predict every ball's whole 2.5 s flight (full, the stored results' "
        "setting) or stop each at the ground (stop; the same predictions, less work)",
    )
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    throwing = args.task == "throwing"
    if args.initial_rollouts is None:
        args.initial_rollouts = 10 if throwing else 20
    if args.inducing is None:
        args.inducing = 50 if throwing else 100
    for name in ("artificial", "trajectories", "initial_rollouts", "inducing", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')}: expected a positive integer")
    if args.artificial < 2:
        parser.error("--artificial: GPREPS needs M >= 2")
    if any(t < 1 for t in args.threads):
        parser.error("--threads: expected positive integers")
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: torch reports no CUDA device on this machine")

    load_before = os.getloadavg()
    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, torch {torch.__version__}, "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, device {args.device}"
        + (f" ({torch.cuda.get_device_name()})" if args.device == "cuda" else "")
    )
    print("load average before: " + " ".join(f"{x:.2f}" for x in load_before))
    t0 = time.perf_counter()
    if throwing:
        task = make("throwing")
        batch = real_throws(task, args.initial_rollouts, args.seed)
        horizon = task.n_steps - 1
        print(
            f"task: throwing, real data: N0 = {args.initial_rollouts} throws of the imitation "
            f"policy, {args.initial_rollouts * horizon} transitions (collected in "
            f"{time.perf_counter() - t0:.1f} s)"
        )
    else:
        task = Balancing()
        batch, n_failed = real_batch(task, args.initial_rollouts, args.seed)
        horizon = task.n_steps
        print(
            f"task: balancing, real data: N0 = {args.initial_rollouts} rollouts of stable_gains "
            f"({n_failed} failed and replaced), {args.initial_rollouts * horizon} transitions "
            f"(collected in {time.perf_counter() - t0:.1f} s)"
        )
    print(
        f"update: M = {args.artificial} artificial samples x L = {args.trajectories} "
        f"trajectories, horizon T = {horizon}, FITC with {args.inducing} pseudo-inputs, "
        f"{args.repeats} repeat(s) per thread count, interleaved (fastest total shown)"
    )
    if args.artificial < SMALL_M:
        print(f"  (M < {SMALL_M}: the policy fit's effective-sample-size check is relaxed to 1)")

    before = torch.get_num_threads()
    flights = args.flight if throwing else ["full"]
    keys = [(th, dt, fl) for th in args.threads for dt in args.dtype for fl in flights]
    runs: dict[tuple[int, str, str], list[dict[str, float]]] = {k: [] for k in keys}
    try:
        for _ in range(args.repeats):  # interleaved, so load drift hits every variant
            for th, dt, fl in keys:
                torch.set_num_threads(th)
                runs[th, dt, fl].append(one_update(task, batch, args, getattr(torch, dt), fl))
    finally:
        torch.set_num_threads(before)
    results = {k: min(rs, key=lambda r: r["total"]) for k, rs in runs.items()}

    steps = args.artificial * args.trajectories * horizon
    print()
    print(
        f"{'threads':>7}  {'dtype':>7}  {'flight':>6}  {'training':>9}  {'prediction':>10}  "
        f"{'policy':>8}  {'total':>8}  {'traj-steps/s':>12}  {'GP iters':>8}"
    )
    for (th, dt, fl), r in results.items():
        print(
            f"{th:>7}  {dt:>7}  {fl:>6}  {r['training']:8.2f}s  {r['prediction']:9.2f}s  "
            f"{r['policy']:7.3f}s  {r['total']:7.2f}s  {steps / r['prediction']:12.3g}  "
            f"{r['iterations']!s:>8}"
        )
    if args.repeats > 1:
        for (th, dt, fl), rs in runs.items():
            print(
                f"{th} thread(s), {dt}, flight {fl}, totals of all repeats: "
                + ", ".join(f"{r['total']:.2f}s" for r in rs)
            )
    if len(args.threads) > 1:
        lo, hi = min(args.threads), max(args.threads)
        for dt in args.dtype:
            for fl in flights:
                base, other = results[lo, dt, fl], results[hi, dt, fl]
                print(
                    f"\n{dt}, flight {fl}: ratio {hi} / {lo} threads (time): "
                    + ", ".join(
                        f"{k} {other[k] / base[k]:.2f}"
                        for k in ("training", "prediction", "policy", "total")
                    )
                )
    if len(flights) > 1:
        for th in args.threads:
            for dt in args.dtype:
                a, b = results[th, dt, "full"], results[th, dt, "stop"]
                print(
                    f"{th} thread(s), {dt}: flight stop / full (time): prediction "
                    f"{b['prediction'] / a['prediction']:.2f}, total {b['total'] / a['total']:.2f}"
                )
    if len(args.dtype) > 1:
        for th in args.threads:
            a, b = results[th, "float64", flights[0]], results[th, "float32", flights[0]]
            print(
                f"{th} thread(s): float32 / float64 (time): prediction "
                f"{b['prediction'] / a['prediction']:.2f}, total {b['total'] / a['total']:.2f}"
            )
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
