"""Wall time of one experiment with 1 worker against N workers, and that both give the same
numbers.

Runs ``run_trials`` twice into fresh temporary directories (no checkpoint is reused): once with
the ``local`` executor (one trial after another in this process) and once with the ``process``
(or ``ray``) executor and ``--workers`` workers. Prints both wall times, the speed-up, and
whether the summaries are identical.

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_executors.py fig3.3 --scale paper --trials 2``
(about 14 min on a quiet 2-core machine). Give as many trials as workers, or a multiple.
"""

from __future__ import annotations

import argparse
import tempfile
import time

from skillkit.experiments.runner import run_trials


def _timed_run(exp_id: str, scale: str, trials: int, seed: int, **kw) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = run_trials(
            exp_id, scale, trials=trials, seed=seed, progress=True, checkpoint_dir=tmp, **kw
        )
        return time.perf_counter() - t0, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment")
    parser.add_argument("--scale", default="quick", choices=("quick", "paper"))
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--executor", default="process", choices=("process", "ray"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    one, r1 = _timed_run(args.experiment, args.scale, args.trials, args.seed, executor="local")
    many, rn = _timed_run(
        args.experiment,
        args.scale,
        args.trials,
        args.seed,
        executor=args.executor,
        workers=args.workers,
    )
    print(f"{args.experiment} ({args.scale}, {args.trials} trials, seed {args.seed})")
    print(f"  1 worker (local):          {one:8.1f} s")
    print(f"  {args.workers} workers ({args.executor}): {many:8.1f} s")
    print(f"  speed-up: {one / many:.2f}x; identical summaries: {r1['summary'] == rn['summary']}")


if __name__ == "__main__":
    main()
