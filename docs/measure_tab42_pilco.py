"""PILCO's first update on tab4.2's data: does the optimiser go where the model is wrong?

The random-policy data of ``tab4.2`` (``n_random`` rollouts of ``random_steps`` steps with
``excitation_std`` torque excitation, data seed ``--seeds``) plus one rollout of a π₀ sample
(the experiment's first batch) train the FITC model of the experiment; PILCO then optimises
the gain from π₀'s mean with ``--iterations`` L-BFGS iterations. Printed: the model's
expected return J (moment matching) of π₀'s mean, of the optimised gain and of the LQR gain
(R = 1e-4), the simulator's mean reward of each from 10 start states, and how far the gain
moved (‖ΔG‖ / ‖G₀‖). A gain that the model scores far above the simulator is one the
optimiser found where the model is wrong in its favour. Run from the repository root::

    OMP_NUM_THREADS=1 python docs/measure_tab42_pilco.py --seeds 0 1 --iterations 30
"""

from __future__ import annotations

import argparse
import warnings
from dataclasses import replace

import numpy as np
import torch

from skillkit.experiments.ch4_balancing import BalancingComparisonSettings, _fitc, initial_policy_42
from skillkit.search import Batch
from skillkit.search.pilco import PILCO, PILCOSettings
from skillkit.tasks import make
from skillkit.tasks.balancing import collect_balancing


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1])
    p.add_argument("--iterations", type=int, default=30)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--n-random", type=int, default=12)
    p.add_argument("--excitation", type=float, default=3.0)
    a = p.parse_args()
    torch.set_num_threads(1)
    st = replace(BalancingComparisonSettings(), random_steps=a.steps, n_random=a.n_random,
                 excitation_std=a.excitation, gp_steps=50)  # fmt: skip
    task = make("balancing", initial_std=st.initial_std)
    excited = make("balancing", initial_std=st.initial_std, excitation_std=st.excitation_std,
                   n_steps=st.random_steps)  # fmt: skip
    pi0 = initial_policy_42(st, task)
    lqr = task.lqr_gain(control_weight=1e-4)
    for seed in a.seeds:
        rng = np.random.default_rng(seed)
        prior = collect_balancing(excited, st.n_random, rng, 1.0, policy=pi0)["trajectories"]
        omega = pi0.sample(np.zeros((1, 0)), rng)[0]
        first = task.rollout(omega, rng=rng)
        x0 = task.initial_states(None, 10, np.random.default_rng(seed + 300))

        def real(g, x0=x0):
            return float(
                np.mean([task.reward(task.rollout_from(np.ravel(g), x, rng=0)) for x in x0])
            )

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            algo = PILCO(task, pi0, lambda: _fitc(st.n_inducing, st.gp_steps, st.model_mean),
                         PILCOSettings(policy_iterations=a.iterations), rng=seed,
                         prior_trajectories=prior)  # fmt: skip
            batch = Batch(None, omega[None], np.array([task.reward(first)]), [first])
            d = algo.update(batch)
            g0 = pi0.mean.reshape(4, 8)
            move = np.linalg.norm(algo.gain - g0) / np.linalg.norm(g0)
            j_lqr = algo.expected_return(lqr)
        print(
            f"seed {seed} it {a.iterations}: J(pi0 mean) {d.return_before:.4g} real "
            f"{real(g0):.4g}; J(new) {d.return_after:.4g} real {real(algo.gain):.4g}; "
            f"move {move:.3f}; J(LQR) {j_lqr:.4g} real {real(lqr):.4g}",
            flush=True,
        )


if __name__ == "__main__":
    main()
