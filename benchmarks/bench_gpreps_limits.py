"""Why GPREPS's final policies stop short of the thesis's bounds, on the stored runs.

Run ``OMP_NUM_THREADS=1 python benchmarks/bench_gpreps_limits.py PART`` with PART one of

``errors``
    fig4.10: each trial's final policy mean on its 50 held-out contexts — the placed puck's
    error per context (mean, median, share below 5 cm) and by the desired distance d*.
``models``
    fig4.10 and fig4.12: the stored final reward model of each trial against the simulator on
    the final policy's shots — the error the model predicts against the real one, and the
    model's displacement / landing point against the real one (20 predicted paths per shot);
    fig4.11: the model's hit probability on shots that really hit and on those that miss, and
    the correlation of predicted and real rewards.
``exploration``
    fig4.10, fig4.11 and fig4.12: √tr Σ of the search distribution after each quarter of the
    run, relative to the start, and the KL the updates spent
    (:func:`skillkit.teaching.ch4.exploration_table`).
``noise --sigma-cm S --trials T --out DIR``
    fig4.11 at paper scale (seed 0, its first T trials, into DIR) with the pucks tracked at
    σ = S cm instead of our 1 cm, everything else as stored, so trial t differs from the
    stored trial t by the tracking noise only; then the final policies' rewards and hit rates
    beside the stored ones and the final models' P(hit) on hits and misses (as ``models``).
    Whether our noise or the 80 shots limit the model's contact prediction.
``bound TASK TRIAL EVALS``
    How good a policy the simulator and the thesis's policy class allow, from the final policy
    of trial TRIAL of fig4.10 (``hockey``) or fig4.12 (``table-tennis``): (a) CMA-ES on ω for
    each of 10 held-out contexts (800 / 600 rollouts each); (b) CMA-ES on the linear upper-level
    mean a + A s over 30 training contexts (EVALS evaluations of 30 rollouts each), scored on
    50 held-out contexts (hockey: the trial's stored ones; table tennis: 50 fresh ones).
    Model-free, on the simulator: a bound on what the policy class can reach, not a learning
    method (tens of thousands of rollouts).

Every part reads ``data/results`` and rolls out the simulator; only ``noise`` writes (its
run folder, resumable). CMA-ES is
the ``cma`` package's (seeded). Timings and the numbers of one run are in data/README.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from skillkit.tasks import make
from skillkit.viz.history import load_policy_history
from skillkit.viz.model_layers import load_gpreps_run

RESULTS = Path(__file__).resolve().parents[1] / "data" / "results"
RUNS = {"hockey": "fig4.10", "hockey-real": "fig4.11", "table-tennis": "fig4.12"}


def _run(exp_id: str) -> Path:
    return RESULTS / f"{exp_id}-paper-s0"


def _hockey_shot(task, omega, context) -> tuple[float, bool, float]:
    """Reward, hit, |d_T − d*| of one shot (a miss leaves d_T = 0)."""
    reward, traj = task.evaluate(omega, context, 0)
    hit = bool(traj.info.get("hit", False))
    return reward, hit, abs(float(traj.info.get("displacement", 0.0)) - float(context[2]))


def _tt_shot(task, omega, context) -> tuple[float, str, float]:
    """Reward, outcome, ‖b − p‖ of one return: fig3.7's ``shot_scores`` on a single shot."""
    from skillkit.experiments.ch3_table_tennis import shot_scores

    class _Fixed:  # shot_scores plays a policy's mean; this one's mean is omega
        @staticmethod
        def mean_of(contexts):
            return np.atleast_2d(omega)

    _, shots = shot_scores(task, _Fixed, context[None], 0)
    return float(shots["rewards"][0]), shots["outcomes"][0], float(shots["landing_error"][0])


def _mean_of(values: np.ndarray, mask: np.ndarray, spec: str) -> str:
    return format(values[mask].mean(), spec) if mask.any() else "none"


def errors() -> None:
    task = make("hockey")
    run = _run("fig4.10")
    with np.load(run / "trials.npz") as z:
        held = {t: z[f"trial{t}__heldout_contexts"] for t in range(5)}
    all_d, all_e = [], []
    for t, contexts in held.items():
        policy = load_policy_history(run, trial=t).policies[-1]
        shots = [
            _hockey_shot(task, w, s)
            for w, s in zip(policy.mean_of(contexts), contexts, strict=True)
        ]
        hit = np.array([h for _, h, _ in shots])
        err = np.array([e for _, _, e in shots])[hit]
        all_d.append(contexts[hit, 2])
        all_e.append(err)
        print(
            f"fig4.10 trial {t}: placed-puck error (hits, {hit.sum()}/50) mean "
            f"{100 * err.mean():.1f} cm, median {100 * np.median(err):.1f} cm, "
            f"{np.mean(err < 0.05):.0%} below 5 cm, largest {100 * err.max():.0f} cm"
        )
    d, e = np.concatenate(all_d), np.concatenate(all_e)
    for lo, hi in ((0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.0)):
        m = (d >= lo) & (d < hi)
        print(f"  d* in [{lo}, {hi}) m ({m.sum()} shots): mean {100 * e[m].mean():.1f} cm, "
              f"median {100 * np.median(e[m]):.1f} cm")  # fmt: skip


def models() -> None:
    rng = np.random.default_rng(0)
    # fig4.10: predicted against real displacement of the final policy's hits
    task, run = make("hockey"), _run("fig4.10")
    rows = []
    with np.load(run / "trials.npz") as z:
        held = {t: z[f"trial{t}__heldout_contexts"] for t in range(5)}
    for t, contexts in held.items():
        history, model = load_gpreps_run(run, trial=t)
        omegas = history.policies[-1].mean_of(contexts)
        predicted = model.predict(contexts, omegas, 20, rng=rng).displacements.mean(axis=1)
        for w, s, d_hat in zip(omegas, contexts, predicted, strict=True):
            _, traj = task.evaluate(w, s, 0)
            if traj.info.get("hit", False):
                rows.append((s[2], float(traj.info["displacement"]), d_hat))
    d_star, d_real, d_pred = np.array(rows).T
    for lo, hi in ((0, 0.5), (0.5, 0.75), (0.75, 1.0), (0, 1.0)):
        m = (d_star >= lo) & (d_star < hi + 1e-12 * (hi == 1.0))
        real, pred = np.abs(d_real - d_star)[m], np.abs(d_pred - d_star)[m]
        gap = np.abs(d_pred - d_real)[m]
        print(
            f"fig4.10 d* in [{lo}, {hi}]: real error {100 * real.mean():.1f} cm, "
            f"model-predicted {100 * pred.mean():.1f} cm, |predicted − real displacement| "
            f"mean {100 * gap.mean():.1f} cm, median {100 * np.median(gap):.1f} cm"
        )
    # fig4.12: predicted against real landing points of the final policy's returns
    task, run = make("table-tennis"), _run("fig4.12")
    contexts = task.sample_context(np.random.default_rng(7), n=50)
    for t in range(5):
        history, model = load_gpreps_run(run, trial=t)
        omegas = history.policies[-1].mean_of(contexts)
        prediction = model.predict(contexts, omegas, 20, rng=rng)
        landing = np.nanmean(prediction.landing, axis=1)
        real, pred, gap, outcomes = [], [], [], []
        for w, s, p_hat in zip(omegas, contexts, landing, strict=True):
            _, traj = task.evaluate(w, s, 0)
            outcomes.append(traj.info["outcome"])
            if traj.info["outcome"] != "returned":
                continue
            p = np.asarray(traj.info["landing_point"])
            real.append(np.linalg.norm(p - s[3:5]))
            pred.append(np.linalg.norm(p_hat - s[3:5]))
            gap.append(np.linalg.norm(p_hat - p))
        print(
            f"fig4.12 trial {t}: {len(real)}/50 returned; landing error real "
            f"{100 * np.mean(real):.1f} cm, model-predicted {100 * np.nanmean(pred):.1f} cm; "
            f"|predicted − real landing point| median {100 * np.nanmedian(gap):.1f} cm"
        )
        # the shots that really went into the net: what the model expected of them
        net = np.array(outcomes) == "net"
        if net.any():
            r_hat = prediction.expected_rewards
            error_hat = np.linalg.norm(landing - contexts[:, 3:5], axis=1)
            print(
                f"  net {net.sum()}/50: model-predicted reward {r_hat[net].mean():.4f} "
                f"(returns {r_hat[~net].mean():.4f}), predicted landing error "
                f"{100 * np.nanmean(error_hat[net]):.1f} cm, predicted P(contact) "
                f"{prediction.contact_score[net].mean():.2f}"
            )
    # fig4.11: the real setting's contact prediction
    _contact_prediction(make("hockey-real"), _run("fig4.11"), range(5), rng)


def _contact_prediction(task, run: Path, trials, rng) -> None:
    """fig4.11: the final model's P(hit) on the final policy's shots that hit and miss."""
    with np.load(run / "trials.npz") as z:
        held = {t: z[f"trial{t}__heldout_contexts"] for t in trials}
    for t, contexts in held.items():
        history, model = load_gpreps_run(run, trial=t)
        omegas = history.policies[-1].mean_of(contexts)
        pred = model.predict(contexts, omegas, 20, rng=rng)
        p_hit = pred.contact.mean(axis=1)
        shots = [_hockey_shot(task, w, s) for w, s in zip(omegas, contexts, strict=True)]
        reward = np.array([r for r, _, _ in shots])
        hit = np.array([h for _, h, _ in shots])
        p_hits, p_misses = (_mean_of(p_hit, m, ".2f") for m in (hit, ~hit))
        r_hits, r_misses = (_mean_of(reward, m, ".3f") for m in (hit, ~hit))
        print(f"fig4.11 trial {t}: hit {hit.mean():.0%}; model P(hit) on hits {p_hits}, on "
              f"misses {p_misses}; real reward of hits {r_hits}, of misses {r_misses}; "
              f"predicted {pred.expected_rewards.mean():.3f} vs real {reward.mean():.3f}, "
              f"correlation {np.corrcoef(pred.expected_rewards, reward)[0, 1]:.2f}")  # fmt: skip


def noise(sigma_cm: float, trials: int, out: Path) -> None:
    """fig4.11 at paper scale (seed 0, its first ``trials`` trials) with the pucks tracked at
    σ = ``sigma_cm`` instead of 1 cm, everything else as stored: the same trials' seeds, so
    trial t differs from the stored trial t by the tracking noise only."""
    import skillkit.experiments.ch4_events as events
    from skillkit.experiments import reproduce
    from skillkit.tasks.hockey import Observation

    task = make("hockey-real", observation=Observation(noise=sigma_cm / 100))

    def make_task(name, **kwargs):  # fig4.11's trials build their task by name
        if name != "hockey-real" or kwargs:
            raise ValueError(f"noise: expected fig4.11's make('hockey-real'), got {name!r}")
        return task

    events.make = make_task
    run = reproduce("fig4.11", scale="paper", seed=0, trials=trials, out=out, html=False)
    stored = json.loads((_run("fig4.11") / "result.json").read_text())["summary"]["gpreps"]
    g = run.summary["gpreps"]
    print(f"fig4.11 with σ = {sigma_cm:g} cm ({trials} trials, {run.path}):")
    for key in ("final_reward_per_trial", "final_hit_rate_per_trial"):
        print(f"  {key}: {np.round(g[key], 3).tolist()}  (stored, σ = 1 cm: "
              f"{np.round(stored[key][:trials], 3).tolist()})")  # fmt: skip
    _contact_prediction(task, run.path, range(trials), np.random.default_rng(0))


def exploration() -> None:
    from skillkit.experiments import load_run
    from skillkit.teaching.ch4 import exploration_table

    for exp_id in ("fig4.10", "fig4.11", "fig4.12"):
        print(f"{exp_id}:\n{exploration_table(load_run(_run(exp_id))).to_string()}")


def bound(task_name: str, trial: int, evals: int) -> None:
    import cma

    task = make(task_name)
    run = _run(RUNS[task_name])
    history = load_policy_history(run, trial=trial)
    policy = history.policies[-1]
    std0 = np.sqrt(np.diag(history.policies[0].cov))
    rng = np.random.default_rng(123)
    hockey = task_name == "hockey"
    if hockey:  # the trial's own held-out contexts, as the stored summary's
        with np.load(run / "trials.npz") as z:
            held = z[f"trial{trial}__heldout_contexts"]
    else:
        held = task.sample_context(rng, n=50)
    train = task.sample_context(rng, n=30)
    shot = _hockey_shot if hockey else _tt_shot
    unit = "placed-puck error (hits)" if hockey else "landing error (all shots)"

    def error(omegas, contexts) -> str:
        shots = [shot(task, w, s) for w, s in zip(omegas, contexts, strict=True)]
        err = np.array([e for _, _, e in shots])
        if hockey:
            err = err[np.array([h for _, h, _ in shots])]
        return f"mean {100 * np.nanmean(err):.1f} cm, median {100 * np.nanmedian(err):.1f} cm"

    print(f"{RUNS[task_name]} trial {trial}, final policy, {unit} on 50 held-out contexts: "
          f"{error(policy.mean_of(held), held)}")  # fmt: skip
    start = time.perf_counter()
    per_context = 800 if hockey else 600
    for s in held[:10]:
        w0 = policy.mean_of(s[None])[0]
        options = {"maxfevals": per_context, "verbose": -9, "seed": 1}
        es = cma.CMAEvolutionStrategy(np.zeros(w0.size), 0.1, options)
        es.optimize(lambda u, s=s, w0=w0: -shot(task, w0 + u * std0, s)[0])
        before = shot(task, w0, s)[2]
        after = shot(task, w0 + es.result.xbest * std0, s)[2]
        print(f"  context {np.round(s, 2).tolist()}: {100 * before:.1f} -> {100 * after:.2f} cm")
    took = time.perf_counter() - start
    print(f"  (per-context CMA-ES, {per_context} rollouts each: {took:.0f} s)")
    d, k = policy.mean.size, policy.gain.shape[1]

    def means(x, contexts):
        da, da_gain = x[:d] * std0, x[d:].reshape(d, k) * std0[:, None]
        return policy.mean_of(contexts) + da[None] + contexts @ da_gain.T

    def cost(x) -> float:
        return -float(
            np.mean([shot(task, w, s)[0] for w, s in zip(means(x, train), train, strict=True)])
        )

    start = time.perf_counter()
    options = {"maxfevals": evals, "verbose": -9, "seed": 2}
    es = cma.CMAEvolutionStrategy(np.zeros(d + d * k), 0.05, options)
    while not es.stop():
        xs = es.ask()
        es.tell(xs, [cost(x) for x in xs])
    best = es.result.xbest
    took = time.perf_counter() - start
    print(
        f"  linear mean a + A s by CMA-ES ({es.result.evaluations} evaluations × 30 rollouts, "
        f"{took:.0f} s): training contexts {error(means(best, train), train)} (from "
        f"{error(means(0 * best, train), train)}); held-out {error(means(best, held), held)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("part", choices=("errors", "models", "exploration", "bound", "noise"))
    parser.add_argument("task", nargs="?", default="hockey", choices=("hockey", "table-tennis"))
    parser.add_argument("trial", nargs="?", type=int, default=2)
    parser.add_argument("evals", nargs="?", type=int, default=3000)
    parser.add_argument("--sigma-cm", type=float, default=0.0, help="noise: tracking σ (cm)")
    parser.add_argument("--trials", type=int, default=2, help="noise: trials of fig4.11")
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bench_noise"), help="noise: run folder"
    )
    args = parser.parse_args()
    if args.part == "bound":
        bound(args.task, args.trial, args.evals)
    elif args.part == "noise":
        noise(args.sigma_cm, args.trials, args.out)
    else:
        {"errors": errors, "models": models, "exploration": exploration}[args.part]()


if __name__ == "__main__":
    main()
