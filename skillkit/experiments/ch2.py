"""Chapter 2 experiments (Preliminaries).

``fig2.10`` (Figs 2.9–2.11): a 1-DoF demonstration (q, q̇, q̈), the DMP without its forcing
term (v = 0) and the DMP whose shape weights are fitted to it by least squares (Eq. 2.23);
RMSEs as fractions of the demonstration's range and end errors to g.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial

from skillkit._validation import check_positive
from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.policies.dmp import DMP
from skillkit.trial import TrialContext

__all__ = ["DMPImitationSettings", "reach_demonstration"]


def reach_demonstration(
    duration: float = 1.0,
    dt: float = 1e-3,
    q_start: float = 0.0,
    q_goal: float = 1.0,
    overshoot: float = 0.25,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A smooth 1-DoF reach that overshoots its goal and comes back (the Fig. 2.9 stand-in).

    With s = t / duration,

        q(s) = q_start + (q_goal - q_start) (10 s^3 - 15 s^4 + 6 s^5) + overshoot b(s) / b(4/7),
        b(s) = s^4 (1 - s)^3,

    a minimum-jerk reach plus a bump peaking at s = 4/7, sampled every ``dt`` seconds
    (``round(duration / dt) + 1`` samples; angles in rad). Returns ``times`` (N,) and q, q̇,
    q̈ (N, 1), the exact derivatives (q̇ and q̈ vanish at both ends).
    """
    duration = check_positive(duration, "duration")
    dt = check_positive(dt, "dt")
    n = max(2, int(round(duration / dt)) + 1)
    times = np.linspace(0.0, duration, n)
    s = Polynomial([0.0, 1.0])
    bump = s**4 * (1 - s) ** 3
    path = q_start + (q_goal - q_start) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    path = path + overshoot * bump / bump(4.0 / 7.0)
    x = times / duration
    q = path(x)
    qd = path.deriv(1)(x) / duration
    qdd = path.deriv(2)(x) / duration**2
    return times, q[:, None], qd[:, None], qdd[:, None]


FORCING_LABEL = "f [rad/s²]"  # f enters q̈ = τ² α_x(…) + τ² f: an acceleration


@dataclass(frozen=True)
class DMPImitationSettings(Settings):
    """Settings of ``fig2.10`` (Sec. 2.3, Figs 2.9–2.11); the same at every scale."""

    duration: float = setting(1.0, "Length of the demonstration (s).", above=0)
    dt: float = setting(1e-3, "Sampling and integration step (s).", above=0)
    q_start: float = setting(0.0, "Start angle of the demonstration (rad).")
    q_goal: float = setting(1.0, "Goal angle g of the demonstration and the DMP (rad).")
    overshoot: float = setting(0.25, "Amplitude of the bump f must learn (rad).")
    n_basis: int = setting(10, "Basis functions of the forcing term (Eq. 2.21).", minimum=1)
    alpha_x: float = setting(25.0, "Spring gain α_x of the DMP (Eq. 2.21).", above=0)
    beta_x: float = setting(6.25, "Damper gain β_x (Eq. 2.21; α_x / 4: critical).", above=0)
    alpha_z: float = setting(3.0, "Decay rate α_z of the phase z (Eq. 2.22).", above=0)


SCALES = scales(DMPImitationSettings())  # seconds: every scale is the thesis setting


def _run_trial(
    settings: DMPImitationSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    """Fit the DMP and roll out with and without its forcing term (``rng`` unused)."""
    trial.reset(total=3)
    times, q, qd, qdd = reach_demonstration(
        settings.duration, settings.dt, settings.q_start, settings.q_goal, settings.overshoot
    )
    trial.update()
    gains = {k: getattr(settings, k) for k in ("n_basis", "alpha_x", "beta_x", "alpha_z", "dt")}
    dmp = DMP(1, **gains).fit(times, q, qd, qdd)
    trial.update()
    free = dmp.rollout(times, q[0], qd[0], weights=np.zeros_like(dmp.weights))
    fitted = dmp.rollout(times, q[0], qd[0])
    # Eq. 2.23's regression target Y and the fitted forcing term f(z_t; v), both at tau = 1.
    target = dmp.forcing_target(times, q, qd, qdd)[:, 0]
    trial.update()
    out = {"times": times}
    for src, arrays in (("demo", (q, qd, qdd)), ("free", free), ("dmp", fitted)):
        out.update(
            {f"{src}_{k}": a[:, 0] for k, a in zip(("q", "qd", "qdd"), arrays[:3], strict=True)}
        )
    return {
        **out,
        "forcing_target": target,
        "forcing_fit": dmp.forcing(times)[:, 0],
        "weights": dmp.weights[0],
        "goal": float(dmp.goal[0]),
    }


def _rmse_fraction(y, ref) -> float:
    """Root-mean-square error of ``y`` as a fraction of the range of ``ref``."""
    y, ref = np.asarray(y), np.asarray(ref)
    return float(np.sqrt(np.mean((y - ref) ** 2)) / np.ptp(ref))


def _summarize(settings: DMPImitationSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    tr = trials[0]  # the experiment is deterministic: every trial is identical
    t = np.asarray(tr["times"]).tolist()
    names = {
        "demo": "demonstration (Fig. 2.9)",
        "free": "DMP, v = 0 (Fig. 2.10a)",
        "dmp": f"DMP, {settings.n_basis} basis functions (Figs. 2.10b, 2.11)",
    }
    panels = [
        ("q", "position q [rad]"),
        ("qd", "velocity q̇ [rad/s]"),
        ("qdd", "acceleration q̈ [rad/s²]"),
    ]

    def line(name, key, panel, ylabel, dash=None):
        y = np.asarray(tr[key]).tolist()
        return Series(name, t, y, panel=panel, xlabel="time [s]", ylabel=ylabel, dash=dash)

    series = [  # the thesis draws the demonstration dashed
        line(names[src], f"{src}_{key}", label, label, "dash" if src == "demo" else None)
        for key, label in panels
        for src in ("demo", "free", "dmp")
    ]
    forcing = "forcing term f(z)"
    series += [
        line("target Y (Eq. 2.23)", "forcing_target", forcing, FORCING_LABEL, "dash"),
        line("fitted f(z; v)", "forcing_fit", forcing, FORCING_LABEL),
    ]
    demo_q = np.asarray(tr["demo_q"])
    q_range = float(np.ptp(demo_q))
    end_error = abs(float(tr["dmp_q"][-1]) - tr["goal"])
    rmse = _rmse_fraction(tr["dmp_q"], demo_q)
    summary = {
        "n_basis": settings.n_basis,
        "demo_range_rad": q_range,
        "rmse_q_fraction_of_range": rmse,
        "rmse_qd_fraction_of_range": _rmse_fraction(tr["dmp_qd"], tr["demo_qd"]),
        "rmse_qdd_fraction_of_range": _rmse_fraction(tr["dmp_qdd"], tr["demo_qdd"]),
        "rmse_q_fraction_without_forcing": _rmse_fraction(tr["free_q"], demo_q),
        "end_error_to_goal_rad": end_error,
        "end_error_without_forcing_rad": abs(float(tr["free_q"][-1]) - tr["goal"]),
    }
    return series, summary


register(
    Experiment(
        id="fig2.10",
        title="DMP with and without forcing term imitating a 1-DoF demonstration",
        settings_class=DMPImitationSettings,
        settings=SCALES,
        run_trial=_run_trial,
        summarize=_summarize,
    )
)
