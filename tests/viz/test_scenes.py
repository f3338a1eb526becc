"""Scene building (skillkit.viz.scenes), headless: node names, meshes, poses against independent
forward kinematics, task adapters for every registered task, bad input."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks import Task, make, names
from skillkit.trajectory import Trajectory
from skillkit.viz import scenes
from skillkit.viz.scenes import (
    add_mujoco_model,
    add_trail,
    capsule_mesh,
    interpolate,
    signal_times,
    task_scene,
    tube_mesh,
)
from skillkit.viz.viewer import start_server
from tests._tolerances import fp_tol


@pytest.fixture(scope="module")
def server():
    srv = start_server(port=0)
    yield srv
    srv.stop()


@pytest.fixture
def scene(server):
    server.scene.reset()
    return server.scene


# ----------------------------------------------------------------------------- independent maths
def quat_to_mat(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion wxyz (written out, not MuJoCo's)."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rot(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def pose_tol(scale, frames):
    """Absolute round-off of a pose composed through ``frames`` frames (viser's node tree
    here, MuJoCo's kinematic chain, a closed form): per frame a quaternion to a rotation
    matrix (~10 flops) and a 3-term rotation of the offset, ~15 flops on values of size
    ``scale`` (the positions' magnitude, 1 for rotations)."""
    return fp_tol(15 * frames, scale=scale)


def mesh_tol(scale, radius):
    """Absolute round-off of a mesh vertex's offset from its centre line: the vertex p + r u
    (u a unit vector from sin/cos, a normalisation, a cross product: ~10 flops of size r)
    minus p cancels to ~4 ε of the positions' size ``scale``."""
    return fp_tol(4, scale=scale) + fp_tol(10, scale=radius)


def world_pose(scene, path: str) -> tuple[np.ndarray, np.ndarray]:
    """Compose the poses of every node along ``path`` (viser's kinematic tree)."""
    R, p = np.eye(3), np.zeros(3)
    parts = path.strip("/").split("/")
    for i in range(1, len(parts) + 1):
        handle = scene.get_handle_by_name("/" + "/".join(parts[:i]))
        assert handle is not None, "/" + "/".join(parts[:i])
        p = p + R @ np.asarray(handle.position, float)
        R = R @ quat_to_mat(handle.wxyz)
    return R, p


# ----------------------------------------------------------------------------- meshes
def test_capsule_mesh_is_a_closed_outward_surface_of_the_capsule():
    r, h = 0.1, 0.25
    v, f = capsule_mesh(r, h, segments=12, rings=3)
    # every vertex is at distance r from the axis segment z ∈ [−h, h]
    closest = np.column_stack([np.zeros(len(v)), np.zeros(len(v)), np.clip(v[:, 2], -h, h)])
    tol = mesh_tol(h + r, r)  # the caps' z = h ± r cos p, minus h
    np.testing.assert_allclose(np.linalg.norm(v - closest, axis=1), r, atol=tol)
    assert v[:, 2].max() == pytest.approx(h + r) and v[:, 2].min() == pytest.approx(-h - r)
    # closed: every edge in exactly two faces, Euler characteristic 2
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    assert len(v) - len(counts) + len(f) == 2
    # outward: each face normal points away from the axis
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normal = np.cross(b - a, c - a)
    centroid = (a + b + c) / 3
    axis_point = np.zeros_like(centroid)
    axis_point[:, 2] = np.clip(centroid[:, 2], -h, h)
    assert np.all(np.sum(normal * (centroid - axis_point), axis=1) > 0)


def test_capsule_mesh_rejects_bad_sizes():
    with pytest.raises(ValueError, match="radius"):
        capsule_mesh(0.0, 1.0)
    with pytest.raises(ValueError, match="half_length"):
        capsule_mesh(0.1, -1.0)
    with pytest.raises(ValueError, match="segments"):
        capsule_mesh(0.1, 1.0, segments=2)


def test_tube_mesh_rings_are_perpendicular_circles_around_the_path():
    t = np.linspace(0, np.pi, 40)
    path = np.column_stack([np.cos(t), np.sin(t), 0.3 * t])  # a helix
    radius, sides = 0.05, 7
    v, f = tube_mesh(path, radius, sides)
    assert v.shape == (40 * sides, 3) and f.shape == (2 * 39 * sides, 3)
    rings = v.reshape(40, sides, 3)
    offsets = rings - path[:, None, :]
    tol = mesh_tol(np.abs(path).max(), radius)
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=-1), radius, atol=tol)
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    # the same tangent; the carried normal is re-orthogonalised to it each point (the helix
    # turns by small angles: no loss of orthogonality to amplify)
    np.testing.assert_allclose(np.einsum("tsk,tk->ts", offsets, tangent), 0.0, atol=tol)
    assert f.min() == 0 and f.max() == len(v) - 1


def test_tube_mesh_many_paths_and_points_at_rest():
    paths = np.zeros((3, 5, 3))
    paths[:, :, 0] = np.arange(5)
    paths[1, 2:] = paths[1, 2]  # the second path stops: repeated points
    v, f = tube_mesh(paths, 0.01, 4)
    assert v.shape == (3 * 5 * 4, 3) and np.all(np.isfinite(v))
    np.testing.assert_allclose(
        np.linalg.norm(v.reshape(3, 5, 4, 3) - paths[:, :, None], axis=-1),
        0.01,
        atol=mesh_tol(np.abs(paths).max(), 0.01),
    )
    assert f.shape == (2 * 3 * 4 * 4, 3)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((1, 3)), "paths"),
        (np.zeros((4, 2)), "paths"),
        (np.full((4, 3), np.nan), "paths"),
        (np.zeros((2, 3, 3, 3)), "paths"),
    ],
)
def test_tube_mesh_rejects_bad_paths(bad, match):
    with pytest.raises(ValueError, match=match):
        tube_mesh(bad, 0.1)


def test_add_trail_makes_one_mesh_node_with_opacity(scene):
    handle = add_trail(
        scene,
        "/trails/x",
        np.random.default_rng(0).random((2, 6, 3)),
        (10, 20, 30),
        radius=0.02,
        opacity=0.4,
    )
    assert scene.get_handle_by_name("/trails/x") is handle
    assert handle.opacity == pytest.approx(0.4) and handle.vertices.shape == (2 * 6 * 6, 3)
    with pytest.raises(ValueError, match="name"):
        add_trail(scene, "trails/x", np.zeros((2, 3)))
    with pytest.raises(ValueError, match="opacity"):
        add_trail(scene, "/trails/y", np.eye(3), opacity=1.5)
    with pytest.raises(ValueError, match="color"):
        add_trail(scene, "/trails/y", np.eye(3), color=(0, 0, 300))


# ----------------------------------------------------------------------------- time helpers
def test_interpolate_is_linear_between_samples_and_rests_at_the_ends():
    times = np.array([0.0, 1.0, 3.0])
    values = np.array([[0.0, 10.0], [1.0, 20.0], [5.0, 0.0]])
    np.testing.assert_allclose(interpolate(times, values, 1.0), [1.0, 20.0])
    np.testing.assert_allclose(interpolate(times, values, 2.0), [3.0, 10.0])
    np.testing.assert_allclose(interpolate(times, values, -4.0), values[0])
    np.testing.assert_allclose(interpolate(times, values, 9.0), values[-1])
    with pytest.raises(ValueError, match="values"):
        interpolate(times, values[:2], 0.5)


def test_signal_times_own_clock_same_length_or_control_period():
    traj = Trajectory(
        np.arange(4) * 0.1,
        np.zeros((4, 1)),
        np.zeros((4, 1)),
        signals={
            "ball": np.zeros((3, 2)),
            "ball_times": np.array([0.0, 0.5, 0.7]),
            "racket": np.zeros((4, 3)),
            "long": np.zeros((6, 3)),
        },
    )
    np.testing.assert_array_equal(signal_times(traj, "ball"), [0.0, 0.5, 0.7])
    np.testing.assert_array_equal(signal_times(traj, "racket"), traj.times)
    np.testing.assert_allclose(signal_times(traj, "long"), 0.1 * np.arange(6))
    with pytest.raises(ValueError, match="no signal 'puck'"):
        signal_times(traj, "puck")
    with pytest.raises(ValueError, match="time stamps"):
        signal_times(traj, "racket", "ball_times")


# ----------------------------------------------------------------------------- MuJoCo models
TEST_XML = """
<mujoco model="test_arm">
  <asset>
    <mesh name="tetra" vertex="0 0 0  0.2 0 0  0 0.2 0  0 0 0.2"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.8 0.8 0.8 1"/>
    <geom name="post" type="box" size="0.05 0.05 0.05" pos="0 0 0.05"/>
    <body name="link1" pos="0 0 0.1">
      <joint name="j1" type="hinge" axis="0 0 1"/>
      <geom name="upper" type="capsule" fromto="0 0 0 0.5 0 0" size="0.03"/>
      <geom name="hidden" type="sphere" size="0.05" group="4"/>
      <geom name="ghost" type="sphere" size="0.05" rgba="1 0 0 0"/>
      <body name="link2" pos="0.5 0 0">
        <joint name="j2" type="hinge" axis="0 1 0"/>
        <geom name="lower" type="cylinder" fromto="0 0 0 0.4 0 0" size="0.02"/>
        <geom name="tip" type="sphere" size="0.04" pos="0.4 0 0" rgba="1 0 0 0.5"/>
        <geom name="egg" type="ellipsoid" size="0.02 0.03 0.05" pos="0.2 0.1 0"/>
      </body>
    </body>
    <body name="slider" pos="1 0 0">
      <joint name="s" type="slide" axis="0 1 0"/>
      <geom name="tetra" type="mesh" mesh="tetra"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_string(TEST_XML)


def test_mujoco_model_nodes_and_primitive_sizes(scene, model):
    ms = add_mujoco_model(scene, model, "/arm", world_paths={"floor": "/floor"})
    assert set(ms.bodies) == {"/arm/world", "/arm/link1", "/arm/link2", "/arm/slider"}
    assert set(ms.geoms) == {
        "/floor",
        "/arm/world/post",
        "/arm/link1/upper",
        "/arm/link2/lower",
        "/arm/link2/tip",
        "/arm/link2/egg",
        "/arm/slider/tetra",
    }
    for path in ms.nodes:
        assert scene.get_handle_by_name(path) is ms.nodes[path]
    assert any("hidden" in s and "group 4" in s for s in ms.skipped)
    assert any("ghost" in s and "transparent" in s for s in ms.skipped)
    assert ms.geoms["/arm/world/post"].dimensions == pytest.approx((0.1, 0.1, 0.1))
    assert ms.geoms["/arm/link2/lower"].radius == pytest.approx(0.02)
    assert ms.geoms["/arm/link2/lower"].height == pytest.approx(0.4)
    assert ms.geoms["/arm/link2/tip"].radius == pytest.approx(0.04)
    assert ms.geoms["/arm/link2/tip"].opacity == pytest.approx(0.5)
    assert ms.geoms["/arm/link2/egg"].scale == pytest.approx((0.02, 0.03, 0.05))
    # the capsule mesh spans the fromto segment plus the caps along its local z
    z = ms.geoms["/arm/link1/upper"].vertices[:, 2]
    assert z.max() == pytest.approx(0.25 + 0.03, abs=1e-6)


def test_mujoco_poses_follow_qpos_by_independent_forward_kinematics(scene, model):
    ms = add_mujoco_model(scene, model, "/arm")
    rng = np.random.default_rng(1)
    for _ in range(4):
        q1, q2, s = rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi), rng.uniform(-1, 1)
        ms.set_qpos([q1, q2, s])
        R1 = rot("z", q1)
        p1 = np.array([0, 0, 0.1])
        R2 = R1 @ rot("y", q2)
        p2 = p1 + R1 @ np.array([0.5, 0, 0])
        # centres of the geoms, composed through viser's node tree
        expected = {
            "/arm/link1/upper": (p1 + R1 @ [0.25, 0, 0], R1 @ rot("y", np.pi / 2)),
            "/arm/link2/lower": (p2 + R2 @ [0.2, 0, 0], R2 @ rot("y", np.pi / 2)),
            "/arm/link2/tip": (p2 + R2 @ [0.4, 0, 0], None),
            "/arm/link2/egg": (p2 + R2 @ [0.2, 0.1, 0], None),
        }
        for path, (position, rotation) in expected.items():
            R, p = world_pose(scene, path)
            np.testing.assert_allclose(p, position, atol=1e-9, err_msg=path)
            if rotation is not None:  # a capsule's/cylinder's axis is defined up to its sign
                # MuJoCo's 2-body chain and viser's 3 nodes against 3 rotations here
                tol = pose_tol(1.0, 2 + 3 + 3)
                assert abs(R[:, 2] @ rotation[:, 2]) == pytest.approx(1.0, abs=tol), path
        R, _ = world_pose(scene, "/arm/link2/egg")  # an ellipsoid's frame is the body's
        np.testing.assert_allclose(R, R2, atol=1e-9)
        # mesh: the authored tetrahedron, translated by the slide joint
        R, p = world_pose(scene, "/arm/slider/tetra")
        verts = ms.geoms["/arm/slider/tetra"].vertices.astype(float) @ R.T + p
        authored = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2]]) + [1, s, 0]
        np.testing.assert_allclose(np.sort(verts, axis=0), np.sort(authored, axis=0), atol=1e-6)


class ToyTask(Task):
    """A task nobody wrote an adapter for: it only exposes its MuJoCo model."""

    name, context_dim, parameter_dim = "toy", 0, 1

    def __init__(self, model):
        self.model = model

    def scene_model(self):
        return self.model

    def _simulate(self, omega, context, rng):
        times = np.linspace(0.0, 1.0, 11)
        q = np.column_stack([times, -times, omega[0] * times])
        return Trajectory(times, np.hstack([q, np.zeros_like(q)]), np.zeros((11, 1)))

    def _reward(self, trajectory, context):
        return 0.0

    def initial_policy(self):
        return LinearGaussianPolicy(np.zeros(1), np.eye(1))


def test_generic_adapter_for_any_task_exposing_a_model(scene, model):
    task = ToyTask(model)
    ts = task_scene(scene, task)
    assert type(ts) is scenes.MujocoTaskScene and ts.state_dim == 6
    traj = task.rollout([0.5])
    ts.show(traj, 0.55)
    _, p = world_pose(scene, "/arm/slider")  # the slide joint at s = 0.5 · 0.55
    # the state interpolated at t (one more "frame" of flops), MuJoCo's body, viser's 2 nodes
    tol = pose_tol(1.0 + 0.5, 1 + 1 + 2)
    np.testing.assert_allclose(p, [1.0, 0.275, 0.0], atol=tol)
    # no site in the model: the 3-D point of a state is the last body's origin (the slider)
    np.testing.assert_allclose(ts.trails(traj)["effector"][:, 1], 0.5 * traj.times, atol=tol)
    np.testing.assert_allclose(ts.points(traj.states[4]), [1.0, 0.2, 0.0], atol=tol)
    with pytest.raises(ValueError, match="states"):
        ts.points(np.zeros(3))


def test_mujoco_model_bad_input(scene, model):
    with pytest.raises(ValueError, match="model"):
        add_mujoco_model(scene, "not a model")
    with pytest.raises(ValueError, match="root"):
        add_mujoco_model(scene, model, "arm")
    with pytest.raises(ValueError, match="no geom named"):
        add_mujoco_model(scene, model, skip_geoms=("nope",))
    with pytest.raises(ValueError, match="not static"):
        add_mujoco_model(scene, model, world_paths={"upper": "/upper"})
    ms = add_mujoco_model(scene, model)
    with pytest.raises(ValueError, match="qpos"):
        ms.set_qpos([0.0, 0.0])
    with pytest.raises(ValueError, match="qpos"):
        ms.set_qpos([0.0, np.nan, 0.0])


def test_unsupported_geoms_are_reported(scene):
    xml = """<mujoco><asset><hfield name="h" nrow="2" ncol="2" size="1 1 0.1 0.1"/></asset>
      <worldbody><geom name="terrain" type="hfield" hfield="h"/>
      <geom name="s" type="sphere" size="0.1"/></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.warns(RuntimeWarning, match="terrain"):
        ms = add_mujoco_model(scene, m)
    assert list(ms.geoms) == ["/arm/world/s"]
    assert any("terrain: unsupported" in s for s in ms.skipped)


# ----------------------------------------------------------------------------- task scenes
EXPECTED_NODES = {
    "PendulumScene": {"/pendulum/link1", "/pendulum/link1/bob", "/pendulum/pivot"},
    "PlanarScene": {"/arm/shin", "/arm/thigh", "/arm/torso", "/arm/arm"},
    "ThrowingScene": {"/arm/shin", "/arm/torso", "/arm/arm", "/ball", "/target"},
    "HockeyScene": {
        "/arm/link1",
        "/arm/link3",
        "/arm/link7/blade",
        "/table",
        "/pucks/control",
        "/pucks/target",
        "/target",
    },
    "TableTennisScene": {"/arm/platform", "/arm/hand/blade", "/table", "/net", "/ball", "/target"},
}


@pytest.mark.parametrize("name", names())
def test_every_registered_task_has_a_scene(scene, name):
    task = make(name)
    ts = task_scene(scene, task)
    assert type(ts).__name__ in EXPECTED_NODES, f"{name}: generic scene {type(ts).__name__}"
    assert EXPECTED_NODES[type(ts).__name__] <= set(ts.nodes)
    context = task.sample_context(np.random.default_rng(0)) if task.context_dim else None
    omega = task.initial_policy().mean_of(context if task.context_dim else None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        traj = task.rollout(omega, context, np.random.default_rng(0))
    assert not traj.failed, traj.message
    if task.context_dim:
        ts.set_context(context)
    t0, t1 = ts.time_range(traj)
    assert t0 <= traj.times[-1] <= t1
    for t in (t0, 0.5 * (t0 + t1), t1):
        ts.show(traj, t)
    for key, path in ts.trails(traj).items():
        assert path.ndim == 2 and path.shape[1] == 3 and np.all(np.isfinite(path)), key
    pts = ts.points(traj.states[:3])
    assert pts.shape == (3, 3) and np.all(np.isfinite(pts))


def test_pendulum_bob_follows_the_angle(scene):
    task = make("pendulum")
    ts = task_scene(scene, task)
    length, pivot = ts.LENGTH, np.asarray(ts.PIVOT)
    # viser's 3 nodes (the link's quaternion from α/2) against the closed form
    tol = pose_tol(np.abs(pivot).max() + length, 3)
    for alpha in (0.0, 0.7, -2.0, np.pi):
        ts.set_angle(alpha)
        _, p = world_pose(scene, "/pendulum/link1/bob")
        np.testing.assert_allclose(
            p, pivot + length * np.array([np.sin(alpha), 0, -np.cos(alpha)]), atol=tol
        )
        np.testing.assert_allclose(ts.points([alpha, 3.0]), p, atol=tol)
    traj = task.rollout([-3.0, -1.0], [1.0, 0.5], 0)
    ts.show(traj, traj.times[4])
    _, p = world_pose(scene, "/pendulum/link1/bob")
    np.testing.assert_allclose(p, ts.points(traj.states[4]), atol=tol)
    np.testing.assert_allclose(ts.trails(traj)["bob"], ts.points(traj.states))
    with pytest.raises(ValueError, match="states"):
        ts.points(np.zeros((4, 3)))


def test_hockey_blade_matches_the_tasks_own_forward_kinematics(scene):
    from skillkit.tasks.hockey import arm_forward_kinematics

    task = make("hockey")
    ts = task_scene(scene, task)
    q = np.random.default_rng(2).uniform(-1.0, 1.0, 7)
    ts.robot.set_qpos(q)
    R, p = world_pose(scene, "/arm/link7/blade")
    p_ref, R_ref = arm_forward_kinematics(q)
    np.testing.assert_allclose(p, p_ref, atol=1e-9)
    np.testing.assert_allclose(R, R_ref, atol=1e-9)
    np.testing.assert_allclose(ts.points(np.concatenate([q, np.zeros(7)])), p_ref, atol=1e-9)


def test_hockey_pucks_and_target_follow_signals_and_context(scene):
    task = make("hockey")
    ts = task_scene(scene, task)
    s = np.array([2.2, 0.6, 0.4])
    ts.set_context(s)
    target = scene.get_handle_by_name("/target")
    assert np.allclose(target.position[:2], s[:2]) and target.radius == pytest.approx(0.4)
    traj = task.rollout(task.initial_policy().mean_of(s), s, 0)
    t_p = traj.signals["puck_times"]
    t = 0.5 * (t_p[10] + t_p[11])
    ts.show(traj, t)
    expected = 0.5 * (traj.signals["target_puck"][10] + traj.signals["target_puck"][11])
    np.testing.assert_allclose(scene.get_handle_by_name("/pucks/target").position[:2], expected)
    ts.show(traj, 1e3)  # after the record: the pucks rest where they stopped
    np.testing.assert_allclose(
        scene.get_handle_by_name("/pucks/control").position[:2], traj.signals["control_puck"][-1]
    )


def test_throwing_ball_and_target_in_the_robot_plane(scene):
    task = make("throwing")
    ts = task_scene(scene, task)
    s = np.array([8.0, 2.0])
    ts.set_context(s)
    np.testing.assert_allclose(scene.get_handle_by_name("/target").position, [8.0, 0.0, 2.0])
    traj = task.rollout(task.initial_policy().mean_of(s), s, 0)
    k = traj.signals["ball"].shape[0] - 5
    ts.show(traj, traj.signals["ball_times"][k])
    bx, by = traj.signals["ball"][k]
    np.testing.assert_allclose(scene.get_handle_by_name("/ball").position, [bx, 0.0, by])
    # the hand site by MuJoCo equals the task's closed-form planar kinematics
    from skillkit.tasks.planar import hand_kinematics

    q = traj.states[30, :4]
    xy, _ = hand_kinematics(q)
    np.testing.assert_allclose(ts.points(traj.states[30]), [xy[0], 0.0, xy[1]], atol=1e-9)


def test_task_scene_rejects_unknown_tasks_and_bad_contexts(scene):
    with pytest.raises(ValueError, match="task: no viewer scene"):
        task_scene(scene, object())
    ts = task_scene(scene, make("hockey"))
    with pytest.raises(ValueError, match="b_x"):
        ts.set_context([9.0, 0.6, 0.4])


def test_scenes_module_exports_exist():
    for name in scenes.__all__:
        assert hasattr(scenes, name), name
