"""The viewer app (skillkit.viz.viewer) and ``skillkit view`` (cli_view), headless: server
start/stop frees the port, port-in-use errors name the port, GUI callbacks re-run the policy,
prediction layers, learning playback, policy-history files and bad input."""

from __future__ import annotations

import argparse
import errno
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import mujoco
import numpy as np
import pytest

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks import Task, make
from skillkit.trajectory import Trajectory
from skillkit.viz import cli_view
from skillkit.viz.history import load_policy_history, save_policy_history
from skillkit.viz.viewer import PortInUseError, Viewer, _call_silenced, start_server
from tests._tolerances import fp_tol


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def can_bind(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def http_status(url: str) -> int:
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.status


@pytest.fixture(scope="module")
def pendulum():
    return make("pendulum")


@pytest.fixture(scope="module")
def viewer(pendulum):
    v = Viewer(pendulum, context=[1.0, 0.5], port=0, seed=3).start()
    yield v
    v.stop()


# ----------------------------------------------------------------------------- server lifecycle
def test_start_serves_on_localhost_and_stop_frees_the_port(pendulum):
    port = free_port()
    v = Viewer(pendulum, port=port).start()
    try:
        assert v.port == port and v.server.get_host() == "127.0.0.1"
        assert v.url == f"http://127.0.0.1:{port}/"
        assert http_status(v.url) == 200
        assert not can_bind(port)
    finally:
        v.stop()
    assert v.server is None and can_bind(port)
    v.stop()  # idempotent
    again = Viewer(pendulum, port=port).start()  # the same port is usable again
    try:
        assert again.port == port
    finally:
        again.stop()


def test_viser_is_quiet_unless_verbose(pendulum, capfd):
    """viser prints its banner and "Server stopped" whatever its own ``verbose`` says; the
    viewer keeps both out of the output (notebook cells, tests) unless asked."""
    with Viewer(pendulum, port=0):
        pass
    server = start_server(port=0)
    server.stop()
    out, err = capfd.readouterr()
    assert "viser" not in out + err and "Server stopped" not in out + err
    import rich

    def shout():
        rich.print("[bold]loud[/bold]")
        return 7

    assert _call_silenced(shout) == 7
    with pytest.raises(ZeroDivisionError):
        _call_silenced(lambda: 1 / 0)
    out, err = capfd.readouterr()
    assert "loud" not in out + err
    with Viewer(pendulum, port=0, verbose=True) as v:
        url = f"http://127.0.0.1:{v.port}"
    out, _ = capfd.readouterr()
    assert url in out and "Server stopped" in out


def test_port_in_use_is_reported_with_the_port(pendulum):
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        v = Viewer(pendulum, port=port)
        with pytest.raises(
            PortInUseError, match=f"^port {port} on 127.0.0.1 is already in use"
        ) as info:
            v.start()
        assert (info.value.port, info.value.errno) == (port, errno.EADDRINUSE)
        assert v.server is None


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"port": -1}, "port"),
        ({"port": 70000}, "port"),
        ({"port": "80"}, "port"),
        ({"host": ""}, "host"),
        ({"context": [9.0, 0.0]}, "alpha0=9 is outside"),
        ({"context": [0.0]}, "context"),
        ({"policy": LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)}, "dim=3"),
        ({"policy": "gains.npz"}, "policy"),
    ],
)
def test_bad_viewer_arguments(pendulum, kwargs, match):
    with pytest.raises(ValueError, match=match):
        Viewer(pendulum, **kwargs)


def test_unknown_task_and_unresolvable_host():
    with pytest.raises(ValueError, match="unknown task 'nope'"):
        Viewer("nope")
    with pytest.raises(ValueError, match="host"):
        Viewer("pendulum", host="no-such-host.invalid", port=free_port()).start()


# ----------------------------------------------------------------------------- rollouts and GUI
def test_context_slider_reruns_the_policy_mean_with_the_episode_seed(viewer, pendulum):
    sliders = viewer.gui["context"]
    assert [s.label for s in sliders] == ["alpha0", "alpha_dot0"]
    assert [(s.min, s.max) for s in sliders] == [(-np.pi, np.pi), (-4.0, 4.0)]
    sliders[0].value = -0.8  # as if moved in the browser
    np.testing.assert_array_equal(viewer.context, [-0.8, 0.5])
    omega = viewer.policy.mean_of(viewer.context)
    expected = pendulum.rollout(omega, viewer.context, np.random.default_rng(3))
    np.testing.assert_array_equal(viewer.trajectory.states, expected.states)
    np.testing.assert_array_equal(viewer.omega, omega)
    assert f"{pendulum.reward(expected, viewer.context):.4g}" in viewer.gui["status"].content
    viewer.set_context([0.3, -1.0])
    assert [s.value for s in sliders] == pytest.approx([0.3, -1.0])
    with pytest.raises(ValueError, match="alpha_dot0=5 is outside"):
        viewer.set_context([0.0, 5.0])


class BlowUp(Task):
    """A toy MuJoCo task whose rollout diverges (NaN) when ω[0] > 1."""

    name, context_dim, parameter_dim = "blow-up", 0, 1
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint type="hinge"/><geom type="sphere" size="0.1"/>'
        "</body></worldbody></mujoco>"
    )

    def scene_model(self):
        return self.model

    def _simulate(self, omega, context, rng):
        times = np.linspace(0.0, 1.0, 5)
        q = omega[0] * times if omega[0] <= 1 else np.full(5, np.nan)
        return Trajectory(times, np.column_stack([q, np.zeros(5)]), np.zeros((5, 1)))

    def _reward(self, trajectory, context):
        return -float(trajectory.states[-1, 0] ** 2)

    def initial_policy(self):
        return LinearGaussianPolicy(np.array([0.5]), np.eye(1))


def test_a_failed_rollout_is_reported_not_raised():
    task = BlowUp()
    bad = LinearGaussianPolicy(np.array([2.0]), np.eye(1))
    with pytest.warns(RuntimeWarning, match="rollout failed"), Viewer(task, bad, port=0) as v:
        assert v.trajectory.failed
        assert v.gui["status"].content.startswith("**rollout failed**")
        assert "non-finite" in v.gui["status"].content
        assert not any(n.startswith("/trails") for n in v.node_names())
        v.set_time(0.5)  # nothing to show, and no error
        v.policy = task.initial_policy()
        v.gui["mean"].value = True  # "Use the mean ω": a working rollout again
        assert not v.trajectory.failed and "/trails/effector" in v.node_names()
        assert v.gui["status"].content == "reward R = -0.25 (mean ω)"


def test_time_slider_poses_the_scene(viewer):
    traj = viewer.trajectory
    viewer.gui["time"].value = float(traj.times[7])
    bob = viewer.scene.points(traj.states[7])
    R = viewer.scene.link.wxyz
    angle = -2 * np.arctan2(R[2], R[0])  # rotation about −y by α
    # α → (cos α/2, −sin α/2) → atan2 → ×2 comes back off by ~6 ε max(|α|, π) (modulo 2π),
    # moving the bob by l times that; the bob's position adds ~4 ε of its size
    alpha, length = abs(traj.states[7, 0]), viewer.scene.LENGTH
    pivot = np.abs(viewer.scene.PIVOT).max()
    tol = fp_tol(6, scale=length * max(alpha, np.pi)) + fp_tol(4, scale=pivot + length)
    np.testing.assert_allclose(viewer.scene.points([angle, 0.0]), bob, atol=tol)
    assert viewer.gui["time"].max == pytest.approx(traj.times[-1])


def test_sampled_omega_is_reproducible_with_the_seed(pendulum):
    omegas = []
    for _ in range(2):
        with Viewer(pendulum, context=[0.5, 0.0], port=0, seed=11) as v:
            v.gui["sample"].value = True  # a click
            omegas.append(v.omega.copy())
            assert "sampled" in v.gui["status"].content
    np.testing.assert_array_equal(omegas[0], omegas[1])
    rng = np.random.default_rng(11)
    np.testing.assert_array_equal(omegas[0], pendulum.initial_policy().sample([[0.5, 0.0]], rng)[0])


def test_play_advances_the_timeline_and_pause_stops_it(viewer):
    viewer.set_time(0.0)
    viewer.set_playing(True)
    assert viewer.gui["play"].label == "Pause"
    deadline = time.monotonic() + 20
    while viewer.time == 0.0 and time.monotonic() < deadline:
        time.sleep(0.05)
    viewer.set_playing(False)
    assert viewer.time > 0.0 and viewer.gui["play"].label == "Play"
    t = viewer.time
    time.sleep(0.3)
    assert viewer.time == t


def test_trails_checkbox(viewer):
    assert "/trails/bob" in viewer.node_names()
    viewer.gui["trails"].value = False
    assert "/trails/bob" not in viewer.node_names()
    assert viewer.server.scene.get_handle_by_name("/trails/bob") is None
    viewer.gui["trails"].value = True
    handle = viewer.server.scene.get_handle_by_name("/trails/bob")
    assert handle.vertices.shape[0] == viewer.trajectory.n_steps * 6
    assert "`/trails/bob`" in viewer.gui["tree"].content


# ----------------------------------------------------------------------------- predictions
def test_prediction_layer_nodes_checkbox_and_markers(viewer):
    traj = viewer.trajectory
    L, T = 4, traj.n_steps
    samples = traj.states[None] + 0.05 * np.random.default_rng(0).standard_normal((L, T, 2))
    layer = viewer.add_prediction_layer("gp", samples, color=(200, 0, 200), opacity=0.3)
    for node in ("samples", "mean", "now"):
        assert viewer.server.scene.get_handle_by_name(f"/predictions/gp/{node}") is not None
    assert layer.nodes["/predictions/gp/samples"].opacity == pytest.approx(0.3)
    assert layer.nodes["/predictions/gp/samples"].vertices.shape[0] == L * T * 6
    np.testing.assert_allclose(layer.points, viewer.scene.points(samples))
    viewer.set_time(float(traj.times[5]))
    np.testing.assert_allclose(
        layer.nodes["/predictions/gp/now"].points, viewer.scene.points(samples[:, 5]), atol=1e-3
    )  # float16 on the wire
    layer.checkbox.value = False
    assert not any(h.visible for h in layer.nodes.values())
    layer.checkbox.value = True
    assert layer.visible
    viewer.add_prediction_layer("pts", viewer.scene.points(samples), space="points")
    assert {"gp", "pts"} <= set(viewer.layers)
    viewer.remove_prediction_layer("gp")
    assert viewer.server.scene.get_handle_by_name("/predictions/gp/samples") is None
    assert "/predictions/gp/mean" not in viewer.node_names()


@pytest.mark.parametrize(
    "args, match",
    [
        (("gp", np.zeros((2, 5, 3))), "dimension 2"),
        (("gp", np.zeros((2, 1, 2))), "T >= 2"),
        (("a/b", np.zeros((2, 5, 2))), "name"),
        (("gp", np.zeros((5, 2))), "trajectories"),
        (("gp", np.full((2, 5, 2), np.nan)), "non-finite"),
    ],
)
def test_prediction_layer_bad_input(viewer, args, match):
    with pytest.raises(ValueError, match=match):
        viewer.add_prediction_layer(*args)
    with pytest.raises(ValueError, match="space"):
        viewer.add_prediction_layer("gp", np.zeros((2, 5, 2)), space="joint")


# ----------------------------------------------------------------------------- learning playback
STEP = np.array([0.5, 0.1])


@pytest.fixture(scope="module")
def history_file(tmp_path_factory, pendulum):
    """A policy history of 3 updates, each moving the mean by STEP, 2 rollouts per update."""
    p0 = pendulum.initial_policy()
    policies = [
        LinearGaussianPolicy(p0.mean + k * STEP, p0.cov, p0.gain, p0.context_dim) for k in range(4)
    ]
    path = tmp_path_factory.mktemp("hist") / "history.npz"
    rollouts, mean_reward = [0, 2, 4, 6], [-4.0, -3.0, -2.0, -1.0]
    return save_policy_history(
        path, policies, rollouts=rollouts, mean_reward=mean_reward, task="pendulum"
    )


def test_learning_playback_steps_through_updates(history_file, pendulum):
    history = load_policy_history(history_file)
    with Viewer(pendulum, context=[1.0, 0.0], history=history, port=0, seed=5) as v:
        assert v.update_index == 3 and v.policy is history[3]
        v.gui["update"].value = 1  # the slider, as if moved in the browser
        assert v.update_index == 1 and v.policy is history[1]
        expected = pendulum.rollout(
            history[1].mean_of([1.0, 0.0]), [1.0, 0.0], np.random.default_rng(5)
        )
        np.testing.assert_array_equal(v.trajectory.states, expected.states)
        assert "2 rollouts" in v.gui["history_info"].content
        v.gui["ghosts"].value = True
        assert {f"/history/update{k}/bob" for k in range(4)} <= set(v.node_names())
        v.gui["ghosts"].value = False
        assert not any(n.startswith("/history") for n in v.node_names())
        with pytest.raises(ValueError, match=r"update: expected an integer in \[0, 3\]"):
            v.set_update(4)


def test_a_history_of_another_task_is_refused(tmp_path, pendulum):
    other = save_policy_history(tmp_path / "other", [pendulum.initial_policy()], task="hockey")
    with pytest.raises(ValueError, match="recorded on task 'hockey'"):
        Viewer(pendulum, history=load_policy_history(other))
    with pytest.raises(ValueError, match="history: expected a PolicyHistory"):
        Viewer(pendulum, history=[pendulum.initial_policy()])


# ----------------------------------------------------------------------------- skillkit view
def run_cli(argv, capsys) -> tuple[int, str]:
    parser = argparse.ArgumentParser(prog="skillkit")
    cli_view.add_view_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["view", *argv])
    code = args.func(args)
    return code, capsys.readouterr().err


def test_cli_bad_input_gives_one_line_and_exit_code_2(tmp_path, capsys):
    (tmp_path / "junk.npz").write_bytes(b"junk")
    cases = [
        (["nope"], "unknown task 'nope'"),
        (["pendulum", "--context", "9", "0"], "alpha0=9 is outside"),
        (["pendulum", "--context", "1"], "context: expected shape"),
        (["pendulum", "--policy", str(tmp_path / "junk.npz")], "not a readable .npz"),
        (["pendulum", "--predictions", str(tmp_path / "junk.npz")], "predictions"),
    ]
    for argv, message in cases:
        code, err = run_cli(argv, capsys)
        assert code == 2, argv
        assert err.startswith("skillkit view: error: ") and message in err, err
        assert err.count("\n") == 1 and "Traceback" not in err
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        code, err = run_cli(["pendulum", "--port", str(port)], capsys)
        assert code == 2 and f"port {port}" in err and "in use" in err


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class _FakeViewer:
    """Stands in for a started Viewer; Ctrl-C lands while the "serving" line is formatted."""

    url = "http://127.0.0.1:1/"

    def __init__(self) -> None:
        self.stopped = 0

    @property
    def task(self):
        raise KeyboardInterrupt  # as a SIGINT arriving just before serve_forever

    def start(self):
        return self

    def stop(self) -> None:
        self.stopped += 1

    def serve_forever(self) -> None:  # pragma: no cover - never reached here
        raise AssertionError("serve_forever reached")


def test_cli_ctrl_c_before_serving_stops_the_server(monkeypatch, capsys):
    """A Ctrl-C after the server started but before ``serve_forever`` (here: while the
    "serving" line is printed) stops the server and exits 0, without a traceback."""
    fake = _FakeViewer()
    monkeypatch.setattr(cli_view, "build_viewer", lambda args, history=None: fake)
    try:
        code, err = run_cli(["pendulum"], capsys)
    except KeyboardInterrupt:  # not re-raised: it would end the whole test session
        pytest.fail(f"Ctrl-C escaped run_view (viewer stopped {fake.stopped} times)")
    assert code == 0 and err == ""
    assert fake.stopped >= 1


def test_cli_serves_until_interrupted_and_frees_the_port(tmp_path, history_file):
    port = free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "skillkit.viz.cli_view",
            "pendulum",
            "--port",
            str(port),
            "--context",
            "0.5",
            "-1",
            "--policy",
            str(history_file),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        # the default SIGINT action in the child, whatever the test process inherited or set
        # (an ignored SIGINT is inherited across exec, and Python then installs no handler)
        preexec_fn=_default_sigint,
    )
    try:
        deadline = time.monotonic() + 120
        lines = [""]
        while "serving" not in lines[-1]:
            lines.append(proc.stdout.readline())
            assert lines[-1] or proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline
        assert f"http://127.0.0.1:{port}/" in lines[-1]
        assert http_status(f"http://127.0.0.1:{port}/") == 200
        proc.send_signal(signal.SIGINT)
        # communicate drains both pipes while waiting: a full stderr pipe cannot block the exit
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
        output = "".join(lines) + out + err
        assert "viser" not in output, output  # no banner, no "Server stopped" (no --verbose)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert can_bind(port)


@pytest.mark.slow  # imports torch/gpytorch and fits a GP
def test_gp_samples_as_a_prediction_layer_follow_the_real_rollout(pendulum):
    """Predicted vs real: a GP forward model (skillkit.models) learned from pendulum rollouts,
    sampled with skillkit.models.sampling, drawn as a layer next to the real rollout."""
    import torch

    from skillkit.models.gp import ExactGP, ForwardModel
    from skillkit.models.sampling import sample_trajectories
    from skillkit.tasks.pendulum import TORQUE_LIMIT

    rng = np.random.default_rng(0)
    policy = pendulum.initial_policy()
    x, u, xn = [], [], []
    for s in pendulum.sample_context(rng, n=15):
        traj = pendulum.rollout(policy.sample(s, rng), s, rng)
        a, b, c = traj.transitions()
        x.append(a), u.append(b), xn.append(c)
    model = ForwardModel(ExactGP(n_steps=30)).fit(np.vstack(x), np.vstack(u), np.vstack(xn), rng=0)
    with Viewer(pendulum, context=[1.5, 0.0], port=0) as v:
        gains = torch.as_tensor(v.omega)

        def feedback(t, state, pair):
            return torch.clamp(state @ gains, -TORQUE_LIMIT, TORQUE_LIMIT)[:, None]

        T = v.trajectory.n_steps - 1
        sampled = sample_trajectories(model, v.context[None], feedback, T, 10, rng=1)
        states = sampled.states[0].numpy()  # (L, T + 1, 2)
        layer = v.add_prediction_layer("gp", states)
        real = v.scene.points(v.trajectory.states)
        mean, spread = layer.points.mean(axis=0), layer.points.std(axis=0, ddof=1)
        error = np.linalg.norm(mean - real, axis=1)  # the bob, predicted vs simulated (m)
        assert error[0] == 0  # every sample starts at the real start state
        # the real path lies inside the samples' band: within 3 sample std of their mean
        assert np.all(error[1:] <= 3 * np.linalg.norm(spread[1:], axis=1)), error
        assert v.server.scene.get_handle_by_name("/predictions/gp/samples") is not None
