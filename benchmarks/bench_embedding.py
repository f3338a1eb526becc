"""Benchmark: expected-reward prediction, kernel embedding vs GP trajectory sampling (Sec. 5.4).

One run on the balancing task (T = 40, torque noise 4, initial std 0.3): both models are
trained on the same observed trajectories, then predict the expected trajectory reward of
200 query controllers from the same L = 100 samples of the initial state distribution:

* embedding: Table 5.2 propagation with one (N, N) policy-dependent transition matrix per
  query and E[r_t] = r'ᵀβ_t (linear reward kernel);
* GP: :func:`~skillkit.models.sampling.sample_trajectories` with M = 100 trajectories per query
  (20,000 trajectories of 40 steps), rewards averaged over the samples.

Only the prediction is timed (training is the same kind of work for both and not what the
thesis compares). Usage::

    python benchmarks/bench_embedding.py [--trajectories 10] [--queries 200] [--samples 100]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

from skillkit.experiments.ch5 import embedding_expected_rewards
from skillkit.models.embedding import ConditionalEmbedding
from skillkit.models.embedding_training import transitions
from skillkit.models.gp import ExactGP, ForwardModel
from skillkit.models.kernels import SquaredExponential
from skillkit.models.sampling import sample_trajectories
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP, feedback_policy, random_lqr_gains


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--trajectories", type=int, default=10, help="observed trajectories (N = 40 x this)"
    )
    ap.add_argument("--queries", type=int, default=200, help="query controllers")
    ap.add_argument("--samples", type=int, default=100, help="M (GP) = L (initial samples)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    task = make("balancing-noisy")
    reward = task.immediate_reward

    gains = random_lqr_gains(task, args.trajectories, 1.0, 1e-3, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trajs = [task.rollout(g.ravel(), None, rng) for g in gains]
    trajs = [t for t in trajs if not t.failed]
    states = np.stack([t.states for t in trajs])
    controls = np.stack([t.controls for t in trajs])
    z, xn, _ = transitions(states, controls)
    sd = z.std(axis=0)
    emb = ConditionalEmbedding(
        z, xn, SquaredExponential(12, lengthscale=np.where(sd > 0, sd, 1.0)), 1e-3
    )
    gp = ForwardModel(ExactGP(n_steps=30)).fit(z[:, :8], z[:, 8:], xn, rng=rng)

    test = random_lqr_gains(task, args.queries, 1.0, 1e-3, rng)
    x0 = X_UP + 0.3 * rng.standard_normal((args.samples, 8))
    horizon = states.shape[1] - 1
    n = len(z)
    print(
        f"torch threads: {torch.get_num_threads()}; N = {n} transitions; {args.queries} queries; "
        f"T = {horizon}; L = M = {args.samples}"
    )

    t0 = time.perf_counter()
    r_emb = embedding_expected_rewards(emb, x0, test, horizon, reward)
    t_emb = time.perf_counter() - t0

    t0 = time.perf_counter()
    sampled = sample_trajectories(
        gp,
        np.broadcast_to(x0, (args.queries,) + x0.shape),
        feedback_policy(torch.from_numpy(test)),
        horizon,
        args.samples,
        rng,
    )
    xs = sampled.states.numpy()
    r_gp = reward(xs, np.einsum("bij,bmtj->bmti", test, xs - X_UP))[:, :, 1:].sum(-1).mean(1)
    t_gp = time.perf_counter() - t0

    print(f"embedding prediction:   {t_emb:8.2f} s  ({args.queries} expected rewards)")
    n_traj = args.queries * args.samples
    print(f"GP sampling (M={args.samples}):  {t_gp:8.2f} s  ({n_traj} trajectories)")
    print(f"speed-up of the embedding: {t_gp / t_emb:.1f}x")
    print(f"mean predicted reward: embedding {r_emb.mean():.2f}, GP {np.nanmean(r_gp):.2f}")


if __name__ == "__main__":
    main()
