"""Extra contexts (Sec. 3.4) with and without bias.

Problem: a linear-Gaussian contextual task with a known optimal gain: s ~ U[−1, 1]²,
ω ∈ R², R(s, ω) = −‖ω − 2s‖², the trajectory is ω itself (it does not depend on s, so it
can be re-scored in other contexts). The optimal policy mean is 2s: gain A* = 2 I.

Two measurements, seeds 0–4, ε = 0.5, quadratic baseline features, 20 extra contexts per
rollout (as the thesis's throwing setting):

1. **One update at the optimum**: π = N(2s, 0.25 I), 200 rollouts (4,200 rows). The exact
   REPS update keeps the mean at 2s (the reward is symmetric about it), so an unbiased update
   keeps A = 2 I. Printed: mean of diag(A) / 2 per seed.
2. **Learning**: from N(0, I) with gain 0, 25 updates of 20 rollouts, no reuse; printed:
   diag(A) / 2 and the reward of the mean after the last update per seed, for no extra
   contexts, ``naive``, ``importance`` and ``dual_only``.

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_reps_extra_context.py`` (about 25 s).
"""

from __future__ import annotations

import numpy as np

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.loop import collect, learn
from skillkit.search.reps import ContextualREPS
from skillkit.tasks.toy import LinearTarget

GAIN, EPSILON, N_EXTRA, SEEDS = 2.0, 0.5, 20, range(5)
MODES = ("naive", "importance", "dual_only")


Target = LinearTarget  # R(s, ω) = −‖ω − 2s‖², s ~ U[−1, 1]²


def relative_gain(policy: LinearGaussianPolicy) -> float:
    return float(np.mean(np.diag(policy.gain)) / GAIN)


def main() -> None:
    task = Target()
    print("1. one update at the optimum N(2s, 0.25 I), 200 rollouts x 21 rows: diag(A)/2")
    for mode in MODES:
        gains = []
        for seed in SEEDS:
            start = LinearGaussianPolicy(np.zeros(2), 0.25 * np.eye(2), GAIN * np.eye(2), 2)
            batch = collect(task, start, 200, seed, extra_contexts=N_EXTRA)
            reps = ContextualREPS(start, EPSILON, extra_context_weighting=mode)
            reps.update(batch)
            gains.append(relative_gain(reps.policy))
        print(f"  {mode:11s} " + " ".join(f"{g:.3f}" for g in gains))
    print("2. learning from N(0, I), 25 updates x 20 rollouts: diag(A)/2 | R(mean)")
    for mode in ("no extra",) + MODES:
        gains, rewards = [], []
        for seed in SEEDS:
            reps = ContextualREPS(
                task.initial_policy(),
                EPSILON,
                extra_context_weighting="naive" if mode == "no extra" else mode,
            )
            extra = 0 if mode == "no extra" else N_EXTRA
            res = learn(task, reps, 25, 20, seed, extra_contexts=extra, progress=False)
            gains.append(relative_gain(reps.policy))
            rewards.append(res["mean_reward"][-1])
        print(
            f"  {mode:11s} "
            + " ".join(f"{g:.3f}" for g in gains)
            + " | "
            + " ".join(f"{r:.2g}" for r in rewards)
        )


if __name__ == "__main__":
    main()
