"""Task scenes for the viser viewer: functions that add nodes to a :class:`viser.SceneApi` and
return their handles. Node names are paths (``/arm/link3``); +z is up, quaternions ``wxyz``.
Primitives, :func:`add_mujoco_model` (a frame per body) and :class:`TaskScene` adapters of a
task's trajectories, chosen by :func:`task_scene`."""

from __future__ import annotations

import functools
import importlib
import re
import warnings
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from skillkit._validation import check_array, check_positive, check_type
from skillkit.trajectory import Trajectory

__all__ = [
    "COLORS",
    "HockeyScene",
    "MujocoScene",
    "MujocoTaskScene",
    "PendulumScene",
    "PlanarScene",
    "TableTennisScene",
    "TaskScene",
    "ThrowingScene",
    "add_ball",
    "add_mujoco_model",
    "add_trail",
    "capsule_mesh",
    "interpolate",
    "signal_times",
    "task_model",
    "task_scene",
    "tube_mesh",
]

RGB = tuple[int, int, int]

COLORS: dict[str, RGB] = {
    "robot": (160, 170, 190),
    "ball": (245, 130, 30),
    "control_puck": (30, 30, 30),
    "target_puck": (200, 30, 40),
    "target": (40, 170, 60),
    "table": (60, 110, 170),
    "trail": (30, 100, 220),
    "prediction": (220, 40, 160),
}
"""Default colours (RGB, 0–255) of the scene objects."""

_MJ_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0])
_INFINITE_PLANE_HALF_SIZE = 10.0
_NAME_RE = re.compile(r"[^A-Za-z0-9_.\-]")


def node_name(name: str) -> str:
    """A path component: MuJoCo names with ``/`` or spaces made safe."""
    return _NAME_RE.sub("_", name)


def check_path(name: str, argname: str = "name") -> str:
    if not isinstance(name, str) or not name.startswith("/") or name.endswith("/") or "//" in name:
        raise ValueError(f"{argname}: expected a scene path like '/arm/link3', got {name!r}")
    return name


def check_rgb(color, argname: str = "color") -> RGB:
    c = check_array(color, argname, shape=(3,))
    if np.any(c < 0) or np.any(c > 255):
        raise ValueError(f"{argname}: expected RGB values in [0, 255], got {c.tolist()}")
    return (int(round(c[0])), int(round(c[1])), int(round(c[2])))


def check_opacity(opacity, argname: str = "opacity") -> float | None:
    if opacity is None:
        return None
    v = float(opacity)
    if not 0.0 < v <= 1.0:
        raise ValueError(f"{argname}: expected a value in (0, 1] or None, got {opacity!r}")
    return None if v == 1.0 else v


def capsule_mesh(
    radius: float, half_length: float, segments: int = 16, rings: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of MuJoCo's capsule along z at the origin, z ∈ [−h − r, h + r] (radius r,
    half-length h ≥ 0) with ``segments`` (≥ 3) vertices around the axis and ``rings`` (≥ 1) per
    hemisphere: vertices (2 + 2·rings·segments, 3), faces (4·rings·segments, 3), counter-clockwise
    seen from outside."""
    radius = check_positive(radius, "radius")
    half_length = check_positive(half_length, "half_length", allow_zero=True)
    if int(segments) < 3 or int(rings) < 1:
        msg = f"segments, rings: expected segments >= 3 and rings >= 1, got {segments}, {rings}"
        raise ValueError(msg)
    segments, rings = int(segments), int(rings)
    polar = np.linspace(0.0, np.pi / 2, rings + 1)[1:]  # from the pole, the equator included
    z_rho = [(half_length + radius * np.cos(p), radius * np.sin(p)) for p in polar]
    z_rho += [(-half_length - radius * np.cos(p), radius * np.sin(p)) for p in polar[::-1]]
    theta = 2.0 * np.pi * np.arange(segments) / segments
    ring_vertices = [
        np.column_stack([rho * np.cos(theta), rho * np.sin(theta), np.full(segments, z)])
        for z, rho in z_rho
    ]
    top = np.array([[0.0, 0.0, half_length + radius]])
    bottom = np.array([[0.0, 0.0, -half_length - radius]])
    vertices = np.vstack([top, *ring_vertices, bottom])
    n_rings = len(z_rho)
    k = np.arange(segments)
    k1 = (k + 1) % segments
    faces = [np.column_stack([np.zeros(segments, int), 1 + k, 1 + k1])]
    for i in range(n_rings - 1):
        a, b = 1 + i * segments + k, 1 + i * segments + k1
        c, d = 1 + (i + 1) * segments + k1, 1 + (i + 1) * segments + k
        faces += [np.column_stack([a, d, c]), np.column_stack([a, c, b])]
    last = 1 + (n_rings - 1) * segments
    faces.append(np.column_stack([np.full(segments, vertices.shape[0] - 1), last + k1, last + k]))
    return vertices, np.vstack(faces).astype(np.int64)


def tube_mesh(paths, radius: float, sides: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Open-ended tubes of ``radius`` along one or L polylines (T, 3) or (L, T, 3), T ≥ 2, with
    ``sides`` (≥ 3) vertices per cross-section normal to the tangent (central differences,
    parallel transport). Returns vertices (L·T·sides, 3) and faces (2·L·(T−1)·sides, 3).
    """
    p = check_array(paths, "paths", ndim=(2, 3))
    if p.ndim == 2:
        p = p[None]
    if p.shape[-1] != 3 or p.shape[1] < 2:
        msg = f"paths: expected shape (T, 3) or (L, T, 3) with T >= 2, got {np.shape(paths)}"
        raise ValueError(msg)
    radius = check_positive(radius, "radius")
    if int(sides) < 3:
        raise ValueError(f"sides: expected at least 3 sides, got {sides}")
    sides = int(sides)
    n_paths, n_points, _ = p.shape
    tangent = np.gradient(p, axis=1)
    norm = np.linalg.norm(tangent, axis=-1)
    scale = max(float(np.max(np.abs(p))), 1.0)
    degenerate = norm <= 1e-12 * scale
    tangent = np.divide(
        tangent, norm[..., None], out=np.zeros_like(tangent), where=~degenerate[..., None]
    )
    normals = np.empty_like(p)
    previous_t = np.tile([1.0, 0.0, 0.0], (n_paths, 1))
    previous_n = np.tile([0.0, 0.0, 1.0], (n_paths, 1))
    for t in range(n_points):
        tan = np.where(degenerate[:, t, None], previous_t, tangent[:, t])
        n = previous_n - np.sum(previous_n * tan, axis=1, keepdims=True) * tan
        n_len = np.linalg.norm(n, axis=1, keepdims=True)
        lost = n_len[:, 0] < 1e-6  # the tangent turned parallel to the carried normal
        if np.any(lost):
            alt = np.cross(tan[lost], [0.0, 0.0, 1.0])
            bad = np.linalg.norm(alt, axis=1) < 1e-6
            alt[bad] = np.cross(tan[lost][bad], [1.0, 0.0, 0.0])
            n[lost] = alt
            n_len = np.linalg.norm(n, axis=1, keepdims=True)
        n = n / n_len
        normals[:, t], previous_t[:], previous_n[:] = n, tan, n
        tangent[:, t] = tan
    binormals = np.cross(tangent, normals)
    angle = 2.0 * np.pi * np.arange(sides) / sides
    ring = (
        np.cos(angle)[:, None] * normals[:, :, None, :]
        + np.sin(angle)[:, None] * binormals[:, :, None, :]
    )
    vertices = (p[:, :, None, :] + radius * ring).reshape(-1, 3)
    k = np.arange(sides)
    k1 = (k + 1) % sides
    starts = np.arange(n_paths)[:, None] * n_points + np.arange(n_points - 1)[None, :]
    base = starts.reshape(-1, 1) * sides
    a, b = base + k, base + k1
    c, d = base + sides + k1, base + sides + k
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=1)
    return vertices, faces.reshape(-1, 3).astype(np.int64)


def interpolate(times, values, t: float) -> np.ndarray:
    """Values (T, ...) at time ``t``, linearly interpolated between samples at non-decreasing
    ``times`` (T,); before ``times[0]`` the first sample, after ``times[-1]`` the last one."""
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if times.ndim != 1 or values.shape[:1] != times.shape or times.shape[0] == 0:
        msg = f"times, values: expected shapes (T,), (T, ...); got {times.shape}, {values.shape}"
        raise ValueError(msg)
    i = int(np.searchsorted(times, t, side="right"))
    if i == 0:
        return values[0].copy()
    if i >= times.shape[0]:
        return values[-1].copy()
    t0, t1 = times[i - 1], times[i]
    w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
    return (1.0 - w) * values[i - 1] + w * values[i]


def signal_times(trajectory: Trajectory, key: str, times_key: str | None = None) -> np.ndarray:
    """Time stamps (T_s,) of ``trajectory.signals[key]``: ``signals[times_key]`` (default
    ``key + "_times"`` if present), else ``times`` if the lengths agree, else samples at the
    trajectory's period from ``times[0]``."""
    signals = trajectory.signals
    if key not in signals:
        raise ValueError(f"trajectory: has no signal {key!r} (signals: {sorted(signals)})")
    n = signals[key].shape[0]
    times_key = times_key or (f"{key}_times" if f"{key}_times" in signals else None)
    if times_key is not None:
        if times_key not in signals or signals[times_key].shape != (n,):
            msg = f"trajectory: signal {times_key!r} must hold the {n} time stamps of {key!r}"
            raise ValueError(msg)
        return signals[times_key]
    t = trajectory.times
    if n == t.shape[0]:
        return t
    if t.shape[0] < 2:
        raise ValueError(f"trajectory: signal {key!r} has {n} samples and no time stamps")
    return t[0] + (t[1] - t[0]) * np.arange(n)


def add_ball(
    scene,
    name: str = "/ball",
    radius: float = 0.05,
    color=COLORS["ball"],
    *,
    opacity: float | None = None,
    position=(0.0, 0.0, 0.0),
):
    """A ball (icosphere) of ``radius`` metres at ``position``; returns its handle."""
    return scene.add_icosphere(
        check_path(name),
        radius=check_positive(radius, "radius"),
        color=check_rgb(color),
        opacity=check_opacity(opacity),
        subdivisions=2,
        position=tuple(check_array(position, "position", shape=(3,))),
    )


def add_trail(
    scene,
    name: str,
    paths,
    color=COLORS["trail"],
    *,
    radius: float = 0.008,
    opacity: float | None = None,
):
    """Tubes through each of one or L world-frame paths (T, 3) or (L, T, 3), T ≥ 2, as one mesh
    node (:func:`tube_mesh`) of ``radius`` metres; predictions are drawn translucent
    (``opacity`` in (0, 1])."""
    vertices, faces = tube_mesh(paths, radius)
    return scene.add_mesh_simple(
        check_path(name),
        vertices,
        faces,
        color=check_rgb(color),
        opacity=check_opacity(opacity),
        side="double",
        cast_shadow=False,
        receive_shadow=False,
    )


@dataclass
class MujocoScene:
    """Viser nodes of a MuJoCo model (:func:`add_mujoco_model`): ``bodies`` the ``<root>/<body>``
    frames (world pose) with their MuJoCo ``body_ids``, ``geoms`` by path, ``skipped`` the geoms
    not drawn and why; ``data`` is scratch data for the kinematics."""

    model: mujoco.MjModel
    data: mujoco.MjData
    root: str
    bodies: dict = field(default_factory=dict)
    geoms: dict = field(default_factory=dict)
    body_ids: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)

    def set_qpos(self, qpos) -> None:
        """Pose the body frames for joint positions ``qpos`` (nq,) with ``mujoco.mj_kinematics``."""
        self.data.qpos[:] = check_array(qpos, "qpos", shape=(self.model.nq,))
        mujoco.mj_kinematics(self.model, self.data)
        for path, b in self.body_ids.items():
            self.bodies[path].position = self.data.xpos[b].copy()
            self.bodies[path].wxyz = self.data.xquat[b].copy()

    @property
    def nodes(self) -> dict:
        """Every node of the model by path (body frames and geoms)."""
        return {**self.bodies, **self.geoms}


def kinematic_points(model: mujoco.MjModel, qpos: np.ndarray, bodies, sites) -> np.ndarray:
    """World positions (N, len(bodies) + len(sites), 3) of the body origins and sites (ids) per
    row of joint positions ``qpos`` (N, nq), by ``mujoco.mj_kinematics`` on scratch data."""
    data = mujoco.MjData(model)
    out = np.empty((qpos.shape[0], len(bodies) + len(sites), 3))
    for i, row in enumerate(qpos):
        data.qpos[:] = row
        mujoco.mj_kinematics(model, data)
        out[i, : len(bodies)] = data.xpos[bodies]
        out[i, len(bodies) :] = data.site_xpos[sites]
    return out


def _geom_color(model: mujoco.MjModel, g: int) -> tuple[RGB, float]:
    rgba = np.asarray(model.geom_rgba[g], dtype=np.float64)
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(rgba, _MJ_DEFAULT_RGBA):
        rgba = np.asarray(model.mat_rgba[mat], dtype=np.float64)
    rgb = tuple(int(round(255 * float(np.clip(c, 0.0, 1.0)))) for c in rgba[:3])
    return rgb, float(rgba[3])


def add_geom(scene, name: str, model: mujoco.MjModel, geom: int):
    """MuJoCo geom ``geom`` as a viser primitive at ``name`` posed in its body frame (sizes as
    MuJoCo's; an infinite plane drawn 10 m), or None for an unsupported type."""
    gtype = int(model.geom_type[geom])
    size = np.asarray(model.geom_size[geom], dtype=np.float64)
    color, alpha = _geom_color(model, geom)
    pos, quat = model.geom_pos[geom], model.geom_quat[geom]
    kw = {"color": color, "opacity": None if alpha >= 1.0 else alpha}
    kw.update(position=tuple(np.asarray(pos, float)), wxyz=tuple(np.asarray(quat, float)))
    T = mujoco.mjtGeom
    if gtype == T.mjGEOM_SPHERE:
        return scene.add_icosphere(name, radius=size[0], **kw)
    if gtype == T.mjGEOM_ELLIPSOID:
        return scene.add_icosphere(name, radius=1.0, scale=tuple(size), **kw)
    if gtype == T.mjGEOM_CAPSULE:
        return scene.add_mesh_simple(name, *capsule_mesh(size[0], size[1]), **kw)
    if gtype == T.mjGEOM_CYLINDER:
        return scene.add_cylinder(name, radius=size[0], height=2.0 * size[1], **kw)
    if gtype == T.mjGEOM_BOX:
        return scene.add_box(name, dimensions=tuple(2.0 * size[:3]), **kw)
    if gtype == T.mjGEOM_PLANE:
        hx, hy = (s if s > 0 else _INFINITE_PLANE_HALF_SIZE for s in size[:2])
        v = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
        f = np.array([[0, 1, 2], [0, 2, 3]])
        return scene.add_mesh_simple(name, v, f, side="double", cast_shadow=False, **kw)
    if gtype == T.mjGEOM_MESH:
        m = int(model.geom_dataid[geom])
        va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        v = np.asarray(model.mesh_vert[va : va + vn], float)
        return scene.add_mesh_simple(name, v, np.asarray(model.mesh_face[fa : fa + fn]), **kw)
    return None


def add_mujoco_model(
    scene,
    model: mujoco.MjModel,
    root: str = "/arm",
    *,
    world_paths: Mapping[str, str] | None = None,
    skip_geoms: Sequence[str] = (),
    max_group: int = 2,
) -> MujocoScene:
    """Add every visible geom of a MuJoCo model, one frame per body.

    Body ``b`` becomes a frame ``<root>/<body name>`` (``body<b>`` if unnamed, ``world`` for
    the world body) at its world pose; its geoms are children ``<root>/<body>/<geom name>``, so
    a time step only moves the frames (:meth:`MujocoScene.set_qpos`). ``world_paths`` gives
    named world-body geoms their own paths (``{"table": "/table"}``); ``skip_geoms`` and geoms
    in groups above ``max_group`` are not drawn; unsupported types (height fields, SDFs) are
    listed in ``skipped`` with a ``RuntimeWarning``.
    """
    check_type(model, mujoco.MjModel, "model", "a mujoco.MjModel")
    root = check_path(root, "root")
    world_paths = dict(world_paths or {})
    for p in world_paths.values():
        check_path(p, "world_paths")
    geom_names = {model.geom(g).name for g in range(model.ngeom)}
    unknown = (set(world_paths) | set(skip_geoms)) - geom_names
    if unknown:
        raise ValueError(f"world_paths/skip_geoms: model has no geom named {sorted(unknown)}")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    out = MujocoScene(model, data, root)
    unsupported = []
    for g in range(model.ngeom):
        gname = model.geom(g).name
        label = node_name(gname) if gname else f"geom{g}"
        b = int(model.geom_bodyid[g])
        group = int(model.geom_group[g])
        reasons = {
            "skipped on request": gname in skip_geoms,
            f"group {group} > {max_group}": group > max_group,
            "fully transparent": _geom_color(model, g)[1] <= 0.0,
        }
        why = next((reason for reason, hit in reasons.items() if hit), "")
        if why:
            out.skipped.append(f"{label}: {why}")
            continue
        if gname in world_paths:
            if b != 0:
                msg = f"world_paths: geom {gname!r} is not static (body {model.body(b).name!r})"
                raise ValueError(msg)
            path = world_paths[gname]
        else:
            bname = model.body(b).name
            body = f"{root}/{node_name(bname) if bname else f'body{b}'}" if b else f"{root}/world"
            if body not in out.bodies:
                out.bodies[body] = scene.add_frame(
                    body, show_axes=False, position=tuple(data.xpos[b]), wxyz=tuple(data.xquat[b])
                )
                out.body_ids[body] = b
            path = f"{body}/{label}"
        handle = add_geom(scene, path, model, g)
        if handle is None:
            unsupported.append(label)
        else:
            out.geoms[path] = handle
    if unsupported:
        out.skipped += [f"{u}: unsupported geom type" for u in unsupported]
        msg = f"add_mujoco_model: geoms of unsupported types not drawn: {unsupported}"
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    return out


def task_model(task) -> mujoco.MjModel | None:
    """The compiled MuJoCo model a task simulates (``task.scene_model()``), or None."""
    getter = getattr(task, "scene_model", None)
    model = getter() if callable(getter) else None
    return model if isinstance(model, mujoco.MjModel) else None


class TaskScene(ABC):
    """How one task's trajectories appear in a viser scene: subclasses build their ``nodes``
    (by path) in ``__init__`` and implement :meth:`show`, :meth:`trails` and :meth:`points`;
    ``camera_position``, ``camera_look_at`` give a good initial view."""

    camera_position: tuple[float, float, float] = (3.0, -3.0, 2.0)
    camera_look_at: tuple[float, float, float] = (0.0, 0.0, 0.5)
    task_type: tuple[str, str] | None = None  # (module, class) of the task drawn
    state_dim: int  # dimension n_x of the states :meth:`points` accepts

    def __init__(self, scene, task) -> None:
        self.scene, self.task = scene, task
        self.nodes: dict = {}

    def _add(self, handle):
        self.nodes[handle.name] = handle
        return handle

    @classmethod
    def accepts(cls, task) -> bool:
        """Whether this adapter draws ``task`` (an instance of :attr:`task_type`)."""
        module, name = cls.task_type
        return isinstance(task, getattr(importlib.import_module(module), name))

    @abstractmethod
    def show(self, trajectory: Trajectory, t: float) -> None:
        """Pose the scene at time ``t`` (seconds) of ``trajectory``."""

    @abstractmethod
    def trails(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        """Named world-frame paths of a trajectory, each of shape (T_k, 3)."""

    @abstractmethod
    def points(self, states) -> np.ndarray:
        """3-D point of each state, shape (..., n_x) → (..., 3)."""

    def set_context(self, context) -> None:  # noqa: B027  (optional hook)
        """Show the context (e.g. move the target); the default shows nothing."""

    def time_range(self, trajectory: Trajectory) -> tuple[float, float]:
        """First and last time stamp of the trajectory and of its timed signals."""
        t0, t1 = float(trajectory.times[0]), float(trajectory.times[-1])
        for key in trajectory.signals:
            if key.endswith("_times") and trajectory.signals[key].size:
                t1 = max(t1, float(trajectory.signals[key][-1]))
        return t0, t1


class PendulumScene(TaskScene):
    """The single-link pendulum of Sec. 5.4 from primitives: the bob at pivot + l (sin α, 0,
    −cos α) in the x–z plane; nodes ``/pendulum/pivot``, ``/pendulum/link1`` (rotates with α),
    ``…/rod``, ``…/bob``."""

    LENGTH = 1.0
    PIVOT = (0.0, 0.0, 1.2)
    camera_position = (0.0, -3.2, 1.2)
    camera_look_at = (0.0, 0.0, 0.9)
    task_type = ("skillkit.tasks.pendulum", "Pendulum")
    state_dim = 2

    def __init__(self, scene, task) -> None:
        super().__init__(scene, task)
        length, add = self.LENGTH, self._add
        pivot = {"color": (60, 60, 60), "position": self.PIVOT}
        add(scene.add_icosphere("/pendulum/pivot", radius=0.05, **pivot))
        self.link = add(scene.add_frame("/pendulum/link1", show_axes=False, position=self.PIVOT))
        v, f = capsule_mesh(0.02, length / 2)
        rod = {"color": COLORS["robot"], "position": (0.0, 0.0, -length / 2)}
        add(scene.add_mesh_simple("/pendulum/link1/rod", v, f, **rod))
        bob = {"radius": 0.08, "color": COLORS["ball"], "position": (0.0, 0.0, -length)}
        add(scene.add_icosphere("/pendulum/link1/bob", **bob))
        add(scene.add_grid("/ground", width=4.0, height=4.0))

    def set_angle(self, alpha: float) -> None:
        """Rotate the link to angle α (rad) about the −y axis through the pivot."""
        a = float(alpha)
        self.link.wxyz = (np.cos(a / 2), 0.0, -np.sin(a / 2), 0.0)

    def show(self, trajectory: Trajectory, t: float) -> None:
        self.set_angle(interpolate(trajectory.times, trajectory.states[:, 0], t))

    def points(self, states) -> np.ndarray:
        x = check_array(states, "states")
        if x.shape[-1] != 2:
            raise ValueError(f"states: expected shape (..., 2) = [α, α̇], got {x.shape}")
        a = x[..., 0]
        pivot = np.asarray(self.PIVOT)
        return pivot + self.LENGTH * np.stack([np.sin(a), np.zeros_like(a), -np.cos(a)], axis=-1)

    def trails(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        return {"bob": self.points(trajectory.states)}


class MujocoTaskScene(TaskScene):
    """Any task exposing its MuJoCo model (:func:`task_model`), states x = [q, q̇], drawn under
    ``/arm``; q = ``states[:, :nq]`` or the task's ``qpos(trajectory)`` (T, nq). A state's 3-D
    point is site :attr:`effector_site` (default: the first site, else the last body)."""

    effector_site: str | None = None
    world_paths: dict[str, str] = {}
    skip_geoms: tuple[str, ...] = ()
    ball = None  # a ``/ball`` node following signal ``ball``, placed by :meth:`_world`

    def __init__(self, scene, task) -> None:
        super().__init__(scene, task)
        model = task_model(task)
        if model is None:
            msg = f"task: {type(task).__name__} exposes no MuJoCo model (needs Task.scene_model())"
            raise ValueError(msg)
        self.robot = add_mujoco_model(
            scene, model, "/arm", world_paths=self.world_paths, skip_geoms=self.skip_geoms
        )
        self.nodes.update(self.robot.nodes)
        if self.effector_site is not None:
            self._ids = ([], [model.site(self.effector_site).id])
        else:
            self._ids = ([], [0]) if model.nsite else ([model.nbody - 1], [])

    @classmethod
    def accepts(cls, task) -> bool:
        return super().accepts(task) if cls.task_type else task_model(task) is not None

    @property
    def state_dim(self) -> int:
        m = self.robot.model
        return m.nq + m.nv

    def qpos(self, trajectory: Trajectory) -> np.ndarray:
        """Joint positions per time step, shape (T, nq)."""
        getter = getattr(self.task, "qpos", None)
        if callable(getter):
            return np.asarray(getter(trajectory), dtype=np.float64)
        x = trajectory.states
        if x.shape[1] != self.state_dim:
            msg = f"trajectory: expected states [q, q̇] of {self.state_dim} columns, got {x.shape}"
            raise ValueError(msg)
        return x[:, : self.robot.model.nq]

    def _effector(self, qpos: np.ndarray) -> np.ndarray:
        """The effector's world position per row of joint positions, (N, nq) → (N, 3)."""
        return kinematic_points(self.robot.model, qpos, *self._ids)[:, 0]

    def show(self, trajectory: Trajectory, t: float) -> None:
        self.robot.set_qpos(interpolate(trajectory.times, self.qpos(trajectory), t))
        if self.ball is not None:
            ball = interpolate(signal_times(trajectory, "ball"), trajectory.signals["ball"], t)
            self.ball.position = tuple(self._world(ball))

    @staticmethod
    def _world(points: np.ndarray) -> np.ndarray:
        """World points of the ``ball`` signal's samples."""
        return points

    def points(self, states) -> np.ndarray:
        x = check_array(states, "states")
        if x.shape[-1] != self.state_dim:
            raise ValueError(f"states: expected shape (..., {self.state_dim}), got {x.shape}")
        nq = self.robot.model.nq
        return self._effector(x[..., :nq].reshape(-1, nq)).reshape(*x.shape[:-1], 3)

    def trails(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        out = {"effector": self._effector(self.qpos(trajectory))}
        if self.ball is not None:
            out["ball"] = self._world(trajectory.signals["ball"])
        return out


class PlanarScene(MujocoTaskScene):
    """The planar 4-link robot of Appendix C.1 (balancing, Sec. 4.3.1) in the x–z plane; the
    3-D point of a state is the hand."""

    effector_site = "hand"
    camera_position = (2.6, -4.2, 1.8)
    camera_look_at = (0.2, 0.0, 1.0)
    task_type = ("skillkit.tasks.balancing", "Balancing")


class ThrowingScene(PlanarScene):
    """Ball throwing with the planar 4-link robot (Sec. 3.4.1, Appendix C.1): adds ``/ball``
    (signal ``ball`` in the robot plane on ``ball_times``) and ``/target`` (the context)."""

    camera_position = (5.5, -8.0, 2.6)
    camera_look_at = (5.5, 0.0, 1.6)
    task_type = ("skillkit.tasks.planar", "Throwing")

    def __init__(self, scene, task) -> None:
        super().__init__(scene, task)
        self.ball = self._add(add_ball(scene, "/ball", 0.08))
        self.target = self._add(add_ball(scene, "/target", 0.2, COLORS["target"], opacity=0.6))

    def set_context(self, context) -> None:
        self.target.position = tuple(self._world(self.task.check_context(context)))

    @staticmethod
    def _world(xy: np.ndarray) -> np.ndarray:
        """The planar robot's [x, y] (y up) → world [x, 0, y]."""
        return np.stack([xy[..., 0], np.zeros_like(xy[..., 0]), xy[..., 1]], axis=-1)


class HockeyScene(MujocoTaskScene):
    """Robot hockey (Appendix C.2): the arm, the table, ``/pucks/control`` and ``/pucks/target``
    (signals ``control_puck``, ``target_puck`` on ``puck_times``) and ``/target``, a disc of
    radius d* around the target puck's start b (context [b_x, b_y, d*])."""

    effector_site = "blade"
    world_paths = {"table": "/table"}
    camera_position = (-0.6, -1.8, 1.8)
    camera_look_at = (1.3, 0.4, 0.0)
    task_type = ("skillkit.tasks.hockey", "Hockey")
    _PUCKS = ("control_puck", "target_puck")

    def __init__(self, scene, task) -> None:
        super().__init__(scene, task)
        from skillkit.tasks.hockey import CONTROL_PUCK_START

        r, h = task.physics.puck_radius, task.physics.puck_height
        self._half_height = h / 2
        puck = functools.partial(scene.add_cylinder, radius=r, height=h)
        self.control_puck = self._add(puck("/pucks/control", color=COLORS["control_puck"]))
        self.target_puck = self._add(puck("/pucks/target", color=COLORS["target_puck"]))
        self.control_puck.position = (*CONTROL_PUCK_START, self._half_height)
        disc = {"height": 0.004, "color": COLORS["target"], "opacity": 0.35}
        self.target = self._add(scene.add_cylinder("/target", radius=r, **disc))

    def set_context(self, context) -> None:
        s = self.task.check_context(context)
        self.target_puck.position = (s[0], s[1], self._half_height)
        self.target.position = (s[0], s[1], 0.002)
        self.target.radius = max(float(s[2]), self.task.physics.puck_radius)

    def show(self, trajectory: Trajectory, t: float) -> None:
        super().show(trajectory, t)
        times = signal_times(trajectory, "control_puck", "puck_times")
        for handle, key in zip((self.control_puck, self.target_puck), self._PUCKS, strict=True):
            xy = interpolate(times, trajectory.signals[key], t)
            handle.position = (xy[0], xy[1], self._half_height)

    def trails(self, trajectory: Trajectory) -> dict[str, np.ndarray]:
        out = super().trails(trajectory)
        for key in self._PUCKS:
            xy = trajectory.signals[key]
            out[key] = np.column_stack([xy, np.full(xy.shape[0], self._half_height)])
        return out


class TableTennisScene(MujocoTaskScene):
    """Robot table tennis (Appendix C.3): the arm, the table and net, ``/ball`` (signal
    ``ball`` (T, 3)) and ``/target``, a flat disc at the return target b = context[3:5]."""

    effector_site = "racket"
    camera_position = (-3.0, -2.2, 1.9)
    camera_look_at = (-0.6, 0.1, 0.85)
    task_type = ("skillkit.tasks.table_tennis", "TableTennis")

    def __init__(self, scene, task) -> None:
        super().__init__(scene, task)
        from skillkit.tasks import table_tennis as tt

        length, width, self._height = tt.TABLE_LENGTH, tt.TABLE_WIDTH, tt.TABLE_HEIGHT
        top = {"color": COLORS["table"], "position": (0.0, 0.0, self._height - 0.015)}
        self._add(scene.add_box("/table", dimensions=(length, width, 0.03), **top))
        net_width, net_z = width + 2 * tt.NET_OVERHANG, self._height + tt.NET_HEIGHT / 2
        net = {"color": (240, 240, 240), "opacity": 0.7, "position": (0.0, 0.0, net_z)}
        self._add(scene.add_box("/net", dimensions=(0.01, net_width, tt.NET_HEIGHT), **net))
        self.ball = self._add(add_ball(scene, "/ball", task.ball.radius))
        disc = {"height": 0.004, "color": COLORS["target"], "opacity": 0.6}
        self.target = self._add(scene.add_cylinder("/target", radius=0.1, **disc))

    def set_context(self, context) -> None:
        s = self.task.check_context(context)
        self.target.position = (s[3], s[4], self._height + 0.003)


def task_scene(scene, task) -> TaskScene:
    """Build the scene of ``task`` with the first adapter that accepts it (the specific ones
    first, then :class:`MujocoTaskScene`) and show the mid-range context; ``ValueError``
    (argument ``task``) if none does."""
    adapters = (PendulumScene, PlanarScene, ThrowingScene, HockeyScene, TableTennisScene)
    for adapter in (*adapters, MujocoTaskScene):
        try:
            accepted = adapter.accepts(task)
        except ImportError:  # the task module is not there (yet)
            accepted = False
        if accepted:
            ts = adapter(scene, task)
            ts.set_context(0.5 * (np.asarray(task.context_low) + np.asarray(task.context_high)))
            return ts
    name = f"{type(task).__name__} {getattr(task, 'name', '')!r}"
    raise ValueError(f"task: no viewer scene for {name}: not a known task, and no scene_model()")
