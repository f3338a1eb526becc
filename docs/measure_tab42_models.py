"""Which forward models can predict tab4.2's closed loop: GP (zero or linear prior mean) vs linear.

Table 4.2's model-based methods start from 6 s of real experience (three 2-s rollouts). This
script fits each candidate model on such data and compares it with the simulator on π₀'s own
closed loop (the sluggish LQR gain, no excitation): the one-step RMSE of the predicted next state
on 3 held-out rollouts, and the expected return of π₀'s gain J(G₀) (moment matching through the
model, :func:`~skillkit.search.pilco.expected_return`) and its sampled estimate (GPREPS's Eq. 4.1,
50 trajectories), against the simulator's mean reward over 20 start states. Run from the
repository root::

    OMP_NUM_THREADS=1 python docs/measure_tab42_models.py

Data: ``excitation`` 0 is π₀'s feedback alone, 10 or 30 the white torque excitation (N m) of
the random policy (tab4.2 uses 30). Models: FITC (100 pseudo-inputs, 100 L-BFGS steps) on
Δx with a zero prior mean (PILCO's) or a linear one, and the least-squares linear-Gaussian
model.

Measured for issue #15 (seed 0; the simulator's mean reward of π₀'s gain over 20 start
states is −113.2; RMSE over the 8 state dimensions, positions then velocities):

============  ==================  ==========================  ==========  ===========
excitation    model               velocity RMSE (rad/s)        J(G₀)       sampled
============  ==================  ==========================  ==========  ===========
0             zero-mean FITC      0.11–0.23                   −4253       −4121
0             linear-mean FITC    0.02–0.10                   −243        −218
0             linear-Gaussian     0.01–0.08                   −79         −89
10            zero-mean FITC      0.13–0.47                   −1.56e5     −1.47e5
10            linear-mean FITC    0.06–0.14                   −3630       −3278
10            linear-Gaussian     0.03–0.07                   −109        −2410
30 (tab4.2)   zero-mean FITC      0.17–0.34                   −3.62e5     −3.14e5
30 (tab4.2)   linear-mean FITC    0.13–0.49                   −4.17e4     −3.99e4
30 (tab4.2)   linear-Gaussian     0.09–0.25                   −334        −3.10e4
============  ==================  ==========================  ==========  ===========

Without excitation the closed-loop data predict their own closed loop well but cannot separate
the effect of u from that of x (u = G₀ x̃ on every sample): PILCO on such data (zero-mean FITC,
6 updates) learned gains that diverged on the robot after every update. With excitation the
GPs' predictions of π₀'s return are off by 30× (linear mean) to 3000× (zero mean); under gains of
~1300 N m/rad at 20 Hz small errors in ∂f/∂u are amplified by the feedback and the per-step
predictive variance accumulates over the 40 steps. The linear-Gaussian model's moment
propagation (full residual covariance) is within 3× of the truth, but its sampled estimate,
which draws each state dimension's noise independently (as the GP sampler does), is 100× too
pessimistic: independent position and velocity noise is amplified by the high-gain loop.
PILCO still learns with the linear-mean FITC (tab4.2): the predicted return is too low, but its
gradient points the right way and the model improves with each closed-loop rollout.
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

from skillkit.models.gp import ForwardModel
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sparse import FITC
from skillkit.search import collect
from skillkit.search.gpreps import TrajectoryRewardModel
from skillkit.search.pilco import expected_return, model_moment_step
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP


def measure(excitation: float, make_model, label: str) -> None:
    task = make("balancing", initial_std=0.1)
    excited = make("balancing", initial_std=0.1, excitation_std=excitation)
    pi0 = task.lqr_policy(1.0, 0.005)
    rng = np.random.default_rng(0)
    prior = collect(excited, pi0, 3, rng).trajectories
    test = collect(task, pi0, 3, rng).trajectories
    model = TrajectoryRewardModel(task, make_model, prior_trajectories=prior)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(np.zeros((0, 0)), np.zeros((0, 32)), np.zeros(0), [], 0)
        parts = [task.transitions(t) for t in test]
        x, u, xn = (np.concatenate(p) for p in zip(*parts, strict=True))
        mean = model.model.next_state_moments(torch.as_tensor(x), torch.as_tensor(u)).mean
        rmse = np.sqrt(((mean.numpy() - xn) ** 2).mean(0))
        G = torch.as_tensor(pi0.mean.reshape(4, 8))
        J = expected_return(
            model_moment_step(model.model), G, X_UP, 0.01 * np.eye(8), 40, X_UP, np.eye(8)
        )
        sampled = model.expected_rewards(np.zeros((1, 0)), pi0.mean[None], 50, 1)[0]
    real = np.mean(
        [task.reward(task.rollout(pi0.mean, rng=np.random.default_rng(i))) for i in range(20)]
    )
    print(
        f"excitation {excitation:g}, {label}: closed-loop one-step RMSE "
        f"{np.array2string(rmse, precision=3)}; J(G0) {float(J):.4g}, sampled {sampled:.4g}, "
        f"real {real:.4g}"
    )


def fitc(mean: str):
    return ForwardModel(FITC(n_inducing=100, n_steps=100), mean=mean)


if __name__ == "__main__":
    for excitation in (0.0, 10.0, 30.0):
        measure(excitation, lambda: fitc("zero"), "zero-mean FITC")
        measure(excitation, lambda: fitc("linear"), "linear-mean FITC")
        measure(excitation, LinearGaussianModel, "linear-Gaussian model")
