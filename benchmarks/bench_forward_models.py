"""Benchmark: forward models for GPREPS on balancing and pendulum data.

The probabilistic neural-network ensemble (:class:`~skillkit.models.ensemble.
ProbabilisticEnsemble`) against the FITC GP forward models the library's experiments use,
fitted on the same training transitions and scored on the same held-out transitions (whole
trajectories of other (s, ω) pairs):

* ``FITC x' (GPREPS)``: :class:`~skillkit.search.gpreps.TrajectoryRewardModel`'s default
  model, FITC with 100 pseudo-inputs, PILCO's hyper-parameter curb, x′ targets, 150 L-BFGS
  steps;
* ``FITC dx+lin (tab4.2)``: the model of ``tab4.2``'s GPREPS and PILCO runs, FITC with 100
  pseudo-inputs, Δx targets, a linear prior mean, 100 L-BFGS steps;
* ``ensemble dx`` / ``ensemble x'``: the ensemble with its default settings (5 members of
  64-64 SiLU units, 100 epochs), Δx (its default) or x′ targets;
* ``ensemble dx 3x64/300``: a larger variant, since the default ensemble underfits the
  pendulum once its data hold spinning trajectories (|α| up to 8 rad,
  so sin α over several periods): three hidden layers of 64 units, 300 epochs;
* ``linear-Gaussian``: :class:`~skillkit.models.linear.LinearGaussianModel`, the floor any
  nonlinear model should beat.

Data:

* balancing: the planar 4-link robot (torque noise 0.5 N m, 40 steps at 20 Hz) under
  robustly balancing feedback gains drawn from π₀
  (:func:`~skillkit.tasks.balancing.collect_balancing`); 12 inputs, 8 outputs;
* pendulum: the stochastic pendulum of ``fig4.8`` (torque noise σ_u = 1.5, 30 steps) with
  contexts from μ(s), gains from π₀, and the commanded torque as the model input
  (:func:`~skillkit.experiments.ch4_stochastic.commanded_transitions`: the torque noise is
  part of the learned dynamics); 3 inputs, 2 outputs.

Per model: fit time; sampling time per 1000 next-state samples, measured on GPREPS's own
call (:func:`~skillkit.search.model_rollouts.predict_trajectories`: ``--pairs`` (s, ω) pairs ×
``--trajectories`` trajectories × the task's horizon, best of two runs); held-out RMSE per
dimension divided by that dimension's held-out std of x′ − x (1 ≈ predicting the mean change),
averaged over dimensions; held-out Gaussian negative log-likelihood per dimension (raw units,
averaged over dimensions; the ensemble scored with its mixture's mean and variance, the GP
with its predictive ones including noise). Timings are one run on a possibly shared machine:
the load average is printed before and after each part, and speeds are reported as ratios
measured in the same run. Nothing here is asserted.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_forward_models.py [--n-train 400 1600]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from collections.abc import Callable

import numpy as np
import torch

from skillkit.experiments.ch4_stochastic import commanded_transitions
from skillkit.models.ensemble import EnsembleSettings, ProbabilisticEnsemble
from skillkit.models.gp import ForwardModel
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sparse import FITC
from skillkit.search import TrajectoryRewardModel
from skillkit.search.model_rollouts import predict_trajectories
from skillkit.tasks import make
from skillkit.tasks.balancing import collect_balancing


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


# --------------------------------------------------------------------------- data
def balancing_data(n: int, rng: np.random.Generator):
    """The balancing task and ≥ n transitions of whole rollouts; with the rollouts' gains."""
    task = make("balancing", torque_noise_std=0.5)
    d = collect_balancing(task, int(np.ceil(n / task.n_steps)), rng)
    return task, (d["x"], d["u"], d["x_next"]), d["omegas"], None


def pendulum_data(n: int, rng: np.random.Generator):
    """fig4.8's pendulum and ≥ n commanded-torque transitions; with the pairs (ω, s)."""
    task = make("pendulum-stochastic")
    k = int(np.ceil(n / task.horizon))
    contexts = task.sample_context(rng, k)
    omegas = task.initial_policy().sample(contexts, rng)
    parts = [
        commanded_transitions(task, task.rollout(w, s, rng), w)
        for w, s in zip(omegas, contexts, strict=True)
    ]
    return task, tuple(np.concatenate(p) for p in zip(*parts, strict=True)), omegas, contexts


# --------------------------------------------------------------------------- models
def _fitc_gpreps(task) -> ForwardModel:
    return TrajectoryRewardModel(task).make_model()


def _fitc_tab42(task) -> ForwardModel:
    return ForwardModel(FITC(n_inducing=100, n_steps=100), target="delta", mean="linear")


MODELS: dict[str, Callable] = {
    "FITC x' (GPREPS)": _fitc_gpreps,
    "FITC dx+lin (tab4.2)": _fitc_tab42,
    "ensemble dx": lambda task: ProbabilisticEnsemble(target="delta"),
    "ensemble x'": lambda task: ProbabilisticEnsemble(target="next"),
    "ensemble dx 3x64/300": lambda task: ProbabilisticEnsemble(
        EnsembleSettings(hidden_sizes=(64, 64, 64), epochs=300)
    ),
    "linear-Gaussian": lambda task: LinearGaussianModel(),
}


def _moments(model, x, u) -> tuple[np.ndarray, np.ndarray]:
    """Predictive mean and variance per dimension of x′ at held-out (x, u)."""
    if isinstance(model, LinearGaussianModel):
        with torch.no_grad():
            m = model.next_state_moments(torch.as_tensor(x), torch.as_tensor(u))
        return m.mean.numpy(), m.var.numpy()
    return model.predict(x, u)


def _score(model, x, u, xn) -> tuple[float, float, np.ndarray]:
    """Held-out normalised RMSE (mean over dims), Gaussian NLL per dim, and nRMSE per dim."""
    mean, var = _moments(model, x, u)
    var = np.maximum(var, np.finfo(float).tiny)
    scale = (xn - x).std(0)
    nrmse = np.sqrt(((xn - mean) ** 2).mean(0)) / scale
    nll = 0.5 * (np.log(2 * np.pi * var) + (xn - mean) ** 2 / var)
    return float(nrmse.mean()), float(nll.mean()), nrmse


def _sampling_time(task, model, omegas, contexts, args, rng) -> tuple[float, int]:
    """Best of two ``predict_trajectories`` calls (seconds per 1000 next-state samples) and
    the number of non-finite predicted rewards (a diverged model) in the last call."""
    B, L = args.pairs, args.trajectories
    idx = np.arange(B) % len(omegas)
    w = omegas[idx]
    s = None if contexts is None else contexts[idx]
    horizon = task.n_steps if hasattr(task, "n_steps") else task.horizon  # balancing, pendulum
    best, n_bad = np.inf, 0
    for _ in range(2):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            predict_trajectories(task, model, w, s, horizon=horizon, n_samples=L, rng=rng)
            best = min(best, time.perf_counter() - t0)
        n_bad = sum("non-finite" in str(c.message) for c in caught)
    return best / (B * L * horizon / 1000), n_bad


def run(name: str, data_fn, n_train: int, args, seed: np.random.SeedSequence) -> list[tuple]:
    data_rng, test_rng, fit_rng, sample_rng = (np.random.default_rng(s) for s in seed.spawn(4))
    task, (x, u, xn), omegas, contexts = data_fn(n_train, data_rng)
    _, (xt, ut, xnt), omegas_t, contexts_t = data_fn(args.n_test, test_rng)
    print(
        f"\n== {name}: N = {len(x)} training, {len(xt)} held-out transitions, "
        f"{x.shape[1]} states + {u.shape[1]} controls   (load before: {_load()})",
        flush=True,
    )
    rows = []
    for label, make_model in MODELS.items():
        model = make_model(task)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            model.fit(x, u, xn, rng=fit_rng)
            t_fit = time.perf_counter() - t0
        t_pred, n_bad = _sampling_time(task, model, omegas_t, contexts_t, args, sample_rng)
        nrmse, nll, per_dim = _score(model, xt, ut, xnt)
        rows.append((name, len(x), label, t_fit, t_pred, nrmse, nll, per_dim, len(caught), n_bad))
    print(f"== {name}: done (load after: {_load()})", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n-train", type=int, nargs="+", default=[400, 1600])
    parser.add_argument("--n-test", type=int, default=800)
    parser.add_argument("--pairs", type=int, default=40, help="(s, ω) pairs per prediction")
    parser.add_argument("--trajectories", type=int, default=25, help="L per pair")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(
        f"cpus: {os.cpu_count()} (usable {len(os.sched_getaffinity(0))}), "
        f"torch {torch.__version__} with {torch.get_num_threads()} thread(s), "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, load {_load()}"
    )
    seeds = iter(np.random.SeedSequence(args.seed).spawn(2 * len(args.n_train)))
    rows = []
    for name, fn in (("balancing", balancing_data), ("pendulum", pendulum_data)):
        for n in args.n_train:
            rows += run(name, fn, n, args, next(seeds))

    print(
        f"\nsampling: predict_trajectories, {args.pairs} pairs x {args.trajectories} "
        "trajectories x horizon (balancing 40, pendulum 30), float64, best of 2"
    )
    print(
        f"{'data':<10} {'N':>5}  {'model':<21} {'fit [s]':>8} {'ms/1000 samples':>15} "
        f"{'held-out nRMSE':>14} {'NLL/dim':>8} {'fit warns':>9} {'diverged':>8}"
    )
    for data, n, label, t_fit, t_pred, nrmse, nll, _, n_warn, n_bad in rows:
        print(
            f"{data:<10} {n:>5}  {label:<21} {t_fit:8.2f} {1e3 * t_pred:15.3f} "
            f"{nrmse:14.3f} {nll:8.3f} {n_warn:>9} {n_bad:>8}"
        )
    print("\nheld-out nRMSE per dimension (balancing: q1..q4, dq1..dq4; pendulum: a, da)")
    for data, n, label, *_, per_dim, _, _ in rows:
        print(f"{data:<10} {n:>5}  {label:<21} " + " ".join(f"{v:6.3f}" for v in per_dim))
    print("\nmeasured ratios in this run (FITC / ensemble dx; > 1: the ensemble is faster)")
    for data in ("balancing", "pendulum"):
        for n in sorted({r[1] for r in rows if r[0] == data}):
            by = {r[2]: r for r in rows if r[0] == data and r[1] == n}
            ens = by["ensemble dx"]
            for gp in ("FITC x' (GPREPS)", "FITC dx+lin (tab4.2)"):
                g = by[gp]
                print(
                    f"{data:<10} {n:>5}  {gp:<21} fit {g[3] / ens[3]:6.2f}x   "
                    f"sampling {g[4] / ens[4]:6.2f}x"
                )
    print(f"\nload at the end: {_load()}")


if __name__ == "__main__":
    main()
