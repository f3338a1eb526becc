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
Fig. 4.2 (:class:`~skillkit.tasks.throwing_model.ThrowingRewardModel`: FITC robot dynamics with
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

Printed: the machine, torch version, device and load average before; then one row per
(threads, dtype, flight) with the best repeat's wall times of training, prediction and policy,
their total, the sampler's throughput (traj-steps/s = M · L · T / prediction time) and the GP
optimiser's iterations; the totals of every repeat (``--repeats`` > 1: a shared machine's
spread); the ratios measured in the same run (most / fewest threads, flight stopped / full,
float32 / float64); and the load average after. ``--device cuda`` runs the model and the
sampling on the GPU (compare with a ``cpu`` run in the same session). The sampler's precision
check warns when float32 trajectories drift from float64's.
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
from skillkit.tasks import make
from skillkit.tasks.balancing import Balancing, collect_balancing
from skillkit.tasks.throwing_model import ThrowingRewardModel

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
