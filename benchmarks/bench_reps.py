"""Time one contextual REPS update: dual solve + weights (Eqs. 3.9, 3.10) and the weighted ML
fit (Eqs. 3.11–3.13), for N = 200 and N = 10,000 samples.

Dimensions are the thesis's throwing task: ω ∈ R^41, context s ∈ R^2, linear policy features
and quadratic baseline features (5). Run: ``python benchmarks/bench_reps.py``.
For stable numbers on a shared machine set ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``.
"""

from __future__ import annotations

import time

import numpy as np

from skillkit.policies.features import context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.reps import reps_weights

D, S_DIM, EPSILON, REPEATS = 41, 2, 0.6, 7


def main() -> None:
    rng = np.random.default_rng(0)
    policy = LinearGaussianPolicy(np.zeros(D), 0.1 * np.eye(D), rng.normal(size=(D, S_DIM)), S_DIM)
    target = rng.normal(size=D)
    print(f"one REPS update, d={D}, context_dim={S_DIM}, epsilon={EPSILON}, median of {REPEATS}")
    for n in (200, 10_000):
        contexts = rng.uniform([5.0, 1.0], [15.0, 3.0], size=(n, S_DIM))
        omegas = policy.sample(contexts, rng)
        rewards = -np.sum((omegas - target) ** 2, axis=1) - 0.1 * np.sum(contexts**2, axis=1)
        times, dual_times = [], []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            sol = reps_weights(rewards, context_features(contexts, "quadratic"), EPSILON)
            t1 = time.perf_counter()
            policy.fit(contexts, omegas, sol.weights)
            t2 = time.perf_counter()
            dual_times.append(t1 - t0)
            times.append(t2 - t0)
        print(
            f"N={n:>6}: update {1e3 * np.median(times):8.2f} ms "
            f"(dual + weights {1e3 * np.median(dual_times):8.2f} ms, {sol.n_iterations} L-BFGS-B "
            f"iterations, KL {sol.kl:.4f}, ESS {sol.ess:.0f})"
        )


if __name__ == "__main__":
    main()
