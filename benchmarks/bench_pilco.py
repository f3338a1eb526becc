"""Benchmark: PILCO's cost at Table 4.2's sizes (balancing, 8 states, 4 torques, T = 40).

Measures, for each ``--threads`` count (``torch.set_num_threads``, set here only and restored):

* **J**: one expected return J(G) by moment matching through a FITC forward model
  (``--inducing`` pseudo-inputs, default 100, linear prior mean) over the horizon, without and
  with its gradient (:func:`skillkit.search.pilco.expected_return`, torch autograd); also per
  moment-matching step;
* **update**: one :meth:`skillkit.search.pilco.PILCO.update` on 6 s of data, as much as
  tab4.2 starts from (3 rollouts of a sluggish-LQR π₀ with 30 N m torque excitation) plus one
  rollout of π₀, split into model training and policy optimisation (``--iterations`` L-BFGS-B
  iterations, default 50).

It prints the gradient / value ratio and the 2-thread / 1-thread ratios measured in the same
run, with the machine's load average before and after. Run from the repository root::

    OMP_NUM_THREADS=1 python benchmarks/bench_pilco.py --threads 1 2
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
import torch

from skillkit.models.gp import ForwardModel
from skillkit.models.sparse import FITC
from skillkit.search import collect
from skillkit.search.pilco import PILCO, PILCOSettings, expected_return, model_moment_step
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP


def _best(f, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--inducing", type=int, default=100)
    parser.add_argument("--iterations", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    task = make("balancing", initial_std=0.1)
    excited = make("balancing", initial_std=0.1, excitation_std=30.0)
    pi0 = task.lqr_policy(1.0, 0.005)
    rng = np.random.default_rng(0)
    prior = collect(excited, pi0, 3, rng).trajectories
    batch = collect(task, pi0, 1, rng)

    def make_model():
        return ForwardModel(FITC(n_inducing=args.inducing, n_steps=100), mean="linear")

    load0 = os.getloadavg()
    before = torch.get_num_threads()
    rows = {}
    try:
        for n in args.threads:
            torch.set_num_threads(n)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                alg = PILCO(task, pi0, make_model, PILCOSettings(policy_iterations=args.iterations),
                            rng=0, prior_trajectories=prior)  # fmt: skip
                diag = alg.update(batch)
                step = model_moment_step(alg.model.model)
                G = torch.as_tensor(pi0.mean.reshape(4, 8))

                def value(G=G, step=step):
                    with torch.no_grad():
                        expected_return(step, G, X_UP, 0.01 * np.eye(8), 40, X_UP, np.eye(8))

                def gradient(G=G, step=step):
                    Gr = G.clone().requires_grad_(True)
                    J = expected_return(step, Gr, X_UP, 0.01 * np.eye(8), 40, X_UP, np.eye(8))
                    torch.autograd.grad(J, Gr)

                t_value = _best(value, args.repeats)
                t_grad = _best(gradient, args.repeats)
            rows[n] = (t_value, t_grad, diag)
            print(
                f"threads {n}: J {t_value:.3f} s ({1e3 * t_value / 40:.1f} ms per MM step), "
                f"J + gradient {t_grad:.3f} s (ratio {t_grad / t_value:.2f}); update: training "
                f"{diag.time_training:.1f} s, policy {diag.time_policy:.1f} s in "
                f"{diag.n_iterations} iterations / {diag.n_evaluations} evaluations "
                f"({diag.time_policy / max(diag.n_evaluations, 1):.2f} s each)"
            )
    finally:
        torch.set_num_threads(before)
    if 1 in rows and 2 in rows:
        (v1, g1, d1), (v2, g2, d2) = rows[1], rows[2]
        print(
            f"2 / 1 threads: J {v2 / v1:.2f}, J + gradient {g2 / g1:.2f}, "
            f"policy optimisation {d2.time_policy / d1.time_policy:.2f}"
        )
    print(f"torch {torch.__version__}; load average before {load0}, after {os.getloadavg()}")


if __name__ == "__main__":
    main()
