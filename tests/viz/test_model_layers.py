"""GPREPS reward models in the viewer (skillkit.viz.model_layers): model files, the
``prediction_layers`` contract and its validation, Viewer.add_model_layers (nodes, recomputing
on a new (s, ω), visibility, legend) and ``skillkit view --gpreps``.

The fake models here stand in for the hockey and table-tennis reward models of
skillkit.search: module-level and picklable, their predicted paths move with the context and ω.
"""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from test_viewer import run_cli  # tests/viz/test_viewer.py, beside this

from skillkit._validation import as_generator
from skillkit.search.loop import policy_history_arrays
from skillkit.tasks import make
from skillkit.viz.model_layers import (
    REWARD_MODEL_FORMAT,
    check_model_task,
    dumps_reward_model,
    load_gpreps_run,
    load_reward_model,
    loads_reward_model,
    model_layers,
    reward_model_path,
    save_reward_model,
)
from skillkit.viz.viewer import Viewer

HOCKEY_LAYERS = {
    "arm model: blade": "arm_model_blade",
    "sliding model: control puck": "sliding_model_control_puck",
    "contact model: target puck end": "contact_model_target_puck_end",
}
TABLE_TENNIS_LAYERS = {
    "racket models: racket centre": "racket_models_racket_centre",
    "ball model: ball flight": "ball_model_ball_flight",
    "contact model: returned landing points": "contact_model_returned_landing_points",
}


def _line(start, end, n: int) -> np.ndarray:
    return np.linspace(np.asarray(start, float), np.asarray(end, float), n)


class FakeHockeyModel:
    """A hockey reward model's layers: blade and control-puck paths toward the target puck's
    start b = s[:2] (shifted by ω), and the target puck's predicted end points (T = 1)."""

    def __init__(self, task: str = "hockey") -> None:
        self.task = make(task)

    def prediction_layers(self, context, omega, n_samples, rng=None):
        rng = as_generator(rng)
        b = np.asarray(context[:2]) + 0.01 * np.tanh(omega[:2])
        puck = _line([0.45, -0.3, 0.01], [*b, 0.01], 25)
        blade = _line([0.2, -0.6, 0.05], [0.45, -0.3, 0.05], 15)
        end = np.array([*(b + [context[2], 0.0]), 0.01])
        noise = rng.standard_normal
        return {
            "arm model: blade": {
                "trajectories": blade + 0.005 * noise((n_samples, 15, 3)),
                "color": (150, 70, 220),
                "times": np.linspace(0.0, 0.5, 15),
            },
            "sliding model: control puck": {
                "trajectories": puck + 0.01 * noise((n_samples, 25, 3)),
                "color": (220, 40, 160),
                "times": np.linspace(0.5, 1.5, 25),
            },
            "contact model: target puck end": {
                "trajectories": end + 0.02 * noise((n_samples, 1, 3)),
                "color": (230, 160, 0),
            },
        }


class FakeTableTennisModel:
    """A table-tennis reward model's layers: racket and ball paths toward the return target
    b = s[3:5] and the ball's predicted landing points (T = 1)."""

    def __init__(self) -> None:
        self.task = make("table-tennis")

    def prediction_layers(self, context, omega, n_samples, rng=None):
        rng = as_generator(rng)
        target = np.array([context[3], context[4], 0.76])
        racket = _line([-1.6, 0.3, 0.9], [-1.4, 0.1 + 0.01 * np.tanh(omega[0]), 1.0], 20)
        ball = _line([-1.5, 0.1, 1.0], target, 30)
        noise = rng.standard_normal
        return {
            "racket models: racket centre": {
                "trajectories": racket + 0.005 * noise((n_samples, 20, 3)),
                "color": (150, 70, 220),
            },
            "ball model: ball flight": {
                "trajectories": ball + 0.01 * noise((n_samples, 30, 3)),
                "color": (20, 170, 170),
            },
            "contact model: returned landing points": {
                "trajectories": target + 0.03 * noise((n_samples, 1, 3)),
                "color": (230, 160, 0),
            },
        }


class FixedAnswerModel:
    """Answers ``prediction_layers`` with a fixed object (for the validation tests)."""

    def __init__(self, answer) -> None:
        self.answer = answer

    def prediction_layers(self, context, omega, n_samples, rng=None):
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def make_gpreps_run(folder, model, task: str, trial: int = 0, updates: int = 2):
    """A GPREPS run folder as ``skillkit reproduce`` leaves it for the viewer: ``trials.npz``
    with the trial's policy history (updates + 1 policies whose means move a little) and the
    reward model at :func:`reward_model_path`."""
    p0 = make(task).initial_policy()
    policies = [
        type(p0)(p0.mean + 0.05 * k, p0.cov, p0.gain, p0.context_dim) for k in range(updates + 1)
    ]
    arrays = {f"trial{trial}__{k}": v for k, v in policy_history_arrays(policies).items()}
    folder.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(folder / "trials.npz", **arrays)
    (folder / "result.json").write_text("{}")
    save_reward_model(reward_model_path(folder, trial), model)
    return folder


# ----------------------------------------------------------------------------- model files
def test_save_load_round_trip_and_header(tmp_path):
    model = FakeHockeyModel()
    path = save_reward_model(reward_model_path(tmp_path, 3), model)
    assert path == tmp_path / "reward_model_trial3.pkl" and path.exists()
    with open(path, "rb") as f:
        assert f.readline() == b"skillkit-reward-model-v1\n" == REWARD_MODEL_FORMAT.encode() + b"\n"
        header = json.loads(f.readline())
    assert header == {"class": f"{__name__}.FakeHockeyModel", "skillkit": "0.1.0", "task": "hockey"}
    loaded = load_reward_model(path)
    assert type(loaded) is FakeHockeyModel and loaded.task.name == "hockey"
    s, omega = np.array([2.0, 0.7, 0.5]), np.zeros(15)
    a = model.prediction_layers(s, omega, 4, rng=1)
    b = loaded.prediction_layers(s, omega, 4, rng=1)
    for name in a:
        np.testing.assert_array_equal(a[name]["trajectories"], b[name]["trajectories"])
    with pytest.raises(ValueError, match="trial: expected an integer ≥ 0"):
        reward_model_path(tmp_path, -1)


def test_bad_model_files_are_refused_before_unpickling(tmp_path):
    payload = pickle.dumps(FakeHockeyModel())
    header = json.dumps({"class": f"{__name__}.FakeHockeyModel", "skillkit": "0.1.0"}).encode()
    cases = {
        "missing.pkl": (None, "model: no such file"),
        "garbage.pkl": (b"\x80\x04garbage", "not a skillkit reward-model file"),
        "raw.pkl": (payload, "not a skillkit reward-model file"),  # a bare pickle
        "v2.pkl": (b"skillkit-reward-model-v2\n" + header + b"\n" + payload, "format 'skillkit-"),
        "header.pkl": (REWARD_MODEL_FORMAT.encode() + b"\nnot json\n" + payload, "malformed"),
        "broken.pkl": (
            REWARD_MODEL_FORMAT.encode() + b"\n" + header + b"\n\x80\x04junk",
            "does not load here",
        ),
        "other.pkl": (
            REWARD_MODEL_FORMAT.encode()
            + b"\n"
            + header.replace(b"Hockey", b"Pong")
            + b"\n"
            + payload,
            f"promises a {__name__}.FakePongModel",
        ),
    }
    for name, (content, match) in cases.items():
        if content is not None:
            (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match=match):
            load_reward_model(tmp_path / name)
    (tmp_path / "v2.pkl").write_bytes(b"skillkit-reward-model-v2\n" + header + b"\n" + payload)
    with pytest.raises(ValueError, match="expected 'skillkit-reward-model-v1'"):
        load_reward_model(tmp_path / "v2.pkl")


def test_save_refuses_models_without_layers_or_unpicklable(tmp_path):
    with pytest.raises(ValueError, match="model: a dict has no prediction_layers"):
        save_reward_model(tmp_path / "m.pkl", {})
    with pytest.raises(ValueError, match="model: a FixedAnswerModel cannot be pickled"):
        save_reward_model(tmp_path / "m.pkl", FixedAnswerModel(lambda: 0))
    assert not (tmp_path / "m.pkl").exists()


def test_model_task_check():
    check_model_task(FakeHockeyModel(), "hockey")
    check_model_task(FixedAnswerModel({}), "hockey")  # says nothing about its task: passes
    with pytest.raises(ValueError, match="fitted on task 'hockey-real', not 'hockey'"):
        check_model_task(FakeHockeyModel("hockey-real"), "hockey")


# ----------------------------------------------------------------------------- the contract
def test_model_layers_gives_add_prediction_layer_keywords():
    specs = model_layers(FakeHockeyModel(), [2.0, 0.7, 0.5], np.zeros(15), n_samples=4, rng=0)
    assert [(s["label"], s["name"]) for s in specs] == list(HOCKEY_LAYERS.items())
    blade, puck, end = specs
    assert set(blade) == {"name", "label", "trajectories", "color", "times", "space"}
    assert blade["space"] == "points" and blade["trajectories"].shape == (4, 15, 3)
    assert puck["color"] == (220, 40, 160) and puck["times"].shape == (25,)
    assert end["trajectories"].shape == (4, 1, 3) and "times" not in end
    same = model_layers(FakeHockeyModel(), [2.0, 0.7, 0.5], np.zeros(15), n_samples=4, rng=0)
    np.testing.assert_array_equal(same[1]["trajectories"], puck["trajectories"])
    twins = {
        "a b": {"trajectories": np.zeros((1, 2, 3))},
        "a:b": {"trajectories": np.ones((1, 2, 3))},
    }
    assert [s["name"] for s in model_layers(FixedAnswerModel(twins), [], [])] == ["a_b", "a_b-2"]


GOOD = np.zeros((2, 5, 3))


@pytest.mark.parametrize(
    "answer, match",
    [
        ([GOOD], "returned a list, expected a dict"),
        ({"": {"trajectories": GOOD}}, "non-empty strings"),
        ({"m": GOOD}, "model layer 'm': expected a dict with 'trajectories'"),
        ({"m": {"color": (1, 2, 3)}}, "expected a dict with 'trajectories'"),
        ({"m": {"trajectories": np.zeros((5, 3))}}, "'m': trajectories: expected 3 dimensions"),
        ({"m": {"trajectories": np.zeros((2, 5, 2))}}, r"shape \(L, T, 3\) .* got \(2, 5, 2\)"),
        ({"m": {"trajectories": np.zeros((0, 5, 3))}}, r"L, T >= 1, got \(0, 5, 3\)"),
        ({"m": {"trajectories": np.full((2, 5, 3), np.nan)}}, "non-finite"),
        ({"m": {"trajectories": GOOD, "color": (300, 0, 0)}}, "'m': color: expected RGB"),
        ({"m": {"trajectories": GOOD, "color": (1, 2)}}, r"'m': color: expected shape \(3,\)"),
        ({"m": {"trajectories": GOOD, "times": np.zeros(4)}}, r"times: expected shape \(5,\)"),
        ({"m": {"trajectories": GOOD, "times": -np.arange(5.0)}}, "non-decreasing"),
    ],
)
def test_model_layers_refuses_malformed_answers(answer, match):
    with pytest.raises(ValueError, match=match):
        model_layers(FixedAnswerModel(answer), [0.0], [0.0])


def test_model_layers_argument_errors():
    with pytest.raises(ValueError, match="model: a dict has no prediction_layers"):
        model_layers({}, [0.0], [0.0])
    with pytest.raises(ValueError, match="n_samples: expected an integer ≥ 1"):
        model_layers(FakeHockeyModel(), [2.0, 0.7, 0.5], np.zeros(15), n_samples=0)


# ----------------------------------------------------------------------------- in the viewer
@pytest.fixture(scope="module")
def hockey_viewer():
    v = Viewer("hockey", context=[2.0, 0.75, 0.5], port=0, environment=False).start()
    yield v
    v.stop()


@pytest.fixture
def viewer(hockey_viewer):
    yield hockey_viewer
    hockey_viewer.remove_model_layers()
    for name in list(hockey_viewer.layers):
        hockey_viewer.remove_prediction_layer(name)


def test_model_layers_in_the_viewer_nodes_checkboxes_and_legend(viewer):
    layers = viewer.add_model_layers(FakeHockeyModel(), n_samples=6, seed=1)
    assert [layer.label for layer in layers] == list(HOCKEY_LAYERS)
    assert viewer.model_layer_names == list(HOCKEY_LAYERS.values())
    names = viewer.node_names()
    for name in HOCKEY_LAYERS.values():
        for node in ("samples", "mean", "now"):
            path = f"/predictions/{name}/{node}"
            assert path in names and viewer.server.scene.get_handle_by_name(path) is not None
        assert f"`/predictions/{name}/samples`" in viewer.gui["tree"].content
    assert layers[1].checkbox.label == "sliding model: control puck (L=6)"
    assert layers[1].points.shape == (6, 25, 3)
    # T = 1: predicted points drawn as dots, whatever the timeline's time
    dots = layers[2].nodes["/predictions/contact_model_target_puck_end/samples"]
    np.testing.assert_allclose(dots.points, layers[2].points[:, 0], atol=2e-3)  # float16
    viewer.set_time(0.4)
    # the legend: the simulator's rollout and every layer, each with its colour
    assert viewer.legend() == [
        ("simulator rollout", (30, 100, 220)),
        ("arm model: blade", (150, 70, 220)),
        ("sliding model: control puck", (220, 40, 160)),
        ("contact model: target puck end", (230, 160, 0)),
    ]
    html = viewer.gui["legend"].content
    for label, color in viewer.legend():
        assert f"rgb{color}" in html and label in html
    assert "FakeHockeyModel" in html and "L = 6" in html
    assert viewer.gui["predictions"].visible
    viewer.remove_model_layers()
    assert not any(n.startswith("/predictions") for n in viewer.node_names())
    assert viewer.legend() == [("simulator rollout", (30, 100, 220))]
    assert not viewer.gui["predictions"].visible


def test_model_layers_follow_the_context_and_the_policy(viewer):
    viewer.add_model_layers(FakeHockeyModel(), n_samples=3)
    puck = "sliding_model_control_puck"
    before = viewer.layers[puck].points.copy()
    viewer.set_context([1.6, 0.6, 0.3])
    after = viewer.layers[puck].points
    np.testing.assert_allclose(after[:, -1, :2].mean(axis=0), [1.6, 0.6], atol=0.05)
    assert not np.allclose(before, after)
    viewer.gui["context"][0].value = 2.4  # a slider moved in the browser
    np.testing.assert_allclose(viewer.layers[puck].points[:, -1, 0].mean(), 2.4, atol=0.05)
    # the same (s, ω) gives the same samples (one seed for every computation)
    again = viewer.layers[puck].points.copy()
    viewer.set_context([1.6, 0.6, 0.3])
    viewer.set_context(viewer.context.copy())
    viewer.gui["context"][0].value = 2.4
    np.testing.assert_array_equal(viewer.layers[puck].points, again)
    # a sampled ω: the layers are the model's prediction for it
    viewer.gui["sample"].value = True
    expected = FakeHockeyModel().prediction_layers(
        viewer.context, viewer.omega, 3, rng=np.random.default_rng(0)
    )
    np.testing.assert_allclose(
        viewer.layers[puck].points, expected["sliding model: control puck"]["trajectories"]
    )


def test_a_layer_switched_off_stays_off_when_recomputed(viewer):
    layers = viewer.add_model_layers(FakeHockeyModel(), n_samples=2)
    layers[0].checkbox.value = False  # as if unticked in the browser
    assert not any(h.visible for h in layers[0].nodes.values())
    viewer.set_context([1.8, 0.6, 0.4])
    blade = viewer.layers["arm_model_blade"]
    assert blade is not layers[0]  # recomputed ...
    assert not blade.visible and blade.checkbox.value is False  # ... and still off
    assert viewer.layers["sliding_model_control_puck"].visible
    blade.checkbox.value = True
    assert all(h.visible for h in blade.nodes.values())


def test_model_errors_raise_when_added_and_show_in_the_legend_later(viewer):
    with pytest.raises(ValueError, match="fitted on task 'table-tennis', not 'hockey'"):
        viewer.add_model_layers(FakeTableTennisModel())
    with pytest.raises(ValueError, match="model layer 'm': trajectories"):
        viewer.add_model_layers(FixedAnswerModel({"m": {"trajectories": np.zeros((2, 5, 2))}}))
    assert viewer.model is None and not viewer.model_layer_names
    with pytest.raises(ValueError, match="n_samples"):
        viewer.add_model_layers(FakeHockeyModel(), n_samples=0)
    model = FixedAnswerModel({"m": {"trajectories": np.zeros((2, 5, 3))}})
    viewer.add_model_layers(model)
    assert "/predictions/m/samples" in viewer.node_names()
    model.answer = RuntimeError("GP went singular")
    viewer.gui["context"][1].value = 0.55  # a GUI callback: reported, not raised
    assert "/predictions/m/samples" not in viewer.node_names()
    assert "model prediction failed" in viewer.gui["legend"].content
    assert "GP went singular" in viewer.gui["legend"].content


def test_model_layers_follow_learning_playback_on_table_tennis(tmp_path):
    from skillkit.viz.history import load_policy_history

    run = make_gpreps_run(tmp_path / "run", FakeTableTennisModel(), "table-tennis", updates=2)
    history, model = load_gpreps_run(run, 0)
    assert len(history) == 3 and type(model) is FakeTableTennisModel
    assert len(load_policy_history(run, 0)) == 3
    with Viewer("table-tennis", history=history, port=0, environment=False) as v:
        layers = v.add_model_layers(model, n_samples=4)
        assert [layer.label for layer in layers] == list(TABLE_TENNIS_LAYERS)
        labels = [label for label, _ in v.legend()]
        assert labels == ["simulator rollout", "simulator rollout: ball", *TABLE_TENNIS_LAYERS]
        racket = "racket_models_racket_centre"
        last = v.layers[racket].points.copy()
        v.set_update(0)  # another policy: another ω, recomputed
        assert not np.allclose(v.layers[racket].points, last)
        np.testing.assert_array_equal(v.omega, history[0].mean_of(v.context[None])[0])


# ----------------------------------------------------------------------------- skillkit view
def test_cli_gpreps_errors_give_one_line_and_exit_code_2(tmp_path, capsys):
    hockey_run = make_gpreps_run(tmp_path / "hockey", FakeHockeyModel(), "hockey")
    bad_run = make_gpreps_run(
        tmp_path / "bad", FixedAnswerModel({"m": {"trajectories": np.zeros((2, 5))}}), "hockey"
    )
    (tmp_path / "garbage").mkdir()
    (tmp_path / "garbage" / "trials.npz").write_bytes((hockey_run / "trials.npz").read_bytes())
    (tmp_path / "garbage" / "reward_model_trial0.pkl").write_bytes(b"junk")
    cases = [
        (["hockey", "--gpreps", str(tmp_path / "nope")], "gpreps: no such run folder"),
        (["hockey", "--gpreps", str(hockey_run), "--trial", "1"], "no reward model of trial 1"),
        (["hockey", "--gpreps", str(tmp_path / "garbage")], "not a skillkit reward-model file"),
        (["table-tennis", "--gpreps", str(hockey_run)], "fitted on task 'hockey'"),
        (["hockey", "--gpreps", str(hockey_run), "--policy", "x.npz"], "not both"),
        (["hockey", "--gpreps", str(bad_run)], "gpreps: model layer 'm': trajectories"),
        (["hockey", "--gpreps", str(hockey_run), "--samples", "0"], "gpreps: n_samples"),
    ]
    for argv, message in cases:
        code, err = run_cli(argv, capsys)
        assert code == 2, argv
        assert err.startswith("skillkit view: error: ") and message in err, err
        assert err.count("\n") == 1 and "Traceback" not in err


def test_cli_gpreps_serves_the_runs_policy_and_model_layers(tmp_path, capsys, monkeypatch):
    run = make_gpreps_run(tmp_path / "run", FakeHockeyModel("hockey-real"), "hockey-real")
    seen = {}

    def serve_once(self):  # instead of blocking until Ctrl-C
        seen.update(nodes=self.node_names(), update=self.update_index, legend=self.legend())
        self.stop()

    monkeypatch.setattr(Viewer, "serve_forever", serve_once)
    code, _ = run_cli(
        ["hockey-real", "--gpreps", str(run), "--samples", "3", "--port", "0"], capsys
    )
    assert code == 0
    assert seen["update"] == 2  # the run's last policy
    for name in HOCKEY_LAYERS.values():
        assert f"/predictions/{name}/mean" in seen["nodes"]
    assert [label for label, _ in seen["legend"]] == ["simulator rollout", *HOCKEY_LAYERS]


def test_a_run_can_keep_its_model_in_trials_npz(tmp_path):
    """The experiments keep the model as bytes in trials.npz (``trial<K>__reward_model``):
    load_gpreps_run reads it there when the file is absent; corrupt bytes are refused."""
    folder = make_gpreps_run(tmp_path / "run", FakeHockeyModel(), "hockey", trial=1)
    reward_model_path(folder, 1).unlink()
    with pytest.raises(ValueError, match="no reward model of trial 1"):
        load_gpreps_run(folder, 1)
    with np.load(folder / "trials.npz") as f:
        arrays = dict(f)
    data = dumps_reward_model(FakeHockeyModel())
    arrays["trial1__reward_model"] = np.frombuffer(data, dtype=np.uint8)
    np.savez_compressed(folder / "trials.npz", **arrays)
    history, model = load_gpreps_run(folder, 1)
    assert type(model) is FakeHockeyModel and len(history.policies) == 3
    assert type(loads_reward_model(data)) is FakeHockeyModel
    with pytest.raises(ValueError, match="not a skillkit reward-model file"):
        loads_reward_model(data[5:], "cut")


class _ModelWithGPs(FakeHockeyModel):
    """A reward model holding fitted GPs (two, one shared) and its own copy of a predictor."""

    def __init__(self):
        from skillkit.models.gp import ExactGP
        from skillkit.models.sparse import FITC

        rng = np.random.default_rng(0)
        X = rng.uniform(-2, 2, (60, 3))
        Y = np.column_stack([np.sin(X[:, 0]) + 0.05 * rng.standard_normal(60), X[:, 1] ** 2])
        self.exact = ExactGP(n_steps=20).fit(X, Y, rng=0)
        self.sparse = FITC(n_inducing=10, n_steps=20).fit(X, Y, rng=0)
        self.same = self.exact  # one object, stored once
        self.queries = rng.uniform(-2, 2, (7, 3))


def test_a_stored_model_keeps_its_gps_without_their_caches():
    """dumps_reward_model leaves out each fitted GP's Cholesky factor and predictor (the last
    step of its fit) and loads_reward_model makes them again: the same computation on the
    same inputs in this process, so the predictions are equal bit for bit; the bytes are a
    fraction of a plain pickle's."""
    model = _ModelWithGPs()
    data = dumps_reward_model(model)
    assert len(data) < 0.5 * len(pickle.dumps(model, protocol=pickle.HIGHEST_PROTOCOL))
    back = loads_reward_model(data)
    assert back.same is back.exact
    for name in ("exact", "sparse"):
        a, b = getattr(model, name), getattr(back, name)
        assert b.predictor is not None
        for x, y in zip(a.predict(model.queries), b.predict(model.queries), strict=True):
            np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(model.exact.cholesky.numpy(), back.exact.cholesky.numpy())
    assert model.exact.predictor is not None  # dumping changed nothing of the original


# ----------------------------------------------------------------------------- static figure
def test_run_paths_figure_draws_each_layer_and_the_real_paths(tmp_path):
    """The static picture of ``skillkit view --gpreps``: one series per model layer holding
    its L paths (NaN-separated) on the chosen world axes, then the rollout's real paths."""
    from skillkit.viz.figures import gpreps_run_paths_figure, model_paths_figure

    run = make_gpreps_run(tmp_path / "run", FakeTableTennisModel(), "table-tennis", updates=2)
    fig = gpreps_run_paths_figure(run, 0, update=1, n_samples=4, seed=3, axes=(0, 2))
    names = [trace.name for trace in fig.data]
    assert names[:3] == [f"{label} (4 sampled)" for label in TABLE_TENNIS_LAYERS]
    assert names[3:] == ["real: ball"]
    # ball flight: 4 paths of 30 points, each followed by a NaN gap, drawn as x–z
    model = FakeTableTennisModel()
    s = model.task.sample_context(0)
    layers = model.prediction_layers(s, np.zeros(3), 4, rng=7)
    fig = model_paths_figure(model, s, np.zeros(3), n_samples=4, rng=7, axes=(0, 2))
    x = np.asarray(fig.data[1].x, dtype=float).reshape(4, 31)
    z = np.asarray(fig.data[1].y, dtype=float).reshape(4, 31)
    assert np.isnan(x[:, -1]).all() and np.isnan(z[:, -1]).all()
    np.testing.assert_array_equal(
        x[:, :-1], layers["ball model: ball flight"]["trajectories"][..., 0]
    )
    np.testing.assert_array_equal(
        z[:, :-1], layers["ball model: ball flight"]["trajectories"][..., 2]
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"axes": (0, 0)}, "axes"),
        ({"axes": (0, 3)}, "axes"),
        ({"real": [1, 2]}, "real"),
        ({"real": {"puck": np.zeros((5, 4))}}, r"real\['puck'\]"),
        ({"real": {"puck": np.zeros((5, 2))}, "axes": (0, 2)}, r"real\['puck'\]"),
    ],
)
def test_model_paths_figure_names_bad_arguments(kwargs, match):
    from skillkit.viz.figures import model_paths_figure

    model = FakeHockeyModel()
    s = model.task.sample_context(0)
    with pytest.raises(ValueError, match=match):
        model_paths_figure(model, s, np.zeros(4), n_samples=2, rng=0, **kwargs)


def test_run_paths_figure_names_a_bad_update(tmp_path):
    from skillkit.viz.figures import gpreps_run_paths_figure

    run = make_gpreps_run(tmp_path / "run", FakeHockeyModel(), "hockey", updates=2)
    with pytest.raises(ValueError, match="update"):
        gpreps_run_paths_figure(run, 0, update=3)


@pytest.mark.parametrize("exp_id", ["fig4.10", "fig4.11", "fig4.12"])
def test_the_stored_runs_reward_models_load_and_draw_their_layers(exp_id):
    """The reward models pickled in the shipped paper results load with today's classes and
    predict: a rename of an attribute or a module-level name they reference breaks this."""
    from skillkit.experiments import stored_run
    from skillkit.models.reward import RewardModel

    history, model = load_gpreps_run(stored_run(exp_id).path, 0)
    assert isinstance(model, RewardModel)
    context = model.task.sample_context(np.random.default_rng(0))
    policy = history[-1]
    layers = model_layers(model, context, policy.mean_of(context), n_samples=2, rng=0)
    assert layers and all(np.all(np.isfinite(layer["trajectories"])) for layer in layers)
