"""Chapter 4 model experiments on the planar 4-link robot (Secs 4.2.2–4.2.3, Figs 4.3–4.5).

Models are :class:`~skillkit.models.gp.ForwardModel` on transitions (x_t, u_t) → x_{t+1} at
the 20 Hz control rate; u_t is the commanded torque and the torque noise is part of the
stochastic dynamics the GP has to capture. Since issue #16 fig4.3 and fig4.5 follow the
thesis's setup: the GP learns x_{t+1} (not Δx), with PILCO's hyper-parameter curb
(:class:`~skillkit.models.gp.HyperCurb`), and the controllers are PD controllers
(:meth:`~skillkit.tasks.balancing.Balancing.pd_gain`). Each summary has a setup table.

* ``fig4.3`` — sampling accuracy vs number of sampled trajectories. The lower-level policy is
  a linear trajectory-tracking PD controller u = G (x − r_t) + u_ff,t around a reference
  swinging every joint by ``amplitude`` rad (:meth:`~skillkit.tasks.balancing.Balancing.
  swing_reference`, u_ff its inverse dynamics); linear in x, so moment matching applies with
  the per-step offset u_ff,t − G r_t. A FITC model is trained on tracking rollouts (thesis:
  12000 points, 700 pseudo-inputs, horizon 300); for each of ``n_start`` start distributions
  N(m_0, σ_0²I) (m_0 around r_0, σ_0 log-uniform) the ground truth p(x_t) is the Gaussian
  fitted to ``n_ground_truth`` sampled trajectories; approximations are Gaussians fitted to
  n fresh samples, and moment matching (:func:`~skillkit.models.moment_matching.propagate`).
  Scores are Σ_t KL(p(x_t) ‖ p̃(x_t)) normalised per start so that moment matching scores 100.
* ``fig4.4`` — wall time of one moment-matching prediction vs sampling N trajectories with
  the same model and horizon, with 1 and 2 torch threads (timings are measurements, so
  they differ between runs even with the same seed). Unchanged by issue #16: feedback
  around upright with gains from N(vec G_lqr, (1% |G_lqr|)²) (:data:`DATA_EXPLORATION`,
  kept robustly balancing by :func:`~skillkit.tasks.balancing.stable_gains`), Δx targets.
* ``fig4.5`` — reward-prediction error E[(R̂ − R)²] of the standard GP vs FITC (M = N/4)
  for 50 start states x_0 (T = 20, 20 sampled trajectories each) while one training setting
  varies: the additive-noise factor α (σ_add = α 10⁻² std(y)), the number of
  hyper-parameter optimisation steps, the torque noise, the number of training
  trajectories. One PD controller balances throughout; R is the reward of a real rollout
  from x_0 (the balancing reward −Σ_t x̃_tᵀ x̃_t of Sec. 4.2.3). Two floors are reported: the
  noise floor Var(R | x_0) (repeated real rollouts from x_0) and the error of predicting the
  training rollouts' mean reward. The optimisation-steps panel is also trained without the
  curb, which shows its effect.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from skillkit.experiments.claims import conjunction, is_less, own_check
from skillkit.experiments.registry import Experiment, Series, Verdict, fmt, register, with_verdict
from skillkit.experiments.settings import Settings, setting
from skillkit.models.gp import ExactGP, ForwardModel, HyperCurb
from skillkit.models.moment_matching import (
    gaussian_kl,
    moment_matching_flops_per_step,
    propagate,
)
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

__all__ = ["OWN_CHECKS", "gaussian_fit", "time_predictions"]

DATA_EXPLORATION = 0.01
"""Exploration of the data controllers: σ = 1% of |G_lqr| (R = 1e-4) entry-wise, kept from
before issue #15 so that the stored results stay valid; issue #16 replaces these controllers
with the thesis's PD controllers."""


def _data_policy(task: Balancing):
    return task.lqr_policy(exploration_std_fraction=DATA_EXPLORATION)


def gaussian_fit(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and (unbiased) covariance per time step of samples (n, T, d) → (T, d), (T, d, d)."""
    mean = samples.mean(0)
    c = samples - mean
    return mean, np.einsum("ntd,nte->tde", c, c) / (samples.shape[0] - 1)


def _model(
    kind: str,
    n_data: int,
    settings: SamplingAccuracySettings | ComputeTimeSettings | RewardErrorSettings,
    *,
    n_inducing: int | None = None,
    additive_noise: float | None = None,
    n_steps: int | None = None,
    curb: bool = True,
    target: str = "next",
) -> ForwardModel:
    kw = dict(
        additive_noise=settings.additive_noise if additive_noise is None else additive_noise,
        n_steps=settings.n_opt_steps if n_steps is None else n_steps,
        curb=HyperCurb() if curb else None,
    )
    gp = (
        ExactGP(**kw)
        if kind == "standard"
        else FITC(n_inducing=n_inducing or max(1, n_data // 4), **kw)
    )
    return ForwardModel(gp, target=target)


# ---------------------------------------------------------------------------- fig4.3
CLAIM_4_3 = (
    "Not more than 20 sampled trajectories match the accuracy of moment matching in 75% of "
    "the start states and approximately 50 in 95% (Sec. 4.2.2, Fig. 4.3)."
)
THESIS_4_3 = {"samples_to_match_mm_75pct": 20, "samples_to_match_mm_95pct": 50}

APPROXIMATE = 2.0
"""The factor within which a thesis count given as "approximately" / "about" is accepted
(``fig4.3``'s "approximately 50", ``fig4.4``'s "approximately 1000")."""


@dataclass(frozen=True)
class SamplingAccuracySettings(Settings):
    """Settings of ``fig4.3`` (Sec. 4.2.2, Fig. 4.3; the planar 4-link robot of Fig. 3.1)."""

    n_data: int = setting(
        1800,
        "Training transitions of the FITC model (thesis: 12000), whole trajectories.",
        minimum=1,
    )
    n_pseudo: int = setting(150, "Pseudo-inputs M of the FITC model (thesis: 700).", minimum=1)
    horizon: int = setting(
        60,
        "Steps T of the training trajectories and of the predictions (20 Hz; thesis: 300).",
        minimum=1,
    )
    n_start: int = setting(
        20,
        "Start distributions N(m_0, σ_0² I) (thesis: 100 'with varying initial variance').",
        minimum=1,
    )
    n_ground_truth: int = setting(
        300,
        "Sampled trajectories whose Gaussian fit is the ground truth p(x_t) (thesis: 1000).",
        minimum=10,
    )
    sample_sizes: tuple[int, ...] = setting(
        (10, 20, 50, 100),
        "Numbers of sampled trajectories compared with moment matching (≥ 10).",
        minimum=10,
    )
    amplitude: float = setting(
        0.6, "Amplitude (rad) of the swinging reference on every joint (Balancing.swing_reference)."
    )
    period: float = setting(4.0, "Period (s) of the swinging reference.", above=0)
    initial_std: float = setting(
        0.05,
        "Std (rad, rad/s) of the training starts and of the test means m_0 around r_0.",
        minimum=0,
    )
    torque_noise_std: float = setting(0.5, "Std of the torque noise of the robot (N m).", minimum=0)
    initial_std_range: tuple[float, float] = setting(
        (0.01, 0.1), "Interval of σ_0 (rad, rad/s), drawn log-uniformly per start.", above=0
    )
    n_opt_steps: int = setting(50, "Hyper-parameter optimisation steps of the model.", minimum=0)
    additive_noise: float = setting(
        1.0, "Additive-noise factor α of the model: σ_add = α 10⁻² std(y) (Sec. 4.2.3).", minimum=0
    )
    curb: bool = setting(True, "Train with PILCO's hyper-parameter curb (HyperCurb).")
    gp_target: str = setting("next", "What the GP learns: 'next' (x′, the thesis) or 'delta'.")

    def check(self) -> None:
        """At least one sample size (each ≥ 10 by its bound: a Gaussian fit in 8-D)."""
        if not self.sample_sizes:
            raise ValueError("sample_sizes: expected at least one number of trajectories")
        if self.gp_target not in ("next", "delta"):
            raise ValueError(f"gp_target: expected 'next' or 'delta', got {self.gp_target!r}")


QUICK_4_3 = SamplingAccuracySettings()
SCALES_4_3 = {
    "smoke": replace(
        QUICK_4_3,
        n_data=120,
        n_pseudo=20,
        horizon=6,
        n_start=3,
        n_ground_truth=150,
        sample_sizes=(10, 40),
        n_opt_steps=5,
    ),
    # quick scales down: training transitions 12000→1800, pseudo-inputs 700→150, horizon
    # 300→60, start distributions 100→20, ground-truth samples 1000→300, sample sizes 8→4
    # (10…100), hyper-parameter steps 150→50
    "quick": QUICK_4_3,
    "paper": replace(
        QUICK_4_3,
        n_data=12000,
        n_pseudo=700,
        horizon=300,
        n_start=100,
        n_ground_truth=1000,
        sample_sizes=(10, 15, 20, 30, 50, 75, 100, 200),
        n_opt_steps=150,
    ),
}


def _train_balancing_model(
    settings: ComputeTimeSettings, rng: np.random.Generator
) -> tuple[Balancing, ForwardModel, dict]:
    """fig4.4's model: feedback around upright, Δx targets, no curb (as its stored result)."""
    T = settings.horizon
    task = make("balancing", n_steps=T, torque_noise_std=settings.torque_noise_std)
    data = collect_balancing(
        task, max(1, int(np.ceil(settings.n_data / T))), rng, policy=_data_policy(task)
    )
    model = _model(
        "sparse", len(data["x"]), settings, n_inducing=settings.n_pseudo, curb=False,
        target="delta",
    )  # fmt: skip
    model.fit(data["x"], data["u"], data["x_next"], rng=rng)
    return task, model, data


def _tracking_data(task: Balancing, G, reference, feedforward, n: int, rng) -> dict:
    """``n`` rollouts of the tracking PD from x_0 ~ N(r_0, σ² I), σ = ``task.initial_std``;
    failed rollouts are replaced and counted."""
    parts, n_failed, errors = [], 0, []
    while len(parts) < n:
        x0 = reference[0] + task.initial_std * rng.standard_normal(8)
        traj = task.rollout_from(
            G.ravel(), x0, rng=rng, reference=reference, feedforward=feedforward
        )
        if traj.failed:
            n_failed += 1
            if n_failed > 10 * n:
                raise RuntimeError(f"fig4.3: {n_failed} tracking rollouts failed")
            continue
        parts.append(task.transitions(traj))
        errors.append(np.abs(traj.states[:, :4] - reference[:, :4]).max())
    x, u, xn = (np.vstack([p[i] for p in parts]) for i in range(3))
    return {"x": x, "u": u, "x_next": xn, "n_failed": n_failed, "tracking_error": errors}


def _run_4_3(
    settings: SamplingAccuracySettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    sizes = list(settings.sample_sizes)
    B, T, n_gt = settings.n_start, settings.horizon, settings.n_ground_truth
    L = n_gt + sum(sizes)
    task = make(
        "balancing",
        n_steps=T,
        torque_noise_std=settings.torque_noise_std,
        initial_std=settings.initial_std,
    )
    G = task.pd_gain()
    ref, ff = task.swing_reference(settings.amplitude, settings.period)
    offsets = ff[:T] - ref[:T] @ G.T  # u_t = G x_t + (u_ff,t − G r_t): linear in x_t
    trial.reset(total=1 + B)
    # Resumable after every start state: the trained model, the start states and the KLs so far.
    st = trial.resume("fig4.3", rng)
    if st is None:
        data = _tracking_data(task, G, ref, ff, max(1, int(np.ceil(settings.n_data / T))), rng)
        model = _model(
            "sparse",
            len(data["x"]),
            settings,
            n_inducing=settings.n_pseudo,
            curb=settings.curb,
            target=settings.gp_target,
        )
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
    out = {
        k: st[k]
        for k in (
            "kl_mm", "kl_samples", "sigma0", "n_data", "n_failed_rollouts", "tracking_error",
            "train_time_s",
        )
    }  # fmt: skip
    out["n_variance_clamped"] = st["n_variance_clamped"]
    out["model_jitter"] = model.gp.diagnostics["jitter"]
    out["max_signal_to_noise"] = model.gp.diagnostics["max_signal_to_noise"]
    out["max_lengthscale_ratio"] = model.gp.diagnostics["max_lengthscale_ratio"]
    return out


def _first_reaching(sizes, values, level=100.0):
    hit = [n for n, v in zip(sizes, values, strict=True) if v <= level]
    return hit[0] if hit else None


def _summarize_4_3(
    settings: SamplingAccuracySettings, trials: list[dict]
) -> tuple[list[Series], dict]:
    sizes = list(settings.sample_sizes)
    scores = np.concatenate(
        [100.0 * t["kl_samples"].sum(-1) / t["kl_mm"].sum(-1)[:, None] for t in trials]
    )
    pct = {q: np.percentile(scores, q, axis=0) for q in (50, 75, 95)}
    kw = dict(
        panel="sampling accuracy",
        xlabel="number of sampled trajectories",
        ylabel="normalised KL (moment matching = 100)",
        log_x=True,
        log_y=True,
    )
    series = [
        Series(
            f"sampling, {q}th percentile over start states",
            sizes,
            pct[q].tolist(),
            kind="lines+markers",
            **kw,
        )
        for q in (50, 75, 95)
    ]
    series.append(Series("moment matching", sizes, [100.0] * len(sizes), **kw))
    n75, n95 = _first_reaching(sizes, pct[75]), _first_reaching(sizes, pct[95])
    summary = {
        "percentiles": {
            str(q): dict(zip(map(str, sizes), pct[q].tolist(), strict=True)) for q in pct
        },
        "samples_to_match_mm_75pct": n75,
        "samples_to_match_mm_95pct": n95,
        "thesis_numbers": dict(THESIS_4_3),
        "mean_kl_per_step_mm": float(np.mean([t["kl_mm"].mean() for t in trials])),
        "n_start_states": int(scores.shape[0]),
        "n_variance_clamped": int(sum(t["n_variance_clamped"] for t in trials)),
        "claim_tolerance": "75%: not more than 20 trajectories, the thesis's bound; 95%: "
        "approximately 50, accepted up to a factor 2 (100)",
        "model": {
            "n_data": int(trials[0]["n_data"]),
            "n_pseudo_inputs": settings.n_pseudo,
            "horizon": settings.horizon,
            "train_time_s": float(np.mean([t.get("train_time_s", np.nan) for t in trials])),
            "max_signal_to_noise": float(max(t.get("max_signal_to_noise", np.nan) for t in trials)),
            "max_lengthscale_ratio": float(
                max(t.get("max_lengthscale_ratio", np.nan) for t in trials)
            ),
            "data_tracking_error_rad": float(
                np.mean([t.get("tracking_error", np.nan) for t in trials])
            ),
        },
        "setup": _setup_4_3(settings),
    }
    return series, with_verdict(summary, verdict_4_3(settings, summary))


def _setup_4_3(st: SamplingAccuracySettings) -> list[dict]:
    return [
        {
            "item": "controller",
            "thesis": "a linear trajectory-tracking PD controller",
            "ours": f"u = G (x − r_t) + u_ff,t: the PD of Balancing.pd_gain around a reference "
            f"swinging every joint by {st.amplitude:g} rad (period {st.period:g} s), u_ff its "
            "inverse dynamics",
            "why": "reference not given; large amplitude so that the dynamics along it are "
            "nonlinear (near upright moment matching is nearly exact, issue #16)",
        },
        {
            "item": "model",
            "thesis": "sparse GP, 12000 points, 700 pseudo-inputs",
            "ours": f"FITC, {st.n_data} points, {st.n_pseudo} pseudo-inputs, x′ targets"
            + (", PILCO's curb" if st.curb else ""),
            "why": "as the thesis" if st.n_data >= 12000 else "smaller scale than the thesis",
        },
        {
            "item": "horizon",
            "thesis": "300 steps (the normalisation sums t = 1..100)",
            "ours": f"{st.horizon} steps, KL summed over all of them",
            "why": "the thesis's two numbers disagree; we sum over the whole prediction",
        },
        {
            "item": "start states",
            "thesis": "100 independently chosen, varying initial variance",
            "ours": f"{st.n_start}: m₀ ~ N(r₀, {st.initial_std:g}² I), σ₀ log-uniform in "
            f"[{st.initial_std_range[0]:g}, {st.initial_std_range[1]:g}]",
            "why": "variances not given",
        },
        {
            "item": "ground truth",
            "thesis": "Gaussian fit to 1000 sampled trajectories",
            "ours": f"Gaussian fit to {st.n_ground_truth} sampled trajectories of the same model",
            "why": "",
        },
    ]


def verdict_4_3(settings: SamplingAccuracySettings, summary: dict) -> Verdict:
    """Judges the thesis's sentences (criterion changed after the stored paper run, issue
    #32; before, both counts were accepted within a factor 2, i.e. up to 40 and 100): holds if
    in 75% of the start states "not more than 20" trajectories match moment matching (at most
    20) and in 95% "approximately 50" do (at most 100: "approximately" read as within a factor
    2, :data:`APPROXIMATE`, and fewer as better, since the claim is that few samples
    suffice)."""
    n75, n95 = summary["samples_to_match_mm_75pct"], summary["samples_to_match_mm_95pct"]
    largest = str(max(settings.sample_sizes))
    median = summary["percentiles"]["50"].get(largest)

    def count(n):
        return str(n) if n is not None else f"more than {largest}"

    return Verdict(
        CLAIM_4_3,
        bool(n75 is not None and n95 is not None and n75 <= 20 and n95 <= 50 * APPROXIMATE),
        f"Sampling matches moment matching's accuracy in 75% / 95% of the "
        f"{summary['n_start_states']} start states with {count(n75)} / {count(n95)} "
        "trajectories (thesis: 'not more than 20' / 'approximately 50', read as: at most 20 / "
        f"at most 100, a factor 2 on the approximate count); with {largest} the median "
        f"normalised KL is {fmt(median)} (moment matching = 100).",
    )


register(
    Experiment(
        id="fig4.3",
        title="Sampling accuracy vs number of sampled trajectories (moment matching = 100)",
        settings_class=SamplingAccuracySettings,
        settings=SCALES_4_3,
        run_trial=_run_4_3,
        summarize=_summarize_4_3,
        verdict=verdict_4_3,
        trials={"smoke": 1, "quick": 1, "paper": 1},
        claim=CLAIM_4_3,
    )
)


# ---------------------------------------------------------------------------- fig4.4
CLAIM_4_4 = (
    "Sampling produces about 1000 trajectories in the computation time of one "
    "moment-matching prediction on a single CPU core (Fig. 4.4)."
)


@dataclass(frozen=True)
class ComputeTimeSettings(Settings):
    """Settings of ``fig4.4`` (Sec. 4.2.2, Fig. 4.4): timings, so numbers vary between runs."""

    n_data: int = setting(600, "Training transitions of the FITC model (thesis: 1500).", minimum=1)
    n_pseudo: int = setting(100, "Pseudo-inputs M of the FITC model (thesis: 300).", minimum=1)
    horizon: int = setting(30, "Steps T of every prediction (20 Hz; thesis: 100).", minimum=1)
    n_trajectories: tuple[int, ...] = setting(
        (10, 100, 1000, 3000), "Numbers N of sampled trajectories timed, increasing.", minimum=1
    )
    threads: tuple[int, ...] = setting(
        (1, 2), "Torch thread counts timed (the claim is about one core).", minimum=1
    )
    repeats: int = setting(3, "Timings repeated (minimum kept; one run above N = 1000).", minimum=1)
    torque_noise_std: float = setting(0.5, "Std of the torque noise of the robot (N m).", minimum=0)
    n_opt_steps: int = setting(30, "Hyper-parameter optimisation steps of the model.", minimum=0)
    additive_noise: float = setting(
        1.0, "Additive-noise factor α of the model: σ_add = α 10⁻² std(y) (Sec. 4.2.3).", minimum=0
    )


QUICK_4_4 = ComputeTimeSettings()
SCALES_4_4 = {
    "smoke": replace(
        QUICK_4_4,
        n_data=100,
        n_pseudo=20,
        horizon=5,
        n_trajectories=(10, 100),
        threads=(1,),
        repeats=1,
        n_opt_steps=5,
    ),
    # quick scales down: training transitions 1500→600, pseudo-inputs 300→100, horizon
    # 100→30, trajectory counts up to 3000 (not 10000), hyper-parameter steps 150→30
    "quick": QUICK_4_4,
    "paper": replace(
        QUICK_4_4,
        n_data=1500,
        n_pseudo=300,
        horizon=100,
        n_trajectories=(10, 100, 1000, 3000, 10000),
        n_opt_steps=150,
    ),
}


def time_predictions(
    model: ForwardModel,
    m0: np.ndarray,
    S0: np.ndarray,
    G: np.ndarray,
    horizon: int,
    n_trajectories: list[int],
    threads: list[int],
    repeats: int,
    rng: np.random.Generator,
) -> dict:
    """Wall time of one moment-matching prediction and of sampling N trajectories.

    Same model, controller and horizon for both.

    For each torch thread count: the minimum over ``repeats`` of the time of
    :func:`~skillkit.models.moment_matching.propagate` over ``horizon`` steps, and of
    :func:`~skillkit.models.sampling.sample_trajectories` of N trajectories from N(m0, S0)
    with u = G x̃ (minimum over ``repeats`` for N ≤ 1000, one run above). The thread count is
    restored afterwards.

    Returns
    -------
    dict
        ``mm_time`` {threads: s}, ``sampling_time`` {threads: [s per N]},
        ``trajectories_in_mm_time`` {threads: N·t_MM / t_sampling(N) at the largest N}.
    """
    policy = feedback_policy(torch.as_tensor(G[None]))
    k = -G @ X_UP
    chol = np.linalg.cholesky(S0)
    before = torch.get_num_threads()
    out = {"mm_time": {}, "sampling_time": {}, "trajectories_in_mm_time": {}}
    try:
        for th in threads:
            torch.set_num_threads(int(th))
            propagate(model, m0, S0, 2, G, k)  # warm-up
            mm = min(
                _timed(lambda: propagate(model, m0, S0, horizon, G, k)) for _ in range(repeats)
            )
            times = []
            for n in n_trajectories:
                x0 = m0 + rng.standard_normal((1, n, len(m0))) @ chol.T
                reps = repeats if n <= 1000 else 1
                times.append(
                    min(
                        _timed(
                            lambda x0=x0, n=n: sample_trajectories(
                                model, x0, policy, horizon, n, rng
                            )
                        )
                        for _ in range(reps)
                    )
                )
            out["mm_time"][str(th)] = mm
            out["sampling_time"][str(th)] = times
            out["trajectories_in_mm_time"][str(th)] = mm * n_trajectories[-1] / times[-1]
    finally:
        torch.set_num_threads(before)
    return out


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _run_4_4(settings: ComputeTimeSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    trial.reset(total=2)
    task, model, data = _train_balancing_model(settings, rng)
    trial.update()
    m0 = X_UP + task.initial_std * rng.standard_normal(8)
    G = stable_gains(task, 1, rng, policy=_data_policy(task))[0].reshape(4, 8)
    out = time_predictions(
        model,
        m0,
        0.05**2 * np.eye(8),
        G,
        settings.horizon,
        list(settings.n_trajectories),
        list(settings.threads),
        settings.repeats,
        rng,
    )
    trial.update()
    return {**out, "n_data": len(data["x"]), "n_pseudo": model.predictor.n_support}


def _summarize_4_4(settings: ComputeTimeSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    ns = list(settings.n_trajectories)
    kw = dict(
        panel="compute time of one long-term prediction",
        xlabel="number of sampled trajectories",
        ylabel="wall time (s)",
        log_x=True,
        log_y=True,
    )
    series = []
    summary: dict = {
        "mm_time_s": {},
        "sampling_time_s": {},
        "trajectories_in_mm_time": {},
        "mm_gflops": {},
        "sampling_gflops": {},
    }
    # Counted flops (exp as one flop in both) of one step of the balancing model: E = n_x
    # outputs, D = n_x + n_u inputs, x = [q, q̇] of the robot's joints and one torque per joint.
    T, M = settings.horizon, trials[0]["n_pseudo"]
    n_x = X_UP.size
    n_u = n_x // 2
    mm_flops = moment_matching_flops_per_step(n_x, M, n_x + n_u) * T
    sample_flops = sampler_flops_per_step(n_x, M, n_x + n_u) * T
    for th in map(str, settings.threads):
        st = np.median([t["sampling_time"][th] for t in trials], axis=0)
        mm = float(np.median([t["mm_time"][th] for t in trials]))
        series.append(
            Series(f"sampling, {th} thread(s)", ns, st.tolist(), kind="lines+markers", **kw)
        )
        series.append(Series(f"moment matching, {th} thread(s)", ns, [mm] * len(ns), **kw))
        summary["mm_time_s"][th] = mm
        summary["sampling_time_s"][th] = dict(zip(map(str, ns), st.tolist(), strict=True))
        summary["trajectories_in_mm_time"][th] = float(
            np.median([t["trajectories_in_mm_time"][th] for t in trials])
        )
        summary["mm_gflops"][th] = mm_flops / mm / 1e9
        summary["sampling_gflops"][th] = {
            str(n): sample_flops * n / t / 1e9 for n, t in zip(ns, st.tolist(), strict=True)
        }
    summary.update(
        {
            "model": {
                "n_data": trials[0]["n_data"],
                "n_pseudo_inputs": trials[0]["n_pseudo"],
                "horizon": settings.horizon,
                "state_dim": n_x,
                "control_dim": n_u,
            },
            "flops_per_prediction": {
                "moment_matching": mm_flops,
                "sampling_per_trajectory": sample_flops,
                "counted": "moment_matching_flops_per_step and sampler_flops_per_step "
                "(exp counted as one flop in both)",
            },
            "thesis_numbers": "about 1000 trajectories in the time of one moment-matching "
            "prediction on one CPU core",
            "goal": "at least 10,000 trajectories on these 2 cores",
        }
    )
    summary["own_checks"] = own_checks_4_4(settings, summary)
    return series, with_verdict(summary, verdict_4_4(settings, summary))


def verdict_4_4(settings: ComputeTimeSettings, summary: dict) -> Verdict:
    """Judges the thesis's sentence (criterion changed after the stored paper run, issue #32;
    before, at least 1000 were required, now an own check): holds if on one thread sampling
    produces "approximately 1000" trajectories in the time of one moment-matching prediction,
    read as at least 1000 / :data:`APPROXIMATE` = 500 (more is better; it also "outperforms
    moment matching", which needs about 50 trajectories for the same accuracy, Fig. 4.4
    caption). False if one thread was not timed."""
    per = summary["trajectories_in_mm_time"]
    one = per.get("1")
    others = "; ".join(
        f"{fmt(v, '.0f')} on {th} threads" for th, v in per.items() if th != "1" and v
    )
    rates = ""
    if "1" in summary.get("mm_gflops", {}):
        n_max = str(settings.n_trajectories[-1])
        rates = (
            f"; on one thread moment matching ran at {fmt(summary['mm_gflops']['1'], '.1f')} "
            f"GFLOP/s and sampling {n_max} trajectories at "
            f"{fmt(summary['sampling_gflops']['1'][n_max], '.1f')} GFLOP/s"
        )
    return Verdict(
        CLAIM_4_4,
        bool((one or 0.0) >= 1000 / APPROXIMATE),
        f"In the time of one moment-matching prediction over {summary['model']['horizon']} "
        f"steps sampling produces {fmt(one, '.0f')} trajectories on one thread"
        + (f" ({others})" if others else "")
        + rates
        + " (thesis: 'approximately 1000' on one core, read as: at least 500, a factor 2).",
    )


def own_checks_4_4(settings: ComputeTimeSettings, summary: dict) -> dict:
    """Our condition beyond the thesis's sentence on ``fig4.4``: the full 1000 on one thread."""
    one = summary["trajectories_in_mm_time"].get("1")
    return {
        "at_least_1000_on_one_thread": own_check(
            bool((one or 0.0) >= 1000),
            "at least 1000 trajectories in one moment-matching prediction's time on one thread "
            "(the criterion before issue #32; stricter than 'approximately 1000')",
        )
    }


register(
    Experiment(
        id="fig4.4",
        title="Compute time: moment matching vs sampling",
        settings_class=ComputeTimeSettings,
        settings=SCALES_4_4,
        run_trial=_run_4_4,
        summarize=_summarize_4_4,
        verdict=verdict_4_4,
        own_checks=own_checks_4_4,
        trials={"smoke": 1, "quick": 1, "paper": 1},
        claim=CLAIM_4_4,
    )
)


# ---------------------------------------------------------------------------- fig4.5
CLAIM_4_5 = (
    "More additive noise lowers the reward-prediction accuracy slightly, while FITC "
    "(M = N/4) overfits: it predicts worse than the standard GP at higher additive noise and "
    "with control noise, and its error grows as its optimisation continues; more training "
    "trajectories improve the accuracy (Sec. 4.2.3, Fig. 4.5)."
)


_PANELS_4_5 = (
    ("additive_noise", "additive noise factor alpha"),
    ("n_opt_steps", "optimisation steps"),
    ("torque_noise_std", "control noise std (N m)"),
    ("n_train", "number of training trajectories"),
)


@dataclass(frozen=True)
class TrainingSetting(Settings):
    """One training setting of ``fig4.5``: the default every panel varies one field of.

    The field order is part of the experiment's seeds (``_seed(root, 3, *cfg.values())``).
    """

    additive_noise: float = setting(
        1.0, "Additive-noise factor α: σ_add = α 10⁻² std(y) (Sec. 4.2.3).", minimum=0
    )
    n_opt_steps: int = setting(50, "Hyper-parameter optimisation steps (thesis: 150).", minimum=0)
    torque_noise_std: float = setting(0.5, "Std of the torque noise of the robot (N m).", minimum=0)
    n_train: int = setting(15, "Training trajectories (T steps each; thesis: 50).", minimum=1)


@dataclass(frozen=True)
class RewardErrorSettings(Settings):
    """Settings of ``fig4.5`` (Sec. 4.2.3, Fig. 4.5): one panel per ``*_values`` field."""

    defaults: TrainingSetting = setting(
        TrainingSetting(),
        "The default training setting; ``--set`` takes a mapping of some of its fields.",
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
    n_pairs: int = setting(
        15, "Test start states x_0 whose rewards are predicted (thesis: 50).", minimum=1
    )
    initial_std: float = setting(
        0.1, "Std of the initial state around upright (rad, rad/s; Sec. 4.2.3).", minimum=0
    )
    horizon: int = setting(20, "Steps T of training and test trajectories (thesis: 20).", minimum=1)
    n_predicted: int = setting(
        10, "Trajectories sampled from a model per test pair (thesis: 20).", minimum=1
    )
    pseudo_fraction: float = setting(
        0.25, "Pseudo-inputs of FITC as a fraction of N (M = N/4).", above=0, maximum=1
    )
    natural_frequency: float = setting(
        3.0, "ω (rad/s) of the PD controller (:meth:`Balancing.pd_gain`) used throughout.", above=0
    )
    damping: float = setting(1.5, "ζ of the PD controller.", above=0)
    gp_target: str = setting("next", "What the GPs learn: 'next' (x′, the thesis) or 'delta'.")
    uncurbed_panels: tuple[str, ...] = setting(
        ("n_opt_steps",),
        "Panels whose settings are also trained without the hyper-parameter curb (its effect).",
    )
    n_truth: int = setting(
        5,
        "Real rollouts per test start state; their variance gives the noise floor (≥ 2).",
        minimum=2,
    )

    def check(self) -> None:
        """Panels named in ``uncurbed_panels`` exist; ``gp_target`` is known."""
        names = [k for k, _ in _PANELS_4_5]
        bad = [p for p in self.uncurbed_panels if p not in names]
        if bad:
            raise ValueError(f"uncurbed_panels: expected names from {names}, got {bad}")
        if self.gp_target not in ("next", "delta"):
            raise ValueError(f"gp_target: expected 'next' or 'delta', got {self.gp_target!r}")


QUICK_4_5 = RewardErrorSettings()
SCALES_4_5 = {
    "smoke": replace(
        QUICK_4_5,
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
    # quick scales down: default training trajectories 50→15 and steps 150→50, panel values
    # 6→3 noise factors, 6→2 step counts, 5→2 control noises, 4→2 data sizes, test pairs
    # 50→15, sampled trajectories 20→10, real rollouts per pair 10→5
    "quick": QUICK_4_5,
    "paper": replace(
        QUICK_4_5,
        defaults=TrainingSetting(1.0, 150, 0.5, 50),
        additive_noise_values=(0.1, 0.3, 1.0, 3.0, 10.0, 30.0),
        n_opt_steps_values=(10, 25, 50, 100, 150, 250),
        torque_noise_std_values=(0.0, 0.25, 0.5, 1.0, 2.0),
        n_train_values=(10, 20, 50, 100),
        n_pairs=50,
        n_predicted=20,
        n_truth=10,
    ),
}
REWARD_ERROR_LABEL = "mean squared reward error [reward²]"
"""Y label of ``fig4.5``: (predicted − real trajectory reward)², averaged over the test pairs
(the balancing reward −(x̃ᵀQx̃ + r_u uᵀu) is unitless)."""


def _seed(root: int, *keys) -> np.random.Generator:
    return np.random.default_rng(
        np.random.SeedSequence([root, *[int(round(k * 1000)) for k in keys]])
    )


def _evaluate_4_5(cfg: dict, settings: RewardErrorSettings, root: int, curbs=(True,)) -> dict:
    """Train both models for one training setting and measure their reward-prediction errors.

    One PD controller G throughout (Sec. 4.2.3: "set such that the pendulum is robustly
    balanced ... from a random set of initial positions"). A test pair is a start state x_0:
    its real reward R is that of one real rollout from x_0 (the thesis's R(s, ω)), and
    ``n_truth`` rollouts from the same x_0 give Var(R | x_0), the error even a perfect model
    makes (the *noise floor*). The *constant predictor* predicts the mean reward of the
    training rollouts for every x_0. ``curbs`` lists the hyper-parameter treatments trained
    (True: :class:`~skillkit.models.gp.HyperCurb`; False: plain ML-II, reported under
    ``"<kind>_uncurbed"``); both see the same data and draws.
    """
    T = settings.horizon
    task = make(
        "balancing",
        n_steps=T,
        torque_noise_std=cfg["torque_noise_std"],
        initial_std=settings.initial_std,
    )
    G = task.pd_gain(settings.natural_frequency, settings.damping)
    train = collect_balancing(
        task, cfg["n_train"], _seed(root, 1, cfg["torque_noise_std"], cfg["n_train"]), gain=G
    )
    test_rng = _seed(root, 2, cfg["torque_noise_std"])
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
    for curb in curbs:
        for kind in ("standard", "sparse"):
            model = _model(
                kind,
                N,
                settings,
                additive_noise=cfg["additive_noise"],
                n_steps=cfg["n_opt_steps"],
                n_inducing=max(1, int(settings.pseudo_fraction * N)),
                curb=curb,
                target=settings.gp_target,
            )
            t0 = time.perf_counter()
            model.fit(train["x"], train["u"], train["x_next"], rng=_seed(root, 3, *cfg.values()))
            train_time = time.perf_counter() - t0
            res = sample_trajectories(
                model,
                x0,
                feedback_policy(torch.as_tensor(gains)),
                T,
                settings.n_predicted,
                _seed(root, 4, *cfg.values()),
            )
            predicted = sampled_rewards(task, res.states.numpy(), gains).mean(1)
            d = model.gp.diagnostics
            out[kind if curb else f"{kind}_uncurbed"] = {
                "squared_error": float(np.mean((predicted - real) ** 2)),
                "train_time_s": train_time,
                "n_data": N,
                "jitter": d["jitter"],
                "noise_at_floor": len(d["noise_at_floor"]),
                "stopped_early": d["stopped_early"] is not None,
                "max_signal_to_noise": d["max_signal_to_noise"],
                "max_lengthscale_ratio": d["max_lengthscale_ratio"],
            }
    return out


def _configs_4_5(settings: RewardErrorSettings) -> list[tuple[dict, bool]]:
    """The distinct training settings of the four panels, each with whether it is also
    trained without the curb (it belongs to a panel of ``uncurbed_panels``)."""
    defaults = settings.defaults.to_dict()
    configs: list[dict] = []
    uncurbed: list[bool] = []
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


_KINDS_4_5 = (
    ("standard", "standard GP"),
    ("sparse", "sparse GP (FITC, M = N/4)"),
    ("standard_uncurbed", "standard GP, no curb"),
    ("sparse_uncurbed", "sparse GP (FITC), no curb"),
    ("noise_floor", "noise floor: Var(R | x₀)"),
    ("constant_predictor", "constant predictor (training mean reward)"),
)


def _summarize_4_5(settings: RewardErrorSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    series: list[Series] = []
    summary: dict = {"panels": {}}
    defaults = settings.defaults.to_dict()

    def value(r: dict, kind: str):
        v = r.get(kind)
        return None if v is None else v if isinstance(v, float) else v["squared_error"]

    for key, label in _PANELS_4_5:
        values = list(getattr(settings, f"{key}_values"))
        panel = {}
        for kind, name in _KINDS_4_5:
            if kind.endswith("_uncurbed") and key not in settings.uncurbed_panels:
                continue
            errs = []
            for v in values:
                cfg = dict(defaults, **{key: v})
                vals = [value(r, kind) for t in trials for r in t["results"] if r["config"] == cfg]
                errs.append(float(np.mean(vals)))
            floor = kind in ("noise_floor", "constant_predictor")
            series.append(
                Series(
                    name,
                    values,
                    errs,
                    panel=label,
                    kind="line" if floor else "lines+markers",
                    xlabel=label,
                    ylabel=REWARD_ERROR_LABEL,
                    log_x=key == "additive_noise",
                    log_y=True,
                )
            )
            panel[kind] = dict(zip(map(str, values), errs, strict=True))
        summary["panels"][key] = panel
    default = [r for t in trials for r in t["results"] if r["config"] == defaults]
    by_steps = {
        str(v): [
            r for t in trials for r in t["results"] if r["config"] == dict(defaults, n_opt_steps=v)
        ]
        for v in settings.n_opt_steps_values
    }
    summary.update(
        {
            "default_setting": defaults,
            "default_squared_error": {
                k: float(np.mean([value(r, k) for r in default]))
                for k in ("standard", "sparse", "noise_floor", "constant_predictor")
            },
            "mean_real_reward": float(np.mean([r["real_reward_mean"] for r in default])),
            "train_time_s_default": {
                k: float(np.mean([r[k]["train_time_s"] for r in default]))
                for k in ("standard", "sparse")
            },
            "hyperparameters_by_steps": {
                kind: {
                    v: {
                        "max_signal_to_noise": float(
                            np.max([r[kind]["max_signal_to_noise"] for r in rs])
                        ),
                        "max_lengthscale_ratio": float(
                            np.max([r[kind]["max_lengthscale_ratio"] for r in rs])
                        ),
                    }
                    for v, rs in by_steps.items()
                    if all(kind in r for r in rs)
                }
                for kind in ("standard", "sparse", "standard_uncurbed", "sparse_uncurbed")
            },
            "numerical_events": {
                k: {
                    "jitter": max(r[k]["jitter"] for t in trials for r in t["results"] if k in r),
                    "noise_at_floor": sum(
                        r[k]["noise_at_floor"] for t in trials for r in t["results"] if k in r
                    ),
                    "stopped_early": sum(
                        r[k]["stopped_early"] for t in trials for r in t["results"] if k in r
                    ),
                }
                for k in ("standard", "sparse")
            },
            "n_failed_truth_rollouts": sum(
                r["n_failed_truth"] for t in trials for r in t["results"]
            ),
            "setup": SETUP_4_5,
        }
    )
    summary["own_checks"] = own_checks_4_5(settings, summary)
    return series, with_verdict(summary, verdict_4_5(settings, summary))


SETUP_4_5 = [
    {
        "item": "controller",
        "thesis": "a PD controller that robustly balances from random initial positions",
        "ours": "one PD u = K_p q̃ + K_d q̇ with gravity-stiffness compensation (Balancing.pd_gain, "
        "ω = 3 rad/s, ζ = 1.5) for all training and test rollouts",
        "why": "gains not given; the lowest-stiffness robust PD at 20 Hz (spectral radius 0.94); "
        "its gains reach 1.9e3 N m/rad: no lower-gain PD balances robustly at this rate",
    },
    {
        "item": "test pairs",
        "thesis": "50 context-parameter pairs, 20 model trajectories each, T = 20",
        "ours": "50 start states x₀ ~ N(x_up, 0.1² I) with the PD, 20 sampled trajectories, T = 20",
        "why": "balancing has no context and one controller: a pair is a start state",
    },
    {
        "item": "real reward R",
        "thesis": "the real reward of the pair",
        "ours": "one real rollout from x₀; 10 rollouts from x₀ give the noise floor Var(R | x₀)",
        "why": "a perfect model still errs by Var(R | x₀): the floor shows how close models are",
    },
    {
        "item": "model target",
        "thesis": "x′ = f(x, u) (Secs 4.2.4, 5.1.1)",
        "ours": "x′ (ForwardModel target 'next')",
        "why": "as the thesis; the stored result before issue #16 learned Δx",
    },
    {
        "item": "hyper-parameters",
        "thesis": "ML-II (Eq. 2.28); no bounds stated",
        "ours": "ML-II + PILCO's curb (length-scales ≲ 100 std(x), σ_f/σ_ε ≲ 500); the "
        "optimisation-steps panel is also trained without it",
        "why": "without it ML-II drives the SE kernel to its linear limit on this near-linear, "
        "thin-slab data and the latent variance off the data explodes (issue #16)",
    },
    {
        "item": "data",
        "thesis": "50 trajectories (1000 points), 150 optimisation steps, α = 1, 0.5 N m noise",
        "ours": "the same",
        "why": "",
    },
]


def _parts_4_5(settings: RewardErrorSettings, summary: dict) -> dict[str, dict]:
    """The five parts of ``fig4.5``'s verdict, one per judged sentence of the thesis, each
    ``{"holds": bool | None, "text": str}`` (our numbers and the reading)."""
    panels = summary["panels"]

    def curve(panel: str, kind: str, values) -> list[float | None]:
        got = panels[panel].get(kind, {})
        return [got.get(str(v)) for v in values]

    out = {}
    # (1) "With increasing additive noise factor ... the accuracy ... decreases slightly."
    alphas = sorted(settings.additive_noise_values)
    std_a = curve("additive_noise", "standard", alphas)
    out["additive_noise_lowers_accuracy"] = {
        "holds": is_less(std_a[0], std_a[-1]) if len(alphas) > 1 else None,
        "text": f"(1) the standard GP's error {fmt(std_a[0])} at α = {alphas[0]:g}, "
        f"{fmt(std_a[-1])} at α = {alphas[-1]:g} (thesis: accuracy 'decreases slightly' with "
        "α, read as: a higher error at the largest α; 'slightly' is not judged)",
    }
    # (2) "... the sparse method often overfits ... the worse performance with higher α."
    alpha0 = settings.defaults.additive_noise
    high = [a for a in alphas if a > alpha0]
    std_h, fitc_h = (
        curve("additive_noise", "standard", high),
        curve("additive_noise", "sparse", high),
    )
    worse = [is_less(a, b) for a, b in zip(std_h, fitc_h, strict=True)]
    fitc_0, fitc_top = curve("additive_noise", "sparse", [alpha0, alphas[-1]])
    out["fitc_worse_at_higher_additive_noise"] = {
        "holds": conjunction(worse) if high else None,
        "text": f"(2) FITC's error above the standard GP's at {sum(w is True for w in worse)} "
        f"of the {len(high)} α above the default {alpha0:g} ("
        + ", ".join(
            f"α = {a:g}: FITC {fmt(f)} vs {fmt(g)}"
            for a, f, g in zip(high, fitc_h, std_h, strict=True)
        )
        + f"), and FITC's own error {fmt(fitc_0)} at α = {alpha0:g}, {fmt(fitc_top)} at α = "
        f"{alphas[-1]:g} (thesis: FITC 'often overfits the data, which results in the worse "
        "performance with higher additive noise factor', read as: FITC above the standard GP "
        "at every α above the default)",
    }
    # (3) "... a small overfitting effect for the sparse models as we continue the optimization."
    later = sorted(v for v in settings.n_opt_steps_values if v >= 50)
    fitc_s = curve("n_opt_steps", "sparse", later)
    std_50 = curve("n_opt_steps", "standard", later[:1])[0] if later else None
    finite = [v for v in fitc_s if v is not None and np.isfinite(v)]
    out["fitc_overfits_with_more_steps"] = {
        "holds": (
            bool(fitc_s[-1] > min(finite)) if len(later) > 1 and len(finite) == len(later) else None
        ),
        "text": (
            "(3) FITC's error "
            + " / ".join(fmt(v) for v in fitc_s)
            + f" at {' / '.join(map(str, later))} optimisation steps"
            if later
            else "(3) no optimisation-step count from 50 on was run"
        )
        + " (thesis: 'a small overfitting effect for the sparse models as we continue the "
        "optimization', read as: its error at the most steps above its lowest from 50 steps "
        "on); the standard GP's error "
        + (f"{fmt(std_50)} at {later[0]} steps" if later else "from 50 steps on not measured")
        + " (thesis: 'accurate models' after 50 steps; not quantified, not judged)",
    }
    # (4) "... with control noise ... the sparse method ... produces inaccurate predictions."
    noisy = sorted(v for v in settings.torque_noise_std_values if v > 0)
    std_n = curve("torque_noise_std", "standard", noisy)
    fitc_n = curve("torque_noise_std", "sparse", noisy)
    floor_n = curve("torque_noise_std", "noise_floor", noisy)
    worse_n = [is_less(a, b) for a, b in zip(std_n, fitc_n, strict=True)]
    out["fitc_worse_with_control_noise"] = {
        "holds": conjunction(worse_n) if noisy else None,
        "text": f"(4) FITC's error above the standard GP's at {sum(w is True for w in worse_n)} "
        f"of the {len(noisy)} control-noise levels above 0 (thesis: FITC 'produces inaccurate "
        "predictions' with control noise, read as: above the standard GP at every level); the "
        + (
            f"standard GP's error at {noisy[-1]:g} N m {fmt(std_n[-1])} against the noise floor "
            f"{fmt(floor_n[-1])}"
            if noisy
            else "standard GP's error with control noise not measured"
        )
        + " (thesis: it 'could capture the uncertainty well'; not quantified, not judged)",
    }
    # (5) "... an increasing number of sample trajectories clearly has a positive effect ..."
    counts = sorted(settings.n_train_values)
    ends = {k: curve("n_train", k, [counts[0], counts[-1]]) for k in ("standard", "sparse")}
    out["more_trajectories_improve_accuracy"] = {
        "holds": (
            conjunction([is_less(v[1], v[0]) for v in ends.values()]) if len(counts) > 1 else None
        ),
        "text": f"(5) with {counts[-1]} instead of {counts[0]} training trajectories the "
        f"standard GP's error is {fmt(ends['standard'][1])} instead of "
        f"{fmt(ends['standard'][0])}, FITC's {fmt(ends['sparse'][1])} instead of "
        f"{fmt(ends['sparse'][0])} (thesis: 'a positive effect on the prediction accuracy', "
        "read as: both models' errors lower with the most trajectories)",
    }
    return out


def verdict_4_5(settings: RewardErrorSettings, summary: dict) -> Verdict:
    """Judges the thesis's four sentences on Fig. 4.5, part by part (criterion changed after
    the stored paper run, issue #32; before it was "the standard GP's error at most FITC's at
    the default setting, and lower with the most training trajectories than with the fewest",
    now an own check). Holds if (1) the standard GP's error is higher at the largest additive
    noise factor α than at the smallest; (2) FITC's error is above the standard GP's at every
    α above the default; (3) FITC's error at the most optimisation steps is above its lowest
    from 50 steps on; (4) FITC's error is above the standard GP's at every control-noise level
    above 0; (5) both models' errors are lower with the most training trajectories than with
    the fewest. A part that a panel cannot decide (too few values) is None, and so is
    ``holds`` unless another part is False. The unquantified words ("slightly", "accurate",
    "capture the uncertainty well") are reported, not judged."""
    parts = _parts_4_5(settings, summary)
    d = summary["default_squared_error"]
    by = {
        word: ", ".join(f"({i})" for i, p in enumerate(parts.values(), 1) if p["holds"] is value)
        for word, value in (("hold", True), ("do not hold", False), ("are undecided", None))
    }
    lead = "; ".join(f"{v} {k}" for k, v in by.items() if v)
    return Verdict(
        CLAIM_4_5,
        conjunction([p["holds"] for p in parts.values()]),
        f"Of the five parts judged, {lead}: "
        + "; ".join(p["text"] for p in parts.values())
        + f". At the default setting the mean squared reward error is {fmt(d['standard'])} for "
        f"the standard GP and {fmt(d['sparse'])} for FITC (noise floor "
        f"{fmt(d['noise_floor'])}, constant predictor {fmt(d['constant_predictor'])}).",
    )


def own_checks_4_5(settings: RewardErrorSettings, summary: dict) -> dict:
    """Our condition on ``fig4.5``: the criterion fixed before the paper run."""
    d = summary["default_squared_error"]
    n_tr = summary["panels"]["n_train"]["standard"]
    lo, hi = str(min(settings.n_train_values)), str(max(settings.n_train_values))
    return {
        "criterion_before_issue_32": own_check(
            conjunction([is_less(n_tr.get(hi), n_tr.get(lo)), is_less(d["standard"], d["sparse"])]),
            "the standard GP's error below FITC's at the default setting and lower with the "
            "most training trajectories than with the fewest (the criterion fixed before the "
            "paper run; the thesis's sentences are judged part by part in the verdict)",
        )
    }


OWN_CHECKS = {"fig4.4": own_checks_4_4, "fig4.5": own_checks_4_5}
"""Experiment id → ``own_checks(settings, summary)``: our conditions beyond the thesis's
sentences (``summary["own_checks"]``), from the summary's numbers alone."""


register(
    Experiment(
        id="fig4.5",
        title="Standard vs sparse (FITC) GP reward-prediction error",
        settings_class=RewardErrorSettings,
        settings=SCALES_4_5,
        run_trial=_run_4_5,
        summarize=_summarize_4_5,
        verdict=verdict_4_5,
        own_checks=own_checks_4_5,
        trials={"smoke": 1, "quick": 1, "paper": 1},
        claim=CLAIM_4_5,
    )
)
