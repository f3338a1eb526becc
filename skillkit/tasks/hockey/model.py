"""The decomposed reward model of the robot hockey task (Sec. 4.3.3, Appendix C.2).

Event models chained as in Sec. 4.3.3: 1. **launch** (GP ω ↦ the control puck's state at
x = :data:`X_LAUNCH`, :class:`LaunchTargets`; once a shot never crosses, a GP ω ↦ ±1 whose
positive draws launch); 2. **free sliding** (GP v ↦ Δ[p, v] per ``slide_dt``, iterated until
slower than :data:`STOP_SPEED` or reversing); 3. **contact detection** from the puck radius
(:func:`first_contact`); 4. **contact** (GP: both velocities after it in the frame [n, t]);
5. the task's reward, averaged over L (Eq. 4.1). In the **real setting** (``hockey-real``)
the models learn from the smoothed observed tracks and :class:`DisplacementModel` replaces
model 4: after a predicted hit the paths run straight to its end points.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from skillkit._validation import (
    as_generator,
    check_array,
    check_choice,
    check_count,
    check_positive,
    check_type,
)
from skillkit.models.gp import ExactGP, GPRegression
from skillkit.models.reward import (
    Prediction,
    RewardModel,
    check_refit,
    gp_stats,
    set_factories,
    subsample,
    usable_trajectories,
    worst_if_nonfinite,
)
from skillkit.tasks.hockey.table import CONTROL_PUCK_START
from skillkit.tasks.hockey.task import Hockey, butterworth_smooth

X_LAUNCH = float(CONTROL_PUCK_START[0]) + 0.2
"""The launch line x = 0.65 m (0.2 m past the control puck's start), m."""
PUCK_Z = 0.0125
"""Height of a puck's centre above the table (half its 2.5 cm height), m, for drawing."""
REST_FRAMES = 15
"""Rest frames appended to predicted real-setting paths (the smoothing's padlen is 9)."""
STOP_SPEED, HORIZON = 0.03, 6.0
"""Speed (m/s) below which a predicted puck stops; longest predicted sliding (s)."""
REAL_THRESHOLD = 0.2
"""Centre distance (m) at which the real setting's displacement model takes over."""


def _segment_hit(d0: np.ndarray, d1: np.ndarray, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Hit (...) and the first f ∈ [0, 1] with ‖d0 + f (d1 − d0)‖ = distance (0 if none/inside)."""
    e = d1 - d0
    a = np.sum(e * e, axis=-1)
    b = np.sum(d0 * e, axis=-1)
    c = np.sum(d0 * d0, axis=-1) - distance**2
    disc = b * b - a * c
    safe_a = np.where(a > 0, a, 1.0)
    f = (-b - np.sqrt(np.maximum(disc, 0.0))) / safe_a
    inside = c <= 0
    hit = inside | ((a > 0) & (disc >= 0) & (f >= 0) & (f <= 1))
    return hit, np.where(inside, 0.0, np.where(hit, f, 0.0))


def first_contact(control, target, radius: float) -> tuple[bool, int, float]:
    """First contact ‖d_k + f (d_{k+1} − d_k)‖ = 2r, d = x_c − x_t linear between samples.

    Parameters
    ----------
    control, target : array_like, shape (T, 2)
        Puck centres at common sample times.
    radius : float
        r, m.

    Returns
    -------
    hit, k, f : bool, int, float
        Whether they touch, and the contact x_k + f (x_{k+1} − x_k) (0, 0 where no hit).
    """
    c = check_array(control, "control", ndim=2)
    t = check_array(target, "target", shape=c.shape)
    radius = check_positive(radius, "radius")
    if c.shape[1] != 2 or c.shape[0] < 2:
        raise ValueError(f"control: expected a path of shape (T >= 2, 2), got {c.shape}")
    hits, f = _segment_hit(c[:-1] - t[:-1], c[1:] - t[1:], 2.0 * radius)
    k = int(hits.argmax())  # 0 with f = 0 where none
    return bool(hits[k]), k, float(f[k])


def _frame(n: np.ndarray) -> np.ndarray:
    """Rotation rows [n, n rotated by +90°], shape (..., 2, 2)."""
    t = np.stack([-n[..., 1], n[..., 0]], axis=-1)
    return np.stack([n, t], axis=-2)


def _rotate(R: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Each (x, y) pair of the rows of y (N, 2k) rotated by R (N, 2, 2)."""
    return np.einsum("nij,nkj->nki", R, y.reshape(len(y), y.shape[1] // 2, 2)).reshape(y.shape)


def _interp(times: np.ndarray, values: np.ndarray, at) -> np.ndarray:
    at = np.asarray(at, dtype=np.float64)
    return np.stack([np.interp(at, times, values[:, i]) for i in range(values.shape[1])], -1)


class LaunchTargets:
    """The launch GP's outputs for the launch state [p_y, v_x, v_y, t_0].

    Parameters
    ----------
    kind : {"heading", "velocity"}
        [p_y, ψ, ‖v‖, t_0] with ψ = atan2(v_y, v_x), or [p_y, v_x, v_y, t_0].
    """

    def __init__(self, kind: str = "heading"):
        self.kind = check_choice(kind, "launch_targets", ("heading", "velocity"))

    def encode(self, state: np.ndarray) -> np.ndarray:
        """GP targets (N, 4) of launch states (N, 4)."""
        state = np.asarray(state, dtype=np.float64)
        if self.kind == "velocity":
            return state.copy()
        v = state[:, 1:3]
        heading = np.arctan2(v[:, 1], v[:, 0])
        return np.column_stack([state[:, 0], heading, np.hypot(v[:, 0], v[:, 1]), state[:, 3]])

    def decode(self, targets: np.ndarray) -> np.ndarray:
        """Launch states (N, 4) of GP targets or draws (N, 4); a negative speed is a rest."""
        targets = np.asarray(targets, dtype=np.float64)
        if self.kind == "velocity":
            return targets.copy()
        speed = np.maximum(targets[:, 2], 0.0)
        heading = targets[:, 1]
        return np.column_stack(
            [targets[:, 0], speed * np.cos(heading), speed * np.sin(heading), targets[:, 3]]
        )

    def __repr__(self) -> str:
        return f"LaunchTargets({self.kind!r})"


def approach_frame(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Approach features and frames of the incoming control puck.

    Parameters
    ----------
    x : ndarray, shape (N, 4)
        [x_c − b, v_c]: position relative to the target, velocity.

    Returns
    -------
    features, frames : ndarray, shape (N, 2), (N, 2, 2)
        [h, ‖v_c‖], h the signed offset of the line of approach from the target's centre;
        rows [u, u⊥], u = v_c / ‖v_c‖ (x at rest).
    """
    x = np.asarray(x, dtype=np.float64)
    rel, v = x[:, :2], x[:, 2:]
    speed = np.linalg.norm(v, axis=1)
    u = np.where(speed[:, None] > 0, v / np.where(speed > 0, speed, 1.0)[:, None], [1.0, 0.0])
    frames = _frame(u)
    h = np.einsum("ni,ni->n", frames[:, 1], rel)
    return np.column_stack([h, speed]), frames


def _classifier_inputs(x: np.ndarray) -> np.ndarray:
    feats, _ = approach_frame(x)
    return np.column_stack([np.abs(feats[:, 0]), feats[:, 1]])


class DisplacementModel:
    """Real setting: where both pucks end up once the control puck comes within the threshold.

    Parameters
    ----------
    kind : {"hit_gp", "gp"}
        ``"hit_gp"``: P(hit) by logistic regression on [|h|, ‖v_c‖] (:func:`approach_frame`)
        and a GP [h, ‖v_c‖] → both displacements in the approach frame, fitted on the hits;
        ``"gp"``: one GP [x_c − b, v_c] → [Δy_target, Δx_control] in world coordinates.
    hit_distance : float
        An approach is a hit when the target puck moved more than this, m.

    Once fitted: ``gp``; ``classifier`` (None while the data hold one class: then the
    fraction of hits ``hit_rate``).
    """

    def __init__(self, kind: str = "hit_gp", hit_distance: float = 0.08):
        self.kind = check_choice(kind, "displacement", ("hit_gp", "gp"))
        self.hit_distance = check_positive(hit_distance, "hit_distance")
        self.gp = None
        self.classifier = None
        self.hit_rate = 1.0

    def hits(self, y: np.ndarray) -> np.ndarray:
        """Which recorded approaches (targets y (N, 4)) moved the target puck, (N,)."""
        return np.linalg.norm(np.asarray(y)[:, :2], axis=1) > self.hit_distance

    def gp_data(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GP inputs and targets: all rows (``"gp"``) or the hits in the approach frame."""
        if self.kind == "gp":
            return x, y
        keep = self.hits(y)
        feats, R = approach_frame(x[keep])
        return feats, _rotate(R, y[keep])

    def fit_classifier(self, x: np.ndarray, y: np.ndarray) -> None:
        """Fit P(hit | approach) on every recorded approach (``"hit_gp"``)."""
        if self.kind == "gp":
            return
        from sklearn.linear_model import LogisticRegression
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        hit = self.hits(y)
        self.hit_rate = float(hit.mean()) if hit.size else 0.0
        self.classifier = None
        if 0 < hit.sum() < hit.size:
            self.classifier = make_pipeline(StandardScaler(), LogisticRegression(C=100.0))
            self.classifier.fit(_classifier_inputs(x), hit)

    def hit_probability(self, x: np.ndarray) -> np.ndarray:
        """P(hit) of approaches x (N, 4), (N,); 1 for ``"gp"``, 0 without a GP."""
        x = np.asarray(x, dtype=np.float64)
        if self.kind == "gp":
            return np.ones(x.shape[0])
        if self.gp is None:
            return np.zeros(x.shape[0])
        if self.classifier is None or x.shape[0] == 0:
            return np.full(x.shape[0], self.hit_rate)
        return self.classifier.predict_proba(_classifier_inputs(x))[:, 1]

    def draw_hits(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Bernoulli hit draws for approaches x (N, 4), (N,) bool."""
        p = self.hit_probability(x)
        return p > 0 if self.kind == "gp" else rng.random(p.shape[0]) < p

    def draw(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One draw of [Δy_target, Δx_control] (N, 4), world frame (zeros without a GP)."""
        x = np.asarray(x, dtype=np.float64)
        if self.gp is None or x.shape[0] == 0:
            return np.zeros((x.shape[0], 4))
        if self.kind == "gp":
            return self.gp.sample(x, 1, rng).reshape(x.shape[0], -1)
        feats, R = approach_frame(x)
        local = self.gp.sample(feats, 1, rng).reshape(x.shape[0], -1)
        return _rotate(np.swapaxes(R, 1, 2), local)

    def __repr__(self) -> str:
        return f"DisplacementModel({self.kind!r}, fitted={self.gp is not None})"


@dataclass(frozen=True)
class HockeyPrediction(Prediction):
    """L predicted shots for each of B (ω, s) pairs.

    ``control``, ``target`` (B, L, K, 2): puck paths padded with the last position (simulated:
    start, launch point, then every ``slide_dt``; real: every observation frame); ``launch``
    (B, L, 4) [x, y, v_x, v_y] at the launch line (the start at rest if not ``launched``);
    ``contact`` (B, L) and its path sample ``contact_index`` (−1 if none); ``rewards`` (B, L).
    """

    control: np.ndarray
    target: np.ndarray
    launch: np.ndarray
    launched: np.ndarray
    contact: np.ndarray
    contact_index: np.ndarray
    rewards: np.ndarray

    @property
    def displacements(self) -> np.ndarray:
        """Target-puck displacement d_T = ‖y_K − y_0‖ per shot, shape (B, L)."""
        return np.linalg.norm(self.target[:, :, -1] - self.target[:, :, 0], axis=-1)

    def __repr__(self) -> str:
        B, L, K, _ = self.control.shape
        r = self.expected_rewards
        return (
            f"HockeyPrediction(pairs={B}, trajectories={L}, samples={K}, "
            f"expected_reward={r.min():.4g}…{r.max():.4g}, "
            f"launched={int(self.launched.sum())}/{B * L}, contacts={int(self.contact.sum())})"
        )


class HockeyRewardModel(RewardModel):
    """Decomposed GPREPS reward model of :class:`~skillkit.tasks.hockey.Hockey` (Sec. 4.3.3).

    Parameters
    ----------
    task : Hockey
    make_launch_model, make_launch_probability_model, make_sliding_model : callable, optional
    make_contact_model, make_displacement_model : callable, optional
        Unfitted GP regressions (default ``ExactGP``, module-level for checkpoints) of
        ω → ``launch_targets``, ω → ±1, v → Δ[p, v], [v·n, v·t] → post-contact velocities,
        and the real setting's :class:`DisplacementModel`.
    real : bool, optional
        Learn from the smoothed observed tracks (default: when ``task.observation`` is set).
    slide_dt : float, optional
        Sliding step, s (default 0.04; the observation period when ``real``).
    max_sliding_points : int
        The sliding GP is fitted on at most this many random points (the contact GP on 300).
    refit : {"best", "cold", "warm"}
        Start of each hyper-parameter optimisation (:func:`refit_gp`).
    launch_targets, displacement : str
        :class:`LaunchTargets` and :class:`DisplacementModel` kinds.
    device : str or torch.device, optional
        Where the fitted GPs' predictors are queried.
    """

    _KEYS = ("launch", "launch_probability", "sliding", "contact", "displacement")

    def __init__(
        self,
        task: Hockey,
        make_launch_model: Callable[[], Any] | None = None,
        make_launch_probability_model: Callable[[], Any] | None = None,
        make_sliding_model: Callable[[], Any] | None = None,
        make_contact_model: Callable[[], Any] | None = None,
        make_displacement_model: Callable[[], Any] | None = None,
        real: bool | None = None,
        slide_dt: float | None = None,
        max_sliding_points: int = 400,
        refit: str = "best",
        launch_targets: str = "heading",
        displacement: str = "hit_gp",
        device=None,
    ):
        check_type(task, Hockey, "task", "a Hockey task")
        set_factories(
            self,
            make_launch_model=(make_launch_model, ExactGP),
            make_launch_probability_model=(make_launch_probability_model, ExactGP),
            make_sliding_model=(make_sliding_model, ExactGP),
            make_contact_model=(make_contact_model, ExactGP),
            make_displacement_model=(make_displacement_model, ExactGP),
        )
        self.task = task
        self.real = task.observation is not None if real is None else bool(real)
        if self.real and task.observation is None:
            raise ValueError("real: the real setting needs a task with an observation model")
        obs_dt = None if task.observation is None else 1.0 / task.observation.rate
        if slide_dt is None:
            slide_dt = obs_dt if self.real else 0.04
        self.slide_dt = check_positive(slide_dt, "slide_dt")
        if self.real and not np.isclose(self.slide_dt, obs_dt):
            raise ValueError(
                f"slide_dt: the real setting slides at the observation period {obs_dt:g} s"
            )
        self.stop_speed, self.n_slide = STOP_SPEED, int(np.ceil(HORIZON / self.slide_dt))
        self.radius = task.physics.puck_radius
        self.real_threshold = REAL_THRESHOLD
        if self.real_threshold <= 2 * self.radius:
            raise ValueError(
                f"task: the contact distance {2 * self.radius:g} m reaches the real threshold"
            )
        self.contact_margin = 0.25 if self.real else 0.02  # s: no sliding data this near contact
        self.max_sliding_points = check_count(max_sliding_points, "max_sliding_points", 2)
        self.max_contact_points = 300
        self.refit = check_refit(refit)
        self.launch_targets = LaunchTargets(launch_targets).kind
        self.displacement = DisplacementModel(displacement).kind
        self.device = device
        self.models: dict[str, Any] = dict.fromkeys(self._KEYS)
        self._hypers: dict[str, dict | None] = dict.fromkeys(self._KEYS)
        self.n_data = 0

    def paths(self, trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The puck paths a model learns from, times (T,), control and target (T, 2): recorded,
        or in the real setting observed and smoothed with the reward's filter."""
        sig = trajectory.signals
        if not self.real:
            return sig["puck_times"], sig["control_puck"], sig["target_puck"]
        obs = self.task.observation
        smooth = [
            butterworth_smooth(sig[k], obs.rate, obs.cutoff, obs.order)
            for k in ("control_puck_observed", "target_puck_observed")
        ]
        return sig["observation_times"], smooth[0], smooth[1]

    def launch_data(self, trajectories) -> tuple[np.ndarray, np.ndarray]:
        """Whether each shot crossed :data:`X_LAUNCH` (N,) and its [p_y, v_x, v_y, t_0] there
        (N, 4; NaN rows elsewhere), interpolated linearly (velocities from ``np.gradient``)."""
        crossed, states = [], []
        for t in trajectories:
            times, c, _ = self.paths(t)
            above = c[:, 0] >= X_LAUNCH  # the first sample at or past the line, from below
            crossed.append(bool(above.any() and not above[0]))
            if not crossed[-1]:
                states.append(np.full(4, np.nan))
                continue
            k = int(above.argmax())
            f = float((X_LAUNCH - c[k - 1, 0]) / (c[k, 0] - c[k - 1, 0]))
            v = np.gradient(c, times, axis=0)
            p = (1 - f) * c[k - 1] + f * c[k]
            vel = (1 - f) * v[k - 1] + f * v[k]
            t0 = (1 - f) * times[k - 1] + f * times[k]
            states.append(np.array([p[1], vel[0], vel[1], t0]))
        return np.array(crossed), np.array(states)

    def _contact_time(self, times, c, y) -> float | None:
        """Time of the first contact (simulated) or threshold crossing (real)."""
        dist = self.real_threshold if self.real else 2 * self.radius
        hit, f = _segment_hit(c[:-1] - y[:-1], c[1:] - y[1:], dist)
        if not hit.any():
            return None
        k = int(hit.argmax())
        return float((1 - f[k]) * times[k] + f[k] * times[k + 1])

    def sliding_data(self, trajectories, t_launch) -> tuple[np.ndarray, np.ndarray]:
        """Sliding transitions v_k (N, 2) → Δ[p, v] (N, 4) on a ``slide_dt`` grid (control puck
        from its launch at ``t_launch``, NaN for none; target from the contact), none near a
        contact or slow."""
        dt, xs, ys = self.slide_dt, [], []
        for t, t0 in zip(trajectories, t_launch, strict=True):
            if np.isnan(t0):
                continue
            times, c, y = self.paths(t)
            t_contact = self._contact_time(times, c, y)
            for path, start in ((c, t0), (y, t_contact)):
                if start is None:
                    continue
                grid = np.arange(start, times[-1] - dt + 1e-12, dt)
                if grid.size < 2:
                    continue
                p = _interp(times, path, grid)
                v = _interp(times, np.gradient(path, times, axis=0), grid)
                b = np.hstack([p, v])
                keep = np.linalg.norm(v[:-1], axis=1) > self.stop_speed
                if t_contact is not None:
                    g0 = grid[:-1]
                    keep &= (g0 + dt < t_contact - self.contact_margin) | (
                        g0 > t_contact + self.contact_margin
                    )
                xs.append(v[:-1][keep])
                ys.append((b[1:] - b[:-1])[keep])
        if not xs or sum(len(x) for x in xs) < 2:
            raise ValueError("trajectories: fewer than two sliding transitions to learn from")
        return np.concatenate(xs), np.concatenate(ys)

    def contact_data(self, trajectories) -> tuple[np.ndarray, np.ndarray]:
        """Contacts on the recorded paths (:func:`first_contact`) in the contact frame: x =
        [v·n, v·t] (N, 2) ``contact_margin`` before, y = [v_c'·n, v_c'·t, v_t'·n, v_t'·t]
        (N, 4) ``contact_margin`` and one sample after."""
        xs, ys = [], []
        for t in trajectories:
            times, c, y = self.paths(t)
            hit, k, f = first_contact(c, y, self.radius)
            if not hit or k + 3 >= len(times):
                continue
            tc = (1 - f) * times[k] + f * times[k + 1]
            pc = (1 - f) * c[k] + f * c[k + 1]
            R = _frame((y[k] - pc) / np.linalg.norm(y[k] - pc))
            vc = np.gradient(c, times, axis=0)
            vy = np.gradient(y, times, axis=0)
            after = tc + self.contact_margin + (times[k + 1] - times[k])
            xs.append(R @ _interp(times, vc, tc - self.contact_margin))
            ys.append(np.r_[R @ _interp(times, vc, after), R @ _interp(times, vy, after)])
        return np.array(xs).reshape(-1, 2), np.array(ys).reshape(-1, 4)

    def displacement_data(self, trajectories) -> tuple[np.ndarray, np.ndarray]:
        """Real setting: [x_c − b, v_c] (N, 4) where the pucks first come within
        ``real_threshold``, and [y_T − y_0, x_T − x_c] (N, 4), the target's final
        displacement and the control puck's remaining one."""
        xs, ys = [], []
        for t in trajectories:
            times, c, y = self.paths(t)
            tc = self._contact_time(times, c, y)
            if tc is None:
                continue
            pc = _interp(times, c, tc)
            vc = _interp(times, np.gradient(c, times, axis=0), tc)
            xs.append(np.r_[pc - y[0], vc])
            ys.append(np.r_[y[-1] - y[0], c[-1] - pc])
        return np.array(xs).reshape(-1, 4), np.array(ys).reshape(-1, 4)

    def fit(self, contexts, omegas, rewards, trajectories, rng=None) -> dict[str, Any]:
        """Refit the event models on every non-failed real shot.

        Returns ``n_data`` (sliding transitions), ``n_trajectories``, ``n_launched``,
        ``n_contacts``, per GP its :func:`gp_stats` and refit record, and with ``"hit_gp"``
        ``n_hits`` and ``hit_accuracy``.
        """
        ok = usable_trajectories(trajectories, "hockey")
        rng = as_generator(rng)
        shape = (len(trajectories), self.task.parameter_dim)  # one row per trajectory
        omegas = check_array(omegas, "omegas", shape=shape)
        first = {id(t): i for i, t in reversed(list(enumerate(trajectories)))}
        w = omegas[[first[id(t)] for t in ok]]
        crossed, launch = self.launch_data(ok)
        if crossed.sum() < 2:
            raise ValueError("trajectories: fewer than two launched shots to learn from")
        stats: dict[str, Any] = {"n_trajectories": len(ok), "n_launched": int(crossed.sum())}
        self.models = dict.fromkeys(self._KEYS)
        fits: dict[str, tuple] = {}  # key: (gp, refit record, points)

        def fit(key: str, x: np.ndarray, y: np.ndarray):
            gp, record = self._refit(key, getattr(self, f"make_{key}_model"), x, y, rng)
            if self.device is not None:
                gp.predictor = gp.predictor.to(torch.device(self.device))
            fits[key] = (gp, record, int(x.shape[0]))
            return gp

        fit("launch", w[crossed], LaunchTargets(self.launch_targets).encode(launch[crossed]))
        if not crossed.all():
            fit("launch_probability", w, np.where(crossed, 1.0, -1.0))
        x, y = self.sliding_data(ok, launch[:, 3])
        self.n_data = int(x.shape[0])
        fit("sliding", *subsample(rng, self.max_sliding_points, x, y))
        self.models.update({key: f[0] for key, f in fits.items()})
        cx, cy = (self.displacement_data if self.real else self.contact_data)(ok)
        stats["n_contacts"] = int(cx.shape[0])
        cx, cy = subsample(rng, self.max_contact_points, cx, cy)
        if not self.real and cx.shape[0] >= 2:
            self.models["contact"] = fit("contact", cx, cy)
        elif self.real:
            model = DisplacementModel(self.displacement)
            model.fit_classifier(cx, cy)
            gx, gy = model.gp_data(cx, cy)
            if gx.shape[0] >= 2:
                model.gp = fit("displacement", gx, gy)
                self.models["displacement"] = model
            if model.kind == "hit_gp":
                stats["n_hits"] = int(gx.shape[0])
                if cx.shape[0]:
                    guess = model.hit_probability(cx) > 0.5  # all misses without a GP
                    stats["hit_accuracy"] = float(np.mean(guess == model.hits(cy)))
        stats["n_data"] = self.n_data
        for key, (gp, record, n) in fits.items():
            if isinstance(gp, GPRegression):
                stats[key] = {**gp_stats(gp, n), **record}
        return stats

    def _draw(self, key: str, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One draw y ~ N(μ(x), σ²(x)) of GP ``key`` (noisy observation), shape (n, E)."""
        if x.shape[0] == 0:
            return np.zeros((0, self.models[key].predictor.output_dim))
        return self.models[key].sample(x, 1, rng).reshape(x.shape[0], -1)

    def _slide(self, b: np.ndarray, moving: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
        """One sliding step of the rows ``moving`` of b = [p, v] (n, 4); stops slow pucks."""
        b = b.copy()
        rows = np.flatnonzero(moving)
        new = b[rows] + self._draw("sliding", b[rows, 2:], rng)
        stop = (np.linalg.norm(new[:, 2:], axis=1) < self.stop_speed) | (
            np.sum(new[:, 2:] * b[rows, 2:], axis=1) <= 0
        )
        new[stop, 2:] = 0.0
        b[rows] = new
        moving = moving.copy()
        moving[rows[stop]] = False
        return b, moving

    def _launch(self, w: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Launch states [x, y, v_x, v_y] (n, 4), times t_0 (n,) and launched flags (n,)."""
        n = w.shape[0]
        draw = LaunchTargets(self.launch_targets).decode(self._draw("launch", w, rng))
        launched = np.ones(n, dtype=bool)
        if self.models["launch_probability"] is not None:
            launched = self._draw("launch_probability", w, rng)[:, 0] > 0
        state = np.column_stack([np.full(n, X_LAUNCH), draw[:, :3]])
        state[~launched] = np.r_[CONTROL_PUCK_START, 0.0, 0.0]
        return state, np.maximum(draw[:, 3], 0.0), launched

    def predict(self, contexts, omegas, n_trajectories: int, rng=None) -> HockeyPrediction:
        """Sample L = ``n_trajectories`` shots for each of B pairs, contexts (B, 3) and omegas
        (B, 15), through the event models."""
        fitted = self.models["launch"] is not None
        w, s, L, rng = self._pairs(fitted, contexts, omegas, n_trajectories, rng)
        task, B = self.task, w.shape[0]
        wl, sl = np.repeat(w, L, axis=0), np.repeat(s, L, axis=0)
        launch, t0, launched = self._launch(wl, rng)
        if self.real:
            control, target, contact, index = self._predict_real(launch, t0, launched, sl, rng)
        else:
            control, target, contact, index = self._predict_simulated(launch, launched, sl, rng)
        with np.errstate(all="ignore"):
            keys = task.model_signals().signals
            rewards = task.reward_batch(None, None, {keys[0]: control, keys[1]: target}, sl)
        rewards = worst_if_nonfinite(rewards, task, "HockeyRewardModel.predict")
        out = (control, target, launch, launched, contact, index, rewards)
        return HockeyPrediction(*(a.reshape(B, L, *a.shape[1:]) for a in out))

    def _predict_simulated(self, launch, launched, s, rng):
        """Slide, detect the first contact by radius, apply the contact model, slide on."""
        n, r2 = launch.shape[0], 2 * self.radius
        c = launch.copy()
        y = np.column_stack([s[:, :2], np.zeros((n, 2))])
        c_moving, y_moving = launched & (np.linalg.norm(c[:, 2:], axis=1) > 0), np.zeros(n, bool)
        contact = np.zeros(n, dtype=bool)
        index = np.full(n, -1)
        cp = [np.tile(CONTROL_PUCK_START, (n, 1)), c[:, :2].copy()]
        yp = [y[:, :2].copy(), y[:, :2].copy()]
        can_contact = self.models["contact"] is not None
        for _ in range(self.n_slide):
            if not (c_moving.any() or y_moving.any()):
                break
            both = np.vstack([c, y])
            both, moving = self._slide(both, np.r_[c_moving, y_moving], rng)
            new_c, y, c_moving2, y_moving = both[:n], both[n:], moving[:n], moving[n:]
            pending = c_moving & ~contact
            if can_contact and pending.any():
                rows = np.flatnonzero(pending)
                hit, f = _segment_hit(c[rows, :2] - y[rows, :2], new_c[rows, :2] - y[rows, :2], r2)
                rows, f = rows[hit], f[hit][:, None]
                if rows.size:
                    pc = c[rows, :2] + f * (new_c[rows, :2] - c[rows, :2])
                    v_in = c[rows, 2:] + f * (new_c[rows, 2:] - c[rows, 2:])
                    nvec = y[rows, :2] - pc
                    R = _frame(nvec / np.linalg.norm(nvec, axis=1, keepdims=True))
                    out = self._draw("contact", _rotate(R, v_in), rng)
                    out = _rotate(np.swapaxes(R, 1, 2), out)
                    new_c[rows] = np.column_stack([pc, out[:, :2]])
                    y[rows, 2:] = out[:, 2:]
                    y_moving[rows] = np.linalg.norm(y[rows, 2:], axis=1) > self.stop_speed
                    c_moving2[rows] = np.linalg.norm(new_c[rows, 2:], axis=1) > self.stop_speed
                    contact[rows] = True
                    index[rows] = len(cp)
            c, c_moving = new_c, c_moving2
            cp.append(c[:, :2].copy())
            yp.append(y[:, :2].copy())
        return np.stack(cp, 1), np.stack(yp, 1), contact, index

    def _predict_real(self, launch, t0, launched, s, rng):
        """Real setting: slide until the pucks come within the threshold, draw hit or miss there;
        a miss slides on, a hit draws the paths to the model's end points."""
        n, dt, r2 = launch.shape[0], self.slide_dt, 2 * self.radius
        c = launch.copy()
        b = s[:, :2]
        moving = launched & (np.linalg.norm(c[:, 2:], axis=1) > 0)
        near = np.zeros(n, dtype=bool)  # came within the threshold and hit
        passed = np.zeros(n, dtype=bool)  # came within the threshold and missed
        at = np.zeros((n, 4))
        steps = [c[:, :2].copy()]
        ends = np.full(n, -1)
        model = self.models["displacement"]
        for k in range(self.n_slide):
            if not moving.any():
                break
            new, moving2 = self._slide(c, moving, rng)
            if model is not None:
                rows = np.flatnonzero(moving & ~near & ~passed)
                hit, f = _segment_hit(
                    c[rows, :2] - b[rows], new[rows, :2] - b[rows], self.real_threshold
                )
                rows, f = rows[hit], f[hit][:, None]
                state = c[rows] + f * (new[rows] - c[rows])
                hits = model.draw_hits(np.column_stack([state[:, :2] - b[rows], state[:, 2:]]), rng)
                passed[rows[~hits]] = True
                rows = rows[hits]
                at[rows] = state[hits]
                near[rows] = True
                ends[rows] = k + 1
                moving2[rows] = False
                new[rows] = at[rows]
            c, moving = new, moving2
            steps.append(c[:, :2].copy())
        slid = np.stack(steps, 1)  # (n, K, 2), frame 0 = the launch
        disp = np.zeros((n, 4))  # no displacement model yet: no row came near (near is False)
        if model is not None:
            disp[near] = model.draw(np.column_stack([at[near, :2] - b[near], at[near, 2:]]), rng)
        n_pre = np.where(launched, np.round(t0 / dt).astype(int), 0)
        controls, targets, contact, index = [], [], np.zeros(n, bool), np.full(n, -1)
        for i in range(n):
            pre = np.tile(CONTROL_PUCK_START, (n_pre[i], 1))
            if not near[i]:
                controls.append(np.vstack([pre, slid[i]]))
                targets.append(np.tile(b[i], (len(controls[-1]), 1)))
                continue
            p, v = at[i, :2], at[i, 2:]
            speed = max(np.linalg.norm(v), 1e-6)
            u = v / speed
            rel = p - b[i]
            along = max(-rel @ u, 0.0)
            perp = np.linalg.norm(rel + along * u)
            touch = perp < r2 and along > 0
            if touch:
                along -= np.sqrt(r2**2 - perp**2)
            mid = p + max(along, 0.0) * u
            n1 = max(1, int(np.ceil(along / speed / dt)))
            leg1 = p + np.outer(np.arange(1, n1 + 1) / n1, mid - p)
            end_c, end_y = mid + disp[i, 2:] - (mid - p), b[i] + disp[i, :2]
            d2 = max(np.linalg.norm(end_c - mid), np.linalg.norm(end_y - b[i]))
            n2 = max(1, int(np.ceil(2 * d2 / speed / dt)))
            prof = 1 - (1 - np.arange(1, n2 + 1) / n2) ** 2
            head = np.vstack([pre, slid[i, : ends[i] + 1], leg1])
            controls.append(np.vstack([head, mid + np.outer(prof, end_c - mid)]))
            targets.append(
                np.vstack([np.tile(b[i], (len(head), 1)), b[i] + np.outer(prof, end_y - b[i])])
            )
            contact[i] = touch or model.kind == "hit_gp"
            index[i] = len(head) - 1
        K = max(len(p) for p in controls) + REST_FRAMES
        pc, pt = (
            np.stack([np.vstack([p, np.tile(p[-1], (K - len(p), 1))]) for p in ps])
            for ps in (controls, targets)
        )
        return pc, pt, contact, index

    def prediction_layers(self, context, omega, n_samples: int, rng=None) -> dict[str, dict]:
        """``{legend: {"trajectories": (L, T, 3), "color": (r, g, b)}}`` of one pair's predicted
        launch arrows (0.1 s) and puck paths before and after the contact, at :data:`PUCK_Z`."""
        s = check_array(context, "context", shape=(self.task.context_dim,))
        w = check_array(omega, "omega", shape=(self.task.parameter_dim,))
        p = self.predict(s[None], w[None], check_count(n_samples, "n_samples"), rng)
        c, y, idx = p.control[0], p.target[0], p.contact_index[0]
        K = c.shape[1]
        first = 0 if self.real else 1
        before, after_c, after_y = [], [], []
        for i in range(c.shape[0]):
            k = idx[i] if idx[i] >= 0 else K - 1
            before.append(
                np.vstack([c[i, first : k + 1], np.tile(c[i, k], (first + K - k - 1, 1))])
            )
            after_c.append(np.vstack([c[i, k:], np.tile(c[i, -1], (k, 1))]))
            after_y.append(np.vstack([y[i, k:], np.tile(y[i, -1], (k, 1))]))
        launch = p.launch[0]
        arrow = np.stack([launch[:, :2], launch[:, :2] + 0.1 * launch[:, 2:]], axis=1)

        def lift(xy: np.ndarray) -> np.ndarray:
            return np.concatenate([xy, np.full(xy.shape[:-1] + (1,), PUCK_Z)], axis=-1)

        after = "displacement model" if self.real else "contact model"
        layers = (
            (f"launch model: control puck at x={X_LAUNCH:.2f} m", arrow, (255, 140, 0)),
            ("sliding model: control puck", np.stack(before), (30, 120, 255)),
            (f"{after}: control puck after contact", np.stack(after_c), (120, 200, 255)),
            (f"{after}: target puck", np.stack(after_y), (220, 40, 40)),
        )
        return {name: {"trajectories": lift(xy), "color": rgb} for name, xy, rgb in layers}

    def __repr__(self) -> str:
        fitted = [k for k, m in self.models.items() if m is not None]
        state = f"fitted {fitted}, {self.n_data} sliding transitions" if fitted else "unfitted"
        setting = "real (observed tracks)" if self.real else "simulated"
        return (
            f"HockeyRewardModel(task={self.task.name!r}, {setting}, {state}, "
            f"slide_dt={self.slide_dt:.4g}, x_launch={X_LAUNCH:g})"
        )
