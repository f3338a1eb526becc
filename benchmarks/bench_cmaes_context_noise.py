"""Why CMA-ES ends below π₀ on hockey and table tennis in ``cmp.methods``, measured.

Run ``OMP_NUM_THREADS=1 python benchmarks/bench_cmaes_context_noise.py TASK [SEED]`` with TASK
``hockey``, ``table-tennis`` or ``throwing`` (where CMA-ES does learn: the control; 1–2 min
each on one core). Two parts, both with exactly ``cmp.methods``'s paper setup for CMA-ES on
the task (its task, π₀, cma's defaults with the glue's m = 4 contexts per candidate, REPS's
real-rollout budget, its evaluation contexts):

1. *How noisy a candidate's fitness is.* The first generation's λ candidates, each rolled out
   on the same 64 contexts: the spread of their expected rewards J(θ_k) across candidates,
   the spread of R over contexts within one candidate (so the noise of the 4-context fitness
   CMA-ES is told), and the rank correlation of 4-context fitness with J (200 draws).
2. *What the run does.* One ``learn`` run: per generation, the policy mean's reward on the
   evaluation contexts, the batch's mean and best candidate reward, σ and failures.

Not a thesis claim; the numbers of one run are in data/README.md (``cmp.methods``).
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
from scipy.stats import spearmanr

from skillkit.experiments.cmp_methods import PAPER, _algorithm, _setup
from skillkit.search.loop import learn


def main(name: str, seed: int = 0, n_contexts: int = 64) -> None:
    rng = np.random.default_rng(seed)
    setup = _setup(name, PAPER, rng)
    algo, n_updates, n, n0 = _algorithm("cmaes", setup, PAPER, rng.spawn(1)[0])
    task, policy = setup.task, algo.policy
    print(
        f"{name}, CMA-ES: {n_updates} generations of λ = {algo.popsize} × "
        f"m = {algo.contexts_per_candidate} rollouts, worst reward {task.worst_reward:g}"
    )

    contexts = task.sample_context(np.random.default_rng(seed + 1), n=n_contexts)
    rewards = np.empty((policy.popsize, n_contexts))
    for k, theta in enumerate(policy.population):
        omegas = policy._omega(np.broadcast_to(theta, (n_contexts, theta.size)), contexts)
        for i, (omega, s) in enumerate(zip(omegas, contexts, strict=True)):
            rewards[k, i] = task.reward(task.rollout(omega, s, np.random.default_rng(i)), s)
    expected = rewards.mean(axis=1)
    within = np.median(rewards.std(axis=1, ddof=1))
    m = algo.contexts_per_candidate
    draws = np.random.default_rng(seed + 2)
    rho = [
        spearmanr(rewards[:, draws.choice(n_contexts, m, replace=False)].mean(1), expected)[0]
        for _ in range(200)
    ]
    q = np.percentile(rho, [25, 50, 75])
    print(
        f"first generation: J(θ_k) {expected.mean():.3f} ± {expected.std(ddof=1):.3f} across "
        f"candidates; R's spread over contexts within a candidate {within:.3f}, so the "
        f"{m}-context fitness has noise ≈ {within / np.sqrt(m):.3f}; rank correlation of that "
        f"fitness with J: median {q[1]:.2f} (quartiles {q[0]:.2f}–{q[2]:.2f})"
    )

    out = learn(
        task,
        algo,
        n_updates,
        n,
        rng,
        progress=False,
        initial_rollouts=n0,
        eval_contexts=setup.eval_contexts,
        eval_seed=setup.eval_seed,
    )
    curve, diagnostics = out["mean_reward"], out["diagnostics"]
    print(f"policy mean before the first update: {curve[0]:.3f}")
    for g in sorted({*range(0, n_updates, max(1, n_updates // 12)), n_updates - 1}):
        d = diagnostics[g]
        print(
            f"generation {g + 1:3d}: policy mean {curve[g + 1]:.3f}, batch {d.mean_reward:.3f}, "
            f"best candidate {d.best_reward:.3f}, σ {d.sigma:.3g}, "
            f"failed {out['n_failed'][g]}"
        )
    tail = curve[len(curve) // 2 :]
    print(
        f"policy mean over the second half: {tail.mean():.3f} (min {tail.min():.3f}, "
        f"max {tail.max():.3f})"
    )


if __name__ == "__main__":
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # failed rollouts are counted above
        if len(sys.argv) < 2 or sys.argv[1] not in ("hockey", "table-tennis", "throwing"):
            sys.exit("usage: bench_cmaes_context_noise.py {hockey,table-tennis,throwing} [SEED]")
        main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 0)
