"""The browser viewer: a viser server showing a task's rollouts, model predictions and learning
playback (:class:`Viewer`); a port in use raises :class:`PortInUseError`."""

from __future__ import annotations

import contextlib
import errno
import functools
import html
import socket
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from skillkit._validation import as_generator, check_array, check_choice, check_type
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.trajectory import Trajectory
from skillkit.viz import DEFAULT_HOST, DEFAULT_PORT
from skillkit.viz.history import PolicyHistory
from skillkit.viz.scenes import (
    COLORS,
    TaskScene,
    add_trail,
    check_opacity,
    check_rgb,
    interpolate,
    node_name,
    task_scene,
)

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "PortInUseError",
    "PredictionLayer",
    "Viewer",
    "start_server",
]

PREDICTION_COLORS = [(220, 40, 160), (150, 70, 220), (20, 170, 170), (230, 160, 0)]
"""Colours given to prediction layers in turn when none is specified."""
MAX_GHOST_UPDATES = 12
"""At most this many earlier updates get ghost trails in learning playback."""
_Result = TypeVar("_Result")


class PortInUseError(OSError):
    """The viewer's port (``port`` on ``host``) is taken by another process (EADDRINUSE)."""

    def __init__(self, host: str, port: int, detail: str = "") -> None:
        super().__init__(f"port {port} on {host} is already in use{detail}; choose another port")
        self.errno, self.host, self.port = errno.EADDRINUSE, host, port


@dataclass
class PredictionLayer:
    """A layer of world-frame ``points`` (L, T, 3) at ``times`` (T,) with ``nodes``
    ``/predictions/<name>/samples``, ``…/mean`` and ``…/now`` (the L points at the timeline's
    time); ``label`` names it in the checkbox and the legend."""

    name: str
    points: np.ndarray
    times: np.ndarray
    color: tuple
    opacity: float
    label: str
    nodes: dict = field(default_factory=dict)
    checkbox: object = None

    @property
    def visible(self) -> bool:
        return bool(self.nodes[f"/predictions/{self.name}/samples"].visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        for handle in self.nodes.values():
            handle.visible = bool(value)

    def at(self, t: float) -> np.ndarray:
        """The L predicted points at time ``t`` (linear interpolation), shape (L, 3)."""
        return interpolate(self.times, np.swapaxes(self.points, 0, 1), t)


def _call_silenced(fn: Callable[[], _Result]) -> _Result:
    """``fn()`` in a helper thread whose ``rich`` output is dropped; result or error passed on."""
    import rich

    def run() -> _Result:
        rich.get_console().begin_capture()  # dropped with the thread
        return fn()

    with ThreadPoolExecutor(1, thread_name_prefix="skillkit-quiet-call") as pool:
        return pool.submit(run).result()


def start_server(
    host: str = DEFAULT_HOST, port: int = 0, *, label: str | None = None, verbose: bool = False
):
    """A started ``viser.ViserServer``, quiet unless ``verbose``; ``port`` 0 takes any free port
    (a taken one: viser moves on to the next); ``label`` titles the GUI."""
    import viser

    make = functools.partial(viser.ViserServer, host=host, port=port, verbose=verbose, label=label)
    if verbose:
        return make()
    import rich

    server = _call_silenced(make)
    # drop what rich prints from now on in the server's event-loop thread (unless it is closed)
    with contextlib.suppress(RuntimeError):
        server.get_event_loop().call_soon_threadsafe(rich.get_console().begin_capture)
    return server


def _check_port(host: str, port: int) -> None:
    """Raise :class:`PortInUseError` if ``host:port`` cannot be bound because it is taken."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ValueError(f"host: cannot resolve {host!r} ({exc.strerror})") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server will
        try:
            sock.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise PortInUseError(host, port) from None
            raise ValueError(f"host: cannot listen on {host}:{port} ({exc.strerror})") from None


class Viewer:
    """A viser server showing a task (or its name): a timeline, context sliders re-running the
    mean ω = a + A φ(s) (Eq. 3.13) of ``policy`` (default: the last of ``history``, else the
    task's initial one) or a sample ω ~ π(ω|s), prediction layers and learning playback.
    ``context`` defaults to mid-range, ``port`` 0 takes any free port, ``seed`` seeds every
    rollout and ω sample; ``environment=False`` drops viser's HDRI map, ``verbose`` lets it print.

    Examples
    --------
    >>> with Viewer("pendulum", port=0) as viewer:       # doctest: +SKIP
    ...     viewer.set_context([1.0, 0.0])
    ...     viewer.add_prediction_layer("gp", samples)  # (L, T, n_x)
    """

    def __init__(
        self,
        task,
        policy: LinearGaussianPolicy | None = None,
        context=None,
        *,
        history: PolicyHistory | None = None,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        seed: int = 0,
        environment: bool = True,
        verbose: bool = False,
    ) -> None:
        from skillkit.tasks import Task, make

        self.task = make(task) if isinstance(task, str) else task
        check_type(self.task, Task, "task", "a Task or a registered task name")
        check_type(history, (PolicyHistory, type(None)), "history", "a PolicyHistory")
        if history is not None and history.task and history.task != self.task.name:
            msg = f"policy: history recorded on task {history.task!r}, not {self.task.name!r}"
            raise ValueError(msg)
        self.history = history
        if policy is None:
            policy = history[-1] if history is not None else self.task.initial_policy()
        self.policy = self._check_policy(policy, "policy")
        if history is not None:
            self._check_policy(history[0], "policy")
        if context is None:
            context = 0.5 * (np.asarray(self.task.context_low) + np.asarray(self.task.context_high))
        self.context = self.task.check_context(context)
        bad_port = not isinstance(port, (int, np.integer)) or isinstance(port, bool)
        if bad_port or not 0 <= port < 65536:
            raise ValueError(f"port: expected an integer in [0, 65535], got {port!r}")
        if not isinstance(host, str) or not host:
            raise ValueError(f"host: expected a host name or address, got {host!r}")
        self.host, self._requested_port, self.seed = host, int(port), int(seed)
        self.environment, self.verbose = bool(environment), bool(verbose)
        self._omega_rng = as_generator(self.seed)
        self.server = self.trajectory = self.omega = self.model = self._thread = None
        self.scene: TaskScene | None = None
        self.time = 0.0
        self.update_index = len(history) - 1 if history is not None else None
        self.layers: dict[str, PredictionLayer] = {}
        self.model_samples, self.model_seed, self.model_layer_names = 10, 0, []
        self._model_key, self._model_error = None, ""
        self._trail_nodes, self._ghost_nodes, self.gui = {}, {}, {}
        self._lock, self._stop = threading.RLock(), threading.Event()
        self.playing = self.stepping_updates = False
        self._local = threading.local()  # .quiet: this thread is moving a GUI input itself

    def _check_policy(self, policy, name: str) -> LinearGaussianPolicy:
        check_type(policy, LinearGaussianPolicy, name, "a LinearGaussianPolicy")
        t = self.task
        if policy.dim != t.parameter_dim or policy.context_dim != t.context_dim:
            raise ValueError(
                f"{name}: has dim={policy.dim}, context_dim={policy.context_dim}; task "
                f"{t.name!r} needs dim={t.parameter_dim}, context_dim={t.context_dim}"
            )
        return policy

    @property
    def port(self) -> int:
        """The bound port (the requested one; the OS's choice for port 0)."""
        return self.server.get_port() if self.server is not None else self._requested_port

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> Viewer:
        """Start the server, build the scene and the GUI and show the first rollout; raises
        :class:`PortInUseError` when the port is taken."""
        if self.server is not None:
            raise ValueError("viewer: already started")
        port = self._requested_port
        if port:
            _check_port(self.host, port)
        label = f"skillkit · {self.task.name}"
        server = start_server(self.host, port, label=label, verbose=self.verbose)
        if port and server.get_port() != port:
            bound = server.get_port()
            server.stop()  # viser moved on to the next free port: refuse that
            raise PortInUseError(self.host, port, f" (taken while starting; viser offered {bound})")
        self.server = server
        try:
            with self._lock:
                self.scene = task_scene(server.scene, self.task)
                self.scene.set_context(self.context)
                if not self.environment:
                    server.scene.configure_environment_map(None)
                    light = {"sky_color": (255, 255, 255), "ground_color": (120, 120, 120)}
                    server.scene.add_light_hemisphere("/lights/hemisphere", **light, intensity=2.0)
                cam = server.initial_camera
                cam.position, cam.look_at = self.scene.camera_position, self.scene.camera_look_at
                self._build_gui()
                self._rerun()
            self._stop.clear()
            self._thread = threading.Thread(
                target=self._animate, name="skillkit-viewer-play", daemon=True
            )
            self._thread.start()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop playback and the server and free the port (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self) -> Viewer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def serve_forever(self) -> None:
        """Block until Ctrl-C, then stop."""
        try:
            while not self._stop.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def _build_gui(self) -> None:
        gui, task, g = self.server.gui, self.task, self.gui
        g["status"] = gui.add_markdown("")
        with gui.add_folder("Playback"):
            g["time"] = gui.add_slider("time [s]", min=0.0, max=1.0, step=0.01, initial_value=0.0)
            g["play"] = gui.add_button("Play", icon="player-play")
            g["trails"] = gui.add_checkbox("trails", True)
        g["time"].on_update(self._unless_quiet(lambda: self.set_time(g["time"].value)))
        g["play"].on_click(lambda _: self.set_playing(not self.playing))
        g["trails"].on_update(lambda _: self._draw_trails())
        if task.context_dim:
            with gui.add_folder("Context s"):
                g["context"] = []
                for i in range(task.context_dim):
                    lo, hi = float(task.context_low[i]), float(task.context_high[i])
                    label = task.context_names[i] if i < len(task.context_names) else f"s[{i}]"
                    step = (hi - lo) / 100 if hi > lo else 1.0
                    slider = gui.add_slider(
                        label, min=lo, max=hi, step=step, initial_value=float(self.context[i])
                    )
                    slider.on_update(self._unless_quiet(self._context_from_gui))
                    g["context"].append(slider)
        with gui.add_folder("Policy"):
            g["sample"] = gui.add_button("Sample ω ~ π(ω|s)")
            g["mean"] = gui.add_button("Use the mean ω")
        g["sample"].on_click(lambda _: self._rerun(sample=True))
        g["mean"].on_click(lambda _: self._rerun())
        if self.history is not None:
            with gui.add_folder("Learning playback"):
                K = len(self.history) - 1
                g["update"] = gui.add_slider(
                    "policy update k", min=0, max=max(K, 1), step=1, initial_value=K, disabled=not K
                )
                g["step_updates"] = gui.add_button("Step through updates", icon="player-play")
                g["ghosts"] = gui.add_checkbox("trails of earlier updates", False)
                g["history_info"] = gui.add_markdown("")
            g["update"].on_update(
                self._unless_quiet(lambda: self.set_update(int(g["update"].value)))
            )
            g["step_updates"].on_click(lambda _: self._toggle_update_stepping())
            g["ghosts"].on_update(lambda _: self._draw_ghosts())
        g["predictions"] = gui.add_folder("Predictions", visible=False)
        with g["predictions"]:
            g["legend"] = gui.add_html("")
        with gui.add_folder("Scene tree", expand_by_default=False):
            g["tree"] = gui.add_markdown("")

    def node_names(self) -> list[str]:
        """Paths of every scene node the viewer made (task scene, trails, predictions)."""
        names = set(self.scene.nodes) if self.scene is not None else set()
        names |= set(self._trail_nodes) | set(self._ghost_nodes)
        for layer in self.layers.values():
            names |= set(layer.nodes)
        return sorted(names)

    def _refresh_tree(self) -> None:
        if "tree" in self.gui:
            self.gui["tree"].content = "\n".join(f"- `{n}`" for n in self.node_names())

    def _require_started(self) -> None:
        if self.server is None:
            raise ValueError("viewer: not started; call start() first")

    def _roll_out(self, policy, sample: bool = False):
        """(ω, trajectory) of ``policy``'s mean (or a sample) in the current context."""
        s = self.context if self.task.context_dim else None
        ctx = self.context[None, :] if self.task.context_dim else np.zeros((1, 0))
        omega = policy.sample(ctx, self._omega_rng) if sample else policy.mean_of(ctx)
        omega = np.atleast_2d(omega)[0]
        return omega, self.task.rollout(omega, s, np.random.default_rng(self.seed))

    def _rerun(self, sample: bool = False) -> Trajectory:
        """Roll out the policy in the current context (mean ω, or a sample) and show it."""
        with self._lock:
            self.omega, traj = self._roll_out(self.policy, sample)
            self.trajectory = traj
            if self.model is not None:
                self._update_model_layers()
            status = "sampled ω" if sample else "mean ω"
            if traj.failed:
                self.gui["status"].content = f"**rollout failed** ({status}): {traj.message}"
                self._draw_trails()
                return traj
            reward = self.task.reward(traj, self.context if self.task.context_dim else None)
            self.gui["status"].content = f"reward R = {reward:.4g} ({status})"
            t0, t1 = self.scene.time_range(traj)
            slider = self.gui["time"]
            dt = float(np.median(np.diff(traj.times))) if traj.n_steps > 1 else (t1 - t0) / 100
            slider.min, slider.max, slider.step = t0, max(t1, t0 + dt), max(dt, 1e-3)
            self._draw_trails()
            self.set_time(min(max(self.time, t0), t1))
            return traj

    def set_context(self, context) -> Trajectory:
        """Validate and set the context s, move the target and re-run the policy mean."""
        self._require_started()
        s = self.task.check_context(context)
        with self._lock:
            self.context = s
            self.scene.set_context(s)
            sliders = self.gui.get("context", [])
            self._set_quietly([(sl, float(v)) for sl, v in zip(sliders, s, strict=True)])
            return self._rerun()

    def _set_quietly(self, pairs) -> None:
        """Move GUI inputs without running their callbacks (viser runs them synchronously)."""
        self._local.quiet = True
        try:
            for handle, value in pairs:
                handle.value = value
        finally:
            self._local.quiet = False

    def _unless_quiet(self, fn: Callable[[], object]) -> Callable:
        """A GUI callback running ``fn()`` unless this thread is moving the input itself."""
        return lambda _event: None if getattr(self._local, "quiet", False) else fn()

    def _context_from_gui(self) -> None:
        values = [float(slider.value) for slider in self.gui["context"]]
        if not np.array_equal(values, self.context):
            self.set_context(values)

    def set_time(self, t: float) -> None:
        """Show the current rollout and the prediction layers' points at time ``t``."""
        self._require_started()
        with self._lock:
            self.time = float(t)
            traj = self.trajectory
            with self.server.atomic():
                if traj is not None and not traj.failed:
                    self.scene.show(traj, self.time)
                for layer in self.layers.values():
                    layer.nodes[f"/predictions/{layer.name}/now"].points = layer.at(self.time)
            self._set_quietly([(self.gui["time"], self.time)])

    def set_playing(self, playing: bool) -> None:
        """Start or pause playback of the timeline (loops at the end)."""
        self.playing = bool(playing)
        button = self.gui.get("play")
        if button is not None:
            button.label = "Pause" if self.playing else "Play"
            button.icon = "player-pause" if self.playing else "player-play"

    def _animate(self) -> None:
        period, last, last_update = 1 / 30, time.monotonic(), time.monotonic()
        while not self._stop.wait(period):
            now = time.monotonic()
            elapsed, last = now - last, now
            try:
                if self.playing and self.trajectory is not None and not self.trajectory.failed:
                    slider = self.gui["time"]
                    t = self.time + elapsed
                    self.set_time(slider.min if t > slider.max else t)
                if self.stepping_updates and now - last_update >= 1.0:
                    last_update = now
                    self.set_update((self.update_index + 1) % len(self.history))
            except Exception as exc:  # keep serving; show what went wrong
                self.playing = self.stepping_updates = False
                if "status" in self.gui and self.server is not None:
                    self.gui["status"].content = f"**playback stopped**: {exc}"

    def _remove(self, nodes: dict) -> None:
        for handle in nodes.values():
            handle.remove()
        nodes.clear()

    def _add_trails(self, nodes: dict, traj: Trajectory, prefix: str, color=None, **style):
        """A trail per path of ``traj`` with at least two points, kept in ``nodes``."""
        for key, path in self.scene.trails(traj).items():
            if path.shape[0] >= 2:
                c = color or (COLORS["ball"] if key == "ball" else COLORS["trail"])
                handle = add_trail(self.server.scene, f"{prefix}/{key}", path, c, **style)
                nodes[handle.name] = handle

    def _draw_trails(self) -> None:
        with self._lock:
            self._remove(self._trail_nodes)
            traj = self.trajectory
            if traj is not None and not traj.failed and self.gui["trails"].value:
                self._add_trails(self._trail_nodes, traj, "/trails")
            self._refresh_legend()
            self._refresh_tree()

    def set_update(self, k: int) -> Trajectory:
        """Show policy π_k of the history (learning playback) and re-run it."""
        self._require_started()
        if self.history is None:
            raise ValueError("update: this viewer has no policy history")
        K = len(self.history) - 1
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= K:
            raise ValueError(f"update: expected an integer in [0, {K}], got {k!r}")
        with self._lock:
            self.update_index, self.policy = int(k), self.history[int(k)]
            self._set_quietly([(self.gui["update"], int(k))])
            info = [f"update {k} of {K}"]
            if self.history.rollouts is not None:
                info.append(f"{int(self.history.rollouts[k])} rollouts")
            if self.history.mean_reward is not None:
                info.append(f"mean reward {self.history.mean_reward[k]:.4g}")
            self.gui["history_info"].content = " · ".join(info)
            return self._rerun()

    def _toggle_update_stepping(self) -> None:
        self.stepping_updates = not self.stepping_updates
        self.gui["step_updates"].label = "Stop" if self.stepping_updates else "Step through updates"

    def _draw_ghosts(self) -> None:
        """Trails of earlier updates' rollouts, fading from old (light) to new."""
        with self._lock:
            self._remove(self._ghost_nodes)
            K = len(self.history) - 1
            ghosts = np.linspace(0, K, min(K + 1, MAX_GHOST_UPDATES)).round().astype(int)
            updates = sorted(set(ghosts)) if self.gui["ghosts"].value else []
            for i, k in enumerate(updates):
                _, traj = self._roll_out(self.history[k])
                opacity = 0.15 + 0.6 * (i + 1) / len(updates)
                style = {"color": (120, 120, 120), "radius": 0.005, "opacity": opacity}
                if not traj.failed:
                    self._add_trails(self._ghost_nodes, traj, f"/history/update{k}", **style)
            self._refresh_tree()

    def add_prediction_layer(
        self,
        name: str,
        trajectories,
        color=None,
        opacity: float = 0.3,
        *,
        times=None,
        space: str = "state",
        label: str | None = None,
        visible: bool = True,
    ) -> PredictionLayer:
        """Overlay L predicted trajectories (L, T, n) on the real rollout as layer ``name`` (a
        path component; replaces one of that name): states (``space="state"``, T ≥ 2) or 3-D
        points (``space="points"``; T = 1: dots). ``color`` defaults to the next of
        :data:`PREDICTION_COLORS`; ``opacity`` is the samples' (the mean path's twice it, ≤ 1);
        ``times`` (T,) default to the rollout's; ``label`` (default ``name``) names it."""
        self._require_started()
        if not isinstance(name, str) or not name or node_name(name) != name:
            msg = f"name: expected a layer name of letters, digits, '_', '.', '-', got {name!r}"
            raise ValueError(msg)
        if label is not None and (not isinstance(label, str) or not label.strip()):
            raise ValueError(f"label: expected a non-empty string, got {label!r}")
        check_choice(space, "space", ("state", "points"))
        x = check_array(trajectories, "trajectories", ndim=3)
        L, T, n = x.shape
        min_steps = 1 if space == "points" else 2
        if L < 1 or T < min_steps:
            msg = f"trajectories: expected shape (L, T, n), L >= 1, T >= {min_steps}, got {x.shape}"
            raise ValueError(msg)
        dim = self.scene.state_dim if space == "state" else 3
        if n != dim:
            msg = f"trajectories: expected {space} vectors of dimension {dim}, got shape {x.shape}"
            raise ValueError(msg)
        points = self.scene.points(x) if space == "state" else x
        if times is None:
            base = self.trajectory.times
            dt = float(base[1] - base[0]) if base.shape[0] > 1 else 1.0
            times = base[:T] if base.shape[0] >= T else base[0] + dt * np.arange(T)
        times = check_array(times, "times", shape=(T,))
        if np.any(np.diff(times) < 0):
            raise ValueError("times: expected non-decreasing time stamps")
        color = check_rgb(
            PREDICTION_COLORS[len(self.layers) % len(PREDICTION_COLORS)] if color is None else color
        )
        opacity = check_opacity(opacity) or 1.0
        with self._lock:
            self.remove_prediction_layer(name)
            base, scene = f"/predictions/{name}", self.server.scene
            layer = PredictionLayer(name, points, times, color, opacity, label or name)
            trail = functools.partial(add_trail, scene, color=color)
            dots = functools.partial(scene.add_point_cloud, colors=color, point_shape="circle")
            if T >= 2:
                samples = trail(f"{base}/samples", points, opacity=opacity, radius=0.004)
                m = points.mean(axis=0)
                mean = trail(f"{base}/mean", m, opacity=min(1.0, 2 * opacity), radius=0.008)
            else:  # predicted points: the L dots and their mean
                samples = dots(f"{base}/samples", points[:, 0], point_size=0.02)
                m = points[:, 0].mean(axis=0, keepdims=True)
                mean = dots(f"{base}/mean", m, point_size=0.045, point_shape="diamond")
            now = dots(f"{base}/now", layer.at(self.time), point_size=0.03)
            layer.nodes = {handle.name: handle for handle in (samples, mean, now)}
            layer.visible = visible
            what = "trajectories" if T >= 2 else "points"
            with self.gui["predictions"]:
                layer.checkbox = self.server.gui.add_checkbox(
                    f"{layer.label} (L={L})",
                    bool(visible),
                    hint=f"show the {L} {what} predicted by {layer.label}",
                )
            layer.checkbox.on_update(lambda _: setattr(layer, "visible", layer.checkbox.value))
            self.layers[name] = layer
            self._refresh_legend()
            self._refresh_tree()
            return layer

    def remove_prediction_layer(self, name: str) -> None:
        """Remove a prediction layer and its checkbox (no-op if absent)."""
        with self._lock:
            layer = self.layers.pop(name, None)
            if layer is None:
                return
            self._remove(layer.nodes)
            if layer.checkbox is not None:
                layer.checkbox.remove()
            if name in self.model_layer_names:
                self.model_layer_names.remove(name)
            self._refresh_legend()
            self._refresh_tree()

    def legend(self) -> list[tuple[str, tuple]]:
        """What the legend lists, (label, RGB): the simulator's rollout (and its ball trail
        where the rollout has a ``ball`` signal), then the prediction layers in order."""
        entries = [("simulator rollout", COLORS["trail"])]
        traj = self.trajectory
        if traj is not None and not traj.failed and "ball" in traj.signals:
            entries.append(("simulator rollout: ball", COLORS["ball"]))
        return entries + [(layer.label, layer.color) for layer in self.layers.values()]

    def _refresh_legend(self) -> None:
        """The legend and, shown while it holds layers or a model, the Predictions folder."""
        if "legend" not in self.gui:
            return
        self.gui["predictions"].visible = bool(self.layers) or self.model is not None
        rows = [
            f'<div><span style="color: rgb{tuple(color)}; font-size: 1.2em">&#9632;</span> '
            f"{html.escape(label)}</div>"
            for label, color in self.legend()
        ]
        head = ""
        if self.model is not None:
            head = (
                f"<div><b>reward model</b> {html.escape(type(self.model).__name__)}: "
                f"L = {self.model_samples} samples per learned model, for the shown (s, ω)</div>"
            )
            if self._model_error:
                error = html.escape(self._model_error)
                head += f"<div><b>model prediction failed</b>: {error}</div>"
        self.gui["legend"].content = f'<div style="font-size: 0.85em">{head}{"".join(rows)}</div>'

    def add_model_layers(self, model, n_samples: int = 10, seed: int = 0) -> list[PredictionLayer]:
        """Overlay a GPREPS reward model's layers (:func:`~skillkit.viz.model_layers.model_layers`,
        L = ``n_samples``), recomputed with ``seed`` for every new (s, ω) and replacing an earlier
        model's; returns them in order.

        Raises
        ------
        ValueError
            No ``prediction_layers``, fitted on another task, or an answer of wrong shapes.
        """
        from skillkit.viz.model_layers import check_model_task

        self._require_started()
        check_model_task(model, self.task.name)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed: expected an integer, got {seed!r}")
        with self._lock:
            self.remove_model_layers()
            self.model, self.model_samples, self.model_seed = model, n_samples, int(seed)
            try:
                self._update_model_layers(raise_errors=True)
            except BaseException:
                self.remove_model_layers()
                raise
            return [self.layers[name] for name in self.model_layer_names]

    def remove_model_layers(self) -> None:
        """Remove the reward model's layers and stop recomputing them (no-op if none)."""
        with self._lock:
            self._remove_model_layers()
            self.model, self._model_key, self._model_error = None, None, ""
            self._refresh_legend()

    def _remove_model_layers(self) -> None:
        for name in list(self.model_layer_names):
            self.remove_prediction_layer(name)

    def _update_model_layers(self, raise_errors: bool = False) -> None:
        """(Re)compute the model layers for the shown (s, ω); errors raise or go to the legend."""
        from skillkit.viz.model_layers import model_layers

        with self._lock:
            s = self.context if self.task.context_dim else np.zeros(0)
            key = (s.tobytes(), np.asarray(self.omega).tobytes())
            if key == self._model_key:
                return
            shown = {n: self.layers[n].visible for n in self.model_layer_names}
            rng = np.random.default_rng(self.model_seed)
            try:
                specs = model_layers(self.model, s, self.omega, self.model_samples, rng=rng)
            except Exception as exc:
                if raise_errors:
                    raise
                self._remove_model_layers()
                self._model_key, self._model_error = key, f"{type(exc).__name__}: {exc}"
                self._refresh_legend()
                return
            with self.server.atomic():
                self._remove_model_layers()
                for i, spec in enumerate(specs):
                    default = PREDICTION_COLORS[i % len(PREDICTION_COLORS)]
                    spec = {"color": default, **spec, "visible": shown.get(spec["name"], True)}
                    self.add_prediction_layer(**spec)
                    self.model_layer_names.append(spec["name"])
            self._model_key, self._model_error = key, ""
            self._refresh_legend()
