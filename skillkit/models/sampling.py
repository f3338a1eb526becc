"""Batched stochastic trajectory prediction with a learned forward model (Secs 2.1.2, 4.2.1):
u_t = π_ω(t, x_t), x_{t+1} ~ p(x_{t+1} | x_t, u_t) for B (context, ω) pairs × L trajectories
in one vectorised loop over time (Eq. 4.3, Fig. 2.4), chunks of rows on several threads. The
noise is drawn up front in float64, so results do not depend on the chunk size or the threads
and float32 follows float64's paths."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from skillkit._repr import number, span
from skillkit._validation import as_generator, check_array, check_count
from skillkit.models.gp import (
    DTYPE,
    GPNumericalWarning,
    GPPredictor,
    as_device,
    check_dtype,
    warn_if_clamped,
)
from skillkit.models.pathwise import PathwiseBasis

__all__ = [
    "PRECISION_TOL",
    "SampledTrajectories",
    "StepModel",
    "sample_trajectories",
    "sampler_flops_per_step",
    "sampling_dtype",
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
    controls : Tensor, shape (B, L, T, n_u)
        After saturation.
    n_saturated : int
        Control entries clipped to ``control_limit``.
    n_variance_clamped : int
        Negative predictive variances set to 0.
    worst_variance : float
        Most negative latent variance relative to σ_f² (0 if none).
    precision_error : float
        float32: largest one-step moment error against float64 on visited states; else 0.
    stopped_at : Tensor of int64, shape (B, L), or None
        With ``stop``: the step k each trajectory stopped at (T if never); later states repeat
        x_k, later controls are 0.
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
    workers: int = 1,
) -> SampledTrajectories:
    """Sample L trajectories for each of B start states / policies in one vectorised call.

    Parameters
    ----------
    model : StepModel
        Fitted, e.g. :class:`~skillkit.models.gp.ForwardModel`; an optional
        ``noise_factor_tensor`` F gives correlated noise x′ = mean + F ε.
    x0 : array_like or Tensor, shape (B, n_x) or (B, L, n_x)
        Start states, per pair or per trajectory (drawn from p(x_0; s), Eq. 4.3).
    policy : callable
        ``policy(t, x, pair) -> u``: step ``t``, states (n, n_x), pair indices (n,) in [0, B);
        returns controls (n, n_u) on the same device and dtype.
    horizon : int
        T, the number of transitions.
    n_trajectories : int, default 1
        L, trajectories per pair.
    rng : Generator, int, SeedSequence or None
    control_limit : float or array_like, shape (n_u,), optional
        Saturates ``|u| ≤ control_limit``.
    device : str or torch.device, optional
    dtype : torch.float64 or torch.float32, default float64
        float32 warns when ``precision_error`` exceeds :data:`PRECISION_TOL`.
    max_chunk_bytes : int, default 2**25
        Bound on the kernel work arrays per chunk and worker (at least one row per chunk).
    method : {"per-step", "pathwise", "pathwise-shared"}
        "per-step" (the thesis's, Sec. 4.2.1): independent draws per transition; "pathwise":
        one posterior function per trajectory (:mod:`skillkit.models.pathwise`, GP forward
        models only); "pathwise-shared": one feature basis for all trajectories.
    n_features : int, default 256
        F, random Fourier features per function and output (pathwise methods).
    stop : callable, optional
        ``stop(k, x) -> done``, bool (n,) for states x_k (k = 1 … T − 1): done trajectories
        stop propagating (per-step only; ``stopped_at``).
    workers : int, default 1
        Threads that propagate chunks of rows at once on the CPU (``policy`` and ``stop`` are
        then called concurrently); the results do not depend on it. On two cores two workers
        measured no faster than torch's own threads, so one is the default.

    Returns
    -------
    SampledTrajectories

    Raises
    ------
    ValueError
        On bad arguments, and on policy or ``stop`` output of the wrong shape, type or values.
    """
    device = as_device(device)  # as tensors report it, so the policy's controls can be checked
    check_dtype(dtype)
    if method not in ("per-step", "pathwise", "pathwise-shared"):
        raise ValueError(f"method: expected 'per-step' or 'pathwise[-shared]', got {method!r}")
    pathwise = method != "per-step"
    workers = check_count(workers, "workers")
    if stop is not None and not callable(stop):
        raise ValueError(f"stop: expected a callable or None, got {type(stop).__name__}")
    if stop is not None and pathwise:
        raise ValueError(f"stop: supported with method='per-step' only, got method={method!r}")
    if pathwise and not isinstance(getattr(model, "_predictor", None), GPPredictor):
        raise ValueError(f"model: pathwise needs a fitted ForwardModel, got {type(model).__name__}")
    n_x, n_u = int(model.state_dim), int(model.control_dim)
    T, L = check_count(horizon, "horizon"), check_count(n_trajectories, "n_trajectories")
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
        lim = check_array(control_limit, "control_limit")
        if lim.shape not in ((), (1,), (n_u,)) or np.any(lim <= 0):
            bad = f"expected a scalar or shape ({n_u},) > 0, got {control_limit!r}"
            raise ValueError(f"control_limit: {bad}")
        limit = torch.as_tensor(np.broadcast_to(lim, (n_u,)).copy(), dtype=dtype, device=device)

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
    stopped_at = None if stop is None else torch.full((n,), T, dtype=torch.long, device=device)

    def run(lo: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Propagate rows lo:lo + chunk; their (saturated, clamped, worst variance)."""
        hi = min(lo + chunk, n)
        x, p = states[lo:hi, 0], pair[lo:hi]
        n_sat = n_clamp = torch.zeros((), dtype=torch.long, device=device)
        worst = torch.zeros((), dtype=dtype, device=device)
        step = model if basis is None else model.with_predictor(basis.draw(seeds[lo:hi]))
        rows: slice | torch.Tensor = slice(lo, hi)  # the rows still running
        with torch.no_grad():  # per thread
            for t in range(T):
                u = policy(t, x, p)
                if t == 0 and lo == 0:
                    _check_tensor(u, "policy", (hi - lo, n_u), dtype, device)
                if limit is not None:
                    n_sat = n_sat + (u.abs() > limit).sum()
                    u = torch.maximum(torch.minimum(u, limit), -limit)
                m = step.next_state_moments(x, u)
                if factor_t is None:
                    x = m[0] + m[1].sqrt() * eps[rows, t]
                else:
                    x = m[0] + eps[rows, t] @ factor_t
                states[rows, t + 1] = x
                controls[rows, t] = u
                if len(m) > 2:
                    n_clamp = n_clamp + m[2]
                    worst = torch.minimum(worst, m[3])
                if stop is not None and t + 1 < T:
                    done = _check_tensor(stop(t + 1, x), "stop", (x.shape[0],), torch.bool)
                    done = done.to(device)
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
        return n_sat, n_clamp, worst

    starts = range(0, n, chunk)
    if workers == 1 or device.type != "cpu" or len(starts) == 1:
        parts = [run(lo) for lo in starts]
    else:
        with ThreadPoolExecutor(min(workers, len(starts))) as pool:
            parts = list(pool.map(run, starts))
    n_sat, n_clamp, worst = (torch.stack(v) for v in zip(*parts, strict=True))
    if not torch.isfinite(controls).all():
        raise ValueError("policy: returned non-finite controls")
    precision = 0.0  # float32: the largest one-step moment error against float64, visited states
    if dtype != DTYPE:
        at = sorted({0, T // 2, T - 1})
        visited = states[:64, at].flatten(0, 1), controls[:64, at].flatten(0, 1)
        precision = sampling_dtype(source, *visited, device)[1]
        if precision > PRECISION_TOL:
            warnings.warn(
                f"sample_trajectories: {dtype} moments differ from float64 by up to "
                f"{precision:.2e} on the visited states (too ill-conditioned for float32)",
                GPNumericalWarning,
                stacklevel=2,
            )
    worst_f = float(worst.min())
    warn_if_clamped("sample_trajectories", worst_f, n_clamp.sum())
    return SampledTrajectories(
        states.reshape(B, L, T + 1, n_x),
        controls.reshape(B, L, T, n_u),
        int(n_sat.sum()),
        int(n_clamp.sum()),
        worst_f,
        precision,
        None if stopped_at is None else stopped_at.reshape(B, L),
    )


def _check_tensor(value, name: str, shape: tuple, dtype, device=None) -> torch.Tensor:
    """``value`` if a ``dtype`` Tensor of ``shape`` (on ``device`` if given), else ValueError."""
    if not (
        isinstance(value, torch.Tensor)
        and tuple(value.shape) == shape
        and value.dtype == dtype
        and (device is None or value.device == torch.device(device))
    ):
        got = (
            f"{value.dtype} of shape {tuple(value.shape)} on {value.device}"
            if isinstance(value, torch.Tensor)
            else type(value).__name__
        )
        where = "" if device is None else f" on {device}"
        kind = str(dtype).removeprefix("torch.")
        raise ValueError(f"{name}: expected a {kind} Tensor of shape {shape}{where}, got {got}")
    return value


def sampling_dtype(
    model: StepModel, states, controls, device=None, dtype: torch.dtype | None = None
) -> tuple[torch.dtype, float | None]:
    """The precision to sample ``model`` in: float32 if its one-step moments at (states (n,
    n_x), controls (n, n_u)), at most 64 evenly spaced rows, differ from float64's by at most
    :data:`PRECISION_TOL` (mean error in predictive standard deviations, or relative variance
    error), else float64; and that error. A given ``dtype`` is returned unchecked (error None).
    """
    if dtype is not None:
        return check_dtype(dtype), None
    device = as_device(device)
    rows = np.unique(np.linspace(0, len(states) - 1, 64).astype(int))
    x, u = (torch.as_tensor(v, dtype=DTYPE, device=device)[rows] for v in (states, controls))
    with torch.no_grad():
        a = model.to(device, DTYPE).next_state_moments(x, u)
        b = model.to(device, torch.float32).next_state_moments(x.float(), u.float())
    var = a[1].clamp_min(torch.finfo(DTYPE).tiny)
    err_mean = ((b[0].to(DTYPE) - a[0]).abs() / var.sqrt()).max()
    error = max(float(err_mean), float(((b[1].to(DTYPE) - a[1]).abs() / var).max()))
    return (torch.float32 if error <= PRECISION_TOL else DTYPE), error


def _chunk_rows(model, max_bytes: int, n: int, n_features: int = 0) -> int:
    """Rows per chunk so that the kernel work arrays (and pathwise features) fit, in equal
    chunks of an even number if several (two workers share them evenly)."""
    pred = getattr(model, "predictor", None)
    if pred is None:
        return n
    E, M, d = pred.output_dim, pred.n_support, pred.input_dim
    per_row = 3 * E * M * pred.support.element_size()
    if n_features:
        per_row += 8 * E * (n_features * (d + 2) + M)
    chunks = -(-n // max(1, min(n, max_bytes // max(per_row, 1))))
    return -(-n // (chunks + chunks % 2 if chunks > 1 else 1))


def sampler_flops_per_step(output_dim: int, n_support: int, input_dim: int) -> int:
    """Floating-point operations of one sampled GP transition of one trajectory."""
    E, M, d = int(output_dim), int(n_support), int(input_dim)
    return E * (2 * M * d + 3 * M + M + 2 * M + 2 * M * M + 2 * M)
