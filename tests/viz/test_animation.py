"""skillkit.viz.animation: plotly animations of throwing (Fig. 3.2) and table tennis (Fig. 3.8),
checked against independent kinematics and the trajectories' own signals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skillkit.tasks import make
from skillkit.tasks.planar import hand_kinematics
from skillkit.tasks.planar_model import LINK_LENGTHS
from skillkit.tasks.table_tennis import TABLE_HEIGHT
from skillkit.viz.animation import (
    TABLE_TENNIS_CONTEXTS,
    THROWING_TARGETS,
    arm_link_points,
    planar_link_points,
    racket_rim,
    table_tennis_animation,
    throwing_animation,
)
from tests._tolerances import fp_tol


@pytest.fixture(scope="module")
def throwing():
    task = make("throwing")
    policy = task.initial_policy()
    trajs = [task.rollout(policy.mean_of(s), s, rng=0) for s in THROWING_TARGETS]
    assert not any(t.failed for t in trajs)
    return task, trajs


@pytest.fixture(scope="module")
def table_tennis():
    task = make("table-tennis")
    policy = task.initial_policy()
    trajs = [task.rollout(policy.mean_of(s), s, rng=0) for s in TABLE_TENNIS_CONTEXTS]
    assert not any(t.failed for t in trajs)
    return task, trajs


def closed_form_planar(q: np.ndarray) -> np.ndarray:
    """Ankle, knee, hip, shoulder, hand of Appendix C.1's robot from the link angles alone."""
    theta = np.cumsum(q, axis=-1)
    out = np.zeros((*q.shape[:-1], 5, 2))
    for k in range(3):  # shin, thigh, torso point along (sin θ, cos θ) from their lower joint
        step = LINK_LENGTHS[k] * np.stack([np.sin(theta[..., k]), np.cos(theta[..., k])], -1)
        out[..., k + 1, :] = out[..., k, :] + step
    out[..., 4, :] = hand_kinematics(q)[0]  # the arm hangs from the shoulder at q_4 = 0
    return out


def interp_columns(t_grid, times, values):
    """Linear interpolation per column with numpy's own np.interp (clamped at both ends)."""
    flat = values.reshape(values.shape[0], -1)
    cols = [np.interp(t_grid, times, flat[:, j]) for j in range(flat.shape[1])]
    return np.stack(cols, -1).reshape(len(t_grid), *values.shape[1:])


# ----------------------------------------------------------------------------- kinematics
def test_planar_link_points_equal_the_closed_form_kinematics(throwing):
    task, _ = throwing
    rng = np.random.default_rng(0)
    q = rng.uniform([-0.8, -2.5, -0.1, 0.0], [0.8, 0.05, 2.0, 1.5 * np.pi], size=(50, 4))
    got = planar_link_points(task, q)
    # a chain of 4 links of ≤ 1 m, each a rotation (quaternion) and a sum: ~10 ops per link
    np.testing.assert_allclose(got, closed_form_planar(q), rtol=0, atol=fp_tol(40, scale=3.0))
    # the hand is the task's own closed-form hand kinematics
    np.testing.assert_allclose(got[:, -1], hand_kinematics(q)[0], rtol=0, atol=fp_tol(40, 3.0))


def test_arm_link_points_reach_the_recorded_racket_centre(table_tennis):
    task, trajs = table_tennis
    tr = trajs[0]
    points = arm_link_points(task, tr.states[:, :8])
    # the simulator recorded the blade centre from the same states (MuJoCo, site_xpos)
    np.testing.assert_allclose(points[:, -1], tr.signals["racket"], rtol=0, atol=fp_tol(60, 3.0))
    # the column: platform on the floor, shoulder 1.2 m above it
    np.testing.assert_allclose(points[:, 0, 2], 0.0, atol=fp_tol(10))
    np.testing.assert_allclose(
        points[:, 1] - points[:, 0],
        [[0, 0, 1.2]] * len(points),
        atol=fp_tol(4, scale=np.abs(points).max()),
    )


def test_racket_rim_is_a_circle_of_the_blade_radius_normal_to_the_blade():
    center, normal = np.array([0.3, -0.2, 1.1]), np.array([1.0, 2.0, -0.5])
    rim = racket_rim(center, normal, 0.08, n=12)
    n = normal / np.linalg.norm(normal)
    assert rim.shape == (13, 3) and np.array_equal(rim[0], rim[-1])
    np.testing.assert_allclose(np.linalg.norm(rim - center, axis=1), 0.08, rtol=fp_tol(20))
    np.testing.assert_allclose((rim - center) @ n, 0.0, atol=fp_tol(20, 0.08))


# ----------------------------------------------------------------------------- throwing
@pytest.mark.parametrize("n_frames", [2, 7, 40])
def test_throwing_frame_count_is_the_requested_one(throwing, n_frames):
    task, trajs = throwing
    fig = throwing_animation(task, trajs, THROWING_TARGETS, n_frames=n_frames)
    assert len(fig.frames) == n_frames
    assert [f.name for f in fig.frames] == [str(k) for k in range(n_frames)]
    assert len(fig.layout.sliders[0].steps) == n_frames
    assert fig.layout.width is None and fig.layout.autosize  # responsive


def test_throwing_frames_hold_the_robot_and_the_ball_of_the_trajectories(throwing):
    task, trajs = throwing
    n_frames = 9
    fig = throwing_animation(task, trajs, THROWING_TARGETS, n_frames=n_frames)
    end = max(max(t.times[-1], t.signals["ball_times"][-1]) for t in trajs)
    grid = np.linspace(0.0, end, n_frames)
    for i, tr in enumerate(trajs):
        q = interp_columns(grid, tr.times, tr.states[:, :4])
        links = closed_form_planar(q)
        ball = interp_columns(grid, tr.signals["ball_times"], tr.signals["ball"])
        for k, frame in enumerate(fig.frames):
            robot, marker = frame.data[2 * i], frame.data[2 * i + 1]
            np.testing.assert_allclose(
                np.column_stack([robot.x, robot.y]), links[k], rtol=0, atol=fp_tol(60, 3.0)
            )
            np.testing.assert_allclose(
                [marker.x[0], marker.y[0]], ball[k], rtol=0, atol=fp_tol(10, 20.0)
            )
        # the dotted path is the whole recorded ball path, sample for sample
        path = next(
            t
            for t in fig.data
            if t.name == "ball path" and t.xaxis == ("x" if i == 0 else f"x{i + 1}")
        )
        assert np.array_equal(np.column_stack([path.x, path.y]), tr.signals["ball"])
    # the longest flight ends on its landing sample exactly, the others rest where they landed
    last = fig.frames[-1].data
    for i, tr in enumerate(trajs):
        assert [last[2 * i + 1].x[0], last[2 * i + 1].y[0]] == list(tr.signals["ball"][-1])


def test_throwing_panel_titles_give_the_reward_distance(throwing):
    task, trajs = throwing
    fig = throwing_animation(task, trajs, THROWING_TARGETS, n_frames=3)
    for note, tr, s in zip(fig.layout.annotations, trajs, THROWING_TARGETS, strict=True):
        d = task.reward_terms(tr, s)["distance"]
        assert f"{100 * d:.0f} cm" in note.text and f"{tr.info['release_time']:.3f} s" in note.text


# ----------------------------------------------------------------------------- table tennis
@pytest.mark.parametrize("n_frames", [2, 11])
def test_table_tennis_frame_count_is_the_requested_one(table_tennis, n_frames):
    task, trajs = table_tennis
    fig = table_tennis_animation(task, trajs, TABLE_TENNIS_CONTEXTS, n_frames=n_frames)
    assert len(fig.frames) == n_frames
    assert len(fig.layout.sliders[0].steps) == n_frames
    assert fig.layout.width is None and fig.layout.autosize


def test_table_tennis_frames_hold_the_ball_arm_and_racket_of_the_trajectories(table_tennis):
    task, trajs = table_tennis
    n_frames = 13
    fig = table_tennis_animation(task, trajs, TABLE_TENNIS_CONTEXTS, n_frames=n_frames)
    # the ball's record, continued to the landing point when it lands after the episode
    records = []
    for tr in trajs:
        t, b = tr.times, tr.signals["ball"]
        if tr.info["landing_time"] > t[-1]:
            p = tr.info["landing_point"]
            t = np.append(t, tr.info["landing_time"])
            b = np.vstack([b, [p[0], p[1], TABLE_HEIGHT + task.ball.radius]])
        records.append((t, b))
    end = max(t[-1] for t, _ in records)
    grid = np.linspace(0.0, end, n_frames)
    for i, (tr, (t, b)) in enumerate(zip(trajs, records, strict=True)):
        ball = interp_columns(grid, t, b)
        racket = interp_columns(grid, tr.times, tr.signals["racket"])
        q = interp_columns(grid, tr.times, tr.states[:, :8])
        for k, frame in enumerate(fig.frames):
            arm, rim, marker = frame.data[3 * i : 3 * i + 3]
            np.testing.assert_allclose(
                [marker.x[0], marker.y[0], marker.z[0]], ball[k], rtol=0, atol=fp_tol(10, 3.0)
            )
            # the arm: the task's kinematics of the interpolated joints
            np.testing.assert_allclose(
                np.column_stack([arm.x, arm.y, arm.z]),
                arm_link_points(task, q[k : k + 1])[0],
                rtol=0,
                atol=fp_tol(10, 3.0),
            )
            # the blade rim lies around the interpolated recorded centre
            centre = np.column_stack([rim.x, rim.y, rim.z])[:-1].mean(axis=0)
            np.testing.assert_allclose(centre, racket[k], rtol=0, atol=fp_tol(40, 3.0))
    # the last frame shows every ball at its landing point
    for i, tr in enumerate(trajs):
        marker = fig.frames[-1].data[3 * i + 2]
        assert [marker.x[0], marker.y[0]] == tr.info["landing_point"]


# ----------------------------------------------------------------------------- bad input
def test_bad_input_is_rejected_naming_the_argument(throwing, table_tennis):
    task, trajs = throwing
    tt_task, tt_trajs = table_tennis
    failed = dataclasses.replace(trajs[0], failed=True, message="diverged")
    short = dataclasses.replace(trajs[0], states=trajs[0].states[:, :6])
    no_racket = dataclasses.replace(
        tt_trajs[0], signals={k: v for k, v in tt_trajs[0].signals.items() if k != "racket"}
    )
    cases = [
        (
            lambda: throwing_animation(task, [failed, trajs[1]], THROWING_TARGETS),
            r"trajectories\[0\]",
        ),
        (
            lambda: throwing_animation(task, [short, trajs[1]], THROWING_TARGETS),
            r"trajectories\[0\]\.states",
        ),
        (lambda: throwing_animation(task, [], THROWING_TARGETS), "trajectories"),
        (lambda: throwing_animation(task, trajs, THROWING_TARGETS[:1]), "contexts"),
        (lambda: throwing_animation(task, trajs, [[6.0, 1.0], [40.0, 1.0]]), "contexts"),
        (lambda: throwing_animation(task, trajs, THROWING_TARGETS, n_frames=1), "n_frames"),
        (lambda: throwing_animation(task, trajs, THROWING_TARGETS, n_frames=1000), "n_frames"),
        (lambda: throwing_animation(task, trajs, THROWING_TARGETS, frame_ms=0), "frame_ms"),
        (lambda: throwing_animation(tt_task, trajs, THROWING_TARGETS), "task"),
        (lambda: table_tennis_animation(task, tt_trajs, TABLE_TENNIS_CONTEXTS), "task"),
        (
            lambda: table_tennis_animation(tt_task, [no_racket], TABLE_TENNIS_CONTEXTS[:1]),
            r"trajectories\[0\]",
        ),
        (
            lambda: table_tennis_animation(tt_task, tt_trajs, TABLE_TENNIS_CONTEXTS[:, :3]),
            "contexts",
        ),
        (lambda: planar_link_points(task, np.zeros((3, 5))), "q"),
        (lambda: racket_rim([0, 0, 0], [0, 0, 0], 0.08), "normal"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()


def test_same_input_gives_the_same_figure(throwing):
    task, trajs = throwing
    a = throwing_animation(task, trajs, THROWING_TARGETS, n_frames=6).to_json()
    assert a == throwing_animation(task, trajs, THROWING_TARGETS, n_frames=6).to_json()
