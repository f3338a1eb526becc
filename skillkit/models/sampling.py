"""Batched stochastic trajectory prediction with a learned forward model (Secs 2.1.2, 4.2.1).

For B (context, ω) pairs and L trajectories each, :func:`sample_trajectories` draws, in one
vectorised loop over time (Eq. 4.3, Fig. 2.4),

.. math:: u_t = \\pi_\\omega(t, x_t), \\qquad x_{t+1} \\sim p(x_{t+1} \\mid x_t, u_t),

for all B·L trajectories at once; each step is a few batched matrix products.

* **Model protocol.** ``state_dim``, ``control_dim``, ``to(device, dtype)`` and
  ``next_state_moments(x, u) -> (mean, var, ...)`` (per-dimension Gaussian, shape (n, n_x)),
  e.g. :class:`~skillkit.models.gp.ForwardModel`. A model with noise correlated across
  dimensions also has ``noise_factor_tensor(device, dtype) -> F`` (n_x, n_x): then
  x' = mean + F ε and ``var`` is diag F Fᵀ (:class:`~skillkit.models.linear.LinearGaussianModel`).
* **Policy.** ``policy(t, x, pair) -> u``, ``x`` (n, n_x), ``pair`` (n,) the index of each
  row's (context, ω) pair; returns (n, n_u). An optional ``control_limit`` saturates u and
  counts the saturated entries.
* **Memory and randomness.** Rows are processed in chunks bounded by ``max_chunk_bytes``.
  All Gaussian noise (B·L, T, n_x) is drawn up front in float64 from one torch generator
  seeded by ``rng``, so results do not depend on the chunk size (up to BLAS round-off) and
  float32 paths follow the float64 paths of the same seed.
* **Precision.** float64 by default (every stored result); float32 is opt-in. The float32
  path keeps the set-up and the kernel exponent in float64 and runs ``exp`` and the main
  product in float32 (:meth:`~skillkit.models.gp.GPPredictor.kernel_vectors`). Its accuracy
  depends on the model's conditioning: near-linear-limit GPs (σ_f²/σ_ε² ~ 1e4) can be off by
  ~0.1 predictive standard deviations, so every float32 run compares its one-step moments
  with float64's on visited states (``precision_error``; a ``GPNumericalWarning`` above
  :data:`PRECISION_TOL`). Speed and accuracy figures: ``benchmarks/bench_sampler.py``,
  ``benchmarks/bench_prediction.py``.
* **Underflow in float64.** Kernel entries below e^{−600} σ_f² are raised to that value
  (:data:`~skillkit.models.gp.FLOOR_EXPONENT_FLOAT64`) so no ``exp`` underflows and no
  product is denormal (every stored experiment's smoke run is bit-identical without it,
  ``data/README.md``).
* **Pathwise alternative** (``method="pathwise"``, :mod:`skillkit.models.pathwise`): each
  trajectory follows one function drawn from the GP posterior. Same one-step marginals,
  different multi-step statistics (a wider final-state spread on the balancing FITC model);
  the per-step sampler is the thesis's (Sec. 4.2.1) and the default.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from skillkit._repr import number, span
from skillkit._validation import as_generator, check_count, check_positive
from skillkit.models.gp import (
    DTYPE,
    VARIANCE_TOL,
    GPNumericalWarning,
    GPPredictor,
    as_device,
    report_event,
)
from skillkit.models.pathwise import PathwiseBasis

__all__ = [
    "PRECISION_TOL",
    "SampledTrajectories",
    "StepModel",
    "sample_trajectories",
    "sampler_flops_per_step",
]

#: float32 sampling warns when its one-step moments differ from float64's by more than this
#: (mean error in predictive standard deviations, or relative variance error).
PRECISION_TOL = 1e-2


class StepModel(Protocol):
    """What :func:`sample_trajectories` needs from a forward model."""

    state_dim: int
    control_dim: int

    def to(self, device=None, dtype: torch.dtype | None = None) -> StepModel: ...

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor): ...


Policy = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class SampledTrajectories:
    """Trajectories sampled for B (context, ω) pairs × L repetitions.

    Attributes
    ----------
    states : Tensor, shape (B, L, T + 1, n_x)
        x_0 … x_T.
    controls : Tensor, shape (B, L, T, n_u)
        u_0 … u_{T−1} (after saturation).
    n_saturated : int
        Number of control entries clipped to ``control_limit``.
    n_variance_clamped : int
        Number of predictive variances that were negative from round-off and set to 0
        (see :mod:`skillkit.models.gp`).
    worst_variance : float
        The most negative latent variance relative to σ_f² (0 if none).
    precision_error : float
        float32 sampling only (0.0 in float64): the largest difference between the float32
        and float64 one-step predictive moments on visited states (first 64 trajectories at
        t = 0, T/2, T − 1): mean error in predictive standard deviations or relative variance
        error. Above ``PRECISION_TOL`` (1e-2) a :class:`GPNumericalWarning` is issued.
    stopped_at : Tensor of int64, shape (B, L), or None
        Only with a ``stop`` rule: the step k at which each trajectory was stopped (T if it
        never was); its states after x_k repeat x_k and its controls from u_k on are 0.
    """

    states: torch.Tensor
    controls: torch.Tensor
    n_saturated: int
    n_variance_clamped: int
    worst_variance: float
    precision_error: float = 0.0
    stopped_at: torch.Tensor | None = None

    def __repr__(self) -> str:
        B, L, T1, n_x = self.states.shape
        return (
            f"SampledTrajectories(B={B}, L={L}, T={T1 - 1}, state_dim={n_x}, "
            f"control_dim={self.controls.shape[-1]}, states={span(self.states)}, "
            f"n_saturated={self.n_saturated}, n_variance_clamped={self.n_variance_clamped}, "
            f"worst_variance={number(self.worst_variance)})"
        )

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """States and controls as numpy arrays."""
        return self.states.cpu().numpy(), self.controls.cpu().numpy()


def sample_trajectories(
    model: StepModel,
    x0,
    policy: Policy,
    horizon: int,
    n_trajectories: int = 1,
    rng=None,
    *,
    control_limit=None,
    device=None,
    dtype: torch.dtype = DTYPE,
    max_chunk_bytes: int = 2**25,
    method: str = "per-step",
    n_features: int = 256,
    stop: Callable[[int, torch.Tensor], torch.Tensor] | None = None,
) -> SampledTrajectories:
    """Sample L trajectories for each of B start conditions / policies in one vectorised call.

    Parameters
    ----------
    model : StepModel
        Fitted forward model, e.g. :class:`~skillkit.models.gp.ForwardModel`.
    x0 : array_like or Tensor, shape (B, n_x) or (B, L, n_x)
        Start states: one per pair (shared by its L trajectories) or one per trajectory
        (e.g. drawn from the task's initial-state distribution p(x_0; s), Eq. 4.3).
    policy : callable
        ``policy(t, x, pair) -> u``: ``t`` the step (int), ``x`` Tensor (n, n_x), ``pair``
        LongTensor (n,) in [0, B); returns Tensor (n, n_u) on the same device and dtype.
    horizon : int
        T, the number of transitions.
    n_trajectories : int
        L, trajectories per pair.
    rng : Generator, int, SeedSequence or None
        Randomness.
    control_limit : float or array_like, shape (n_u,), optional
        Saturate ``|u| ≤ control_limit`` (counted in ``n_saturated``).
    device : str or torch.device, optional
        Where to compute: a CPU or CUDA device (default: the CPU).
    dtype : torch.float64 or torch.float32
        float64 (default) or the opt-in float32 path (module notes; its error on the visited
        states is reported as ``precision_error``).
    max_chunk_bytes : int
        Bound (≥ 1) on the kernel work arrays per chunk of trajectories (default 32 MiB); a
        chunk holds at least one trajectory whatever the bound.
    method : {"per-step", "pathwise", "pathwise-shared"}
        "per-step" (default, the thesis's Sec. 4.2.1): every transition is an independent
        draw from the one-step predictive distribution. "pathwise": every trajectory draws one
        function from the GP posterior and follows it, with i.i.d. observation noise
        (:mod:`skillkit.models.pathwise`; GP forward models only), each with its own random
        features; "pathwise-shared": the same with one feature basis for all trajectories
        (cheaper; covariances off by O(1/√F), see :class:`~skillkit.models.pathwise.PathwiseBasis`).
    n_features : int
        F, random Fourier features per function and output (pathwise methods).
    stop : callable, optional
        ``stop(k, x) -> done``: ``x`` Tensor (n, n_x) the states x_k of the trajectories
        still running (k = 1 … T − 1), ``done`` a bool Tensor (n,). A trajectory that is done
        is no longer propagated: x_{k+1} … x_T repeat x_k and u_k … u_{T−1} are 0 (recorded in
        ``stopped_at``). For rollouts whose later states are not needed (a ball that has
        landed): the states up to x_k are the ones the full rollout draws (the same noise
        ε_{t} per trajectory and step; per-step method only), and the cost falls with the
        number of trajectories still running.

    Returns
    -------
    SampledTrajectories

    Raises
    ------
    ValueError
        On bad shapes, a device that is not a CPU or an available CUDA device, non-finite
        start states, a ``control_limit`` that is not positive or of the wrong length, a
        ``max_chunk_bytes`` that is not a positive integer, a policy returning the wrong shape
        or non-finite controls, an unsupported dtype or method, pathwise sampling of a model
        that is not a GP forward model, a ``stop`` that is not callable or is combined with a
        pathwise method, or a ``stop`` returning anything but a bool Tensor of shape (n,).
    """
    device = as_device(device)  # as tensors report it, so the policy's controls can be checked
    if dtype not in (torch.float64, torch.float32):
        raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
    if method not in ("per-step", "pathwise", "pathwise-shared"):
        raise ValueError(
            f"method: expected 'per-step', 'pathwise' or 'pathwise-shared', got {method!r}"
        )
    pathwise = method != "per-step"
    if stop is not None and not callable(stop):
        raise ValueError(f"stop: expected a callable or None, got {type(stop).__name__}")
    if stop is not None and pathwise:
        raise ValueError(f"stop: supported with method='per-step' only, got method={method!r}")
    if pathwise:
        if not isinstance(getattr(model, "_predictor", None), GPPredictor) or not hasattr(
            model, "with_predictor"
        ):
            raise ValueError(
                "model: pathwise sampling needs a fitted GP forward model (ForwardModel), got "
                f"{type(model).__name__}"
            )
        if isinstance(n_features, bool) or int(n_features) != n_features or n_features < 1:
            raise ValueError(f"n_features: expected a positive integer, got {n_features!r}")
    n_x, n_u = int(model.state_dim), int(model.control_dim)
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon: expected a positive integer, got {horizon!r}")
    if int(n_trajectories) != n_trajectories or n_trajectories < 1:
        raise ValueError(f"n_trajectories: expected a positive integer, got {n_trajectories!r}")
    T, L = int(horizon), int(n_trajectories)
    max_chunk_bytes = check_count(max_chunk_bytes, "max_chunk_bytes")
    x0 = (
        torch.tensor(np.asarray(x0), dtype=dtype, device=device)  # a copy: x0 may be read-only
        if not isinstance(x0, torch.Tensor)
        else x0.to(device, dtype)
    )
    if x0.ndim == 2 and x0.shape[1] == n_x:
        x0 = x0[:, None, :].expand(x0.shape[0], L, n_x)
    elif not (x0.ndim == 3 and x0.shape[1:] == (L, n_x)):
        raise ValueError(f"x0: expected shape (B, {n_x}) or (B, {L}, {n_x}), got {tuple(x0.shape)}")
    if not torch.isfinite(x0).all():
        raise ValueError("x0: contains non-finite values")
    B = x0.shape[0]
    if B < 1:
        raise ValueError("x0: expected at least one start state (B >= 1)")
    limit = None
    if control_limit is not None:
        try:
            lim = np.broadcast_to(np.asarray(control_limit, dtype=float), (n_u,))
        except (TypeError, ValueError):
            raise ValueError(
                f"control_limit: expected a scalar or shape ({n_u},), got {control_limit!r}"
            ) from None
        for v in lim:
            check_positive(v, "control_limit")
        limit = torch.as_tensor(lim.copy(), dtype=dtype, device=device)

    source = model
    model = model.to(device, dtype)
    # Correlated noise x' = mean + F ε (a linear-Gaussian model's full Σ_w), else mean + √var ε.
    factor = getattr(model, "noise_factor_tensor", None)
    factor_t = None if factor is None else factor(device, dtype).T
    gen = torch.Generator(device=device)
    np_gen = as_generator(rng)
    gen.manual_seed(int(np_gen.integers(2**63 - 1)))
    n = B * L
    # Drawn in float64 whatever the dtype: float32 paths follow the float64 paths of a seed.
    eps = torch.randn((n, T, n_x), generator=gen, dtype=DTYPE, device=device).to(dtype)
    basis = seeds = None
    if pathwise:
        seeds = np_gen.integers(2**63 - 1, size=n)
        shared = int(np_gen.integers(2**63 - 1)) if method == "pathwise-shared" else None
        basis = PathwiseBasis(source.predictor.to(device), n_features, dtype, shared_seed=shared)
    pair = torch.arange(B, device=device).repeat_interleave(L)
    states = torch.empty((n, T + 1, n_x), dtype=dtype, device=device)
    controls = torch.empty((n, T, n_u), dtype=dtype, device=device)
    states[:, 0] = x0.reshape(n, n_x)
    chunk = _chunk_rows(model, max_chunk_bytes, n, n_features if method == "pathwise" else 0)
    n_sat = torch.zeros((), dtype=torch.long, device=device)
    n_clamp = torch.zeros((), dtype=torch.long, device=device)
    worst = torch.zeros((), dtype=dtype, device=device)
    stopped_at = None if stop is None else torch.full((n,), T, dtype=torch.long, device=device)
    with torch.no_grad():
        for lo in range(0, n, chunk):
            hi = min(lo + chunk, n)
            x = states[lo:hi, 0]
            p = pair[lo:hi]
            step = model if basis is None else model.with_predictor(basis.draw(seeds[lo:hi]))
            rows: slice | torch.Tensor = slice(lo, hi)  # the rows still running
            for t in range(T):
                u = policy(t, x, p)
                if t == 0 and lo == 0:
                    _check_control(u, hi - lo, n_u, dtype, device)
                if limit is not None:
                    n_sat += (u.abs() > limit).sum()
                    u = torch.maximum(torch.minimum(u, limit), -limit)
                m = step.next_state_moments(x, u)
                if factor_t is None:
                    x = m[0] + m[1].sqrt() * eps[rows, t]
                else:
                    x = m[0] + eps[rows, t] @ factor_t
                states[rows, t + 1] = x
                controls[rows, t] = u
                if len(m) > 2:
                    n_clamp += m[2]
                    worst = torch.minimum(worst, m[3])
                if stop is not None and t + 1 < T:
                    done = _check_stop(stop(t + 1, x), x.shape[0], device)
                    if bool(done.any()):
                        if isinstance(rows, slice):
                            rows = torch.arange(lo, hi, device=device)
                        gone = rows[done]
                        states[gone, t + 2 :] = x[done][:, None]
                        controls[gone, t + 1 :] = 0.0
                        stopped_at[gone] = t + 1
                        keep = ~done
                        rows, x, p = rows[keep], x[keep], p[keep]
                        if rows.numel() == 0:
                            break
    if not torch.isfinite(controls).all():
        raise ValueError("policy: returned non-finite controls")
    precision = 0.0
    if dtype != DTYPE:
        precision = _precision_error(source, model, states, controls, device)
        if precision > PRECISION_TOL:
            warnings.warn(
                f"sample_trajectories: {dtype} predictions differ from float64 by up to "
                f"{precision:.2e} (predictive std for means, relative for variances) on the "
                "visited states; the model is too ill-conditioned for float32, use float64",
                GPNumericalWarning,
                stacklevel=2,
            )
    worst_f = float(worst)
    if worst_f < -VARIANCE_TOL:  # handled (set to 0): counted by a recorder, else a warning
        report_event(
            "negative_variance_clipped",
            f"sample_trajectories: {int(n_clamp)} predictive variances were negative (worst "
            f"{worst_f:.2e} x sigma_f^2, beyond round-off) and set to 0",
            stacklevel=2,
        )
    return SampledTrajectories(
        states.reshape(B, L, T + 1, n_x),
        controls.reshape(B, L, T, n_u),
        int(n_sat),
        int(n_clamp),
        worst_f,
        precision,
        None if stopped_at is None else stopped_at.reshape(B, L),
    )


def _precision_error(source, model, states, controls, device, rows: int = 64) -> float:
    """Max float32-vs-float64 error of the one-step predictive moments on visited states.

    Evaluated on the first ``rows`` trajectories at t = 0, T/2 and T − 1: the mean error in
    float64 predictive standard deviations and the relative variance error, whichever is
    larger. (For pathwise sampling this checks the predictor the functions are drawn from.)
    """
    hi = source.to(device, DTYPE)
    T = controls.shape[1]
    worst = 0.0
    for t in sorted({0, T // 2, T - 1}):
        x, u = states[:rows, t], controls[:rows, t]
        a = hi.next_state_moments(x.to(DTYPE), u.to(DTYPE))
        b = model.next_state_moments(x, u)
        var = a.var.clamp_min(torch.finfo(DTYPE).tiny)
        err_mean = ((b.mean.to(DTYPE) - a.mean).abs() / var.sqrt()).max()
        err_var = ((b.var.to(DTYPE) - a.var).abs() / var).max()
        worst = max(worst, float(err_mean), float(err_var))
    return worst


def _check_stop(done, n: int, device) -> torch.Tensor:
    if not isinstance(done, torch.Tensor) or done.dtype != torch.bool or tuple(done.shape) != (n,):
        got = (
            f"{done.dtype} of shape {tuple(done.shape)}"
            if isinstance(done, torch.Tensor)
            else type(done).__name__
        )
        raise ValueError(f"stop: expected a bool Tensor of shape ({n},), got {got}")
    return done.to(device)


def _check_control(u, n: int, n_u: int, dtype, device) -> None:
    if not isinstance(u, torch.Tensor):
        raise ValueError(
            f"policy: expected a torch.Tensor of shape ({n}, {n_u}), got {type(u).__name__}"
        )
    if tuple(u.shape) != (n, n_u):
        raise ValueError(f"policy: expected controls of shape ({n}, {n_u}), got {tuple(u.shape)}")
    if u.dtype != dtype or u.device != torch.device(device):
        raise ValueError(
            f"policy: expected controls as {dtype} on {device}, got {u.dtype} on {u.device}"
        )


def _chunk_rows(model, max_bytes: int, n: int, n_features: int = 0) -> int:
    """Rows per chunk so that ~3 (E, rows, M) work arrays fit in ``max_bytes``.

    With ``n_features`` (pathwise sampling) each row also holds its function's features
    (E · F · (d + 2) numbers, drawn in float64) and update vector (E · M).
    """
    pred = getattr(model, "predictor", None)
    if pred is None:
        return n
    E, M, d = pred.output_dim, pred.n_support, pred.input_dim
    per_row = 3 * E * M * pred.support.element_size()
    if n_features:
        per_row += 8 * E * (n_features * (d + 2) + M)
    return int(max(1, min(n, max_bytes // max(per_row, 1))))


def sampler_flops_per_step(output_dim: int, n_support: int, input_dim: int) -> int:
    """Floating-point operations of one sampled transition of one trajectory with a GP model.

    Per output: the scaled squared distances to the M support points (a (1 × d)(d × M)
    product plus norms, ≈ 2Md + 3M), the exponential (counted as 1 per entry), the mean
    kᵀβ (2M) and the variance kᵀ iK k (2M² + 2M). Used by the benchmark to compare the
    sampler with the machine's matmul peak.
    """
    E, M, d = int(output_dim), int(n_support), int(input_dim)
    return E * (2 * M * d + 3 * M + M + 2 * M + 2 * M * M + 2 * M)
