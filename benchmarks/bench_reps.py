"""Time one contextual REPS update with each solver of the dual: dual solve, weights and
diagnostics (Eqs. 3.9, 3.10), and the weighted ML fit (Eqs. 3.11–3.13), for N = 200 and
N = 10,000 samples.

Dimensions are the thesis's throwing task: ω ∈ R^41, context s ∈ R^2, linear policy features
and quadratic baseline features (5). For each solver of :func:`~skillkit.search.reps.reps_weights`
(``"lbfgsb"``, the default, and ``"newton"``) it prints the median over
``REPEATS`` of: the whole update; ``reps_weights`` (normalisation, dual solve, weights and
diagnostics); the dual solve alone (the solver on the normalised problem, set up here as
``reps_weights`` does); the fit; the solver's iterations; and the largest weight difference
between the solvers. CPU time of this process (``time.process_time``) and wall time, with the
load average before and after. Run::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_reps.py
"""

from __future__ import annotations

import os
import time
from functools import partial

import numpy as np

from skillkit.policies.features import context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.reps import _minimise_lbfgsb, _minimise_newton, reps_weights

D, S_DIM, EPSILON, REPEATS = 41, 2, 0.6, 15


def _normalised(rewards: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalised problem ``reps_weights`` hands its solver (uniform base weights)."""
    r_n = (rewards - rewards.max()) / rewards.std()
    centred = phi - phi.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred / np.sqrt(len(rewards)), full_matrices=False)
    return r_n, centred @ (vt.T / sv)


def _median_times(f, repeats: int) -> tuple[float, float]:
    """Median CPU and wall seconds of ``repeats`` calls."""
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        f()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return float(np.median(cpu)), float(np.median(wall))


def _update(policy, contexts, omegas, rewards, phi, solver: str) -> None:
    """One update: the weights from the dual, then the weighted ML fit."""
    sol = reps_weights(rewards, phi, EPSILON, solver=solver)
    policy.fit(contexts, omegas, sol.weights)


def main() -> None:
    print(f"load before: {os.getloadavg()}")
    rng = np.random.default_rng(0)
    policy = LinearGaussianPolicy(np.zeros(D), 0.1 * np.eye(D), rng.normal(size=(D, S_DIM)), S_DIM)
    target = rng.normal(size=D)
    print(f"one REPS update, d={D}, context_dim={S_DIM}, epsilon={EPSILON}, median of {REPEATS}")
    for n in (200, 10_000):
        contexts = rng.uniform([5.0, 1.0], [15.0, 3.0], size=(n, S_DIM))
        omegas = policy.sample(contexts, rng)
        rewards = -np.sum((omegas - target) ** 2, axis=1) - 0.1 * np.sum(contexts**2, axis=1)
        phi = context_features(contexts, "quadratic")
        r_n, psi = _normalised(rewards, phi)
        weights = {}
        for solver, minimise in (("lbfgsb", _minimise_lbfgsb), ("newton", _minimise_newton)):
            sol = reps_weights(rewards, phi, EPSILON, solver=solver)
            weights[solver] = sol.weights

            t_update = _median_times(
                partial(_update, policy, contexts, omegas, rewards, phi, solver), REPEATS
            )
            t_weights = _median_times(
                partial(reps_weights, rewards, phi, EPSILON, solver=solver), REPEATS
            )
            t_dual = _median_times(partial(minimise, r_n, psi, EPSILON, None), REPEATS)
            t_fit = _median_times(partial(policy.fit, contexts, omegas, sol.weights), REPEATS)
            print(
                f"N={n:>6} {solver:>6}: update {1e3 * t_update[0]:7.2f} ms CPU "
                f"({1e3 * t_update[1]:7.2f} wall) = reps_weights {1e3 * t_weights[0]:6.2f} "
                f"(dual solve {1e3 * t_dual[0]:6.2f}, {sol.n_iterations} iterations) + fit "
                f"{1e3 * t_fit[0]:6.2f}; KL {sol.kl:.6f}, ESS {sol.ess:.1f}"
            )
        diff = np.max(np.abs(weights["newton"] - weights["lbfgsb"])) / weights["lbfgsb"].max()
        print(f"          largest weight difference newton - lbfgsb: {diff:.1e} (of the largest)")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
