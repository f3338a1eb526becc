"""Discrete Dynamic Movement Primitives (thesis Sec. 2.2.1, Eqs. 2.21–2.23).

Joints share one phase z(t) = exp(−τ α_z t) (Eq. 2.22) driving a forcing term
f(z) = φ(z)ᵀv of K normalised Gaussian basis functions times z. Each joint follows the
spring-damper system (Eq. 2.21) with the moving goal of Kober et al. (2010), in real time t:

    g_t   = g + gd (t − T_end),            T_end = duration / τ,
    qdd_t = τ² α_x (β_x (g_t − q_t) + (gd − qd_t) / τ) + τ² f(z_t; v).

The damping term carries qd/τ (Ijspeert et al. 2013), so τ is an exact time scaling; at
τ = 1 this is Eq. 2.21 as printed. The linear ODE is integrated exactly (matrix exponential,
first-order hold on the input between nodes of step ≤ ``dt``). Basis centres
c_i = exp(−α_z s_i) at times s_i evenly spaced on [0, duration], widths (c_i − c_{i+1})/√2."""

from __future__ import annotations

import copy
import functools
import itertools
import warnings
from collections.abc import Sequence

import numpy as np
from scipy.signal import lfilter

from skillkit._repr import number, span, vector
from skillkit._validation import check_array, check_count, check_positive, check_type

__all__ = ["DMP", "DMPParameters"]

_LEARNABLE = ("weights", "goal", "goal_velocity", "tau")


def _expm_small(m: np.ndarray) -> np.ndarray:
    """exp(m) of a small matrix: scaling and squaring of a degree-12 Taylor polynomial."""
    norm = float(np.abs(m).sum(axis=0).max())
    s = max(0, int(np.ceil(np.log2(norm / 0.25)))) if norm > 0 else 0
    x = m / 2.0**s
    term = np.eye(m.shape[0])
    out = term.copy()
    for j in range(1, 13):
        term = term @ x / j
        out += term
    for _ in range(s):
        out = out @ out
    return out


@functools.lru_cache(maxsize=64)
def _discretise(h: float, stiffness: float, damping: float):
    """Exact discretisation of q'' = −stiffness q − damping q' + u with u linear on [0, h]:
    s(h) = Φ s(0) + g_u u(0) + g_du u' (read-only, cached)."""
    m = np.zeros((4, 4))
    m[0, 1] = 1.0
    m[1, 0], m[1, 1], m[1, 2] = -stiffness, -damping, 1.0
    m[2, 3] = 1.0
    e = _expm_small(m * h)
    out = e[:2, :2].copy(), e[:2, 2].copy(), e[:2, 3].copy()
    for a in out:
        a.flags.writeable = False
    return out


class DMP:
    """Discrete DMP for ``n_joints`` joints sharing one phase (Eqs. 2.21–2.23).

    The learned state is ``weights`` v (J, K; zeros until :meth:`fit`), ``goal`` g (J,) or
    ``None``, ``goal_velocity`` gd (J,) and the time scaling ``tau`` τ.

    Parameters
    ----------
    n_joints : int
        J.
    n_basis : int, default 10
        K basis functions per joint.
    alpha_x, beta_x : float, default 25.0, 6.25
        Spring-damper gains of Eq. 2.21 (β_x = α_x/4: critically damped).
    alpha_z : float, default 3.0
        Phase decay of Eq. 2.22.
    dt, duration : float, default 1e-3, 1.0
        Largest integration step and nominal duration at τ = 1 (s).

    Raises
    ------
    ValueError
        On a non-positive count, gain or time.
    """

    def __init__(
        self,
        n_joints: int,
        n_basis: int = 10,
        alpha_x: float = 25.0,
        beta_x: float = 6.25,
        alpha_z: float = 3.0,
        dt: float = 1e-3,
        duration: float = 1.0,
    ) -> None:
        self.n_joints = check_count(n_joints, "n_joints")
        self.n_basis = check_count(n_basis, "n_basis")
        self.alpha_x = check_positive(alpha_x, "alpha_x")
        self.beta_x = check_positive(beta_x, "beta_x")
        self.alpha_z = check_positive(alpha_z, "alpha_z")
        self.dt = check_positive(dt, "dt")
        self.duration = check_positive(duration, "duration")
        self.weights = np.zeros((self.n_joints, self.n_basis))
        self.goal: np.ndarray | None = None
        self.goal_velocity = np.zeros(self.n_joints)
        self.tau = 1.0

    def __repr__(self) -> str:
        goal = "None" if self.goal is None else vector(self.goal)
        return (
            f"DMP(n_joints={self.n_joints}, n_basis={self.n_basis}, "
            f"duration={number(self.duration)} s, tau={number(self.tau)}, goal={goal}, "
            f"weights={span(self.weights)}, alpha_x={number(self.alpha_x)}, "
            f"beta_x={number(self.beta_x)}, alpha_z={number(self.alpha_z)})"
        )

    @property
    def centers(self) -> np.ndarray:
        """Basis centres c_i in phase space, decreasing from 1."""
        s = np.linspace(0.0, self.duration, self.n_basis)
        return np.exp(-self.alpha_z * s)

    @property
    def widths(self) -> np.ndarray:
        """Basis bandwidths σ_i."""
        if self.n_basis == 1:
            return np.ones(1)
        gaps = -np.diff(self.centers)
        return np.append(gaps, gaps[-1]) / np.sqrt(2.0)

    def phase(self, t, tau: float | None = None) -> np.ndarray:
        """z(t) = exp(−τ α_z t), Eq. 2.22 (default τ: ``self.tau``)."""
        tau = self.tau if tau is None else check_positive(tau, "tau")
        return np.exp(-tau * self.alpha_z * np.asarray(t, dtype=np.float64))

    def basis(self, z) -> np.ndarray:
        """φ(z) (n, n_basis): φ_i(z) = z ψ_i(z) / Σ_j ψ_j(z), ψ_i(z) = exp(−(z − c_i)² /
        (2σ_i²))."""
        z = check_array(z, "z", ndim=1)
        log_psi = -((z[:, None] - self.centers) ** 2) / (2.0 * self.widths**2)
        log_psi -= log_psi.max(axis=1, keepdims=True)  # normalise stably
        psi = np.exp(log_psi)
        return psi / psi.sum(axis=1, keepdims=True) * z[:, None]

    def replace(self, *, weights=None, goal=None, goal_velocity=None, tau=None) -> DMP:
        """A copy with some of weights, goal, goal_velocity, tau replaced (validated)."""
        new = copy.deepcopy(self)
        J, K = self.n_joints, self.n_basis
        if weights is not None:
            new.weights = check_array(weights, "weights", shape=(J, K)).copy()
        if goal is not None:
            new.goal = check_array(goal, "goal", shape=(J,)).copy()
        if goal_velocity is not None:
            new.goal_velocity = check_array(goal_velocity, "goal_velocity", shape=(J,)).copy()
        if tau is not None:
            new.tau = check_positive(tau, "tau")
        return new

    def fit(self, times, q, qd, qdd, tau: float = 1.0, ridge: float = 0.0) -> DMP:
        """Fit the weights v to a demonstration by least squares (Eq. 2.23).

        Sets ``goal``, ``goal_velocity`` to the last demonstrated position and velocity, ``tau``
        and ``duration`` = τ (times[-1] − times[0]), then solves v = argmin ‖Φ v − Y‖² +
        ridge ‖v‖² with Y of :meth:`forcing_target`.

        Parameters
        ----------
        times : array_like, shape (N,)
            Strictly increasing time stamps (s), N ≥ 2.
        q, qd, qdd : array_like, shape (N, J)
            Demonstrated positions, velocities, accelerations.
        tau : float, default 1.0
        ridge : float, default 0.0
            Ridge on v; a rank-deficient basis with ``ridge=0`` warns (``RuntimeWarning``).

        Returns
        -------
        self
        """
        t, q, qd, qdd = self._check_demo(times, q, qd, qdd, 2)
        tau = check_positive(tau, "tau")
        ridge = check_positive(ridge, "ridge", allow_zero=True)
        self.tau, self.duration = tau, tau * t[-1]
        self.goal, self.goal_velocity = q[-1].copy(), qd[-1].copy()
        target = self.forcing_target(times, q, qd, qdd)
        phi = self.basis(self.phase(t, tau))
        if ridge > 0:
            phi = np.vstack([phi, np.sqrt(ridge) * np.eye(self.n_basis)])
            target = np.vstack([target, np.zeros((self.n_basis, self.n_joints))])
        v, _, rank, _ = np.linalg.lstsq(phi, target, rcond=None)
        if rank < self.n_basis:
            warnings.warn(
                f"DMP.fit: the basis matrix has rank {rank} < n_basis={self.n_basis}; "
                "the demonstration does not excite every basis function (pass ridge > 0)",
                RuntimeWarning,
                stacklevel=2,
            )
        self.weights = v.T.copy()
        return self

    def forcing_target(self, times, q, qd, qdd) -> np.ndarray:
        """Eq. (2.23)'s target Y = q̈/τ² − α_x (β_x (g_t − q) + (ġ − q̇)/τ), shape (N, n_joints)."""
        if self.goal is None:
            raise ValueError("DMP.forcing_target: the DMP has no goal; fit() it first")
        t, q, qd, qdd = self._check_demo(times, q, qd, qdd, 1)
        tau, g, gd = self.tau, self.goal, self.goal_velocity
        g_t = self._moving_goal(t, g, gd, tau)
        return qdd / tau**2 - self.alpha_x * (self.beta_x * (g_t - q) + (gd - qd) / tau)

    def _check_demo(self, times, q, qd, qdd, min_n: int) -> tuple[np.ndarray, ...]:
        """Times (N,) from 0, strictly increasing, and q, qd, qdd (N, J) of a demonstration."""
        t = self._check_times(times, min_n, uniform=False)
        shape = (t.shape[0], self.n_joints)
        arrays = (check_array(a, n, shape=shape) for a, n in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
        return (t - t[0], *arrays)

    def grid(self, duration: float) -> np.ndarray:
        """The :meth:`rollout` grid for a ``duration``: ceil(duration / dt) equal steps."""
        duration = check_positive(duration, "duration")
        n = max(1, int(np.ceil(duration / self.dt - 1e-9)))
        return np.linspace(0.0, duration, n + 1)

    def forcing(self, t, tau: float | None = None, weights=None) -> np.ndarray:
        """Forcing term f(z_t; v) (n, n_joints) at times ``t`` (n,) (Eq. 2.21)."""
        tau = self.tau if tau is None else check_positive(tau, "tau")
        w = self._weights(weights)
        t = check_array(t, "t", ndim=1)
        return self.basis(self.phase(t, tau)) @ w.T

    def rollout(
        self,
        times,
        q0,
        qd0=None,
        goal=None,
        goal_velocity=None,
        tau: float | None = None,
        weights=None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Integrate the DMP (Eqs. 2.21–2.22, moving goal) exactly between grid nodes.

        Parameters
        ----------
        times : float or array_like, shape (T,)
            A duration (s; the grid of :meth:`grid`) or uniformly spaced increasing stamps.
        q0, qd0 : array_like, shape (J,)
            Start position and velocity (default 0).
        goal, goal_velocity, tau, weights : optional
            Override g (J,), gd (J,), τ and v (J, K).

        Returns
        -------
        q, qd, qdd : ndarray, shape (T, J)

        Raises
        ------
        ValueError
            On malformed input or a missing goal.
        FloatingPointError
            If the integration overflowed.
        """
        J = self.n_joints
        times = self.grid(times) if np.ndim(times) == 0 else self._check_times(times)
        q0 = check_array(q0, "q0", shape=(J,))
        qd0 = np.zeros(J) if qd0 is None else check_array(qd0, "qd0", shape=(J,))
        if goal is None and self.goal is None:
            raise ValueError("goal: the DMP has no goal yet; pass goal= or fit() it first")
        goal = check_array(self.goal if goal is None else goal, "goal", shape=(J,))
        gd = self.goal_velocity if goal_velocity is None else goal_velocity
        gd = check_array(gd, "goal_velocity", shape=(J,))
        tau = self.tau if tau is None else check_positive(tau, "tau")
        w = self._weights(weights)

        t_out = times - times[0]
        if t_out.shape[0] == 1:
            sub, t = 1, t_out
        else:
            sub = max(1, int(np.ceil(t_out[1] / self.dt - 1e-9)))
            t = np.linspace(0.0, t_out[-1], (t_out.shape[0] - 1) * sub + 1)
        a, b = self.alpha_x, self.beta_x
        stiffness, damping = tau**2 * a * b, tau * a
        u = (
            stiffness * self._moving_goal(t, goal, gd, tau)
            + damping * gd
            + tau**2 * (self.basis(self.phase(t, tau)) @ w.T)
        )  # (N, J)

        s = np.empty((t.shape[0], 2, J))
        s[0] = q0, qd0
        if t.shape[0] > 1:
            s = self._integrate(s[0], u, t[1] - t[0], stiffness, damping)
        q, qd = s[::sub, 0], s[::sub, 1]
        qdd = -stiffness * q - damping * qd + u[::sub]
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise FloatingPointError("DMP.rollout: the integration produced non-finite values")
        return q, qd, qdd

    def _moving_goal(self, t, goal, goal_velocity, tau) -> np.ndarray:
        return goal + goal_velocity * (t[:, None] - self.duration / tau)

    def _weights(self, weights) -> np.ndarray:
        shape = (self.n_joints, self.n_basis)
        return self.weights if weights is None else check_array(weights, "weights", shape=shape)

    @staticmethod
    def _check_times(times, min_n: int = 1, uniform: bool = True) -> np.ndarray:
        """At least ``min_n`` strictly increasing (and ``uniform``ly spaced) time stamps (N,)."""
        t = check_array(times, "times", ndim=1)
        if t.shape[0] < min_n:
            raise ValueError(f"times: expected at least {min_n} time stamp(s), got {t.shape[0]}")
        steps = np.diff(t)
        if np.any(steps <= 0):
            raise ValueError("times: expected strictly increasing time stamps")
        if uniform and steps.size and np.max(np.abs(steps - steps[0])) > 1e-6 * steps[0]:
            raise ValueError("times: expected uniformly spaced time stamps")
        return t

    @staticmethod
    def _integrate(s0, u, h, stiffness, damping) -> np.ndarray:
        """s_{n+1} = Φ s_n + w_n as a second-order linear filter over all joints (Cayley–Hamilton);
        ``s0`` (2, J), ``u`` (N, J): returns (N, 2, J)."""
        phi, g_u, g_du = _discretise(h, stiffness, damping)
        du = np.diff(u, axis=0) / h
        w = g_u[None, :, None] * u[:-1, None, :] + g_du[None, :, None] * du[:, None, :]
        tr, det = phi[0, 0] + phi[1, 1], phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0]
        r = np.empty((u.shape[0], 2, u.shape[1]))
        r[0] = s0
        r[1] = phi @ s0 + w[0] - tr * s0
        r[2:] = w[1:] + (phi - tr * np.eye(2)) @ w[:-1]
        return lfilter([1.0], [1.0, -tr, det], r, axis=0)


class DMPParameters:
    """Flat parameter vector ω over a chosen subset of a DMP's parameters.

    The learned entries, in this order: weights v (joint-major), goal g, final velocity gd and
    τ; the rest stays as in ``dmp`` (not modified). E.g. hockey (Sec. 3.4.2) learns
    ``("goal", "goal_velocity", "tau")`` for 7 joints: ``dim == 15``.

    ``dim`` is the length of ω and ``names`` a label per entry.

    Parameters
    ----------
    dmp : DMP
        The template.
    learn : sequence of {"weights", "goal", "goal_velocity", "tau"}
        Non-empty, without repeats (default all).
    """

    def __init__(self, dmp: DMP, learn: Sequence[str] = _LEARNABLE) -> None:
        check_type(dmp, DMP, "dmp", "a DMP")
        if isinstance(learn, str):
            learn = (learn,)
        learn = tuple(learn)
        unknown = [p for p in learn if p not in _LEARNABLE]
        if unknown or not learn or len(set(learn)) != len(learn):
            raise ValueError(f"learn: expected distinct names from {_LEARNABLE}, got {learn}")
        if "goal" in learn and dmp.goal is None:
            raise ValueError("dmp: has no goal to learn from; fit() it or set its goal first")
        self.dmp = dmp
        self.learn = tuple(p for p in _LEARNABLE if p in learn)
        J, K = dmp.n_joints, dmp.n_basis
        labels = {
            "weights": [f"w[{j},{i}]" for j in range(J) for i in range(K)],
            "goal": [f"g[{j}]" for j in range(J)],
            "goal_velocity": [f"gd[{j}]" for j in range(J)],
            "tau": ["tau"],
        }
        self.names = [n for p in self.learn for n in labels[p]]
        self.dim = len(self.names)
        sizes = {p: len(labels[p]) for p in self.learn}
        ends = itertools.accumulate(sizes.values())
        self._slices = {p: slice(e - sizes[p], e) for p, e in zip(sizes, ends, strict=True)}

    def __repr__(self) -> str:
        d = self.dmp
        return (
            f"DMPParameters(dim={self.dim}, learn={self.learn}, n_joints={d.n_joints}, "
            f"n_basis={d.n_basis}, omega={vector(self.to_vector())})"
        )

    def to_vector(self, dmp: DMP | None = None) -> np.ndarray:
        """ω of ``dmp`` (default: the template), shape (dim,)."""
        dmp = self.dmp if dmp is None else dmp
        return np.concatenate([np.ravel(getattr(dmp, p)).astype(np.float64) for p in self.learn])

    def from_vector(self, omega) -> DMP:
        """A copy of the template with the learned parameters from ``omega`` (τ > 0)."""
        omega = check_array(omega, "omega", shape=(self.dim,))
        J, K = self.dmp.n_joints, self.dmp.n_basis
        kw = {p: omega[self._slices[p]] for p in self.learn}
        if "weights" in kw:
            kw["weights"] = kw["weights"].reshape(J, K)
        if "tau" in kw:
            tau = float(kw["tau"][0])
            if tau <= 0:
                raise ValueError(f"omega: its tau entry must be > 0, got {tau:g}")
            kw["tau"] = tau
        return self.dmp.replace(**kw)
