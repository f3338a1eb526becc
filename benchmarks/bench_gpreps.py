"""Benchmark: wall time of one GPREPS update (Table 4.1) at the thesis's M × L.

Times :meth:`skillkit.search.gpreps.GPREPS.update`, split as its diagnostics split it:
**training** (refitting the reward model, step 1), **prediction** (M artificial (s, ω) and
their M · L model trajectories, Eq. 4.1, step 2; also as trajectory-steps per second) and
**policy** (the REPS dual and weighted ML fit on the M samples, step 3), for each torch thread
count ``--threads`` (set in this script only; torch's threads share each step's work)
and sampling precision ``--dtype`` (``auto``: ``dtype=None``, float32 for a model whose
float32 one-step moments pass the check, else float64; or pinned). The update timed is the
first one on the real batch, from a fresh GPREPS with the same seed; the best of
``--repeats`` (interleaved) is shown, with the dtypes the update sampled in.

**Tasks.** ``throwing`` (Sec. 4.3.2): the decomposed model of Fig. 4.2 (FITC robot dynamics
with ``--inducing`` pseudo-inputs, default 50, on ≤ 1000 transitions; exact-GP release model;
FITC flight model), trained on N₀ = 10 imitation throws (1240 transitions), T = 124 control
steps, each ball flown until it lands (``--flight stop``) or for 2.5 s (``full``); L = 25.
``balancing``: 4-link robot, 32 gains, T = 40, a
:class:`~skillkit.search.gpreps.TrajectoryRewardModel` (FITC, 100 pseudo-inputs) on N₀ = 20
rollouts of :func:`~skillkit.tasks.balancing.stable_gains`; L = 10. M = 500 for both.

``--against COMMIT`` also runs this script on a temporary git worktree of COMMIT (a
subprocess importing skillkit from there; the worktree is removed afterwards) and prints its
rows and the time ratios this / COMMIT. The load average is printed before and after: other
processes inflate the times.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_gpreps.py [--task throwing|balancing]
        [--threads 1 2] [--dtype auto float64 float32] [--flight stop full]
        [--against HEAD] [--artificial 500] [--trajectories 25|10] [--repeats 1]
        [--initial-rollouts 10|20] [--inducing 50|100] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
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
PARTS = ("training", "prediction", "policy", "total")


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


def one_update(task, batch: Batch, args: argparse.Namespace, dtype: str, flight: str) -> dict:
    """Wall times of one GPREPS update from a fresh GPREPS (seeded by ``args.seed``) sampling
    in ``dtype`` ("auto": the library default); throwing: ``flight`` "stop" stops each
    predicted ball at the ground, "full" flies it for 2.5 s."""
    kw = {} if dtype == "auto" else {"dtype": getattr(torch, dtype)}
    if args.task == "throwing":
        model = ThrowingRewardModel(
            task,
            make_robot_model=_FITCForwardModel(args.inducing),
            max_robot_points=1000,
            device=args.device,
            stop_flight_at_ground=flight == "stop",
            **kw,
        )
    else:
        model = TrajectoryRewardModel(
            task, make_model=_FITCForwardModel(args.inducing), device=args.device, **kw
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
    fit = diag.model_fit
    parts = [fit.get("robot", {}), fit.get("flight", {}), fit]  # throwing: per sampled model
    sampled = [d.get("sampling_dtype") for d in parts]
    return {
        "training": diag.time_training,
        "prediction": diag.time_prediction,
        "policy": diag.time_policy,
        "total": total,
        "iterations": fit.get("iterations", fit.get("robot", {}).get("iterations")),
        "sampled": "/".join(d for d in sampled if d) or "-",
    }


def measure(args: argparse.Namespace) -> tuple[dict[str, dict], int]:
    """The best of ``args.repeats`` updates per (threads, dtype, flight); and the horizon T."""
    t0 = time.perf_counter()
    if args.task == "throwing":
        task = make("throwing")
        batch, horizon = real_throws(task, args.initial_rollouts, args.seed), task.n_steps - 1
        data = f"N0 = {args.initial_rollouts} throws of the imitation policy"
    else:
        task = Balancing()
        (batch, n_failed), horizon = (
            real_batch(task, args.initial_rollouts, args.seed),
            task.n_steps,
        )
        data = f"N0 = {args.initial_rollouts} rollouts of stable_gains ({n_failed} replaced)"
    print(
        f"task {args.task}: {data}, {args.initial_rollouts * horizon} transitions (collected "
        f"in {time.perf_counter() - t0:.1f} s); M = {args.artificial} x L = "
        f"{args.trajectories}, T = {horizon}, FITC with {args.inducing} pseudo-inputs"
    )
    flights = args.flight if args.task == "throwing" else ["-"]
    keys = [(th, dt, fl) for th in args.threads for dt in args.dtype for fl in flights]
    runs: dict[tuple, list[dict]] = {k: [] for k in keys}
    before = torch.get_num_threads()
    try:
        for _ in range(args.repeats):  # interleaved, so load drift hits every variant
            for th, dt, fl in keys:
                torch.set_num_threads(th)
                runs[th, dt, fl].append(one_update(task, batch, args, dt, fl))
    finally:
        torch.set_num_threads(before)
    best = {" ".join(map(str, k)): min(rs, key=lambda r: r["total"]) for k, rs in runs.items()}
    return best, horizon


def print_rows(results: dict[str, dict], steps: int, label: str, header: bool = True) -> None:
    if header:
        print(
            f"{'code':>10}  {'threads dtype flight':>22}  {'training':>9}  {'prediction':>10}  "
            f"{'policy':>8}  {'total':>8}  {'traj-steps/s':>12}  {'GP iters':>8}  sampled in"
        )
    for key, r in results.items():
        print(
            f"{label:>10}  {key:>22}  {r['training']:8.2f}s  {r['prediction']:9.2f}s  "
            f"{r['policy']:7.3f}s  {r['total']:7.2f}s  {steps / r['prediction']:12.3g}  "
            f"{r['iterations']!s:>8}  {r['sampled']}"
        )


def run_against(commit: str, argv: list[str]) -> dict[str, dict]:
    """This benchmark's results on a temporary worktree of ``commit`` (removed afterwards)."""
    root = subprocess.run(
        ["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True, check=True
    ).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        tree, out = os.path.join(tmp, "tree"), os.path.join(tmp, "results.json")
        subprocess.run(["git", "-C", root, "worktree", "add", "--detach", tree, commit], check=True)
        try:
            env = {**os.environ, "PYTHONPATH": tree}
            cmd = [sys.executable, os.path.abspath(__file__), *argv, "--json", out]
            subprocess.run(cmd, env=env, cwd=tree, check=True)
            with open(out) as f:
                return json.load(f)
        finally:
            subprocess.run(["git", "-C", root, "worktree", "remove", "--force", tree], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", choices=["throwing", "balancing"], default="throwing")
    parser.add_argument("--artificial", type=int, default=500, help="M artificial samples")
    parser.add_argument("--trajectories", type=int, default=None, help="L (25 / 10)")
    parser.add_argument("--initial-rollouts", type=int, default=None, help="N0 (10 / 20)")
    parser.add_argument("--inducing", type=int, default=None, help="FITC M_ind (50 / 100)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument(
        "--dtype", choices=["auto", "float64", "float32"], nargs="+", default=["auto"]
    )
    parser.add_argument("--flight", choices=["stop", "full"], nargs="+", default=["stop"])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--against", metavar="COMMIT", default=None)
    parser.add_argument("--json", default=None, help=argparse.SUPPRESS)  # for --against
    argv = sys.argv[1:]
    args = parser.parse_args(argv)
    throwing = args.task == "throwing"
    for name, default in (
        ("trajectories", 25 if throwing else 10),
        ("initial_rollouts", 10 if throwing else 20),
        ("inducing", 50 if throwing else 100),
    ):
        if getattr(args, name) is None:
            setattr(args, name, default)
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
    )
    print("load average before: " + " ".join(f"{x:.2f}" for x in load_before))
    results, horizon = measure(args)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f)
    steps = args.artificial * args.trajectories * horizon
    print()
    print_rows(results, steps, args.against[:10] if args.json else "this")
    if args.against and not args.json:  # the subprocess ignores --against
        print(f"\n--- the same benchmark on {args.against} ---", flush=True)
        old = run_against(args.against, argv)
        print()
        print_rows(results, steps, "this")
        print_rows(old, steps, args.against[:10], header=False)
        for key, r in results.items():
            ratios = ", ".join(f"{k} {r[k] / old[key][k]:.2f}" for k in PARTS)
            print(f"{key}: this / {args.against} (time): {ratios}")
    if len(args.threads) > 1:
        lo, hi = min(args.threads), max(args.threads)
        for key, r in results.items():
            if key.split()[0] == str(hi):
                base = results[" ".join([str(lo), *key.split()[1:]])]
                ratios = ", ".join(f"{k} {r[k] / base[k]:.2f}" for k in PARTS)
                print(f"{key}: {hi} / {lo} threads (time): {ratios}")
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
