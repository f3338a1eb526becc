"""Chapter 4 model experiments on the planar 4-link robot (Secs 4.2.2–4.2.3, Figs 4.3–4.5).

:class:`~skillkit.models.gp.ForwardModel` on transitions (x_t, u_t) → x_{t+1} at 20 Hz under
PD controllers. ``fig4.3``: Σ_t KL(p ‖ p̃) of Gaussians fitted to n sampled trajectories and
of moment matching, normalised so moment matching scores 100. ``fig4.4``: wall time of moment
matching vs sampling N trajectories. ``fig4.5``: reward-prediction error of the standard GP
vs FITC (M = N/4) as one training setting varies. Departures: ``skillkit/data/claims/ch4.toml``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from skillkit.experiments.judge import thesis_value
from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ExactGP, ForwardModel, HyperCurb
from skillkit.models.moment_matching import gaussian_kl, moment_matching_flops_per_step, propagate
from skillkit.models.sampling import sample_trajectories, sampler_flops_per_step
from skillkit.models.sparse import FITC
from skillkit.tasks import make
from skillkit.tasks.balancing import (
    X_UP,
    Balancing,
    collect_balancing,
    feedback_policy,
    sampled_rewards,
    stable_gains,
)
from skillkit.trial import TrialContext

__all__ = ["gaussian_fit"]

DATA_EXPLORATION = 0.01  # fig4.4's data controllers: σ = 1% of |G_lqr| (R = 1e-4) entry-wise
_ALPHA = "Additive-noise factor α: σ_add = α 10⁻² std(y) (Sec. 4.2.3)."
_TORQUE_NOISE = "Std of the torque noise of the robot (N m)."
_TARGET = "What the GP learns: 'next' (x′, the thesis) or 'delta'."


def gaussian_fit(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and (unbiased) covariance per time step of samples (n, T, d) → (T, d), (T, d, d)."""
    mean = samples.mean(0)
    c = samples - mean
    return mean, np.einsum("ntd,nte->tde", c, c) / (samples.shape[0] - 1)


def _model(kind: str, n_inducing: int, curb: bool, target: str, alpha: float, steps: int):
    """A standard GP or FITC forward model (additive-noise factor ``alpha``, ``steps``)."""
    kw = dict(additive_noise=alpha, n_steps=steps, curb=HyperCurb() if curb else None)
    gp = ExactGP(**kw) if kind == "standard" else FITC(n_inducing=n_inducing, **kw)
    return ForwardModel(gp, target=target)


# ---------------------------------------------------------------------------- fig4.3


@dataclass(frozen=True)
class SamplingAccuracySettings(Settings):
    """Settings of ``fig4.3`` (Sec. 4.2.2, Fig. 4.3; the planar 4-link robot of Fig. 3.1)."""

    n_data: int = setting(1800, "Training transitions of FITC (thesis: 12000).", minimum=1)
    n_pseudo: int = setting(150, "Pseudo-inputs M of FITC (thesis: 700).", minimum=1)
    horizon: int = setting(60, "Steps T of training and prediction (thesis: 300).", minimum=1)
    n_start: int = setting(20, "Start distributions N(m_0, σ_0² I) (thesis: 100).", minimum=1)
    n_ground_truth: int = setting(300, "Ground-truth trajectories (thesis: 1000).", minimum=10)
    sample_sizes: tuple[int, ...] = setting((10, 20, 50, 100), "Sample sizes compared.", minimum=10)
    amplitude: float = setting(0.6, "Amplitude (rad) of the swinging reference on every joint.")
    period: float = setting(4.0, "Period (s) of the swinging reference.", above=0)
    initial_std: float = setting(0.05, "Std of training starts and m_0 around r_0.", minimum=0)
    torque_noise_std: float = setting(0.5, _TORQUE_NOISE, minimum=0)
    initial_std_range: tuple[float, float] = setting((0.01, 0.1), "Log-uniform σ_0.", above=0)
    n_opt_steps: int = setting(50, "Hyper-parameter optimisation steps of the model.", minimum=0)
    additive_noise: float = setting(1.0, _ALPHA, minimum=0)
    curb: bool = setting(True, "Train with PILCO's hyper-parameter curb (HyperCurb).")
    gp_target: Literal["next", "delta"] = setting("next", _TARGET)

    def check(self) -> None:
        if not self.sample_sizes:
            raise ValueError("sample_sizes: expected at least one number of trajectories")


SCALES_4_3 = scales(
    SamplingAccuracySettings(),
    smoke=dict(
        n_data=120,
        n_pseudo=20,
        horizon=6,
        n_start=3,
        n_ground_truth=150,
        sample_sizes=(10, 40),
        n_opt_steps=5,
    ),
    paper=dict(
        n_data=12000,
        n_pseudo=700,
        horizon=300,
        n_start=100,
        n_ground_truth=1000,
        sample_sizes=(10, 15, 20, 30, 50, 75, 100, 200),
        n_opt_steps=150,
    ),
)


def _train_balancing_model(
    settings: ComputeTimeSettings, rng: np.random.Generator
) -> tuple[Balancing, ForwardModel, dict]:
    """fig4.4's model: feedback around upright, Δx targets, no curb (as its stored result)."""
    T = settings.horizon
    task = make("balancing", n_steps=T, torque_noise_std=settings.torque_noise_std)
    policy = task.lqr_policy(exploration_std_fraction=DATA_EXPLORATION)
    data = collect_balancing(task, max(1, int(np.ceil(settings.n_data / T))), rng, policy=policy)
    s = settings
    model = _model("sparse", s.n_pseudo, False, "delta", s.additive_noise, s.n_opt_steps)
    model.fit(data["x"], data["u"], data["x_next"], rng=rng)
    return task, model, data


def _tracking_data(task: Balancing, G, ref, ff, n: int, rng) -> dict:
    """``n`` tracking-PD rollouts from x_0 ~ N(r_0, σ² I), failed ones replaced and counted."""
    parts, n_failed, errors = [], 0, []
    while len(parts) < n:
        x0 = ref[0] + task.initial_std * rng.standard_normal(8)
        traj = task.rollout_from(G.ravel(), x0, rng=rng, reference=ref, feedforward=ff)
        if traj.failed:
            n_failed += 1
            if n_failed > 10 * n:
                raise RuntimeError(f"fig4.3: {n_failed} tracking rollouts failed")
            continue
        parts.append(task.transitions(traj))
        errors.append(np.abs(traj.states[:, :4] - ref[:, :4]).max())
    x, u, xn = (np.vstack([p[i] for p in parts]) for i in range(3))
    return {"x": x, "u": u, "x_next": xn, "n_failed": n_failed, "tracking_error": errors}


def _run_4_3(
    settings: SamplingAccuracySettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    sizes = list(settings.sample_sizes)
    B, T, n_gt = settings.n_start, settings.horizon, settings.n_ground_truth
    L = n_gt + sum(sizes)
    noise, std = settings.torque_noise_std, settings.initial_std
    task = make("balancing", n_steps=T, torque_noise_std=noise, initial_std=std)
    G = task.pd_gain()
    ref, ff = task.swing_reference(settings.amplitude, settings.period)
    offsets = ff[:T] - ref[:T] @ G.T  # u_t = G x_t + (u_ff,t − G r_t): linear in x_t
    trial.reset(total=1 + B)
    # Resumable after every start state: the trained model, the start states and the KLs so far.
    st = trial.resume("fig4.3", rng)
    if st is None:
        data = _tracking_data(task, G, ref, ff, max(1, int(np.ceil(settings.n_data / T))), rng)
        s = settings
        model = _model("sparse", s.n_pseudo, s.curb, s.gp_target, s.additive_noise, s.n_opt_steps)
        t0 = time.perf_counter()
        model.fit(data["x"], data["u"], data["x_next"], rng=rng)
        lo, hi = np.log(settings.initial_std_range)
        st = {
            "model": model,
            "train_time_s": time.perf_counter() - t0,
            "m0": ref[0] + settings.initial_std * rng.standard_normal((B, 8)),
            "sigma0": np.exp(rng.uniform(lo, hi, B)),
            "kl_mm": np.full((B, T), np.nan),
            "kl_samples": np.full((B, len(sizes), T), np.nan),
            "done": 0,
            "n_variance_clamped": 0,
            "n_data": len(data["x"]),
            "n_failed_rollouts": data["n_failed"],
            "tracking_error": float(np.mean(data["tracking_error"])),
        }
        trial.save("fig4.3", st, rng)
    trial.update(1 + st["done"])
    model, m0, sigma0 = st["model"], st["m0"], st["sigma0"]
    policy = feedback_policy(torch.as_tensor(G[None]), reference=ref, feedforward=ff)
    for b in range(st["done"], B):
        # L trajectories from N(m0_b, σ0_b² I): the first n_gt are the ground truth, the rest
        # are split into the sample sizes compared with moment matching.
        x0 = m0[b] + sigma0[b] * rng.standard_normal((1, L, 8))
        res = sample_trajectories(model, x0, policy, T, L, rng)
        states = res.states[0, :, 1:].numpy()
        gt_mean, gt_cov = gaussian_fit(states[:n_gt])
        means, covs = propagate(model, m0[b], sigma0[b] ** 2 * np.eye(8), T, G, offsets)
        st["kl_mm"][b] = gaussian_kl(gt_mean, gt_cov, means[1:].numpy(), covs[1:].numpy())
        offset = n_gt
        for i, n in enumerate(sizes):
            mean, cov = gaussian_fit(states[offset : offset + n])
            st["kl_samples"][b, i] = gaussian_kl(gt_mean, gt_cov, mean, cov)
            offset += n
        st["n_variance_clamped"] += res.n_variance_clamped
        st["done"] = b + 1
        trial.save("fig4.3", st, rng)
        trial.update()
    keys = "kl_mm kl_samples sigma0 n_data n_failed_rollouts tracking_error train_time_s".split()
    d = model.gp.diagnostics
    out = {k: st[k] for k in [*keys, "n_variance_clamped"]} | {"model_jitter": d["jitter"]}
    return out | {k: d[k] for k in _HYPER}


_MATCH = "trajectories to match MM"
_HYPER = ("max_signal_to_noise", "max_lengthscale_ratio")


def _loglog(panel: str, ylabel: str) -> dict:
    return dict(
        panel=panel, xlabel="number of sampled trajectories", ylabel=ylabel, log_x=True, log_y=True
    )


def _summarize_4_3(
    settings: SamplingAccuracySettings, trials: list[dict]
) -> tuple[list[Series], dict]:
    sizes = list(settings.sample_sizes)
    scores = np.concatenate(
        [100.0 * t["kl_samples"].sum(-1) / t["kl_mm"].sum(-1)[:, None] for t in trials]
    )
    pct = {q: np.percentile(scores, q, axis=0) for q in (50, 75, 95)}
    kw = _loglog("sampling accuracy", "normalised KL (moment matching = 100)")
    name = "sampling, {}th percentile over start states"
    series = [
        Series(name.format(q), sizes, pct[q].tolist(), kind="lines+markers", **kw) for q in pct
    ]
    series.append(Series("moment matching", sizes, [100.0] * len(sizes), **kw))
    # The first sample size whose percentile reaches moment matching's score.
    hits = {q: [n for n, v in zip(sizes, pct[q], strict=True) if v <= 100.0] for q in (75, 95)}
    reach = {q: h[0] if h else None for q, h in hits.items()}
    summary = {
        "percentiles": {
            str(q): dict(zip(map(str, sizes), pct[q].tolist(), strict=True)) for q in pct
        },
        **{f"samples_to_match_mm_{q}pct": reach[q] for q in reach},
        "thesis_numbers": {  # the claims spec's
            f"samples_to_match_mm_{q}pct": int(thesis_value("fig4.3", f"{_MATCH}, {q}%"))
            for q in (75, 95)
        },
        "mean_kl_per_step_mm": float(np.mean([t["kl_mm"].mean() for t in trials])),
        "n_start_states": int(scores.shape[0]),
        "n_variance_clamped": int(sum(t["n_variance_clamped"] for t in trials)),
        "model": {
            "n_data": int(trials[0]["n_data"]),
            "n_pseudo_inputs": settings.n_pseudo,
            "horizon": settings.horizon,
            "train_time_s": float(np.mean([t["train_time_s"] for t in trials])),
            **{k: float(max(t[k] for t in trials)) for k in _HYPER},
            "data_tracking_error_rad": float(np.mean([t["tracking_error"] for t in trials])),
        },
    }
    return series, summary


register(
    Experiment(
        id="fig4.3",
        title="Sampling accuracy vs number of sampled trajectories (moment matching = 100)",
        settings_class=SamplingAccuracySettings,
        settings=SCALES_4_3,
        run_trial=_run_4_3,
        summarize=_summarize_4_3,
    )
)


# ---------------------------------------------------------------------------- fig4.4
@dataclass(frozen=True)
class ComputeTimeSettings(Settings):
    """Settings of ``fig4.4`` (Sec. 4.2.2, Fig. 4.4): timings, so numbers vary between runs."""

    n_data: int = setting(600, "Training transitions of FITC (thesis: 1500).", minimum=1)
    n_pseudo: int = setting(100, "Pseudo-inputs M of FITC (thesis: 300).", minimum=1)
    horizon: int = setting(30, "Steps T of every prediction (thesis: 100).", minimum=1)
    n_trajectories: tuple[int, ...] = setting(
        (10, 100, 1000, 3000), "Numbers N of sampled trajectories timed, increasing.", minimum=1
    )
    threads: tuple[int, ...] = setting((1, 2), "Torch thread counts timed.", minimum=1)
    repeats: int = setting(3, "Timings repeated (minimum kept; once above N = 1000).", minimum=1)
    torque_noise_std: float = setting(0.5, _TORQUE_NOISE, minimum=0)
    n_opt_steps: int = setting(30, "Hyper-parameter optimisation steps of the model.", minimum=0)
    additive_noise: float = setting(1.0, _ALPHA, minimum=0)


SCALES_4_4 = scales(
    ComputeTimeSettings(),
    smoke=dict(
        n_data=100,
        n_pseudo=20,
        horizon=5,
        n_trajectories=(10, 100),
        threads=(1,),
        repeats=1,
        n_opt_steps=5,
    ),
    paper=dict(
        n_data=1500,
        n_pseudo=300,
        horizon=100,
        n_trajectories=(10, 100, 1000, 3000, 10000),
        n_opt_steps=150,
    ),
)


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _run_4_4(settings: ComputeTimeSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    """Per torch thread count, the least wall time over ``repeats`` (one above N = 1000) of
    ``propagate`` and of sampling N trajectories from N(m0, S0) under u = G x̃."""
    trial.reset(total=2)
    task, model, data = _train_balancing_model(settings, rng)
    trial.update()
    m0 = X_UP + task.initial_std * rng.standard_normal(8)
    lqr = task.lqr_policy(exploration_std_fraction=DATA_EXPLORATION)
    G = stable_gains(task, 1, rng, policy=lqr)[0].reshape(4, 8)
    S0 = 0.05**2 * np.eye(8)
    horizon, ns, repeats = settings.horizon, list(settings.n_trajectories), settings.repeats
    policy = feedback_policy(torch.as_tensor(G[None]))
    k = -G @ X_UP
    chol = np.linalg.cholesky(S0)
    before = torch.get_num_threads()
    out = {"mm_time": {}, "sampling_time": {}, "trajectories_in_mm_time": {}}
    try:
        for th in settings.threads:
            torch.set_num_threads(int(th))
            propagate(model, m0, S0, 2, G, k)  # warm-up
            mm = min(
                _timed(lambda: propagate(model, m0, S0, horizon, G, k)) for _ in range(repeats)
            )
            times = []
            for n in ns:
                x0 = m0 + rng.standard_normal((1, n, len(m0))) @ chol.T

                def sample(x0=x0, n=n):
                    return sample_trajectories(model, x0, policy, horizon, n, rng)

                times.append(min(_timed(sample) for _ in range(repeats if n <= 1000 else 1)))
            out["mm_time"][str(th)] = mm
            out["sampling_time"][str(th)] = times
            out["trajectories_in_mm_time"][str(th)] = mm * ns[-1] / times[-1]
    finally:
        torch.set_num_threads(before)
    trial.update()
    return {**out, "n_data": len(data["x"]), "n_pseudo": model.predictor.n_support}


def _summarize_4_4(settings: ComputeTimeSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    ns = list(settings.n_trajectories)
    kw = _loglog("compute time of one long-term prediction", "wall time (s)")
    series = []
    keys = ("mm_time_s", "sampling_time_s", "trajectories_in_mm_time", "mm_gflops")
    summary: dict = {k: {} for k in (*keys, "sampling_gflops")}
    # Counted flops (exp as one flop) of one step: n_x outputs, n_x + n_u inputs.
    T, M = settings.horizon, trials[0]["n_pseudo"]
    n_x = X_UP.size
    n_u = n_x // 2
    mm_flops = moment_matching_flops_per_step(n_x, M, n_x + n_u) * T
    sample_flops = sampler_flops_per_step(n_x, M, n_x + n_u) * T
    for th in map(str, settings.threads):
        st = np.median([t["sampling_time"][th] for t in trials], axis=0)
        mm = float(np.median([t["mm_time"][th] for t in trials]))
        series += [
            Series(f"sampling, {th} thread(s)", ns, st.tolist(), kind="lines+markers", **kw),
            Series(f"moment matching, {th} thread(s)", ns, [mm] * len(ns), **kw),
        ]
        summary["mm_time_s"][th] = mm
        summary["sampling_time_s"][th] = dict(zip(map(str, ns), st.tolist(), strict=True))
        summary["trajectories_in_mm_time"][th] = float(
            np.median([t["trajectories_in_mm_time"][th] for t in trials])
        )
        summary["mm_gflops"][th] = mm_flops / mm / 1e9
        summary["sampling_gflops"][th] = {
            str(n): sample_flops * n / t / 1e9 for n, t in zip(ns, st.tolist(), strict=True)
        }
    summary["model"] = {
        "n_data": trials[0]["n_data"],
        "n_pseudo_inputs": trials[0]["n_pseudo"],
        "horizon": settings.horizon,
        "state_dim": n_x,
        "control_dim": n_u,
    }
    flops = dict(moment_matching=mm_flops, sampling_per_trajectory=sample_flops)
    summary["flops_per_prediction"] = flops
    summary["trajectories_in_mm_flops"] = mm_flops / sample_flops
    return series, summary


register(
    Experiment(
        id="fig4.4",
        title="Compute time: moment matching vs sampling",
        settings_class=ComputeTimeSettings,
        settings=SCALES_4_4,
        run_trial=_run_4_4,
        summarize=_summarize_4_4,
    )
)


# ---------------------------------------------------------------------------- fig4.5
_PANELS_4_5 = (
    ("additive_noise", "additive noise factor alpha"),
    ("n_opt_steps", "optimisation steps"),
    ("torque_noise_std", "control noise std (N m)"),
    ("n_train", "number of training trajectories"),
)


@dataclass(frozen=True)
class TrainingSetting(Settings):
    """One training setting of ``fig4.5``: the default every panel varies one field of (the
    field order is part of the experiment's seeds)."""

    additive_noise: float = setting(1.0, _ALPHA, minimum=0)
    n_opt_steps: int = setting(50, "Hyper-parameter optimisation steps (thesis: 150).", minimum=0)
    torque_noise_std: float = setting(0.5, _TORQUE_NOISE, minimum=0)
    n_train: int = setting(15, "Training trajectories (thesis: 50).", minimum=1)


@dataclass(frozen=True)
class RewardErrorSettings(Settings):
    """Settings of ``fig4.5`` (Sec. 4.2.3, Fig. 4.5): one panel per ``*_values`` field."""

    defaults: TrainingSetting = setting(
        TrainingSetting(), "The default training setting (``--set`` takes a mapping)."
    )
    additive_noise_values: tuple[float, ...] = setting(
        (0.1, 1.0, 10.0), "Additive-noise factors α of the first panel.", minimum=0
    )
    n_opt_steps_values: tuple[int, ...] = setting(
        (10, 50), "Optimisation step counts of the second panel.", minimum=0
    )
    torque_noise_std_values: tuple[float, ...] = setting(
        (0.5, 2.0), "Torque-noise stds (N m) of the third panel.", minimum=0
    )
    n_train_values: tuple[int, ...] = setting(
        (5, 15), "Training-trajectory counts of the fourth panel.", minimum=1
    )
    n_pairs: int = setting(15, "Test start states x_0 (thesis: 50).", minimum=1)
    initial_std: float = setting(0.1, "Std of the initial state around upright.", minimum=0)
    horizon: int = setting(20, "Steps T of training and test trajectories (thesis: 20).", minimum=1)
    n_predicted: int = setting(10, "Trajectories sampled per test pair (thesis: 20).", minimum=1)
    pseudo_fraction: float = setting(0.25, "FITC's pseudo-inputs M / N.", above=0, maximum=1)
    natural_frequency: float = setting(3.0, "ω (rad/s) of the PD controller.", above=0)
    damping: float = setting(1.5, "ζ of the PD controller.", above=0)
    gp_target: Literal["next", "delta"] = setting("next", _TARGET)
    uncurbed_panels: tuple[str, ...] = setting(("n_opt_steps",), "Panels also trained uncurbed.")
    n_truth: int = setting(5, "Real rollouts per test start (variance: the floor).", minimum=2)

    def check(self) -> None:
        names = [k for k, _ in _PANELS_4_5]
        bad = [p for p in self.uncurbed_panels if p not in names]
        if bad:
            raise ValueError(f"uncurbed_panels: expected names from {names}, got {bad}")


SCALES_4_5 = scales(
    RewardErrorSettings(),
    smoke=dict(
        defaults=TrainingSetting(1.0, 5, 0.5, 2),
        additive_noise_values=(1.0, 10.0),
        n_opt_steps_values=(5,),
        torque_noise_std_values=(0.5,),
        n_train_values=(2,),
        n_pairs=3,
        horizon=5,
        n_predicted=3,
        n_truth=2,
    ),
    paper=dict(
        defaults=TrainingSetting(1.0, 150, 0.5, 50),
        additive_noise_values=(0.1, 0.3, 1.0, 3.0, 10.0, 30.0),
        n_opt_steps_values=(10, 25, 50, 100, 150, 250),
        torque_noise_std_values=(0.0, 0.25, 0.5, 1.0, 2.0),
        n_train_values=(10, 20, 50, 100),
        n_pairs=50,
        n_predicted=20,
        n_truth=10,
    ),
)


def _seed(root: int, *keys) -> np.random.Generator:
    milli = [int(round(k * 1000)) for k in keys]
    return np.random.default_rng(np.random.SeedSequence([root, *milli]))


def _evaluate_4_5(cfg: dict, settings: RewardErrorSettings, root: int, curbs=(True,)) -> dict:
    """Both models' reward-prediction errors for one training setting (``curbs``: with the
    HyperCurb and/or without, ``"<kind>_uncurbed"``); R of a test start: one real rollout."""
    T = settings.horizon
    noise = cfg["torque_noise_std"]
    task = make("balancing", n_steps=T, torque_noise_std=noise, initial_std=settings.initial_std)
    G = task.pd_gain(settings.natural_frequency, settings.damping)
    train = collect_balancing(task, cfg["n_train"], _seed(root, 1, noise, cfg["n_train"]), gain=G)
    test_rng = _seed(root, 2, noise)
    x0 = task.initial_states(n=settings.n_pairs, rng=test_rng)
    rollouts = [
        [task.rollout_from(G.ravel(), x, rng=test_rng) for _ in range(settings.n_truth)] for x in x0
    ]
    truth = np.array([[task.reward(t) for t in row] for row in rollouts])  # (P, n_truth)
    real = truth[:, 0]
    train_mean = float(np.mean([task.reward(t) for t in train["trajectories"]]))
    gains = np.broadcast_to(G, (settings.n_pairs, 4, 8)).copy()
    out = {
        "real_reward_mean": float(real.mean()),
        "noise_floor": float(np.var(truth, axis=1, ddof=1).mean()),
        "constant_predictor": float(np.mean((train_mean - real) ** 2)),
        "n_failed_truth": int(sum(t.failed for row in rollouts for t in row)),
    }
    N = len(train["x"])
    M = max(1, int(settings.pseudo_fraction * N))
    for curb in curbs:
        for kind in ("standard", "sparse"):
            alpha, steps = cfg["additive_noise"], cfg["n_opt_steps"]
            model = _model(kind, M, curb, settings.gp_target, alpha, steps)
            t0 = time.perf_counter()
            model.fit(train["x"], train["u"], train["x_next"], rng=_seed(root, 3, *cfg.values()))
            train_time = time.perf_counter() - t0
            policy = feedback_policy(torch.as_tensor(gains))
            draws = _seed(root, 4, *cfg.values())
            res = sample_trajectories(model, x0, policy, T, settings.n_predicted, draws)
            predicted = sampled_rewards(task, res.states.numpy(), gains).mean(1)
            d = model.gp.diagnostics
            out[kind if curb else f"{kind}_uncurbed"] = {
                "squared_error": float(np.mean((predicted - real) ** 2)),
                "train_time_s": train_time,
                "n_data": N,
                "jitter": d["jitter"],
                "noise_at_floor": len(d["noise_at_floor"]),
                "stopped_early": d["stopped_early"] is not None,
                **{k: d[k] for k in _HYPER},
            }
    return out


def _configs_4_5(settings: RewardErrorSettings) -> list[tuple[dict, bool]]:
    """The panels' distinct training settings, each with whether it is also trained uncurbed."""
    defaults = settings.defaults.to_dict()
    configs, uncurbed = [], []  # the distinct settings; whether each is also trained uncurbed
    for key, _ in _PANELS_4_5:
        for v in getattr(settings, f"{key}_values"):
            cfg = dict(defaults, **{key: v})
            if cfg not in configs:
                configs.append(cfg)
                uncurbed.append(False)
            if key in settings.uncurbed_panels:
                uncurbed[configs.index(cfg)] = True
    return list(zip(configs, uncurbed, strict=True))


def _run_4_5(settings: RewardErrorSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    root = int(rng.integers(2**31))
    configs = _configs_4_5(settings)
    trial.reset(total=len(configs))
    results = list(trial.resume("fig4.5", rng) or [])
    trial.update(len(results))
    for cfg, uncurbed in configs[len(results) :]:
        curbs = (True, False) if uncurbed else (True,)
        results.append({"config": cfg, **_evaluate_4_5(cfg, settings, root, curbs)})
        trial.save("fig4.5", list(results), rng)
        trial.update()
    return {"results": results}


_SQ_ERROR = "mean squared reward error [reward²]"  # the balancing reward is unitless
_KINDS_4_5 = (
    ("standard", "standard GP"),
    ("sparse", "sparse GP (FITC, M = N/4)"),
    ("standard_uncurbed", "standard GP, no curb"),
    ("sparse_uncurbed", "sparse GP (FITC), no curb"),
    ("noise_floor", "noise floor: Var(R | x₀)"),
    ("constant_predictor", "constant predictor (training mean reward)"),
)


def sparse_minus_standard(panels: dict, settings) -> dict[str, list[float]]:
    """FITC's reward-prediction error minus the standard GP's at the additive-noise factors
    above the default and the control-noise levels above 0, where the thesis compares them:
    from fig4.5's ``summary["panels"]`` one entry per setting, from ``"panels_per_trial"``
    one per (setting, trial)."""

    def diff(key: str, above: float) -> list[float]:
        p, values = panels[key], sorted(getattr(settings, f"{key}_values"))
        d = [np.subtract(p["sparse"][str(v)], p["standard"][str(v)]) for v in values if v > above]
        return np.ravel(d).tolist()

    return {
        "additive_noise_above_default": diff("additive_noise", settings.defaults.additive_noise),
        "torque_noise_above_zero": diff("torque_noise_std", 0),
    }


def _summarize_4_5(settings: RewardErrorSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    series: list[Series] = []
    summary: dict = {"panels": {}, "panels_per_trial": {}}
    defaults = settings.defaults.to_dict()

    def value(r: dict, kind: str):
        v = r.get(kind)
        return None if v is None else v if isinstance(v, float) else v["squared_error"]

    results = [r for t in trials for r in t["results"]]

    def at(cfg: dict) -> list[dict]:
        return [r for r in results if r["config"] == cfg]

    def per_trial(cfg: dict, kind: str) -> list[float]:
        """Each trial's error at ``cfg`` (its mean over the trial's results there)."""
        rs = [[r for r in t["results"] if r["config"] == cfg] for t in trials]
        return [float(np.mean([value(r, kind) for r in x])) for x in rs]

    for key, label in _PANELS_4_5:
        values = list(getattr(settings, f"{key}_values"))
        panel, by_trial = {}, {}
        kw = dict(panel=label, xlabel=label, ylabel=_SQ_ERROR, log_x=key == "additive_noise")
        for kind, name in _KINDS_4_5:
            if kind.endswith("_uncurbed") and key not in settings.uncurbed_panels:
                continue
            errs = [per_trial(dict(defaults, **{key: v}), kind) for v in values]
            means = [float(np.mean(e)) for e in errs]
            line = "line" if kind in ("noise_floor", "constant_predictor") else "lines+markers"
            series.append(Series(name, values, means, kind=line, log_y=True, **kw))
            panel[kind] = dict(zip(map(str, values), means, strict=True))
            by_trial[kind] = dict(zip(map(str, values), errs, strict=True))
        summary["panels"][key] = panel
        summary["panels_per_trial"][key] = by_trial
    default = at(defaults)
    by_steps = {str(v): at(dict(defaults, n_opt_steps=v)) for v in settings.n_opt_steps_values}
    floors = ("standard", "sparse", "noise_floor", "constant_predictor")
    default_per_trial = {k: per_trial(defaults, k) for k in floors}

    summary |= {
        "n_trials": len(trials),
        "default_setting": defaults,
        "default_squared_error": {k: float(np.mean(v)) for k, v in default_per_trial.items()},
        "default_squared_error_per_trial": default_per_trial,
        "mean_real_reward": float(np.mean([r["real_reward_mean"] for r in default])),
        "train_time_s_default": {
            k: float(np.mean([r[k]["train_time_s"] for r in default]))
            for k in ("standard", "sparse")
        },
        "hyperparameters_by_steps": {
            kind: {
                v: {k: float(np.max([r[kind][k] for r in rs])) for k in _HYPER}
                for v, rs in by_steps.items()
                if all(kind in r for r in rs)
            }
            for kind in ("standard", "sparse", "standard_uncurbed", "sparse_uncurbed")
        },
        "numerical_events": {
            k: {
                "jitter": max(r[k]["jitter"] for r in results if k in r),
                "noise_at_floor": sum(r[k]["noise_at_floor"] for r in results if k in r),
                "stopped_early": sum(r[k]["stopped_early"] for r in results if k in r),
            }
            for k in ("standard", "sparse")
        },
        "n_failed_truth_rollouts": sum(r["n_failed_truth"] for r in results),
    }
    summary["sparse_minus_standard"] = sparse_minus_standard(summary["panels"], settings)
    summary["sparse_minus_standard_per_trial"] = sparse_minus_standard(
        summary["panels_per_trial"], settings
    )
    return series, summary


register(
    Experiment(
        id="fig4.5",
        title="Standard vs sparse (FITC) GP reward-prediction error",
        settings_class=RewardErrorSettings,
        settings=SCALES_4_5,
        run_trial=_run_4_5,
        summarize=_summarize_4_5,
        trials={"smoke": 1, "quick": 1, "paper": 5},
    )
)
