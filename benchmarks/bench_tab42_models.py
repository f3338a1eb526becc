"""How well tab4.2's forward models predict the balancing robot, and where PILCO's first
update goes on them: model against simulator on the same start states and gains.

Run one part from the repository root::

    OMP_NUM_THREADS=1 python benchmarks/bench_tab42_models.py fit [MODEL ...] [--seeds 0 1 2]
        [--steps 10] [--excitation 3]
    OMP_NUM_THREADS=1 python benchmarks/bench_tab42_models.py closed-loop
    OMP_NUM_THREADS=1 python benchmarks/bench_tab42_models.py pilco [--seeds 0 1]
        [--iterations 30] [--steps 10] [--n-random 12] [--excitation 3]

``fit`` (≈ 20 s per model and seed): random-policy data like tab4.2's (6 s as 120 / ``--steps``
rollouts of gains drawn from π₀ with ``--excitation`` N m white torque excitation; the defaults
are tab4.2's), each MODEL (``fitc``, ``fitc_curb``, ``fitc_fixedZ``, ``exact``, ``exact_curb``,
``fitc_zero``, ``fitc_next``, ``linear``; default ``fitc linear``; the GPs: 100 pseudo-inputs,
50 L-BFGS steps, Δx targets, a linear prior mean unless the name says otherwise) fitted per
data seed. One line per seed and model, ``key value`` pairs: ``fit_s`` fit time; for GP models
``ls_min`` / ``ls_med`` the shortest / median length-scale of the velocity outputs in input
stds, ``noise_rel`` / ``signal_rel`` / ``sigma_add_rel`` the noise, signal and additive noise
std relative to std(y), ``iters`` L-BFGS iterations; ``dqd_std`` / ``dqd_std_up`` the std of
Δq̇ on the training data / upright, ``q_rms`` the training data's RMS joint-angle deviation;
``rmse_train`` / ``rmse_held`` / ``rmse_up`` the one-step RMSE of the next joint velocities
(rad/s) on the training data, three held-out 30 N m random-policy rollouts and the LQR gain's
upright closed loop, ``pred_sd_up`` the model's predictive std there; ``pi0_mean`` / ``lqr`` /
``pd`` the predicted reward of that gain from 10 common start states as sampled (L = 10) /
noise-free mean path / the simulator's.

``closed-loop``: a closed-loop setup (σ₀ = 0.1, a sluggish-LQR π₀, three 2-s rollouts) at
excitation 0, 10 and 30 N m, each with a zero-mean and a linear-mean FITC (100 pseudo-inputs,
Δx) and the linear-Gaussian model: per line the one-step RMSE per state dimension on 3
held-out closed-loop rollouts of π₀, π₀'s expected return J(G₀) by moment matching
(:func:`~skillkit.search.pilco.expected_return`), its sampled estimate (Eq. 4.1, 50
trajectories), and the simulator's mean reward over 20 start states.

``pilco``: the random-policy data plus one rollout of a π₀ sample train the experiment's FITC,
then PILCO optimises the gain from π₀'s mean (``--iterations`` L-BFGS iterations). Per seed the
model's J and the simulator's mean reward from 10 start states for π₀'s mean, the new gain and
the LQR gain (R = 1e-4), and how far the gain moved (‖ΔG‖ / ‖G₀‖): a gain the model scores far
above the simulator is one the optimiser found where the model is wrong in its favour.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace

import numpy as np
import torch

from skillkit.experiments.ch4_balancing import BalancingComparisonSettings, _fitc, initial_policy_42
from skillkit.models.gp import ExactGP, ForwardModel, HyperCurb
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sparse import FITC
from skillkit.search import Batch, collect, model_rollouts
from skillkit.search.gpreps import TrajectoryRewardModel
from skillkit.search.pilco import PILCO, PILCOSettings, expected_return, model_moment_step
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


def fit_scores(
    name: str, seed: int, cache: dict, steps: int = 40, excitation: float = 30.0
) -> dict:
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


def closed_loop(excitation: float, make_model, label: str) -> None:
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


def _fitc_100(mean: str) -> ForwardModel:
    return ForwardModel(FITC(n_inducing=100, n_steps=100), mean=mean)


def fit_part(a: argparse.Namespace) -> None:
    cache: dict = {}
    for seed in a.seeds:
        for name in a.models:
            r = fit_scores(name, seed, cache, a.steps, a.excitation)
            text = ", ".join(
                f"{k} " + ("/".join(f"{x:.3g}" for x in v) if isinstance(v, tuple) else f"{v:.3g}")
                for k, v in r.items()
            )
            print(f"seed {seed} steps {a.steps} exc {a.excitation:g} {name}: {text}", flush=True)


def closed_loop_part(a: argparse.Namespace) -> None:
    for excitation in (0.0, 10.0, 30.0):
        closed_loop(excitation, lambda: _fitc_100("zero"), "zero-mean FITC")
        closed_loop(excitation, lambda: _fitc_100("linear"), "linear-mean FITC")
        closed_loop(excitation, LinearGaussianModel, "linear-Gaussian model")


def pilco_part(a: argparse.Namespace) -> None:
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="part", required=True)
    f = sub.add_parser("fit", help="each model's fit and predictions on random-policy data")
    f.add_argument("models", nargs="*", default=["fitc", "linear"], help=", ".join(MODELS))
    f.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    f.add_argument("--steps", type=int, default=ST.random_steps, help="steps per rollout")
    f.add_argument("--excitation", type=float, default=ST.excitation_std, help="σ_ξ (N m)")
    sub.add_parser("closed-loop", help="π₀'s closed loop per excitation and model class")
    q = sub.add_parser("pilco", help="PILCO's first update: model against simulator")
    q.add_argument("--seeds", nargs="*", type=int, default=[0, 1])
    q.add_argument("--iterations", type=int, default=30)
    q.add_argument("--steps", type=int, default=ST.random_steps)
    q.add_argument("--n-random", type=int, default=ST.n_random)
    q.add_argument("--excitation", type=float, default=ST.excitation_std)
    a = p.parse_args()
    torch.set_num_threads(1)
    {"fit": fit_part, "closed-loop": closed_loop_part, "pilco": pilco_part}[a.part](a)


if __name__ == "__main__":
    main()
