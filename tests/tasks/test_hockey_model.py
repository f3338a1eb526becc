"""The decomposed hockey model of GPREPS (Sec. 4.3.3) against the simulator."""

from __future__ import annotations

import warnings
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.models.gp import ExactGP
from skillkit.tasks import make
from skillkit.tasks.hockey.arm import BLADE_HALF
from skillkit.tasks.hockey.model import (
    PUCK_Z,
    X_LAUNCH,
    DisplacementModel,
    HockeyPrediction,
    HockeyRewardModel,
    LaunchTargets,
    approach_frame,
    first_contact,
)


def _shots(task, n, seed):
    """n shots of the initial policy; each target put near the control puck's straight path
    (within ±0.1 m sideways, the contact distance being 2r = 0.08 m), so hits and misses mix.
    A pre-rollout with the sampled context finds the path; contexts stay in the task range."""
    rng = np.random.default_rng(seed)
    s = task.sample_context(rng, n=n)
    w = task.initial_policy().sample(s, rng)
    lo, hi = task.context_low[:2], task.context_high[:2]
    for i in range(n):
        pre = task.rollout(w[i], s[i], rng=0)
        c = pre.signals["control_puck"]
        if pre.info["hit"]:
            c = c[pre.signals["puck_times"] < pre.info["hit_time"]]
        inside = np.flatnonzero(np.all((c >= lo) & (c <= hi), axis=1))
        if inside.size and 0 < inside[0]:
            j = int(rng.choice(inside[inside < len(c) - 1]))
            d = c[j + 1] - c[j - 1]
            side = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            s[i, :2] = np.clip(c[j] + rng.uniform(-0.1, 0.1) * side, lo, hi)
    trajs = [task.rollout(wi, si, rng) for wi, si in zip(w, s, strict=True)]
    r = np.array([task.reward(t, si) for t, si in zip(trajs, s, strict=True)])
    return s, w, r, trajs


def _fit(task, s, w, r, trajs, **kw):
    model = HockeyRewardModel(task, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stats = model.fit(s, w, r, trajs, rng=1)
    return model, stats


@pytest.fixture(scope="module")
def data():
    task = make("hockey")
    return task, _shots(task, 80, 0)


@pytest.fixture(scope="module")
def fitted(data):
    task, (s, w, r, trajs) = data
    model, stats = _fit(task, s[:60], w[:60], r[:60], trajs[:60])
    return task, model, stats, (s[60:], w[60:], r[60:], trajs[60:])


def test_first_contact_closed_form():
    """A straight pass at lateral offset h touches iff h ≤ 2r, at the chord point."""
    r = 0.04
    x = np.linspace(0.0, 1.0, 11)
    for h, touches in ((0.07, True), (0.079, True), (0.081, False), (0.2, False)):
        control = np.column_stack([x, np.zeros_like(x)])
        target = np.tile([0.55, h], (11, 1))
        hit, k, f = first_contact(control, target, r)
        assert bool(hit) is touches
        if touches:
            xc = control[k, 0] + f * (control[k + 1, 0] - control[k, 0])
            # The root of ‖d0 + f e‖² = 4r² (e = (Δ, 0), Δ = 0.1; d0 = (p, −h), |p| ≤ Δ + ℓ)
            # has disc = Δ² ℓ², ℓ = √(4r² − h²) the half chord: the terms' absolute rounding
            # ε Δ² (3p² + 2h² + 8r²) through √disc / Δ² moves x by ε (3p² + 2h² + 8r²) / 2ℓ,
            # on top of ε per m of the ≈ 10 steps on coordinates ≤ 1 m; two evaluations.
            chord = np.sqrt(4 * r * r - h * h)
            amp = (3 * (0.1 + chord) ** 2 + 2 * h * h + 8 * r * r) / (2 * chord)
            tol = 2 * fp_tol(10, scale=1.0 + amp)
            assert xc == pytest.approx(0.55 - np.sqrt(4 * r * r - h * h), rel=0, abs=tol)
    with pytest.raises(ValueError, match="radius"):
        first_contact(control, target, -1.0)
    with pytest.raises(ValueError, match="target"):
        first_contact(control, target[:5], r)


def test_contact_detection_by_radius_agrees_with_the_simulator(data):
    """On all 80 rollouts (measured: 50 hits, 30 misses) radius detection on the true
    recorded paths agrees with pymunk's contact callback, rollout by rollout."""
    _, (_, _, _, trajs) = data
    ok = [t for t in trajs if not t.failed]
    c = np.array([t.signals["control_puck"] for t in ok], dtype=object)
    detected = np.array(
        [
            bool(first_contact(t.signals["control_puck"], t.signals["target_puck"], 0.04)[0])
            for t in ok
        ]
    )
    truth = np.array([t.info["hit"] for t in ok])
    assert len(c) >= 70 and truth.sum() >= 20 and (~truth).sum() >= 20
    np.testing.assert_array_equal(detected, truth)


def test_racket_never_touches_the_puck_past_the_launch_line(data):
    """After the control puck crosses x = 0.65 m the blade footprint (its box at the recorded
    pose, down or not) keeps clear of the puck (measured ≥ 8 cm of clearance)."""
    _, (_, _, _, trajs) = data
    n_crossed, clearance = 0, np.inf
    for t in trajs:
        c, racket = t.signals["control_puck"], t.signals["racket"]
        if not np.any(c[:, 0] >= X_LAUNCH):
            continue
        n_crossed += 1
        k = int(np.argmax(c[:, 0] >= X_LAUNCH))  # the racket is lifted for good after it
        after = np.arange(k, len(racket))
        if after.size == 0:
            continue
        d = c[after] - racket[after, :2]
        u = np.column_stack([np.cos(racket[after, 3]), np.sin(racket[after, 3])])
        a = np.abs(np.sum(d * u, 1)) - BLADE_HALF[0]
        b = np.abs(d[:, 0] * -u[:, 1] + d[:, 1] * u[:, 0]) - BLADE_HALF[1]
        dist = np.hypot(np.maximum(a, 0), np.maximum(b, 0)) + np.minimum(np.maximum(a, b), 0)
        clearance = min(clearance, float(dist.min()) - 0.04)
    assert n_crossed >= 70
    assert clearance > 0.04, clearance


def test_sliding_model_stops_where_friction_says(fitted):
    """From the observed launch states, the iterated sliding GP stops the puck at the
    closed-form distance v²/(2 μ g) (measured: median 0.6%, worst 6% of 20 sampled paths)."""
    task, model, _, (_, _, _, trajs) = fitted
    crossed, launch = model.launch_data(trajs)
    b0 = np.column_stack([np.full(crossed.sum(), X_LAUNCH), launch[crossed, :3]])
    far = np.tile([10.0, 10.0, 0.0], (len(b0), 1))
    control, _, contact, _ = model._predict_simulated(
        b0, np.ones(len(b0), bool), far, np.random.default_rng(0)
    )
    assert not contact.any()
    slid = np.linalg.norm(control[:, -1] - control[:, 1], axis=1)
    closed = np.sum(b0[:, 2:] ** 2, 1) / (2 * task.physics.deceleration)
    rel = np.abs(slid / closed - 1)
    assert np.median(rel) < 0.02 and rel.max() < 0.1, rel


def test_held_out_predictions_follow_the_simulator(fitted):
    """Fitted on 60 shots, predictions of 20 unseen ones. With 60 shots the launch GP
    (ω ∈ R¹⁵) still has ~7° of direction error, which decides hits; the bounds are loose
    (measured: displacement RMSE 0.54 m against 0.76 m for the mean, reward correlation
    0.56) but a model that ignores ω or the target fails them."""
    task, model, stats, (s, w, r, trajs) = fitted
    pred = model.predict(s, w, 10, rng=2)
    assert isinstance(pred, HockeyPrediction)
    assert pred.control.shape[:2] == (20, 10) and pred.control.shape == pred.target.shape
    disp = np.array([t.info["displacement"] for t in trajs])
    rmse = np.sqrt(np.mean((pred.displacements.mean(1) - disp) ** 2))
    corr = np.corrcoef(pred.expected_rewards, r)[0, 1]
    assert rmse < 1.0, rmse
    assert corr > 0.2, corr
    crossed, launch = model.launch_data(trajs)
    y_err = np.abs(np.median(pred.launch[crossed, :, 1], 1) - launch[crossed, 0])
    assert np.median(y_err) < 0.02, y_err  # measured 5 mm
    assert pred.launched[crossed].mean() > 0.8
    assert stats["n_trajectories"] == 60 and stats["n_contacts"] >= 20
    for key in ("launch", "sliding", "contact"):
        assert stats[key]["n_data"] > 0
        assert stats[key]["start"] == "cold"  # the first fit has no previous values
        assert stats[key]["log_ml_warm"] is None and np.isfinite(stats[key]["log_ml_cold"])
    assert "contacts=" in repr(pred) and "simulated" in repr(model)


def test_same_seed_same_prediction(fitted):
    _, model, _, (s, w, _, _) = fitted
    a = model.expected_rewards(s[:4], w[:4], 3, rng=5)
    b = model.expected_rewards(s[:4], w[:4], 3, rng=5)
    c = model.expected_rewards(s[:4], w[:4], 3, rng=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_bad_input_is_refused(fitted):
    task, model, _, (s, w, r, trajs) = fitted
    with pytest.raises(ValueError, match="task: expected a Hockey task"):
        HockeyRewardModel(make("pendulum"))
    with pytest.raises(ValueError, match="make_sliding_model: expected a callable"):
        HockeyRewardModel(task, make_sliding_model=3)
    with pytest.raises(ValueError, match="real"):
        HockeyRewardModel(task, real=True)
    with pytest.raises(RuntimeError, match="call fit"):
        HockeyRewardModel(task).predict(s, w, 2)
    with pytest.raises(ValueError, match="omegas"):
        model.predict(s, w[:, :5], 2)
    with pytest.raises(ValueError, match="contexts"):
        model.predict(s[:3], w, 2)
    with pytest.raises(ValueError, match="n_trajectories"):
        model.predict(s, w, 0)
    with pytest.raises(ValueError, match="trajectories"):
        HockeyRewardModel(task).fit(s, w, r, None)
    with pytest.raises(ValueError, match="omegas"):
        HockeyRewardModel(task).fit(s, w[:3], r, trajs)
    with pytest.raises(ValueError, match="refit: expected one of .*'sometimes'"):
        HockeyRewardModel(task, refit="sometimes")
    with pytest.raises(ValueError, match="launch_targets: expected one of .*'polar'"):
        HockeyRewardModel(task, launch_targets="polar")
    with pytest.raises(ValueError, match="displacement: expected one of .*'svm'"):
        HockeyRewardModel(task, displacement="svm")


def test_models_are_swappable_through_the_factories(fitted):
    task, _, _, (s, w, r, trajs) = fitted
    model, _ = _fit(task, s, w, r, trajs, make_sliding_model=lambda: ExactGP(n_steps=10))
    assert model.models["sliding"].n_steps == 10
    assert np.all(np.isfinite(model.expected_rewards(s[:2], w[:2], 2, rng=0)))


def test_prediction_layers(fitted):
    _, model, _, (s, w, _, _) = fitted
    layers = model.prediction_layers(s[0], w[0], 4, rng=0)
    names = list(layers)
    assert names[0].startswith("launch model: control puck at x=0.65")
    assert "sliding model: control puck" in layers
    assert "contact model: target puck" in layers
    for layer in layers.values():
        traj = layer["trajectories"]
        assert traj.ndim == 3 and traj.shape[0] == 4 and traj.shape[2] == 3
        assert np.all(traj[..., 2] == PUCK_Z) and np.all(np.isfinite(traj))
        assert len(layer["color"]) == 3 and all(0 <= v <= 255 for v in layer["color"])
    assert layers["launch model: control puck at x=0.65 m"]["trajectories"].shape[1] == 2
    with pytest.raises(ValueError, match="omega"):
        model.prediction_layers(s[0], w[0, :3], 4)


def test_real_setting_learns_from_observed_tracks():
    """hockey-real: the models learn from the smoothed 30 Hz tracks, the displacement model
    replaces the contact model, and predicted paths are long enough for the smoothing."""
    task = make("hockey-real")
    s, w, r, trajs = _shots(task, 40, 3)
    model, stats = _fit(task, s[:30], w[:30], r[:30], trajs[:30])
    assert model.real and np.isclose(model.slide_dt, 1 / 30)
    assert model.models["contact"] is None and "displacement" in stats
    assert isinstance(model.models["displacement"], DisplacementModel)
    assert 2 <= stats["n_hits"] <= stats["n_contacts"] and stats["hit_accuracy"] > 0.5
    pred = model.predict(s[30:], w[30:], 4, rng=0)
    assert np.all(np.isfinite(pred.rewards))
    assert pred.control.shape[2] > 9  # filtfilt's padlen for the order-2 Butterworth
    assert np.all(pred.control[:, :, -10:] == pred.control[:, :, -1:])  # stopped pucks
    layers = model.prediction_layers(s[30], w[30], 3, rng=0)
    assert "displacement model: target puck" in layers
    # before any shot came near the target there is no displacement model: the pucks never
    # count as near, the target stays put, and the rewards are still finite
    model.models["displacement"] = None
    alone = model.predict(s[30:], w[30:], 4, rng=0)
    assert np.all(np.isfinite(alone.rewards)) and not alone.contact.any()
    assert np.all(alone.target == alone.target[:, :, :1])


def test_launch_targets_round_trip():
    """[p_y, v_x, v_y, t_0] ↔ [p_y, heading, speed, t_0] up to round-off: atan2, hypot, cos,
    sin and one product each add about one unit in the last place, so each velocity
    component is back within a few eps · ‖v‖ and the heading within a few eps · π."""
    rng = np.random.default_rng(0)
    state = np.column_stack(
        [
            rng.uniform(-0.3, 0.3, 50),
            rng.normal(1.5, 1.0, 50),
            rng.normal(0, 1.0, 50),
            rng.uniform(0.2, 0.8, 50),
        ]
    )
    speed = np.hypot(state[:, 1], state[:, 2])
    h = LaunchTargets("heading")
    back = h.decode(h.encode(state))
    np.testing.assert_array_equal(back[:, [0, 3]], state[:, [0, 3]])
    tol = np.array([fp_tol(5, scale=v) for v in speed])
    err = np.abs(back[:, 1:3] - state[:, 1:3])
    assert np.all(err <= tol[:, None]), err / tol[:, None]
    targets = h.encode(state)
    again = h.encode(h.decode(targets))
    assert np.all(np.abs(again[:, 1] - targets[:, 1]) <= fp_tol(5, scale=np.pi))
    assert np.all(np.abs(again[:, 2] - targets[:, 2]) <= tol)
    v = LaunchTargets("velocity")
    np.testing.assert_array_equal(v.decode(v.encode(state)), state)
    # a negative drawn speed is a puck at rest
    rest = h.decode(np.array([[0.1, 0.3, -0.2, 0.5]]))
    np.testing.assert_array_equal(rest[0, 1:3], [0.0, 0.0])


def _approaches(n, seed):
    """n approaches at the 0.2 m threshold: a hit when the line of approach passes within
    2r = 0.08 m of the target (then the target moves along the line of centres by 0.8 s × the
    speed, the control puck on sideways), a miss otherwise (the target stays, the control puck
    slides on by 0.5 s × its speed); 1 cm of tracking noise on every displacement."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(-0.5, 0.5, n)
    u = np.column_stack([np.cos(heading), np.sin(heading)])
    perp = np.column_stack([-u[:, 1], u[:, 0]])
    h = rng.uniform(-0.15, 0.15, n)
    speed = rng.uniform(0.8, 2.0, n)
    rel = -np.sqrt(0.2**2 - h**2)[:, None] * u + h[:, None] * perp
    x = np.column_stack([rel, speed[:, None] * u])
    hit = np.abs(h) < 0.08
    centres = -(rel + np.sqrt(np.maximum(0.08**2 - h**2, 0))[:, None] * u)  # to the target
    n_c = centres / np.linalg.norm(centres, axis=1, keepdims=True)
    y = np.zeros((n, 4))
    y[hit, :2] = 0.8 * speed[hit, None] * n_c[hit]
    y[hit, 2:] = 0.2 * speed[hit, None] * perp[hit] * np.sign(h[hit])[:, None]
    y[~hit, 2:] = 0.5 * speed[~hit, None] * u[~hit]
    return x, y + 0.01 * rng.standard_normal(y.shape), hit


def test_displacement_classifier_and_gp_on_hits():
    """The hit/miss classifier separates approaches by the line's offset (held out: measured
    all correct but those within ~1 cm of 2r; at least 85% asked), and the GP on the hits,
    in the approach frame, places the target within 10 cm on held-out hits (measured 3 cm
    RMS); misses get no displacement draw (the caller slides them on)."""
    x, y, hit = _approaches(80, 0)
    xt, yt, hit_t = _approaches(40, 1)
    m = DisplacementModel("hit_gp")
    m.fit_classifier(x, y)
    gx, gy = m.gp_data(x, y)
    assert gx.shape == (hit.sum(), 2) and gy.shape == (hit.sum(), 4)
    feats, frames = approach_frame(x[hit])
    np.testing.assert_allclose(gx, feats)
    assert np.all(np.abs(feats[:, 0]) < 0.08)
    m.gp = ExactGP(n_steps=50).fit(gx, gy, np.random.default_rng(0))
    p = m.hit_probability(xt)
    assert p.shape == (40,) and np.all((p >= 0) & (p <= 1))
    assert np.mean((p > 0.5) == hit_t) >= 0.85
    draws = np.stack([m.draw(xt[hit_t], np.random.default_rng(i)) for i in range(20)])
    rmse = np.sqrt(np.mean(np.sum((draws.mean(0)[:, :2] - yt[hit_t, :2]) ** 2, axis=1)))
    assert rmse < 0.1, rmse
    hits = m.draw_hits(xt, np.random.default_rng(0))
    assert hits.dtype == bool and hits.shape == (40,)
    # the old kind: every approach a hit, one GP in world coordinates
    g = DisplacementModel("gp")
    g.fit_classifier(x, y)
    gx, gy = g.gp_data(x, y)
    assert gx is x and gy is y and np.all(g.draw_hits(xt, None))
    with pytest.raises(ValueError, match="hit_distance"):
        DisplacementModel("hit_gp", hit_distance=0.0)


LAUNCHES_410 = Path(__file__).resolve().parent / "data" / "hockey_launches_fig410_trial0.npz"
"""The 119 launches of trial 0 of the fig4.10 paper run of commit 1c9393e, as its launch GP
held them: the omegas (119, 15), the launch states [p_y, v_x, v_y, t_0] (119, 4; its additive
target noise included) and the warm-started chain's final hyper-parameters, stuck in a poor
optimum (log marginal likelihood −2.96 per point against +1.13 for a cold fit on the same
data)."""


def test_refit_reaches_the_cold_fits_marginal_likelihood_on_stored_shots():
    """On the stored launches, refitting from the stuck chain's hyper-parameters with
    ``refit="best"`` ends at least at the cold fit's log marginal likelihood (the cold start
    runs with the same additive-noise seed, so it is the same fit)."""
    with np.load(LAUNCHES_410) as z:
        x, state = z["omegas"], z["launch_states"]
        warm = {k: z[f"warm_{k}"] for k in ("lengthscale", "outputscale", "noise")}
    task = make("hockey")
    make_gp = partial(ExactGP, n_steps=60)
    stats = {}
    for refit in ("cold", "best"):
        model = HockeyRewardModel(task, make_launch_model=make_gp, refit=refit)
        model._hypers["launch"] = warm  # the stored (warm) chain's values
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            y = LaunchTargets("heading").encode(state)
            _, stats[refit] = model._refit("launch", make_gp, x, y, np.random.default_rng(0))
    cold, best = stats["cold"], stats["best"]
    assert cold["start"] == "cold" and cold["log_ml_warm"] is None
    assert best["log_ml_cold"] == cold["log_ml_cold"]
    kept = best[f"log_ml_{best['start']}"]
    assert kept == max(best["log_ml_cold"], best["log_ml_warm"])
    assert kept >= cold["log_ml_cold"]
    assert model._hypers["launch"] is not None
