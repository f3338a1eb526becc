"""Shared task pieces: the quintic profile, the MJCF preamble, the planar robot's closed-form
dynamics and the ModelSignals record."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from skillkit.tasks import ModelSignals
from skillkit.tasks._mjcf import mjcf_root
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.planar_model import compile_planar_robot, rigid_body_terms


def test_quintic_meets_its_boundary_conditions():
    q0, q1, v0, v1 = np.array([0.3, -1.0]), np.array([1.2, 0.5]), np.array([0.0, 2.0]), [1.5, -1]
    q, qd, qdd = quintic(np.array([0.0, 0.7]), 0.7, q0, q1, v0, v1)
    np.testing.assert_allclose(q, [q0, q1], atol=1e-12)
    np.testing.assert_allclose(qd, [v0, v1], atol=1e-12)
    np.testing.assert_allclose(qdd, 0.0, atol=1e-11)
    # derivatives are the derivatives (central differences)
    t, h = np.array([0.31]), 1e-6
    a, b = quintic(t - h, 0.7, q0, q1, v0, v1), quintic(t + h, 0.7, q0, q1, v0, v1)
    mid = quintic(t, 0.7, q0, q1, v0, v1)
    np.testing.assert_allclose((b[0] - a[0]) / (2 * h), mid[1], rtol=1e-7)
    np.testing.assert_allclose((b[1] - a[1]) / (2 * h), mid[2], rtol=1e-6)


def test_quintic_rest_to_rest_is_minimum_jerk_and_clips():
    t = np.linspace(-0.5, 2.5, 31)
    s, sd, sdd = quintic(t, 2.0, clip=True)
    u = np.clip(t / 2.0, 0, 1)
    np.testing.assert_array_equal(s, 10 * u**3 - 15 * u**4 + 6 * u**5)
    assert s[0] == 0.0 and s[-1] == 1.0 and sd[0] == sd[-1] == 0.0
    with pytest.raises(ValueError, match="duration"):
        quintic(t, 0.0)


def test_mjcf_preamble():
    root = mjcf_root("m", 0.004, geom_rgba=[1, 0, 0, 1], contacts=False)
    root.worldbody.add("geom", type="sphere", size=[0.1])
    model = mujoco.MjModel.from_xml_string(root.to_xml_string())
    assert model.opt.timestep == 0.004 and model.opt.gravity[2] == -9.81
    assert model.geom_contype[0] == 0 and model.geom_conaffinity[0] == 0
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    with pytest.raises(ValueError, match="timestep"):
        mjcf_root("m", -1.0)


def test_planar_closed_form_dynamics_equal_mujoco():
    physics = compile_planar_robot()
    model, data = physics.model.ptr, physics.data.ptr
    rng = np.random.default_rng(0)
    q, qd = 2 * rng.standard_normal((6, 4)), 5 * rng.standard_normal((6, 4))
    m, c = rigid_body_terms(torch.as_tensor(q), torch.as_tensor(qd))
    for i in range(6):
        data.qpos[:], data.qvel[:] = q[i], qd[i]
        mujoco.mj_forward(model, data)
        full = np.zeros((4, 4))
        mujoco.mj_fullM(model, data, full)
        np.testing.assert_allclose(m[i].numpy(), full, atol=1e-10)
        np.testing.assert_allclose(c[i].numpy(), data.qfrc_bias, atol=1e-9)


def test_model_signals_validate():
    sig = ModelSignals(state=("a", "b"), control=("u",), signals=("ball",))
    assert (sig.state_dim, sig.control_dim) == (2, 1)
    with pytest.raises(ValueError, match="state"):
        ModelSignals(state=())
    with pytest.raises(ValueError, match="control"):
        ModelSignals(state=("a",), control=["u"])
    with pytest.raises(ValueError, match="state"):
        ModelSignals(state=("a", "a"))
