"""Why tab4.2's dynamics models mispredict: the fit, the data and the sampling, measured.

For random-policy data like ``tab4.2``'s (6 s: 120 / ``--steps`` rollouts of gains drawn from
π₀ with ``--excitation`` N m white torque excitation; data seeds 0, 1, 2) each candidate model
is fitted and compared with the simulator:

* the fit: shortest / median length-scale of the velocity outputs (in units of the input's
  std), noise and signal std relative to std(y), the thesis's additive noise
  σ_add = 1e-2 std(y) (Sec. 4.2.3; on by default, ``additive_noise=1``), L-BFGS iterations;
* one-step RMSE of the predicted next joint velocities (rad/s): on the training data, on
  three held-out rollouts of the old random policy (3 × 2 s, 30 N m), and on closed-loop
  rollouts of the LQR gain (R = 1e-4) from σ = 0.07 (upright); the model's predictive sd
  there;
* the predicted reward of known gains (π₀'s mean, the LQR gain, the PD gain ω = 3, ζ = 2) from
  10 common start states: per-step sampling (GPREPS's, L = 10) / the noise-free mean path /
  the simulator's reward from the same start states.

Run from the repository root (≈ 20 s per model and seed on one core)::

    OMP_NUM_THREADS=1 python docs/measure_tab42_fit.py fitc exact linear --seeds 0 1 2 \
        --steps 10 --excitation 3

Measured for issue #31 (FITC: 100 pseudo-inputs, 50 L-BFGS steps, Δx, linear prior mean):
on the old data (40 steps, 30 N m) every model misses upright alike, whatever the fit —
upright RMSE 0.32 (FITC), 0.31 (with PILCO's HyperCurb), 0.34 (fixed pseudo-inputs), 0.31
(exact GP), 0.33 (linear-Gaussian) rad/s against an upright Δq̇ std of 0.02, and the LQR gain
(real −0.41) predicted −5.7e3 / −994 (FITC), −7.4e3 / −1.05e3 (exact GP): not the fit but the
data, whose links are 0.5–1 rad out within 5 steps. With 10-step rollouts at 3 N m (tab4.2's
setting since issue #31) the FITC's upright RMSE is 0.067 / 0.045 / 0.088 rad/s (seeds 0 / 1 /
2) and the LQR gain is predicted −9.9 / −2.4 (real −0.41), −3.4 / −1.3 (−0.63), −13.8 / −2.3
(−0.66); every variant's numbers are in ``skillkit.experiments.ch4_balancing.VARIANTS``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

from skillkit.experiments.ch4_balancing import BalancingComparisonSettings, initial_policy_42
from skillkit.models.gp import ExactGP, ForwardModel, HyperCurb
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sparse import FITC
from skillkit.search import model_rollouts
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP, collect_balancing

ST = BalancingComparisonSettings()

MODELS = {
    "fitc": lambda: ForwardModel(FITC(n_inducing=100, n_steps=50), target="delta", mean="linear"),
    "fitc_curb": lambda: ForwardModel(
        FITC(n_inducing=100, n_steps=50, curb=HyperCurb()), target="delta", mean="linear"
    ),
    "fitc_fixedZ": lambda: ForwardModel(
        FITC(n_inducing=100, n_steps=50, optimize_inducing=False), target="delta", mean="linear"
    ),
    "exact": lambda: ForwardModel(ExactGP(n_steps=50), target="delta", mean="linear"),
    "exact_curb": lambda: ForwardModel(
        ExactGP(n_steps=50, curb=HyperCurb()), target="delta", mean="linear"
    ),
    "fitc_zero": lambda: ForwardModel(FITC(n_inducing=100, n_steps=50), target="delta"),
    "fitc_next": lambda: ForwardModel(
        FITC(n_inducing=100, n_steps=50), target="next", mean="linear"
    ),
    "linear": LinearGaussianModel,
}


def data(seed: int, steps: int = 40, excitation: float = 30.0):
    """The random-policy data: 6 s as 120 / ``steps`` rollouts of ``steps`` steps each."""
    task = make("balancing", initial_std=ST.initial_std)
    excited = make("balancing", initial_std=ST.initial_std, excitation_std=30.0)  # held out
    pi0 = initial_policy_42(ST, task)
    short = make("balancing", initial_std=ST.initial_std, excitation_std=excitation, n_steps=steps)
    train = collect_balancing(short, 120 // steps, np.random.default_rng(seed), 1.0, policy=pi0)
    held = collect_balancing(excited, 3, np.random.default_rng(seed + 100), 1.0, policy=pi0)
    lqr = task.lqr_gain(control_weight=1e-4)
    up = collect_balancing(task, 3, np.random.default_rng(seed + 200), gain=lqr)
    gains = {"pi0_mean": pi0.mean, "lqr": lqr.ravel(), "pd": task.pd_gain(3.0, 2.0).ravel()}
    return task, train, held, up, gains


def mean_path(task, model, omega, x0) -> float:
    """Mean reward of the noise-free mean path x_{t+1} = E[x_{t+1} | x_t, G x̃_t] from x0 (n, 8)."""
    G = torch.as_tensor(np.reshape(omega, (4, 8)))
    x = torch.as_tensor(x0)
    xs, us = [x], []
    with torch.no_grad():
        for _ in range(task.n_steps):
            u = (x - torch.as_tensor(X_UP)) @ G.T
            x = model.next_state_moments(x, u).mean
            us.append(u)
            xs.append(x)
        us.append((x - torch.as_tensor(X_UP)) @ G.T)
    r = task.reward_batch(torch.stack(xs, 1), torch.stack(us, 1))
    r = np.nan_to_num(r.numpy(), nan=-1e12, neginf=-1e12)
    return float(np.mean(np.maximum(r, -1e12)))


def one_step_rmse(model, d) -> float:
    """RMSE of the predicted next joint velocities (rad/s) on transitions ``d``."""
    with torch.no_grad():
        m = model.next_state_moments(torch.as_tensor(d["x"]), torch.as_tensor(d["u"]))
    mean = m.mean.numpy()
    return float(np.sqrt(((mean[:, 4:] - d["x_next"][:, 4:]) ** 2).mean()))


def measure(name: str, seed: int, cache: dict, steps: int = 40, excitation: float = 30.0) -> dict:
    key = (seed, steps, excitation)
    if key not in cache:
        cache[key] = data(seed, steps, excitation)
    task, train, held, up, gains = cache[key]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = MODELS[name]().fit(train["x"], train["u"], train["x_next"], seed)
    out = {"fit_s": time.perf_counter() - t0}
    if isinstance(model, ForwardModel):
        gp = model.gp
        h = gp.hyperparameters
        y = train["x_next"] - train["x"] if model.delta else train["x_next"]
        sd_in = np.hstack([train["x"], train["u"]]).std(0)
        ls = h["lengthscale"].reshape(h["lengthscale"].shape[0], -1) / sd_in
        vel = slice(4, 8)
        out["ls_min"] = float(ls[vel].min())
        out["ls_med"] = float(np.median(ls[vel]))
        out["noise_rel"] = float(np.median(np.sqrt(h["noise"][vel]) / y[:, vel].std(0)))
        out["signal_rel"] = float(np.median(np.sqrt(h["outputscale"][vel]) / y[:, vel].std(0)))
        out["sigma_add_rel"] = float(np.median(gp.diagnostics["additive_noise_std"][vel]
                                               / y[:, vel].std(0)))  # fmt: skip
        out["iters"] = int(gp.diagnostics.get("n_iterations", -1))
    out["dqd_std"] = float((train["x_next"] - train["x"])[:, 4:].std())
    out["q_rms"] = float(np.sqrt(((train["x"][:, :4] - X_UP[:4]) ** 2).mean()))
    out["dqd_std_up"] = float((up["x_next"] - up["x"])[:, 4:].std())
    out["rmse_train"] = one_step_rmse(model, train)
    out["rmse_held"] = one_step_rmse(model, held)
    out["rmse_up"] = one_step_rmse(model, up)
    with torch.no_grad():  # predictive std of q̇' on the upright data: what sampling draws
        v = model.next_state_moments(torch.as_tensor(up["x"]), torch.as_tensor(up["u"])).var
    out["pred_sd_up"] = float(np.sqrt(v[:, 4:].mean()))
    x0 = task.initial_states(None, 10, np.random.default_rng(seed + 300))
    for g, omega in gains.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = model_rollouts.predict_trajectories(
                task, model, omega[None], None, horizon=task.n_steps, n_samples=10,
                rng=seed, x0=x0[None],
            ).expected_rewards[0]  # fmt: skip
        real = np.mean([task.reward(task.rollout_from(omega, x, rng=0)) for x in x0])
        out[f"{g}"] = (float(s), mean_path(task, model, omega, x0), float(real))
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("models", nargs="*", default=["fitc", "linear"])
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    p.add_argument("--steps", type=int, default=40, help="steps per random-policy rollout")
    p.add_argument("--excitation", type=float, default=30.0, help="σ_ξ of the random policy")
    a = p.parse_args()
    torch.set_num_threads(1)
    cache: dict = {}
    for seed in a.seeds:
        for name in a.models:
            r = measure(name, seed, cache, a.steps, a.excitation)
            text = ", ".join(
                f"{k} " + ("/".join(f"{x:.3g}" for x in v) if isinstance(v, tuple) else f"{v:.3g}")
                for k, v in r.items()
            )
            print(f"seed {seed} steps {a.steps} exc {a.excitation:g} {name}: {text}", flush=True)


if __name__ == "__main__":
    main()
