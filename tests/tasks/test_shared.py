"""Shared task pieces: the quintic profile, the MJCF preamble, the planar robot's closed-form
dynamics and the ModelSignals record."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.tasks import ModelSignals
from skillkit.tasks._mjcf import mjcf_root
from skillkit.tasks._trajectories import quintic
from skillkit.tasks.planar_model import (
    GRAVITY,
    _chain_constants,
    compile_planar_robot,
    rigid_body_terms,
)


def _quintic_end_tols(T, q0, q1, v0, v1):
    """Absolute round-off of q, q̇, q̈ at u = 1, where the coefficients c = (10a − 4b,
    −15a + 7b, 6a − 3b) (a = q₁ − q₀ − T v₀, b = T (v₁ − v₀)) cancel to q₁, v₁ and 0:
    ~12 flops on terms of size |q₀| + T|v₀| + Σ|c_k|, (T|v₀| + Σ k|c_k|) / T and
    Σ k(k − 1)|c_k| / T²."""
    q0, q1, v0, v1 = (np.abs(np.asarray(x, dtype=float)) for x in (q0, q1, v0, v1))
    a, b = q1 + q0 + T * v0, T * (v1 + v0)  # bounds on |a|, |b|
    c = (10 * a + 4 * b, 15 * a + 7 * b, 6 * a + 3 * b)
    scales = (
        q0 + T * v0 + c[0] + c[1] + c[2],
        (T * v0 + 3 * c[0] + 4 * c[1] + 5 * c[2]) / T,
        (6 * c[0] + 12 * c[1] + 20 * c[2]) / T**2,
    )
    return tuple(fp_tol(12, scale=s.max()) for s in scales)


def test_quintic_meets_its_boundary_conditions():
    q0, q1, v0, v1 = np.array([0.3, -1.0]), np.array([1.2, 0.5]), np.array([0.0, 2.0]), [1.5, -1]
    q, qd, qdd = quintic(np.array([0.0, 0.7]), 0.7, q0, q1, v0, v1)
    # u = 0: q = q₀ + 0 and q̈ = 0 exactly, q̇ = (T v₀) / T up to two roundings
    np.testing.assert_array_equal(q[0], q0)
    np.testing.assert_allclose(qd[0], v0, atol=fp_tol(2, scale=np.abs(v0).max()))
    np.testing.assert_array_equal(qdd[0], 0.0)
    tol_q, tol_qd, tol_qdd = _quintic_end_tols(0.7, q0, q1, v0, v1)
    np.testing.assert_allclose(q[1], q1, atol=tol_q)
    np.testing.assert_allclose(qd[1], v1, atol=tol_qd)
    np.testing.assert_allclose(qdd[1], 0.0, atol=tol_qdd)
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


def _dynamics_tols(q, qd):
    """Absolute round-off of M(q) and c(q, q̇), closed form vs MuJoCo, for one state.

    M = Lᵀ (H ⊙ cos(θ_i − θ_j) + diag I) L sums up to 16 terms, and MuJoCo's composite
    rigid-body (RNE for c) recursion over the 4 bodies ~10 flops each: ~56 flops on terms of
    size Lᵀ (|H| + I) L (Lᵀ (|H| θ̇² + g |b|) for c); the absolute angles θ = L q are off by
    ε |θ|, which enters through cos/sin as 2 ε max|θ| times the same terms.
    """
    h, b, inertia = (np.abs(x) for x in _chain_constants())
    lower = np.tril(np.ones((4, 4)))
    theta = np.abs(lower @ q).max()
    s_m = (lower.T @ (h + np.diag(inertia)) @ lower).max()
    s_c = (lower.T @ (h @ (lower @ qd) ** 2 + GRAVITY * b)).max()
    return tuple(fp_tol(16 + 4 * 10, scale=s) + fp_tol(2, scale=s * theta) for s in (s_m, s_c))


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
        tol_m, tol_c = _dynamics_tols(q[i], qd[i])
        np.testing.assert_allclose(m[i].numpy(), full, atol=tol_m)
        np.testing.assert_allclose(c[i].numpy(), data.qfrc_bias, atol=tol_c)


def test_model_signals_validate():
    sig = ModelSignals(state=("a", "b"), control=("u",), signals=("ball",))
    assert (sig.state_dim, sig.control_dim) == (2, 1)
    with pytest.raises(ValueError, match="state"):
        ModelSignals(state=())
    with pytest.raises(ValueError, match="control"):
        ModelSignals(state=("a",), control=["u"])
    with pytest.raises(ValueError, match="state"):
        ModelSignals(state=("a", "a"))
