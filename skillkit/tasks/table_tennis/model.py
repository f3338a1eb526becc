r"""The decomposed reward model of robot table tennis (Sec. 4.3.4, Fig. 4.13, App. C.3).

Five learned models chained as in Sec. 4.3.4: 1. **landing** (GP): v = s[:3] ↦ the bounce
[p_x, p_y, v⁻ (3), v⁺ (3), t_b] on the robot's half (:func:`find_bounce`), before it the
cubic Hermite curve from the serve; 2. **bounce trajectory** (GP): [p_x, p_y, v⁺] ↦ c (3 × 3)
of p(t_b + τ) = p_b + v⁺ τ + ½ g τ² + Σ_{m=2}^{4} c_m τ^m; 3. **racket position** and
4. **orientation** (quaternion of the blade normal): GPs ω ↦ the PCA scores of W in
y(t) ≈ Φ(t) W (:class:`TimeBasis`); 5. **contact** (:class:`ContactModel`): a linear SVM for
hit / miss and a GP for the returned ball's landing point, read at :func:`contact_event`.
The reward schedule (Eq. 4.17) is :class:`TableTennisRewardModel`'s.
"""

from __future__ import annotations

import time
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
    refit_gp,
    set_factories,
    worst_if_nonfinite,
)
from skillkit.tasks.table_tennis import (
    SERVE_POSITION,
    TABLE_HEIGHT,
    TABLE_LENGTH,
    TABLE_WIDTH,
    TableTennis,
)

REFERENCE_NORMAL = np.array([1.0, 0.0, 0.0])
"""Racket normal of the identity quaternion (+x; the shortest arc is singular at −x)."""

CONTACT_SCORES = ("probability", "decision", "margin")
"""How a sampled path's contact enters its reward (:meth:`ContactModel.weights`)."""


class TimeBasis:
    r"""Normalised Gaussian basis functions φ_i(t) = b_i(t) / Σ_j b_j(t) (Sec. 4.3.4),
    b_i(t) = exp(−(t − μ_i)² / (2 h²)), centres μ_i evenly over [0, t_end], h their spacing.

    Parameters
    ----------
    n_basis : int
        Number of basis functions per dimension (40 in the thesis).
    t_end : float
        End of the execution time (s).
    """

    ridge = 1e-10
    """λ of the least-squares fit W = (ΦᵀΦ + λI)⁻¹ Φᵀ Y."""

    def __init__(self, n_basis: int = 40, t_end: float = 1.2):
        self.n_basis = check_count(n_basis, "n_basis", 2)
        self.t_end = check_positive(t_end, "t_end")
        self.centres = np.linspace(0.0, self.t_end, self.n_basis)
        self.width = self.centres[1] - self.centres[0]

    def __call__(self, times) -> np.ndarray:
        """Φ(t), shape (T, n_basis); rows sum to one."""
        t = check_array(times, "times", ndim=1)
        b = np.exp(-0.5 * ((t[:, None] - self.centres[None, :]) / self.width) ** 2)
        return b / b.sum(axis=1, keepdims=True)

    def fit(self, times, values) -> np.ndarray:
        """Least-squares weights W (n_basis, D) of values (T, D) sampled at times (T,)."""
        phi = self(times)
        y = check_array(values, "values", shape=(phi.shape[0], None))
        return np.linalg.solve(phi.T @ phi + self.ridge * np.eye(self.n_basis), phi.T) @ y

    def __repr__(self) -> str:
        return f"TimeBasis(n_basis={self.n_basis}, t_end={self.t_end:g}, width={self.width:.4g})"


def normal_to_quaternion(normals) -> np.ndarray:
    r"""Shortest-arc rotation q = normalise([1 + r·n, r × n]) = [w, x, y, z] taking
    :data:`REFERENCE_NORMAL` r to n; (..., 3) → (..., 4), w ≥ 0."""
    n = np.asarray(normals, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    r = np.broadcast_to(REFERENCE_NORMAL, n.shape)
    q = np.concatenate([1.0 + np.sum(r * n, axis=-1, keepdims=True), np.cross(r, n)], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_to_normal(quaternions) -> np.ndarray:
    """The racket normal R(q) r of (possibly unnormalised) quaternions, (..., 4) → (..., 3)."""
    q = np.asarray(quaternions, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1)


def max_target_distance(task: TableTennis) -> float:
    """P = max ‖b − p‖ over return-zone targets b and table points p (at corners)."""
    lo, hi = task.context_low[3:5], task.context_high[3:5]
    targets = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    hx, hy = 0.5 * TABLE_LENGTH, 0.5 * TABLE_WIDTH
    table = np.array([[x, y] for x in (-hx, hx) for y in (-hy, hy)])
    return float(np.max(np.linalg.norm(targets[:, None] - table[None], axis=-1)))


def find_bounce(times, ball, plane: float, t_end: float, n_fit: int = 7) -> np.ndarray | None:
    """The incoming ball's bounce [p_x, p_y, v⁻ (3), v⁺ (3), t_b] (9,) from ``times`` (T,)
    and ``ball`` (T, 3), or None without enough samples.

    Quadratics in t fitted to the ``n_fit`` samples before and after the lowest sample over
    the robot's half before ``t_end``; t_b solves z_pre(t) = ``plane``, v∓ their slopes there.
    """
    keep = (times < t_end) & (ball[:, 0] >= -0.5 * TABLE_LENGTH) & (ball[:, 0] <= 0.0)
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        return None
    j = int(idx[np.argmin(ball[idx, 2])])
    n_inc = int(np.sum(times < t_end))
    if j - n_fit - 1 < 0 or j + n_fit + 1 >= n_inc:
        return None
    pre = slice(j - n_fit - 1, j - 1)
    post = slice(j + 2, j + n_fit + 2)
    c_pre = np.polyfit(times[pre], ball[pre], 2)  # (3, 3): rows t², t, 1
    c_post = np.polyfit(times[post], ball[post], 2)
    a, b, c = c_pre[:, 2]
    roots = np.roots([a, b, c - plane])
    roots = roots[np.isreal(roots)].real
    lo, hi = times[j - 1] - 1e-9, times[j + 1] + 1e-9
    roots = roots[(roots >= lo) & (roots <= hi)]
    if roots.size == 0:
        return None
    tb = float(roots.min())
    p = c_pre[0] * tb**2 + c_pre[1] * tb + c_pre[2]
    v_pre, v_post = 2 * c_pre[0] * tb + c_pre[1], 2 * c_post[0] * tb + c_post[1]
    return np.concatenate([p[:2], v_pre, v_post, [tb]])


def _hermite(t, t1, p0, v0, p1, v1):
    """Cubic Hermite curve on [0, t1]: t (T,), t1 (n,), p/v (n, 3) → (n, T, 3)."""
    u = np.clip(t[None, :] / t1[:, None], 0.0, 1.0)[..., None]
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    d = t1[:, None, None]
    return h00 * p0[:, None] + h10 * d * v0[:, None] + h01 * p1[:, None] + h11 * d * v1[:, None]


def _backward_velocity(paths: np.ndarray, k: np.ndarray, dt: float) -> np.ndarray:
    """(p_k − p_{k−1}) / dt of paths (n, T, 3) at k (n,) (forward at k = 0)."""
    k0 = np.maximum(k, 1)
    rows = np.arange(paths.shape[0])
    return (paths[rows, k0] - paths[rows, k0 - 1]) / dt


class _ScoresGP:
    """A GP from inputs to the PCA scores of many correlated outputs: at most
    ``max_components``, the variance fraction dropped at most ``tolerance``."""

    tolerance, max_components = 1e-6, 20

    def __init__(self, make_gp: Callable[[], Any]):
        self.make_gp, self.gp = make_gp, None

    def fit(self, x, y, rng, previous=None, refit: str = "best") -> dict[str, Any]:
        """PCA of y (N, D), a GP x ↦ the k kept scores (:func:`refit_gp`); the refit record."""
        self.mean = y.mean(axis=0)
        u, sv, vt = np.linalg.svd(y - self.mean, full_matrices=False)
        var = sv**2
        frac = np.cumsum(var) / max(var.sum(), 1e-300)
        k = int(np.searchsorted(frac, 1.0 - self.tolerance) + 1)
        k = max(1, min(k, self.max_components, vt.shape[0]))
        self.components = vt[:k]  # (k, D)
        scores = (y - self.mean) @ self.components.T
        if previous is not None and np.shape(previous["lengthscale"])[0] != k:
            previous = None
        self.gp, record = refit_gp(self.make_gp, x, scores, rng, previous, refit)
        return record

    def sample(self, x, L: int, rng) -> np.ndarray:
        """Sampled outputs (B, L, D)."""
        return self.mean + _sample_gp(self.gp, x, L, rng) @ self.components

    def mean_prediction(self, x) -> np.ndarray:
        m, _ = self.gp.predict(x)
        return self.mean + m.reshape(x.shape[0], -1) @ self.components


def _gp(n_steps: int = 150) -> ExactGP:
    return ExactGP(n_steps=n_steps)


def _linear_svm():
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    return make_pipeline(StandardScaler(), SVC(kernel="linear", C=1.0))


class _Constant:
    def __init__(self, label: bool):
        self.label = bool(label)

    def predict(self, x):
        return np.full(np.asarray(x).shape[0], self.label)

    def decision_function(self, x):
        return np.full(np.asarray(x).shape[0], 1.0 if self.label else -1.0)


def contact_event(ball, racket, quaternion, steps, ball_radius: float):
    r"""Where model 5 reads its inputs, one rule for real and predicted paths (Sec. 4.3.4).

    ``cut`` is the first sample at or behind the racket face: the signed distance
    (p_b − p_r)·n_k less the ball radius changes from > 0 to ≤ 0 (``steps`` if never); the
    ``event`` is the sample of least ball–racket distance before it. ``ball``, ``racket``
    (n, T, 3), ``quaternion`` (n, T, 4), the first ``steps`` (n,) samples the incoming ball.
    Returns ``event``, ``cut`` (1 ≤ cut ≤ steps) and the distance at the event (m), each (n,).
    """
    ball = check_array(ball, "ball", shape=(None, None, 3), finite=False)
    racket = check_array(racket, "racket", shape=ball.shape, finite=False)
    n, T, _ = ball.shape
    quaternion = check_array(quaternion, "quaternion", shape=(n, T, 4), finite=False)
    steps = np.asarray(steps)
    if steps.shape != (n,) or np.any(steps < 1) or np.any(steps > T):
        raise ValueError(f"steps: expected {n} whole numbers in [1, {T}], got {steps!r:.80}")
    steps = steps.astype(np.int64)
    normal = quaternion_to_normal(quaternion)
    g = np.sum((ball - racket) * normal, axis=-1)  # (n, T) centre to face plane
    side = np.where(g[:, :-1] >= 0.0, 1.0, -1.0)
    reach = (side * g[:, :-1] - ball_radius > 0.0) & (side * g[:, 1:] - ball_radius <= 0.0)
    reach &= np.arange(1, T)[None, :] < steps[:, None]  # sample k is still incoming
    cut = np.where(reach.any(axis=1), reach.argmax(axis=1) + 1, steps)
    d = np.linalg.norm(ball - racket, axis=-1)
    d = np.where(np.arange(T)[None, :] < cut[:, None], d, np.inf)
    event = np.argmin(d, axis=1)
    return event, cut, d[np.arange(n), event]


class ContactModel:
    r"""Model 5 of Sec. 4.3.4: a linear SVM for hit / miss on :meth:`inputs` and a GP inputs
    ↦ the returned ball's landing point p (2), fitted on the hits.

    Parameters
    ----------
    dt, ball_radius : float
        Control period (s) of the velocities; ball radius (m).
    features : {"thesis", "extended"}
        [v_ball − v_racket (3), racket position (3), quaternion (4)]; "extended" adds the
        ball's position relative to the racket (3) and its norm.
    score : {"probability", "decision", "margin"}
        The contact weight w ∈ [0, 1] in the reward (:meth:`weights`): the Platt-calibrated
        hit probability, the hard decision, or clip((1 + f) / 2, 0, 1) of the SVM value f.
    make_classifier, make_return_model : callable
        An unfitted scikit-learn classifier with ``decision_function``; a GP regression.
    refit : {"cold", "warm", "best"}
        How the landing GP is refitted (:func:`refit_gp`).
    """

    def __init__(
        self,
        dt: float,
        ball_radius: float,
        features: str = "thesis",
        score: str = "probability",
        make_classifier: Callable[[], Any] | None = None,
        make_return_model: Callable[[], Any] | None = None,
        refit: str = "best",
    ):
        self.features = check_choice(features, "contact_features", ("thesis", "extended"))
        self.score = check_choice(score, "contact_score", CONTACT_SCORES)
        self.dt = check_positive(dt, "dt")
        self.ball_radius = check_positive(ball_radius, "ball_radius")
        self.make_classifier = make_classifier or _linear_svm
        self.make_return_model = make_return_model or _gp
        self.refit = check_refit(refit)
        self.classifier: Any = None
        self.calibrated: Any = None
        self.returns: Any = None
        self._hypers: dict[str, np.ndarray] | None = None

    @property
    def n_features(self) -> int:
        """10 ("thesis") or 14 ("extended")."""
        return 10 if self.features == "thesis" else 14

    def inputs(self, ball, racket, quaternion, steps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inputs x (n, 10 or 14) at :func:`contact_event`'s event, with ``event``, ``cut``."""
        event, cut, dist = contact_event(ball, racket, quaternion, steps, self.ball_radius)
        rows = np.arange(event.shape[0])
        rel = _backward_velocity(ball, event, self.dt) - _backward_velocity(racket, event, self.dt)
        parts = [rel, racket[rows, event], np.asarray(quaternion)[rows, event]]
        if self.features == "extended":
            parts += [ball[rows, event] - racket[rows, event], dist[:, None]]
        return np.hstack(parts), event, cut

    def fit(self, x, hit, p, rng) -> dict[str, Any]:
        """Fit the classifier on x (N, d), hit (N,) and the landing GP on the hits' p (N, 2);
        ``{"n_hits", "calibration_folds", "returns_refit"}``."""
        x = check_array(x, "x", shape=(None, self.n_features))
        hit = np.asarray(hit, dtype=bool)
        p = check_array(p, "p", shape=(x.shape[0], 2))
        if hit.shape != (x.shape[0],):
            raise ValueError(f"hit: expected shape {(x.shape[0],)}, got {hit.shape}")
        n_hit, n_miss = int(hit.sum()), int((~hit).sum())
        folds = min(5, n_hit, n_miss)
        self.calibrated = None
        if n_hit == 0 or n_miss == 0:
            self.classifier = _Constant(bool(hit[0]))
        else:
            self.classifier = self.make_classifier().fit(x, hit)
            if self.score == "probability" and folds >= 2:
                from sklearn.calibration import CalibratedClassifierCV

                self.calibrated = CalibratedClassifierCV(
                    self.make_classifier(), method="sigmoid", cv=folds
                ).fit(x, hit)
        stats: dict[str, Any] = {"n_hits": n_hit, "calibration_folds": folds}
        self.returns = None
        if n_hit >= 2:
            prev = self._hypers
            if prev is not None and np.shape(prev["lengthscale"]) != (2, x.shape[1]):
                prev = None
            self.returns, stats["returns_refit"] = refit_gp(
                self.make_return_model, x[hit], p[hit], rng, prev, self.refit
            )
            if isinstance(self.returns, GPRegression):
                self._hypers = self.returns.hyperparameters
        return stats

    def weights(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Contact weights w ∈ [0, 1] (0 without a landing model), the SVM's decisions and its
        decision values f (> 0: hit) of inputs x (n, d), each (n,)."""
        if self.classifier is None:
            raise RuntimeError("ContactModel: call fit() before weights()")
        decision = np.asarray(self.classifier.predict(x), dtype=bool)
        margin = np.asarray(self.classifier.decision_function(x), dtype=np.float64)
        if self.score == "probability" and self.calibrated is not None:
            weight = self.calibrated.predict_proba(x)[:, list(self.calibrated.classes_).index(True)]
        elif self.score == "margin":
            weight = np.clip(0.5 * (1.0 + margin), 0.0, 1.0)
        else:
            weight = decision.astype(np.float64)
        if self.returns is None:
            return np.zeros(len(decision)), np.zeros(len(decision), dtype=bool), margin
        return np.asarray(weight, dtype=np.float64), decision, margin

    def __repr__(self) -> str:
        return f"ContactModel(features={self.features!r}, score={self.score!r})"


@dataclass(frozen=True)
class TableTennisPrediction(Prediction):
    """L predicted strokes for each of B (ω, s) pairs.

    ``times`` (T,) the control times; the incoming ``ball`` and ``racket`` centre (B, L, T, 3);
    ``quaternion`` (B, L, T, 4) the unit racket orientation; ``bounce`` (B, L, 9) the sampled
    bounce; ``closest`` (B, L) min‖τ_b − τ_r‖ (m); ``contact``, ``margin`` (B, L) the SVM's
    decision and value; ``landing`` (B, L, 2) the returned ball's sampled landing point (NaN
    at contact weight 0); ``rewards`` (B, L) Eq. (4.17) in ``stage``; ``contact_score`` and
    ``face`` (B, L) the contact weight and :func:`contact_event`'s ``cut``.
    """

    times: np.ndarray
    ball: np.ndarray
    racket: np.ndarray
    quaternion: np.ndarray
    bounce: np.ndarray
    closest: np.ndarray
    contact: np.ndarray
    margin: np.ndarray
    landing: np.ndarray
    rewards: np.ndarray
    stage: str
    contact_score: np.ndarray | None = None
    face: np.ndarray | None = None

    def __repr__(self) -> str:
        B, L, T, _ = self.ball.shape
        r = self.expected_rewards
        return (
            f"TableTennisPrediction(pairs={B}, trajectories={L}, steps={T}, stage={self.stage!r}, "
            f"expected_reward={r.min():.4g}…{r.max():.4g}, contacts={int(self.contact.sum())}, "
            f"closest_median={np.median(self.closest):.3g} m)"
        )


class TableTennisRewardModel(RewardModel):
    r"""Decomposed GPREPS reward model of :class:`~skillkit.tasks.table_tennis.TableTennis`.

    Reward schedule of Eq. (4.17): **hitting** R = −c₁ min‖τ_b − τ_r‖ − ε c₁ ‖b − p‖ − c₁ P,
    P = :func:`max_target_distance` (below every returning reward); **returning** the task's
    R = −c₁ min‖τ_b − τ_r‖ − c₂ ‖b − p‖. A sampled path of contact weight w has
    ‖b − p‖ = w ‖b − p̂‖ + (1 − w) P. With ``schedule="auto"`` the stage switches to
    "returning" for good at the first :meth:`fit` with ≥ ``min_hits`` hits and misses, a
    5-fold balanced SVM accuracy ≥ ``min_svm_accuracy`` and a landing RMSE ≤
    ``max_landing_rmse`` (m).

    Parameters
    ----------
    task : TableTennis
    make_landing_model, make_bounce_model, make_racket_model, make_return_model : callable
        Unfitted GP regressions (default ``ExactGP()``) of models 1, 2, 3–4 and 5.
    make_classifier : callable
        An unfitted scikit-learn classifier (default: standardised linear SVC).
    schedule : {"auto", "hitting", "returning"}
        Reward stage; "hitting"/"returning" force it.
    contact_features, contact_score : str
        Inputs and reward weight of model 5 (:class:`ContactModel`).
    epsilon, min_hits, min_svm_accuracy, max_landing_rmse
        ε of the hitting stage; the "good contact model" criterion of ``schedule="auto"``.
    n_basis : int
        Basis functions per racket dimension (40 in the thesis).
    max_points : int
        Each GP is fitted on at most this many rollouts (random subset).
    refit : {"cold", "warm", "best"}
        Where each GP's hyper-parameter optimisation starts (:func:`refit_gp`).
    device : str or torch.device, optional
        Where the sampled racket paths Φ W are assembled (float64).
    """

    def __init__(
        self,
        task: TableTennis,
        make_landing_model: Callable[[], Any] | None = None,
        make_bounce_model: Callable[[], Any] | None = None,
        make_racket_model: Callable[[], Any] | None = None,
        make_return_model: Callable[[], Any] | None = None,
        make_classifier: Callable[[], Any] | None = None,
        schedule: str = "auto",
        contact_features: str = "thesis",
        contact_score: str = "probability",
        epsilon: float = 1e-3,
        min_hits: int = 15,
        min_svm_accuracy: float = 0.8,
        max_landing_rmse: float = 0.3,
        n_basis: int = 40,
        max_points: int = 400,
        refit: str = "best",
        device=None,
    ):
        check_type(task, TableTennis, "task", "a TableTennis task")
        set_factories(
            self,
            make_landing_model=(make_landing_model, _gp),
            make_bounce_model=(make_bounce_model, _gp),
            make_racket_model=(make_racket_model, _gp),
            make_return_model=(make_return_model, _gp),
            make_classifier=(make_classifier, _linear_svm),
        )
        self.task = task
        self.schedule = check_choice(schedule, "schedule", ("auto", "hitting", "returning"))
        self.refit = check_refit(refit)
        scene = (task.control_dt, task.ball.radius, contact_features, contact_score)
        self.contact = ContactModel(
            *scene, self.make_classifier, self.make_return_model, self.refit
        )
        self.stage = "returning" if schedule == "returning" else "hitting"
        self.epsilon = check_positive(epsilon, "epsilon", allow_zero=True)
        self.min_hits = check_count(min_hits, "min_hits", 2)
        self.min_svm_accuracy = check_positive(min_svm_accuracy, "min_svm_accuracy")
        self.max_landing_rmse = check_positive(max_landing_rmse, "max_landing_rmse")
        self.basis = TimeBasis(n_basis, float(task.times[-1]))
        self.max_points = check_count(max_points, "max_points", 2)
        self.device = device
        self.penalty = max_target_distance(task)
        self.plane = TABLE_HEIGHT + task.ball.radius
        self.landing: Any = None
        self.bounce: Any = None
        self.racket_position: _ScoresGP | None = None
        self.racket_orientation: _ScoresGP | None = None
        self._hypers: dict[str, dict | None] = dict.fromkeys(
            ("landing", "bounce", "position", "orientation")
        )
        self.n_data = 0

    def bounce_data(self, trajectories) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """Bounces y (n, 9) (:func:`find_bounce`), the least-squares coefficients c (n, 9) of
        the flight after them, and the indices of the trajectories with a bounce."""
        task = self.task
        t = task.times
        g = np.array([0.0, 0.0, -task.ball.gravity])
        ys, cs, used = [], [], []
        for i, tr in enumerate(trajectories):
            ball = tr.signals["ball"]
            t_end = min(tr.info["incoming_end"], tr.info["landing_time"])
            y = find_bounce(t, ball, self.plane, t_end)
            if y is None:
                continue
            tb, pb = y[8], np.array([y[0], y[1], self.plane])
            k = (t > tb) & (t < t_end)
            if k.sum() < 5:
                continue
            tau = t[k] - tb
            resid = ball[k] - pb - np.outer(tau, y[5:8]) - 0.5 * np.outer(tau**2, g)
            design = np.stack([tau**2, tau**3, tau**4], axis=1)
            coef, *_ = np.linalg.lstsq(design, resid, rcond=None)
            ys.append(y)
            cs.append(coef.ravel())
            used.append(i)
        return np.array(ys).reshape(-1, 9), np.array(cs).reshape(-1, 9), used

    def _real_contact_data(self, trajectories):
        """Model 5's inputs x, labels hit (N,) and landing points p (N, 2) of rollouts."""
        t = self.task.times
        ball = np.stack([tr.signals["ball"] for tr in trajectories])
        racket = np.stack([tr.signals["racket"] for tr in trajectories])
        quat = normal_to_quaternion(np.stack([tr.signals["racket_normal"] for tr in trajectories]))
        steps = np.array(
            [int(np.searchsorted(t, tr.info["incoming_end"], side="right")) for tr in trajectories]
        )
        x, _, _ = self.contact.inputs(ball, racket, quat, np.maximum(steps, 1))
        hit = np.array([bool(tr.info["hit"]) for tr in trajectories])
        p = np.array([tr.info["landing_point"] for tr in trajectories], dtype=np.float64)
        return x, hit, p

    def fit(self, contexts, omegas, rewards, trajectories, rng=None) -> dict[str, Any]:
        """Refit the five models on every non-failed rollout and update the reward stage
        (``rewards`` unused). Returns ``n_data``, ``n_bounces``, ``n_hits``, ``stage``, the
        schedule's ``criterion``, ``pca_components``, per GP its :func:`gp_stats`, the
        ``refit`` records, ``calibration_folds`` and ``fit_seconds``."""
        t0 = time.perf_counter()
        task = self.task
        if trajectories is None:
            raise ValueError("trajectories: the table-tennis model learns from trajectories")
        s = check_array(contexts, "contexts", shape=(None, task.context_dim))
        w = check_array(omegas, "omegas", shape=(s.shape[0], task.parameter_dim))
        if len(trajectories) != len(s):
            raise ValueError(f"trajectories: expected {len(s)}, got {len(trajectories)}")
        keep = np.flatnonzero([not tr.failed for tr in trajectories])
        if len(keep) < 2:
            raise ValueError("trajectories: fewer than two non-failed rollouts to learn from")
        rng = as_generator(rng)
        keep = keep[np.sort(rng.permutation(len(keep))[: self.max_points])]
        trajs, s, w = [trajectories[i] for i in keep], s[keep], w[keep]
        stats: dict[str, Any] = {"n_data": len(trajs), "n_trajectories": len(trajs)}

        # models 1, 2: landing and bounce trajectory
        refits: dict[str, Any] = {}
        yb, cb, used = self.bounce_data(trajs)
        if len(used) < 2:
            raise ValueError("trajectories: fewer than two incoming-ball bounces were found")
        for key, x, y in (("landing", s[used, :3], yb), ("bounce", yb[:, [0, 1, 5, 6, 7]], cb)):
            gp, refits[key] = self._refit(key, getattr(self, f"make_{key}_model"), x, y, rng)
            setattr(self, key, gp)
        stats["n_bounces"] = len(used)

        # models 3, 4: racket position and orientation, from the basis weights of each path
        paths = {
            "position": [tr.signals["racket"] for tr in trajs],
            "orientation": [normal_to_quaternion(tr.signals["racket_normal"]) for tr in trajs],
        }
        stats["pca_components"] = {}
        for key, ys in paths.items():
            target = np.stack([self.basis.fit(task.times, y).ravel() for y in ys])
            model = _ScoresGP(self.make_racket_model)
            refits[key] = model.fit(w, target, rng, self._hypers[key], self.refit)
            if isinstance(model.gp, GPRegression):
                self._hypers[key] = model.gp.hyperparameters
            setattr(self, f"racket_{key}", model)
            stats["pca_components"][key] = int(model.components.shape[0])

        # model 5: contact classifier and returned landing point
        x, hit, p = self._real_contact_data(trajs)
        contact_stats = self.contact.fit(x, hit, p, rng)
        if "returns_refit" in contact_stats:
            refits["returns"] = contact_stats["returns_refit"]
        stats["calibration_folds"] = contact_stats["calibration_folds"]
        stats["n_hits"] = int(hit.sum())
        crit = self._criterion(x, hit, p, rng)
        stats["criterion"] = crit
        if self.schedule == "auto" and crit["good"]:
            self.stage = "returning"
        stats["stage"] = self.stage
        stats["refit"] = refits
        for key, model in (
            ("landing", self.landing),
            ("bounce", self.bounce),
            ("racket_position", self.racket_position.gp),
            ("racket_orientation", self.racket_orientation.gp),
            ("returns", self.contact.returns),
        ):
            if isinstance(model, GPRegression):
                stats[key] = gp_stats(model, model.X.shape[0])
        self.n_data = len(trajs)
        stats["fit_seconds"] = time.perf_counter() - t0
        return stats

    def _criterion(self, x, hit, p, rng) -> dict[str, Any]:
        """The "good contact model" test of ``schedule="auto"`` (see the class docstring)."""
        n_hit, n_miss = int(hit.sum()), int((~hit).sum())
        crit: dict[str, Any] = {
            "n_hits": n_hit,
            "n_misses": n_miss,
            "majority_rate": float(max(n_hit, n_miss) / hit.size),
            "svm_cv_accuracy": None,
            "svm_cv_balanced_accuracy": None,
            "landing_cv_rmse": None,
            "min_hits": self.min_hits,
            "min_svm_accuracy": self.min_svm_accuracy,
            "max_landing_rmse": self.max_landing_rmse,
            "good": False,
        }
        if n_hit < self.min_hits or n_miss < self.min_hits:
            return crit
        from sklearn.model_selection import StratifiedKFold, cross_val_predict

        folds = StratifiedKFold(5, shuffle=True, random_state=int(rng.integers(2**31)))
        guess = cross_val_predict(self.make_classifier(), x, hit, cv=folds)
        acc = float(np.mean(guess == hit))
        bal = float(0.5 * (np.mean(guess[hit]) + np.mean(~guess[~hit])))
        crit["svm_cv_accuracy"], crit["svm_cv_balanced_accuracy"] = acc, bal
        xh, ph = x[hit], p[hit]
        err = []
        for train, test in StratifiedKFold(5, shuffle=True, random_state=0).split(
            xh, np.zeros(len(xh))
        ):
            gp = self.make_return_model().fit(xh[train], ph[train], rng)
            err.append(np.sum((gp.predict(xh[test])[0] - ph[test]) ** 2, axis=1))
        rmse = float(np.sqrt(np.mean(np.concatenate(err))))
        crit["landing_cv_rmse"] = rmse
        crit["good"] = bool(bal >= self.min_svm_accuracy and rmse <= self.max_landing_rmse)
        return crit

    def predict(self, contexts, omegas, n_trajectories: int, rng=None) -> TableTennisPrediction:
        """Sample L = ``n_trajectories`` strokes for each of B pairs, contexts (B, 5) and omegas
        (B, 17), through the five models."""
        w, s, L, rng = self._pairs(self.landing is not None, contexts, omegas, n_trajectories, rng)
        task = self.task
        B, t = w.shape[0], task.times
        T, n = t.shape[0], B * L
        device = torch.device("cpu" if self.device is None else self.device)

        # model 1: the bounce (sampled), model 2: the flight after it
        yb = _sample_gp(self.landing, s[:, :3], L, rng).reshape(n, 9)
        tb = np.clip(yb[:, 8], 1e-3, None)
        pb = np.column_stack([yb[:, :2], np.full(n, self.plane)])
        coef = _sample_gp(self.bounce, np.hstack([yb[:, :2], yb[:, 5:8]]), 1, rng).reshape(n, 3, 3)
        tau = np.clip(t[None, :] - tb[:, None], 0.0, None)  # (n, T)
        g = np.array([0.0, 0.0, -task.ball.gravity])
        powers = np.stack([tau**2, tau**3, tau**4], axis=-1)  # (n, T, 3)
        after = (
            pb[:, None]
            + tau[..., None] * yb[:, None, 5:8]
            + 0.5 * tau[..., None] ** 2 * g
            + np.einsum("ntm,nmd->ntd", powers, coef)
        )
        p0 = np.broadcast_to(SERVE_POSITION, (n, 3))
        v0 = np.repeat(s[:, :3], L, axis=0)
        before = _hermite(t, tb, p0, v0, pb, yb[:, 2:5])
        ball = np.where((t[None, :] < tb[:, None])[..., None], before, after)
        # the incoming ball ends where it falls through the table plane again (behind the robot)
        below = (t[None, :] > tb[:, None] + 0.05) & (ball[..., 2] < self.plane)
        steps = np.where(below.any(axis=1), below.argmax(axis=1) + 1, T)

        # models 3, 4: racket position and orientation, Φ(t) W
        phi = torch.as_tensor(self.basis(t), dtype=torch.float64, device=device)
        nb = self.basis.n_basis

        def paths(model, dims):
            wts = torch.as_tensor(model.sample(w, L, rng), dtype=torch.float64, device=device)
            return (phi @ wts.reshape(n, nb, dims)).cpu().numpy()

        racket = paths(self.racket_position, 3)
        quat = paths(self.racket_orientation, 4)
        quat /= np.linalg.norm(quat, axis=-1, keepdims=True)

        # model 5: contact and return, read where the ball reaches the racket face
        cm = self.contact
        x, _, face = cm.inputs(ball, racket, quat, steps)
        weight, contact, margin = cm.weights(x)
        landing = np.full((n, 2), np.nan)
        some = weight > 0
        if some.any():
            landing[some] = _sample_gp(cm.returns, x[some], 1, rng).reshape(-1, 2)
        # the incoming ball counts up to its first sample at the face (the task: up to the
        # first sample after a hit)
        incoming = np.minimum(steps, face + 1)
        rewards, closest = self._rewards(ball, racket, incoming, landing, weight, s, L)
        rewards = worst_if_nonfinite(rewards, task, "TableTennisRewardModel.predict")
        arrays = (ball, racket, quat, yb, closest, contact, margin, landing, rewards)
        shaped = [a.reshape(B, L, *a.shape[1:]) for a in arrays]
        extra = (weight.reshape(B, L), face.reshape(B, L))
        return TableTennisPrediction(t.copy(), *shaped, self.stage, *extra)

    def _rewards(self, ball, racket, steps, landing, weight, s, L):
        """Eq. (4.17) of the current stage with ‖b − p‖ = w ‖b − p̂‖ + (1 − w) P for contact
        weights w (n,); returns rewards (n,) and min‖τ_b − τ_r‖ (n,)."""
        task = self.task
        c1, c2 = task.reward_weights
        ctx = np.repeat(s, L, axis=0)
        b = ctx[:, 3:5]
        # the task's own reward with p = b isolates −c₁ min‖τ_b − τ_r‖
        signals = {"ball": ball, "racket": racket, "landing_point": b, "incoming_steps": steps}
        hitting = task.reward_batch(None, None, signals, ctx)
        closest = -hitting / c1 if c1 > 0 else np.full(ball.shape[0], np.nan)
        returned = np.linalg.norm(np.nan_to_num(landing) - b, axis=1)
        dist = np.where(weight > 0, weight * returned + (1.0 - weight) * self.penalty, self.penalty)
        if self.stage == "hitting":
            return hitting - self.epsilon * c1 * dist - c1 * self.penalty, closest
        return hitting - c2 * dist, closest

    def heldout_errors(self, contexts, omegas, trajectories, n_samples: int, rng=None) -> dict:
        """Each model's error on held-out rollouts (Fig. 4.13), ``n_samples`` strokes per pair.

        Returns the medians ``bounce_position_error_m``, ``incoming_path_error_m`` (largest
        gap of the mean predicted ball) and ``return_landing_error_m``, the
        ``racket_position_rmse_m``, the SVM's ``contact_accuracy`` on recorded and
        (``contact_accuracy_predicted``, majority vote) predicted paths,
        ``contact_majority_rate``, ``n_hits`` and ``n_pairs``.
        """
        if self.landing is None:
            raise RuntimeError("TableTennisRewardModel: call fit() before heldout_errors()")
        trajs = list(trajectories)
        w = check_array(omegas, "omegas", shape=(len(trajs), self.task.parameter_dim))
        rng = as_generator(rng)
        pred = self.predict(contexts, w, n_samples, rng)  # checks the contexts
        bounce_err, path_err = [], []
        t = self.task.times
        for i, tr in enumerate(trajs):
            end = min(tr.info["incoming_end"], tr.info["landing_time"])
            y = find_bounce(t, tr.signals["ball"], self.plane, end)
            if y is not None:
                bounce_err += np.linalg.norm(pred.bounce[i, :, :2] - y[:2], axis=1).tolist()
            k = t < tr.info["incoming_end"]
            gap = pred.ball[i].mean(axis=0)[k] - tr.signals["ball"][k]
            path_err.append(float(np.linalg.norm(gap, axis=1).max()) if k.any() else np.nan)
        real_racket = np.stack([tr.signals["racket"] for tr in trajs])
        rmse = float(np.sqrt(np.mean(np.sum((pred.racket - real_racket[:, None]) ** 2, -1))))
        x, hit, p = self._real_contact_data(trajs)
        decided = np.asarray(self.contact.classifier.predict(x), dtype=bool)
        predicted_hit = pred.contact.mean(axis=1) > 0.5
        landing_err = np.nan
        if self.contact.returns is not None and hit.any():
            mean, _ = self.contact.returns.predict(x[hit])
            landing_err = float(np.median(np.linalg.norm(mean - p[hit], axis=1)))
        return {
            "bounce_position_error_m": float(np.median(bounce_err)) if bounce_err else np.nan,
            "incoming_path_error_m": float(np.nanmedian(path_err)),
            "racket_position_rmse_m": rmse,
            "contact_accuracy": float(np.mean(decided == hit)),
            "contact_majority_rate": float(max(hit.mean(), 1.0 - hit.mean())),
            "contact_accuracy_predicted": float(np.mean(predicted_hit == hit)),
            "return_landing_error_m": landing_err,
            "n_hits": int(hit.sum()),
            "n_pairs": len(trajs),
        }

    def prediction_layers(self, context, omega, n_samples: int, rng=None) -> dict[str, dict]:
        """Fig. 4.13's layers of one pair, ``{legend: {"trajectories": (L', T', 3), "color":
        (r, g, b), "times"?: (T',)}}``: the incoming ball (stopped at the face on a predicted
        contact), the racket centre and the returned landing points as diamonds."""
        s = self.task.check_context(context)
        w = self.task.check_omega(omega)
        pred = self.predict(s[None], w[None], check_count(n_samples, "n_samples"), rng)
        ball = pred.ball[0].copy()
        for i in np.flatnonzero(pred.contact[0]):
            last = max(int(pred.face[0, i]) - 1, 0)
            ball[i, last + 1 :] = ball[i, last]
        r = 0.025
        diamond = np.array([[r, 0, 0], [0, r, 0], [-r, 0, 0], [0, -r, 0], [r, 0, 0]])
        pts = pred.landing[0][pred.contact[0]]
        centres = np.column_stack([pts, np.full(len(pts), self.plane)])
        layers = {
            "landing+bounce models: incoming ball": (ball, (0, 0, 0)),
            "racket models: racket centre": (pred.racket[0], (0, 0, 255)),
            "contact model: returned landing points": (centres[:, None] + diamond, (255, 0, 0)),
        }
        out = {name: {"trajectories": xyz, "color": rgb} for name, (xyz, rgb) in layers.items()}
        for name in list(out)[:2]:
            out[name]["times"] = pred.times
        return out

    def __repr__(self) -> str:
        state = "unfitted" if self.landing is None else f"{self.n_data} rollouts"
        return (
            f"TableTennisRewardModel(task={self.task.name!r}, {state}, stage={self.stage!r}, "
            f"schedule={self.schedule!r}, contact={self.contact!r}, "
            f"n_basis={self.basis.n_basis}, penalty={self.penalty:.4g} m)"
        )


def _sample_gp(gp, x: np.ndarray, L: int, rng: np.random.Generator) -> np.ndarray:
    """Samples (B, L, E) of a GP's predictive distribution at x (B, d), 1-D targets too."""
    return gp.sample(x, L, rng).reshape(x.shape[0], L, -1)
