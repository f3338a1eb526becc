"""Smooth point-to-point profiles shared by the tasks' scripted demonstrations."""

from __future__ import annotations

import numpy as np

from skillkit._validation import check_positive


def quintic(
    t,
    duration: float,
    start=0.0,
    end=1.0,
    start_velocity=0.0,
    end_velocity=0.0,
    *,
    clip: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic q(u) = q₀ + T q̇₀ u + c₃ u³ + c₄ u⁴ + c₅ u⁵, u = t / T, from (start,
    start_velocity, 0) to (end, end_velocity, 0) over ``duration`` T: a = q₁ − q₀ − T q̇₀,
    b = T (q̇₁ − q̇₀), c₃ = 10a − 4b, c₄ = −15a + 7b, c₅ = 6a − 3b. Boundary values scalars or
    (n,); ``clip`` holds the ends outside [0, T]. Returns q, q̇, q̈, shape (N,) or (N, n).
    """
    T = check_positive(duration, "duration")
    q0, q1, v0, v1 = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (start, end, start_velocity, end_velocity))
    )
    a, b = q1 - q0 - T * v0, T * (v1 - v0)
    c = (10 * a - 4 * b, -15 * a + 7 * b, 6 * a - 3 * b)
    u = np.asarray(t, dtype=np.float64) / T
    if clip:
        u = np.clip(u, 0.0, 1.0)
    u = u.reshape(u.shape + (1,) * q0.ndim)
    q = q0 + T * v0 * u + c[0] * u**3 + c[1] * u**4 + c[2] * u**5
    qd = (T * v0 + 3 * c[0] * u**2 + 4 * c[1] * u**3 + 5 * c[2] * u**4) / T
    qdd = (6 * c[0] * u + 12 * c[1] * u**2 + 20 * c[2] * u**3) / T**2
    return q, qd, qdd
