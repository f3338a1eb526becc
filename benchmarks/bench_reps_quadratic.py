"""Episodic REPS's M-step on an ill-conditioned 10-D quadratic: which M-step keeps the
KL bound and still converges.

Problem: R(ω) = −(ω − ω*)ᵀ H (ω − ω*), H = diag(100^(i/9)), i = 0..9 (condition number 100),
ω* = 0.6 · 1, start N(0, I) (R of the mean −89.3); ε = 1, 100 samples per update, 60 updates,
seeds 0–4 (``np.random.default_rng(seed)``), no sample reuse.

Variants (``ContextualREPS(m_step=...)`` unless marked):

* ``weighted_ml`` — Eqs. 3.11–3.13 alone (the default);
* ``trust_region`` β = ε/2, ε, 2ε — entropy loss ≤ β, then KL(π_new ‖ π_old) ≤ ε
  (:func:`skillkit.policies.gaussian.trust_region_step`; β = ε is the library default);
* ``kl_only`` — the KL projection alone (β = 1e6, never active);
* ``entropy_only`` (local, not in the library) — the entropy bound β = ε alone, no KL bound;
* ``ess_cov`` (local, not in the library) — Σ_ML · ESS / (ESS − 1), the reliability-weights
  unbiased covariance, no bounds.

Prints, per variant, R(mean) after update 60 and the first update with R(mean) > −1e-3 per
seed, the median and largest KL(π_new ‖ π_old); then the per-update KL (median over seeds)
of ``weighted_ml`` and ``trust_region`` (β = ε). Run:
``OMP_NUM_THREADS=1 python benchmarks/bench_reps_quadratic.py`` (about 15 s).
"""

from __future__ import annotations

import numpy as np

from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.reps import ContextualREPS

CURVATURE = 100.0 ** (np.arange(10) / 9)
OPTIMUM = np.full(10, 0.6)
EPSILON, N_SAMPLES, N_UPDATES, SEEDS = 1.0, 100, 60, range(5)


def quadratic(omegas: np.ndarray) -> np.ndarray:
    d = omegas - OPTIMUM
    return -np.sum(CURVATURE * d * d, axis=-1)


class EntropyOnlyREPS(ContextualREPS):
    """Rejected alternative: scale Σ_ML so the entropy loss is at most β, no KL bound."""

    def _m_step(self, old, fitted, contexts):
        loss = old.entropy() - fitted.entropy()
        if loss <= self.entropy_loss_bound:
            return fitted, {}
        scale = np.exp(2 * (loss - self.entropy_loss_bound) / old.dim)
        return LinearGaussianPolicy(
            fitted.mean, scale * fitted.cov, fitted.gain, fitted.context_dim, fitted.features
        ), {}


class ESSCovREPS(ContextualREPS):
    """Rejected alternative: Σ_ML · ESS / (ESS − 1) (unbiased for reliability weights)."""

    def _weigh(self, contexts, rewards):
        weights, fields = super()._weigh(contexts, rewards)
        self._last_ess = fields["ess"]
        return weights, fields

    def _m_step(self, old, fitted, contexts):
        c = self._last_ess / (self._last_ess - 1.0)
        return LinearGaussianPolicy(
            fitted.mean, c * fitted.cov, fitted.gain, fitted.context_dim, fitted.features
        ), {}


VARIANTS = {
    "weighted_ml": lambda p: ContextualREPS(p, EPSILON),
    "trust_region b=eps/2": lambda p: ContextualREPS(
        p, EPSILON, m_step="trust_region", entropy_loss_bound=EPSILON / 2
    ),
    "trust_region b=eps": lambda p: ContextualREPS(p, EPSILON, m_step="trust_region"),
    "trust_region b=2eps": lambda p: ContextualREPS(
        p, EPSILON, m_step="trust_region", entropy_loss_bound=2 * EPSILON
    ),
    "kl_only": lambda p: ContextualREPS(p, EPSILON, m_step="trust_region", entropy_loss_bound=1e6),
    "entropy_only (local)": lambda p: EntropyOnlyREPS(p, EPSILON),
    "ess_cov (local)": lambda p: ESSCovREPS(p, EPSILON),
}


def run(make, seed: int) -> tuple[list[float], list[float]]:
    """Reward of the mean after each update and KL(π_new ‖ π_old) of each update."""
    rng = np.random.default_rng(seed)
    reps = make(GaussianPolicy(np.zeros(10), np.eye(10)))
    rewards, kls = [], []
    for _ in range(N_UPDATES):
        w = reps.policy.sample(np.zeros((N_SAMPLES, 0)), rng)
        kls.append(reps.update(Batch(None, w, quadratic(w))).policy_kl)
        rewards.append(float(quadratic(reps.policy.mean)))
    return rewards, kls


def main() -> None:
    print(f"10-D quadratic, start R(mean) = {quadratic(np.zeros(10)):.4g}, epsilon={EPSILON}")
    per_update = {}
    for name, make in VARIANTS.items():
        runs = [run(make, seed) for seed in SEEDS]
        final = [r[-1] for r, _ in runs]
        first = [next((k + 1 for k, x in enumerate(r) if x > -1e-3), None) for r, _ in runs]
        kls = np.array([k for _, k in runs])
        per_update[name] = np.median(kls, axis=0)
        print(
            f"{name:22s} R(mean)@{N_UPDATES}: {' '.join(f'{x:9.3g}' for x in final)} | "
            f"first > -1e-3: {first} | KL median {np.median(kls):.3g}, max {kls.max():.3g}"
        )
    print("per-update KL(pi_new || pi_old), median over seeds:")
    for name in ("weighted_ml", "trust_region b=eps"):
        print(f"  {name}: " + " ".join(f"{x:.2f}" for x in per_update[name]))


if __name__ == "__main__":
    main()
