"""Chapter 2 experiments (Preliminaries).

``fig2.10`` (thesis Figs. 2.9–2.11): a 1-DoF demonstration (q, q̇, q̈), the DMP without its
forcing term (v = 0) and the DMP whose 10 shape weights are fitted to the demonstration by
least squares (Eq. 2.23). The summary holds the measurements (RMSEs as fractions of the
demonstration's range, end errors to g); the claim and how it is judged are in
``skillkit/data/claims/ch2.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial

from skillkit._validation import check_positive
from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, setting
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

    a minimum-jerk reach plus a bump peaking at s = 4/7; q̇ and q̈ are its exact derivatives,
    all three vanish at both ends (apart from q itself).

    Parameters
    ----------
    duration : float
        Length of the movement (s).
    dt : float
        Sampling step (s); the grid has ``round(duration / dt) + 1`` samples.
    q_start, q_goal : float
        Start and end angle (rad).
    overshoot : float
        Amplitude of the bump added to the reach (rad).

    Returns
    -------
    times : ndarray, shape (N,)
    q, qd, qdd : ndarray, shape (N, 1)
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


FORCING_LABEL = "f [rad/s²]"
"""Y label of the forcing-term panel: f enters q̈ = τ² α_x(…) + τ² f with a unitless τ, so it
is an acceleration (rad/s²), like the fit target Y of Eq. 2.23."""


@dataclass(frozen=True)
class DMPImitationSettings(Settings):
    """Settings of ``fig2.10`` (Sec. 2.3, Figs 2.9–2.11); the same at every scale."""

    duration: float = setting(1.0, "Length of the demonstration (s); Fig. 2.9 stand-in.", above=0)
    dt: float = setting(
        1e-3, "Sampling step of the demonstration and integration step of the DMP (s).", above=0
    )
    q_start: float = setting(0.0, "Start angle of the demonstration (rad).")
    q_goal: float = setting(1.0, "Goal angle g of the demonstration and the DMP (rad).")
    overshoot: float = setting(
        0.25, "Amplitude of the bump added to the minimum-jerk reach (rad): what f must learn."
    )
    n_basis: int = setting(
        10, "Basis functions of the forcing term f(z; v) (Eq. 2.21; Fig. 2.10b uses 10).", minimum=1
    )
    alpha_x: float = setting(25.0, "Spring gain α_x of the DMP (Eq. 2.21).", above=0)
    beta_x: float = setting(
        6.25, "Damper gain β_x of the DMP (Eq. 2.21; α_x / 4 is critically damped).", above=0
    )
    alpha_z: float = setting(3.0, "Decay rate α_z of the phase z (Eq. 2.22).", above=0)


QUICK = DMPImitationSettings()
# Every scale is the thesis setting (10 basis functions, one demonstration): it takes seconds,
# so quick scales nothing down.
SCALES = {"smoke": QUICK, "quick": QUICK, "paper": QUICK}


def _run_trial(
    settings: DMPImitationSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    """Fit the DMP to the demonstration and roll out with and without its forcing term.

    The experiment is deterministic: ``rng`` is not used.
    """
    trial.reset(total=3)
    times, q, qd, qdd = reach_demonstration(
        settings.duration, settings.dt, settings.q_start, settings.q_goal, settings.overshoot
    )
    trial.update()
    dmp = DMP(
        1,
        n_basis=settings.n_basis,
        alpha_x=settings.alpha_x,
        beta_x=settings.beta_x,
        alpha_z=settings.alpha_z,
        dt=settings.dt,
    ).fit(times, q, qd, qdd)
    trial.update()
    free = dmp.rollout(times, q[0], qd[0], weights=np.zeros_like(dmp.weights))
    fitted = dmp.rollout(times, q[0], qd[0])
    # Eq. 2.23's regression target Y and the fitted forcing term f(z_t; v), both at tau = 1.
    target = dmp.forcing_target(times, q, qd, qdd)[:, 0]
    trial.update()
    return {
        "times": times,
        "demo_q": q[:, 0],
        "demo_qd": qd[:, 0],
        "demo_qdd": qdd[:, 0],
        "free_q": free[0][:, 0],
        "free_qd": free[1][:, 0],
        "free_qdd": free[2][:, 0],
        "dmp_q": fitted[0][:, 0],
        "dmp_qd": fitted[1][:, 0],
        "dmp_qdd": fitted[2][:, 0],
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
    series = [
        Series(
            name=names[src],
            x=t,
            y=np.asarray(tr[f"{src}_{key}"]).tolist(),
            panel=label,
            xlabel="time [s]",
            ylabel=label,
            dash="dash" if src == "demo" else None,  # the thesis draws the demonstration dashed
        )
        for key, label in panels
        for src in ("demo", "free", "dmp")
    ]
    series += [
        Series(
            name="target Y (Eq. 2.23)",
            x=t,
            y=np.asarray(tr["forcing_target"]).tolist(),
            panel="forcing term f(z)",
            xlabel="time [s]",
            ylabel=FORCING_LABEL,
            dash="dash",
        ),
        Series(
            name="fitted f(z; v)",
            x=t,
            y=np.asarray(tr["forcing_fit"]).tolist(),
            panel="forcing term f(z)",
            xlabel="time [s]",
            ylabel=FORCING_LABEL,
        ),
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
        trials={"smoke": 1, "quick": 1, "paper": 1},
    )
)
