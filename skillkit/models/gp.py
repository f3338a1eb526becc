"""Exact GP regression and GP forward models (thesis 2.3, 4.2; Eqs 2.24–2.28).

:class:`ExactGP` fits one SE-ARD GP (Eq. 2.25) per output by maximising the log marginal
likelihood (2.28); :class:`GPPredictor` is the fitted model frozen for prediction,
μ_a(x) = k_a(x)ᵀβ_a and σ_a²(x) = σ_{f,a}² − ‖R_a k_a(x)‖² + σ_{ε,a}² (Eqs 2.26–2.27).
Handled numerical events (:data:`EVENT_KINDS`) are counted inside
:func:`record_numerical_events`, else warned about as :class:`GPNumericalWarning`."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import NamedTuple, Self

import gpytorch
import numpy as np
import torch
from gpytorch.constraints import GreaterThan
from linear_operator.utils.errors import NanError, NotPSDError

from skillkit._repr import number, span
from skillkit._validation import as_generator, check_array, check_count, check_positive, check_type
from skillkit.models.kernels import SquaredExponential, se_kernel, se_operands

__all__ = [
    "DTYPE",
    "EVENT_KINDS",
    "FLOOR_EXPONENT_FLOAT64",
    "FLUSH_EXPONENT",
    "ExactGP",
    "ForwardModel",
    "GPNumericalError",
    "GPNumericalWarning",
    "GPPredictor",
    "HyperCurb",
    "Moments",
    "NumericalEvents",
    "TransitionModel",
    "as_device",
    "check_dtype",
    "record_numerical_events",
    "report_event",
    "robust_cholesky",
]

DTYPE = torch.float64
#: Latent variances below −VARIANCE_TOL·σ_f² are reported as beyond round-off.
VARIANCE_TOL = 1e-6
#: float32: kernel entries are raised to at least exp(−FLUSH_EXPONENT)·σ_f².
FLUSH_EXPONENT = 40.0
#: float64: kernel entries are raised to at least exp(−600)·σ_f² and exp(−600) (no denormals).
FLOOR_EXPONENT_FLOAT64 = 600.0
#: Per dtype (e, b): log k is raised to at least max(log σ_f² − e, b).
_KERNEL_FLOOR = {
    torch.float32: (FLUSH_EXPONENT, math.log(torch.finfo(torch.float32).tiny) + 7.0),
    torch.float64: (FLOOR_EXPONENT_FLOAT64, -FLOOR_EXPONENT_FLOAT64),
}
_JITTER_LEVELS = (1e-12, 1e-10, 1e-8, 1e-6, 1e-4)


class GPNumericalWarning(RuntimeWarning):
    """A numerical safeguard kicked in (see :func:`report_event`)."""


class GPNumericalError(RuntimeError):
    """A matrix stayed non-positive-definite even with the largest allowed jitter."""


#: The numerical events the models handle themselves, and what each means.
EVENT_KINDS = {
    "restored_iterate": "an objective evaluation failed; the optimiser kept its last completed "
    "iterate (optimize)",
    "jitter_increased": "a matrix was factorised only with diagonal jitter (robust_cholesky)",
    "noise_at_floor": "a fit ended with a noise variance at its floor, below a tenth of the added "
    "target noise variance: the model fits that noise as signal",
    "negative_variance_clipped": "predictive variances below -1e-6 sigma_f^2 (beyond round-off) "
    "were set to 0",
}


def _check_kind(kind: str) -> str:
    if kind not in EVENT_KINDS:
        raise ValueError(f"kind: expected one of {tuple(EVENT_KINDS)}, got {kind!r}")
    return kind


@dataclass
class NumericalEvents:
    """Handled numerical events counted by kind (:data:`EVENT_KINDS`), and the largest jitter."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(EVENT_KINDS, 0))
    max_jitter: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def add(self, kind: str, jitter: float = 0.0) -> None:
        self.counts[_check_kind(kind)] = self.counts.get(kind, 0) + 1
        self.max_jitter = max(self.max_jitter, float(jitter))

    def update(self, other: NumericalEvents | dict) -> NumericalEvents:
        """Add the counts of ``other`` (a record or its dict); returns self."""
        other = other if isinstance(other, NumericalEvents) else NumericalEvents.from_dict(other)
        for kind, n in other.counts.items():
            self.counts[kind] = self.counts.get(kind, 0) + int(n)
        self.max_jitter = max(self.max_jitter, other.max_jitter)
        return self

    def copy(self) -> NumericalEvents:
        return NumericalEvents(dict(self.counts), self.max_jitter)

    def since(self, mark: NumericalEvents) -> NumericalEvents:
        """Events counted since ``mark`` (an earlier :meth:`copy`); ``max_jitter`` if it grew."""
        counts = {k: n - mark.counts.get(k, 0) for k, n in self.counts.items()}
        jitter = self.max_jitter if self.max_jitter > mark.max_jitter else 0.0
        return NumericalEvents(counts, jitter)

    def to_dict(self) -> dict:
        return {**{k: int(n) for k, n in self.counts.items()}, "max_jitter": float(self.max_jitter)}

    @classmethod
    def from_dict(cls, data: dict) -> NumericalEvents:
        data = dict(data)
        jitter = float(data.pop("max_jitter", 0.0) or 0.0)
        counts = dict.fromkeys(EVENT_KINDS, 0)
        counts.update({_check_kind(k): int(n) for k, n in data.items()})
        return cls(counts, jitter)

    def __repr__(self) -> str:
        seen = ", ".join(f"{k}={n}" for k, n in self.counts.items() if n) or "none"
        jitter = f", max_jitter={self.max_jitter:.0e}" if self.max_jitter else ""
        return f"NumericalEvents({seen}{jitter})"


#: The active recorders of this context, innermost last: (record, quiet) pairs.
_RECORDERS: ContextVar[tuple[tuple[NumericalEvents, bool], ...]] = ContextVar(
    "skillkit_numerical_events", default=()
)


@contextmanager
def record_numerical_events(quiet: bool = True) -> Iterator[NumericalEvents]:
    """Yield the :class:`NumericalEvents` reported inside the block (nesting, per context),
    warned about only when no active recorder is ``quiet``."""
    events = NumericalEvents()
    token = _RECORDERS.set((*_RECORDERS.get(), (events, bool(quiet))))
    try:
        yield events
    finally:
        _RECORDERS.reset(token)


def report_event(kind: str, message: str, *, jitter: float = 0.0, stacklevel: int = 1) -> None:
    """Count an event of ``kind`` in every active recorder; warn ``message`` unless one is quiet."""
    _check_kind(kind)
    active = _RECORDERS.get()
    for events, _ in active:
        events.add(kind, jitter)
    if not any(quiet for _, quiet in active):
        warnings.warn(message, GPNumericalWarning, stacklevel=stacklevel + 1)


def as_device(device, name: str = "device") -> torch.device:
    """The torch device for ``device`` (None: the CPU) as tensors made there report it.

    Raises ValueError unless it is a CPU or an available CUDA device."""
    if device is None:
        return torch.device("cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"{name}: expected a device like 'cuda:0', got {device!r}") from None
    if dev.type == "cpu":
        return torch.device("cpu")
    if dev.type != "cuda":
        raise ValueError(f"{name}: expected a CPU or CUDA device (float64), got {device!r}")
    if not torch.cuda.is_available():
        raise ValueError(f"{name}: {device!r} requested but CUDA is not available")
    if dev.index is None:
        return torch.device("cuda", torch.cuda.current_device())
    if dev.index >= torch.cuda.device_count():
        raise ValueError(f"{name}: {device!r} but {torch.cuda.device_count()} CUDA device(s)")
    return dev


def check_dtype(dtype) -> torch.dtype:
    """``dtype`` if it is ``torch.float64`` or ``torch.float32``, else a ValueError."""
    if dtype not in (torch.float64, torch.float32):
        raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
    return dtype


def robust_cholesky(A: torch.Tensor, what: str = "matrix") -> tuple[torch.Tensor, float]:
    """Cholesky factor L (..., n, n) of SPD ``A`` and the relative jitter j it needed.

    A failing entry gets ``j · mean(diag A) · I`` added, j = 1e-12, 1e-10, …, 1e-4 in turn.
    Raises :class:`GPNumericalError` if ``A`` is non-finite or fails even at 1e-4."""
    if not torch.isfinite(A).all():
        raise GPNumericalError(f"{what}: contains non-finite entries")
    L, info = torch.linalg.cholesky_ex(A)
    if not torch.any(info):
        return L, 0.0
    scale = A.diagonal(dim1=-2, dim2=-1).mean(-1).abs().clamp_min(torch.finfo(A.dtype).tiny)
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    failed = info > 0
    for j in _JITTER_LEVELS:
        shift = torch.where(failed, j * scale, torch.zeros_like(scale))
        L2, info2 = torch.linalg.cholesky_ex(A + shift[..., None, None] * eye)
        if not torch.any(info2):
            report_event(
                "jitter_increased",
                f"{what}: not numerically positive definite; added jitter {j:.0e} x mean(diag) "
                f"to {int(failed.sum())} of {failed.numel()} matrices",
                jitter=j,
                stacklevel=2,
            )
            return torch.where(failed[..., None, None], L2, L), j
    raise GPNumericalError(
        f"{what}: not positive definite even with jitter {_JITTER_LEVELS[-1]:.0e}"
    )


def plain_cholesky(A: torch.Tensor, what: str) -> torch.Tensor:
    """Cholesky factor of ``A``, or :class:`GPNumericalError` (no jitter: inside an optimiser)."""
    L, info = torch.linalg.cholesky_ex(A)
    if torch.any(info):
        raise GPNumericalError(f"{what}: not positive definite at these hyper-parameters")
    return L


class Moments(NamedTuple):
    """Predictive ``mean`` and ``var`` (n, E), the number of negative latent variances set to 0
    and the most negative one relative to σ_f² (``worst``)."""

    mean: torch.Tensor
    var: torch.Tensor
    n_clamped: torch.Tensor
    worst: torch.Tensor

    @classmethod
    def exact(cls, mean: torch.Tensor, var: torch.Tensor) -> Moments:
        """Moments with no variance clamped."""
        zero = torch.zeros((), dtype=mean.dtype, device=mean.device)
        return cls(mean, var, zero.long(), zero)


@dataclass(frozen=True)
class GPPredictor:
    """A trained SE-kernel GP (exact or sparse) frozen for prediction, batched over E outputs.

    Fields: ``support`` (E, M, d) training or pseudo-inputs; ``lengthscale`` (E, d);
    ``outputscale``, ``noise`` (E,) σ_f², σ_ε² in standardised units; ``beta`` (E, M) with
    μ = kᵀβ (Eq. 2.26); ``iK`` (E, M, M) with σ² = σ_f² − kᵀ iK k + σ_ε² (Eq. 2.27;
    K_mm⁻¹ − Σ for FITC/VFE); ``var_factor`` R with RᵀR = iK; ``y_mean``, ``y_scale`` (E,)
    (raw = y_mean + y_scale · standardised)."""

    support: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: torch.Tensor
    noise: torch.Tensor
    beta: torch.Tensor
    iK: torch.Tensor
    var_factor: torch.Tensor
    y_mean: torch.Tensor
    y_scale: torch.Tensor
    _support_operand: torch.Tensor = field(init=False, repr=False)
    _log_outputscale: torch.Tensor = field(init=False, repr=False)
    _weights: torch.Tensor = field(init=False, repr=False)
    _query_scale: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        E, M, d = self.support.shape
        shapes = ((E, d), (E,), (E,), (E, M), (E, M, M), (E, M, M), (E,), (E,))
        for f, shape in zip(dataclasses.fields(self)[1:9], shapes, strict=True):
            if tuple(getattr(self, f.name).shape) != shape:
                got = tuple(getattr(self, f.name).shape)
                raise ValueError(f"{f.name}: expected shape {shape}, got {got}")
        self._set_caches(self)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_reduced"}

    def _set_caches(self, source: GPPredictor) -> None:
        """Float64 caches from ``source``: the support operand and [Rᵀ | β]."""
        support, lengthscale, outputscale, var_factor, beta = (
            getattr(source, k).to(device=self.device, dtype=torch.float64)
            for k in ("support", "lengthscale", "outputscale", "var_factor", "beta")
        )
        lengthscale = lengthscale[:, None, :]
        operand = se_operands(support, lengthscale, outputscale).contiguous()
        weights = torch.cat([var_factor.transpose(-1, -2), beta[..., None]], -1)
        self.__dict__.update(  # frozen dataclass: the caches are set directly
            _support_operand=operand,
            _log_outputscale=torch.log(outputscale),
            _query_scale=lengthscale,
            _weights=flush_tiny(weights.contiguous().to(self.dtype)),
        )

    def __repr__(self) -> str:
        E, M, d = self.support.shape
        return (
            f"GPPredictor(outputs={E}, support={M}, inputs={d}, "
            f"lengthscale={span(self.lengthscale)}, outputscale={span(self.outputscale)}, "
            f"noise={span(self.noise)} (standardised), {self.dtype}, {self.device})"
        )

    @property
    def input_dim(self) -> int:
        return int(self.support.shape[2])

    @property
    def output_dim(self) -> int:
        return int(self.support.shape[0])

    @property
    def n_support(self) -> int:
        return int(self.support.shape[1])

    @property
    def device(self) -> torch.device:
        return self.support.device

    @property
    def dtype(self) -> torch.dtype:
        return self.support.dtype

    def to(self, device=None, dtype: torch.dtype | None = None) -> GPPredictor:
        """A copy on ``device`` in float64 or float32 (self if unchanged; float32 copies keep
        float64 caches and are memoised)."""
        device = self.device if device is None else as_device(device)
        dtype = self.dtype if dtype is None else check_dtype(dtype)
        if device == self.device and dtype == self.dtype:
            return self
        reduced = torch.finfo(dtype).bits < torch.finfo(self.dtype).bits
        converted = self.__dict__.setdefault("_reduced", {})
        if reduced and (device, dtype) in converted:
            return converted[device, dtype]
        fields = [f.name for f in dataclasses.fields(self) if f.init]
        out = GPPredictor(**{f: getattr(self, f).to(device=device, dtype=dtype) for f in fields})
        if reduced:
            out._set_caches(self)
            converted[device, dtype] = out
        return out

    def kernel_vectors(self, x: torch.Tensor) -> torch.Tensor:
        """k_a(x, support_a): Tensor (E, n, M) for queries (n, d).

        log k is computed in float64 and clamped to [max(log σ_f² − e, b), log σ_f²] before ``exp``
        in this dtype, so nothing underflows or is denormal (``_KERNEL_FLOOR``)."""
        query = se_operands(x.unsqueeze(0).to(self._support_operand.dtype), self._query_scale)
        e = query @ self._support_operand.transpose(-1, -2)
        lim = self._log_outputscale[:, None, None]
        below, bound = _KERNEL_FLOOR[self.dtype]
        floor = torch.minimum((lim - below).clamp_min(bound), lim)
        if torch.is_grad_enabled() and e.requires_grad:
            return torch.clamp(e, floor, lim).to(self.dtype).exp()
        return torch.clamp(e, floor, lim, out=e).to(self.dtype).exp_()

    def moments(self, x: torch.Tensor, include_noise: bool = True) -> Moments:
        """Predictive :class:`Moments` (n, E), raw units, at x (n, d) (Eqs 2.26–2.27)."""
        k = self.kernel_vectors(x)  # (E, n, M)
        out = torch.bmm(k, self._weights)  # [(R k)ᵀ, kᵀβ], (E, n, M + 1)
        mean = out[..., -1]
        quad = torch.linalg.vector_norm(out[..., :-1], dim=-1).square()  # ‖R k‖²
        var = self.outputscale[:, None] - quad
        rel = var / self.outputscale[:, None]
        n_clamped = (rel < 0).sum()
        worst = (
            rel.min().clamp_max(0.0)
            if rel.numel()
            else torch.zeros((), dtype=x.dtype, device=x.device)
        )
        var = var.clamp_min(0.0)
        if include_noise:
            var = var + self.noise[:, None]
        mean = self.y_mean[:, None] + self.y_scale[:, None] * mean
        var = self.y_scale[:, None] ** 2 * var
        return Moments(mean.T, var.T, n_clamped, worst)

    def latent_covariance(self, x: torch.Tensor) -> torch.Tensor:
        """Posterior covariance K(x, x) − K(x, Z) iK K(Z, x) of f: Tensor (E, n, n), raw units."""
        xs = x.unsqueeze(0).expand(self.output_dim, *x.shape)
        kxx = se_kernel(xs, xs, self.lengthscale[:, None, :], self.outputscale)
        k = self.kernel_vectors(x)
        v = k @ self.var_factor.transpose(-1, -2)
        cov = kxx - v @ v.transpose(-1, -2)
        cov = 0.5 * (cov + cov.transpose(-1, -2))
        return self.y_scale[:, None, None] ** 2 * cov


def flush_tiny(weights: torch.Tensor) -> torch.Tensor:
    """Below float64: weights under 1e-15 of their output's largest set to 0."""
    if weights.dtype == torch.float64:
        return weights
    top = weights.abs().amax((-2, -1), keepdim=True)
    return weights.masked_fill(weights.abs() < 1e-15 * top, 0.0)


def warn_if_clamped(where: str, worst, n_clamped=1) -> None:
    """Report variances set to 0 whose ``worst`` (relative to σ_f²) is beyond round-off."""
    worst = float(worst)
    if worst < -VARIANCE_TOL:
        report_event(
            "negative_variance_clipped",
            f"{where}: {int(n_clamped)} predictive variance(s) were negative (worst {worst:.2e} "
            "x sigma_f^2, beyond round-off) and were set to 0",
            stacklevel=3,
        )


@dataclass(frozen=True)
class HyperCurb:
    """A soft box on the SE hyper-parameters (PILCO's ``hypCurb.m``), added to −(2.28) per output:
    Σ_d ((log w_d − log std(x_d)) / log r_w)^p + ((log σ_f − log σ_ε) / log r_s)^p.

    Parameters
    ----------
    lengthscale_ratio : float, default 100
        r_w > 1, the allowed w_d / std(x_d).
    snr : float, default 500
        r_s > 1, the allowed σ_f / σ_ε.
    power : int, default 30
        p, an even integer ≥ 2.

    Raises
    ------
    ValueError
        If a ratio is not above 1 or ``power`` is not an even integer ≥ 2.
    """

    lengthscale_ratio: float = 100.0
    snr: float = 500.0
    power: int = 30

    def __post_init__(self) -> None:
        for name in ("lengthscale_ratio", "snr"):
            if not getattr(self, name) > 1:
                raise ValueError(f"{name}: expected a number above 1, got {getattr(self, name)!r}")
        if int(self.power) != self.power or self.power < 2 or self.power % 2:
            raise ValueError(f"power: expected an even integer >= 2, got {self.power!r}")

    def penalty(
        self,
        lengthscale: torch.Tensor,
        outputscale: torch.Tensor,
        noise: torch.Tensor,
        input_std: torch.Tensor,
    ) -> torch.Tensor:
        """The penalty summed over outputs, Tensor (), for ``lengthscale`` (E, d), σ_f² and σ_ε²
        (E,) and the training inputs' ``input_std`` (d,)."""
        p = int(self.power)
        ls = (torch.log(lengthscale) - torch.log(input_std)) / math.log(self.lengthscale_ratio)
        snr = 0.5 * (torch.log(outputscale) - torch.log(noise)) / math.log(self.snr)
        return ls.pow(p).sum() + snr.pow(p).sum()


class _Diverged(Exception):
    pass


def _assign(parameters: list[torch.nn.Parameter], values: list[torch.Tensor]) -> None:
    with torch.no_grad():
        for p, v in zip(parameters, values, strict=True):
            p.copy_(v)


#: L-BFGS stops when the objective changes by less than this in one iteration.
TOLERANCE_CHANGE = 1e-12
#: The convergence test compares the objective with its value this many iterations earlier.
CONVERGENCE_WINDOW = 10


def optimize(
    parameters: list[torch.nn.Parameter],
    loss_fn: Callable[[], torch.Tensor],
    n_steps: int,
    tolerance: float = 0.0,
) -> dict:
    """Minimise ``loss_fn`` over ``parameters`` by L-BFGS (one iteration per step), ending on a
    completed iterate: a failed evaluation restores the last one (``"restored_iterate"``).

    Stops after ``n_steps`` iterations, or once the objective fell by less than ``tolerance``
    over the last :data:`CONVERGENCE_WINDOW` iterations (``stop_reason`` "converged"; 0: never),
    or when L-BFGS makes no progress ("no_progress"). Returns ``trace``, ``n_evaluations``,
    ``n_iterations``, ``best``, ``stopped_early`` and ``stop_reason``."""
    trace: list[float] = []
    stopped = None
    cache: dict[bytes, tuple[float, list[torch.Tensor | None]]] = {}

    def key() -> bytes:
        return b"".join(p.detach().cpu().numpy().tobytes() for p in parameters)

    def closure():
        k = key()
        if k in cache:  # an accepted point: its value and gradient are known
            value, grads = cache[k]
            for p, g in zip(parameters, grads, strict=True):
                p.grad = None if g is None else g.clone()
            return torch.tensor(value, dtype=DTYPE)
        opt.zero_grad()
        try:
            loss = loss_fn()
        except (GPNumericalError, NotPSDError, NanError) as exc:
            raise _Diverged(str(exc)) from exc
        value = float(loss.detach())
        if not math.isfinite(value):
            raise _Diverged(f"non-finite objective {value}")
        trace.append(value)
        loss.backward()
        for p in parameters:
            if p.grad is not None and not torch.isfinite(p.grad).all():
                raise _Diverged("non-finite gradient")
        cache[k] = (value, [None if p.grad is None else p.grad.clone() for p in parameters])
        return loss

    best_state, best_value = [p.detach().clone() for p in parameters], math.nan
    n_iter, values, reason = 0, [], "n_steps"
    if n_steps > 0:
        max_eval = int(n_steps * 1.25) + 5
        opt = torch.optim.LBFGS(
            parameters,
            lr=1.0,
            max_iter=1,
            max_eval=max_eval,
            tolerance_grad=1e-9,
            tolerance_change=TOLERANCE_CHANGE,
            history_size=50,
            line_search_fn="strong_wolfe",
        )
        try:
            k_prev = key()
            while n_iter < n_steps and len(trace) < max_eval:
                opt.step(closure)  # one iteration: the parameters end on an accepted point
                k = key()
                value0, value = cache[k_prev][0], cache[k][0]
                best_state, best_value = [p.detach().clone() for p in parameters], value
                # no step (gradient or directional derivative ~ 0), or torch's lack-of-progress
                # test (a max_iter=1 call returns before it)
                if k == k_prev or abs(value - value0) < TOLERANCE_CHANGE:
                    n_iter += k != k_prev
                    reason = "no_progress"
                    break
                n_iter += 1
                values.append(value)
                if len(values) > CONVERGENCE_WINDOW and (
                    values[-1 - CONVERGENCE_WINDOW] - value < tolerance
                ):
                    reason = "converged"
                    break
                cache = {k: cache[k]}
                k_prev = k
            else:
                reason = "n_steps" if n_iter >= n_steps else "max_evaluations"
        except _Diverged as exc:
            stopped, reason = str(exc), "diverged"
    _assign(parameters, best_state)
    if not math.isfinite(best_value):
        with torch.no_grad():
            try:
                best_value = float(loss_fn().detach())
            except (GPNumericalError, NotPSDError, NanError):
                best_value = math.nan
    if stopped is not None:
        report_event(
            "restored_iterate",
            f"hyper-parameter optimisation stopped early ({stopped}); restored the last "
            f"completed iterate (objective {best_value:.6g})",
            stacklevel=3,
        )
    return {
        "trace": trace,
        "n_evaluations": len(trace),
        "n_iterations": n_iter,
        "best": best_value,
        "stopped_early": stopped,
        "stop_reason": reason,
    }


class GPRegression:
    """Shared base of :class:`ExactGP` and the sparse GPs."""

    def __init__(
        self,
        *,
        lengthscale=None,
        outputscale: float | None = None,
        noise: float | None = None,
        noise_floor: float = 1e-6,
        additive_noise: float = 1.0,
        n_steps: int = 150,
        tolerance: float = 1e-4,
        standardize: bool = True,
        curb: HyperCurb | None = None,
        device=None,
    ):
        self.device = as_device(device)
        if curb is not None and not isinstance(curb, HyperCurb):
            raise ValueError(f"curb: expected a HyperCurb or None, got {type(curb).__name__}")
        self.curb = curb
        self.init_lengthscale = (
            None if lengthscale is None else check_array(lengthscale, "lengthscale", ndim=(0, 1, 2))
        )
        if self.init_lengthscale is not None and np.any(self.init_lengthscale <= 0):
            raise ValueError(f"lengthscale: expected positive values, got {lengthscale}")
        self.init_outputscale = (
            None if outputscale is None else check_positive(outputscale, "outputscale")
        )
        self.init_noise = None if noise is None else check_positive(noise, "noise")
        self.noise_floor = check_positive(noise_floor, "noise_floor")
        self.additive_noise = check_positive(additive_noise, "additive_noise", allow_zero=True)
        if int(n_steps) != n_steps or n_steps < 0:
            raise ValueError(f"n_steps: expected a non-negative integer, got {n_steps!r}")
        self.n_steps = int(n_steps)
        self.tolerance = check_positive(tolerance, "tolerance", allow_zero=True)
        self.standardize = bool(standardize)
        self.cold_start: tuple | None = None  # (w, σ_f², σ_ε²) a warm start replaced
        self.predictor: GPPredictor | None = None
        self.diagnostics: dict = {}

    def _size_repr(self) -> str:
        return f"N={self.X.shape[0]}"

    def __repr__(self) -> str:
        name = type(self).__name__
        if self.predictor is None:
            noise = number(self.additive_noise)
            return f"{name}(unfitted, n_steps={self.n_steps}, additive_noise={noise})"
        pred, h = self.predictor, self.hyperparameters
        lml = self.diagnostics.get("log_marginal_likelihood")
        text = (
            f"{name}({self._size_repr()}, inputs={pred.input_dim}, outputs={pred.output_dim}, "
            f"lengthscale={span(h['lengthscale'])}, signal_var={span(h['outputscale'])}, "
            f"noise_var={span(h['noise'])}"
        )
        if lml is not None:
            text += f", log_ml={number(np.sum(lml), '.5g')}"
        return text + ")"

    def fit(self, X, Y, rng=None) -> GPRegression:
        """Fit the hyper-parameters on (2.28) and cache the predictor.

        Parameters
        ----------
        X : array_like, shape (N, d)
        Y : array_like, shape (N, E) or (N,)
            One GP per column.
        rng : Generator, int, SeedSequence or None
            Draws the additive target noise and the pseudo-input initialisation.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On bad shapes or non-finite data.
        """
        X = check_array(X, "X", ndim=2)
        Y = check_array(Y, "Y", ndim=(1, 2))
        self._squeeze = Y.ndim == 1
        Y = Y[:, None] if Y.ndim == 1 else Y
        if X.shape[0] != Y.shape[0]:
            raise ValueError(f"Y: expected {X.shape[0]} rows like X, got shape {Y.shape}")
        if X.shape[0] < 1 or X.shape[1] < 1 or Y.shape[1] < 1:
            raise ValueError(f"X: expected at least one row and one column, got shape {X.shape}")
        rng = as_generator(rng)
        N, E = Y.shape
        diag: dict = {"n_data": N, "input_dim": X.shape[1], "output_dim": E}
        # Additive target noise (Sec. 4.2.3).
        sigma_add = self.additive_noise * 1e-2 * Y.std(axis=0)
        if self.additive_noise > 0:
            Y = Y + sigma_add * rng.standard_normal(Y.shape)
        diag["additive_noise_std"] = sigma_add
        if self.standardize:
            m, s = Y.mean(axis=0), Y.std(axis=0)
            const = s <= 1e-12 * (1.0 + np.abs(m))
            s = np.where(const, 1.0, s)
        else:
            m, s, const = np.zeros(E), np.ones(E), np.zeros(E, dtype=bool)
        diag["constant_outputs"] = np.flatnonzero(const).tolist()
        self.y_mean, self.y_scale = m, s
        self.X = torch.as_tensor(X, dtype=DTYPE, device=self.device)
        self.Y = torch.as_tensor(  # (E, N), standardised
            ((Y - m) / s).T.copy(), dtype=DTYPE, device=self.device
        )
        sd = X.std(axis=0)
        self._input_sd = np.where(sd > 0, sd, 1.0)  # std(x_d), 1 for a constant input
        self._init = self._initial_hypers()
        self._build(rng)
        input_std = torch.as_tensor(self._input_sd, dtype=DTYPE, device=self.device)
        curb = self.curb

        def objective() -> torch.Tensor:
            loss = self._loss()
            if curb is not None:
                loss = loss + curb.penalty(*self._hypers(), input_std)
            return loss / N

        params, start = self._parameters(), "cold"
        initial = [p.detach().clone() for p in params]
        with record_numerical_events(quiet=False) as events:
            res = optimize(params, objective, self.n_steps, self.tolerance)
            if self.cold_start is not None:
                res, start = self._guard(params, initial, objective, res)
            with torch.no_grad():
                self.predictor, extra = self._make_predictor()
            noise = self.predictor.noise.cpu().numpy()
            at_floor = np.flatnonzero(noise < 1.01 * self.noise_floor).tolist()
            effective = extra.get("effective_noise", noise)  # FITC: mean of Λ
            absorbed = [a for a in at_floor if effective[a] < 0.1 * (sigma_add[a] / s[a]) ** 2]
            if absorbed:
                report_event(
                    "noise_at_floor",
                    f"noise variance of output(s) {absorbed} is at its floor, below a tenth of "
                    "the added target noise variance: the model fits that noise as signal",
                    stacklevel=2,
                )
        diag["objective_trace"] = res["trace"]
        keys = ("n_evaluations", "n_iterations", "stopped_early", "stop_reason")
        diag.update({k: res[k] for k in keys})
        diag.update(extra)
        ls, os_, nz = (t.detach() for t in self._hypers())
        diag["max_lengthscale_ratio"] = float((ls / input_std).max())
        diag["max_signal_to_noise"] = float((os_ / nz).sqrt().max())
        diag["curb_penalty"] = None if curb is None else float(curb.penalty(ls, os_, nz, input_std))
        diag.update(noise_at_floor=at_floor, start=start)
        diag["numerical_events"] = events.to_dict()
        self.diagnostics = diag
        return self

    def _guard(self, params, initial, objective, res: dict) -> tuple[dict, str]:
        """``res`` and "warm", or a refit from ``cold_start`` and "cold" where the warm fit ended
        above the cold start's objective and the refit ends lower."""
        warm = [p.detach().clone() for p in params]
        _assign(params, initial)
        self._set_hypers(self.kernel, self.likelihood, self._initial_hypers(self.cold_start))
        if optimize(params, objective, 0)["best"] < res["best"]:
            cold = optimize(params, objective, self.n_steps, self.tolerance)
            if cold["best"] < res["best"]:
                return cold, "cold"
        _assign(params, warm)
        return res, "warm"

    def _initial_hypers(self, init: tuple | None = None) -> dict:
        """PILCO's initial values: w = std(x), σ_f² = var(y), σ_ε² = σ_f²/100, or the raw
        ``init`` (w, σ_f², σ_ε²) (default: the constructor's) where not None."""
        E, d = self.Y.shape[0], self._input_sd.shape[0]
        ls0, os0, nz0 = init or (self.init_lengthscale, self.init_outputscale, self.init_noise)
        try:
            ls = np.broadcast_to(self._input_sd if ls0 is None else ls0, (E, d)).copy()
        except ValueError:
            got = np.shape(ls0)
            raise ValueError(f"lengthscale: expected (), ({d},) or ({E}, {d}), got {got}") from None
        scale2 = self.y_scale**2
        os = np.ones(E) if os0 is None else os0 / scale2
        nz = 1e-2 * os if nz0 is None else nz0 / scale2
        nz = np.maximum(nz, 1.5 * self.noise_floor)
        return {"lengthscale": ls, "outputscale": np.broadcast_to(os, (E,)).copy(), "noise": nz}

    def _check_fitted(self) -> GPPredictor:
        if self.predictor is None:
            raise RuntimeError(f"{type(self).__name__}: call fit() before predicting")
        return self.predictor

    def predict(self, X, include_noise: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Predictive moments (Eqs 2.26–2.27).

        Parameters
        ----------
        X : array_like, shape (n, d)
        include_noise : bool, default True
            Add σ_ε² to the latent variance.

        Returns
        -------
        mean, var : ndarray, shape (n, E), or (n,) when fitted on a 1-D Y

        Raises
        ------
        RuntimeError
            Before :meth:`fit`.
        """
        pred = self._check_fitted()
        x = check_array(X, "X", shape=(None, pred.input_dim))
        with torch.no_grad():
            m = pred.moments(
                torch.as_tensor(x, dtype=pred.dtype, device=pred.device), include_noise
            )
        warn_if_clamped(type(self).__name__, m.worst, m.n_clamped)
        mean, var = m.mean.cpu().numpy(), m.var.cpu().numpy()
        return (mean[:, 0], var[:, 0]) if self._squeeze else (mean, var)

    def sample(self, X, n_samples: int, rng, include_noise: bool = True) -> np.ndarray:
        """Independent draws from the predictive marginals.

        Parameters
        ----------
        X : array_like, shape (n, d)
        n_samples : int
        rng : Generator, int, SeedSequence or None
        include_noise : bool, default True

        Returns
        -------
        ndarray, shape (n, n_samples, E), or (n, n_samples) when fitted on a 1-D Y
        """
        mean, var = self.predict(X, include_noise)
        mean, var = mean.reshape(mean.shape[0], -1), var.reshape(var.shape[0], -1)
        L = check_count(n_samples, "n_samples")
        eps = as_generator(rng).standard_normal((mean.shape[0], L, mean.shape[1]))
        draws = mean[:, None] + np.sqrt(np.maximum(var, 0.0))[:, None] * eps
        return draws[..., 0] if self._squeeze else draws

    @property
    def hyperparameters(self) -> dict[str, np.ndarray]:
        """θ = {w (E, d), σ_f² (E,), σ_ε² (E,)} in raw units."""
        pred = self._check_fitted()
        s2 = torch.as_tensor(self.y_scale**2, dtype=pred.dtype)
        return {
            "lengthscale": pred.lengthscale.cpu().numpy(),
            "outputscale": (pred.outputscale.cpu() * s2).numpy(),
            "noise": (pred.noise.cpu() * s2).numpy(),
        }

    def _hypers(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """w (E, d), σ_f² (E,), σ_ε² (E,) as trained."""
        return (
            self.kernel.lengthscale[:, 0, :],
            self.kernel.outputscale,
            self.likelihood.noise[:, 0],
        )

    def _standardisation_tensors(self) -> tuple[torch.Tensor, torch.Tensor]:
        return (
            torch.as_tensor(self.y_mean, dtype=DTYPE, device=self.device),
            torch.as_tensor(self.y_scale, dtype=DTYPE, device=self.device),
        )

    def _hyper_modules(self, E: int, d: int) -> tuple[SquaredExponential, gpytorch.Module]:
        kernel = SquaredExponential(d, batch_shape=torch.Size([E])).to(self.device)
        likelihood = gpytorch.likelihoods.GaussianLikelihood(
            batch_shape=torch.Size([E]), noise_constraint=GreaterThan(self.noise_floor)
        ).to(self.device, DTYPE)
        self._set_hypers(kernel, likelihood, self._init)
        return kernel, likelihood

    def _set_hypers(self, kernel, likelihood, init: dict) -> None:
        init = {k: torch.as_tensor(v, dtype=DTYPE).to(self.device) for k, v in init.items()}
        kernel.lengthscale = init["lengthscale"][:, None, :]
        kernel.outputscale = init["outputscale"]
        likelihood.noise = init["noise"][:, None]


class _SENegLogML(torch.autograd.Function):
    """Σ_a −log p(y_a | X, θ_a) (Eq. 2.28) with its analytic gradient (App. B.1).

    With W = K_y⁻¹ − ααᵀ and P = W ∘ K_f: ∂/∂σ_ε² = ½ tr W, ∂/∂σ_f² = ½ ΣP / σ_f²,
    ∂/∂w_d = (Σ_i x_id² (P1)_i − x_dᵀ P x_d) / w_d³."""

    @staticmethod
    def forward(ctx, lengthscale, outputscale, noise, X, Y):
        K = se_kernel(X, X, lengthscale[:, None, :], outputscale)
        K.diagonal(dim1=-2, dim2=-1).add_(noise[:, None])
        L = plain_cholesky(K, "K + noise*I")
        K.diagonal(dim1=-2, dim2=-1).sub_(noise[:, None])  # back to K_f (saves an N x N copy)
        alpha = torch.cholesky_solve(Y.unsqueeze(-1), L).squeeze(-1)
        N = X.shape[0]
        value = (
            0.5 * (Y * alpha).sum()
            + torch.log(L.diagonal(dim1=-2, dim2=-1)).sum()
            + 0.5 * N * Y.shape[0] * math.log(2 * math.pi)
        )
        ctx.save_for_backward(lengthscale, outputscale, X, K, L, alpha)
        return value

    @staticmethod
    def backward(ctx, grad):
        lengthscale, outputscale, X, Kf, L, alpha = ctx.saved_tensors
        W = torch.cholesky_inverse(L)
        W.sub_(alpha[:, :, None] * alpha[:, None, :])
        g_noise = 0.5 * W.diagonal(dim1=-2, dim2=-1).sum(-1)
        P = W.mul_(Kf)
        g_os = 0.5 * P.sum((-2, -1)) / outputscale
        r = P.sum(-1)  # (E, N)
        PX = P @ X  # (E, N, d)
        s = (X.unsqueeze(0) ** 2 * r[..., None]).sum(1) - (X.unsqueeze(0) * PX).sum(1)  # (E, d)
        g_ls = s / lengthscale**3
        return grad * g_ls, grad * g_os, grad * g_noise, None, None


def neg_log_marginal_likelihood(
    X: torch.Tensor,
    Y: torch.Tensor,
    lengthscale: torch.Tensor,
    outputscale: torch.Tensor,
    noise: torch.Tensor,
) -> torch.Tensor:
    """−Σ_a log p(y_a | X, θ_a), Eq. (2.28), for X (N, d), Y (E, N), lengthscale (E, d) and
    outputscale, noise (E,): Tensor () with an analytic gradient."""
    return _SENegLogML.apply(lengthscale, outputscale, noise, X, Y)


class _BatchedExactGP(gpytorch.models.ExactGP):
    def __init__(self, x: torch.Tensor, y: torch.Tensor, likelihood, kernel):
        super().__init__(x, y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean(batch_shape=y.shape[:1])
        self.covar_module = kernel

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class ExactGP(GPRegression):
    """Full GP regression, one GP per output, batched in one GPyTorch model (``self.model``).

    Parameters
    ----------
    lengthscale : float or array_like, shape (d,) or (E, d), optional
        Initial w in raw input units (default std(x)).
    outputscale, noise : float, optional
        Initial σ_f², σ_ε² in raw target units (default var(y), var(y)/100).
    noise_floor : float, default 1e-6
        σ_ε² ≥ ``noise_floor`` · var(y), a nugget; noise-free targets may end there
        (``diagnostics["noise_at_floor"]``), an event only where the fitted noise (FITC: mean Λ)
        is below a tenth of the ``additive_noise`` variance.
    additive_noise : float, default 1.0
        α: adds N(0, (α·10⁻²·std(y))²) to the targets (Sec. 4.2.3); 0 for none.
    n_steps : int, default 150
        At most this many L-BFGS iterations on −(2.28) (the thesis's 150).
    tolerance : float, default 1e-4
        Stop once −(2.28) / N fell by less than this over the last 10 iterations (0: never).
    standardize : bool, default True
        Fit on standardised targets (predictions are in raw units).
    curb : HyperCurb, optional
    device : str or torch.device, optional

    Raises
    ------
    ValueError
        On non-positive scales or a negative ``n_steps``.
    """

    def _build(self, rng: np.random.Generator) -> None:
        E, N = self.Y.shape
        d = self.X.shape[1]
        kernel, self.likelihood = self._hyper_modules(E, d)
        self.model = _BatchedExactGP(self.X.expand(E, N, d), self.Y, self.likelihood, kernel).to(
            self.device, DTYPE
        )

    @property
    def kernel(self) -> SquaredExponential:
        """The SE kernel, ``self.model.covar_module``."""
        return self.model.covar_module

    def _parameters(self) -> list[torch.nn.Parameter]:
        return list(self.model.parameters())

    def _loss(self) -> torch.Tensor:
        return neg_log_marginal_likelihood(self.X, self.Y, *self._hypers())

    def _make_predictor(self) -> tuple[GPPredictor, dict]:
        self.model.eval()
        ls, os, noise = (t.detach() for t in self._hypers())
        E, N = self.Y.shape
        X = self.X.expand(E, *self.X.shape)
        K = se_kernel(X, X, ls[:, None, :], os)
        K.diagonal(dim1=-2, dim2=-1).add_(noise[:, None])
        L, jitter = robust_cholesky(K, "K + noise*I")
        alpha = torch.cholesky_solve(self.Y.unsqueeze(-1), L).squeeze(-1)
        iK = torch.cholesky_inverse(L)
        iK = 0.5 * (iK + iK.transpose(-1, -2))
        eye = torch.eye(N, dtype=DTYPE, device=self.device)
        R = torch.linalg.solve_triangular(L, eye.expand_as(L), upper=False)
        y_mean, y_scale = self._standardisation_tensors()
        self.cholesky = L
        # Eq. (2.28) per output, in raw target units (standardisation is a change of variables).
        lml = (
            -0.5 * (self.Y * alpha).sum(-1)
            - torch.log(L.diagonal(dim1=-2, dim2=-1)).sum(-1)
            - 0.5 * N * math.log(2 * math.pi)
            - N * torch.log(y_scale)
        )
        pred = GPPredictor(X, ls, os, noise, alpha, iK, R, y_mean, y_scale)
        return pred, {"jitter": jitter, "log_marginal_likelihood": lml.cpu().numpy()}


class TransitionModel:
    """Base of the forward models p(x_{t+1} | x_t, u_t): ``target`` "delta" learns x_{t+1} − x_t,
    "next" x_{t+1}."""

    _min_rows = 0  # transitions a fit needs

    def __init__(self, target: str):
        if target not in ("delta", "next"):
            raise ValueError(f"target: expected 'delta' or 'next', got {target!r}")
        self.target = target

    def fit(self, states, controls, next_states, rng=None) -> Self:
        """Fit the model on N transitions.

        Parameters
        ----------
        states, next_states : array_like, shape (N, n_x)
        controls : array_like, shape (N, n_u)
        rng : Generator, int, SeedSequence or None
            The fit's randomness (target noise, initial weights, resamples).

        Returns
        -------
        self
        """
        x = check_array(states, "states", ndim=2)
        u = check_array(controls, "controls", ndim=2)
        xn = check_array(next_states, "next_states", ndim=2)
        if self._min_rows and (x.shape[0] < self._min_rows or x.shape[1] < 1):
            raise ValueError(f"states: expected {self._min_rows}+ rows, 1+ columns, got {x.shape}")
        if u.shape[0] != x.shape[0]:
            raise ValueError(f"controls: expected {x.shape[0]} rows like states, got {u.shape}")
        if xn.shape != x.shape:
            raise ValueError(f"next_states: expected shape {x.shape} like states, got {xn.shape}")
        self._fit(x, u, xn, rng)
        return self

    def _queries(self, states, controls, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
        """Validated query states (n, n_x) and controls (n, n_u) as tensors."""
        x = check_array(states, "states", shape=(None, self.state_dim))
        u = check_array(controls, "controls", shape=(x.shape[0], self.control_dim))
        kw = {"dtype": dtype, "device": device}
        return torch.as_tensor(x, **kw), torch.as_tensor(u, **kw)


class ForwardModel(TransitionModel):
    """A GP forward model p(x_{t+1} | x_t, u_t) on z = [x_t, u_t] (Sec. 4.2).

    Parameters
    ----------
    gp : GPRegression
        Unfitted :class:`ExactGP`, :class:`~skillkit.models.sparse.FITC` or
        :class:`~skillkit.models.sparse.VFE`; one output per state dimension.
    target : {"next", "delta"}
        "next" learns x_{t+1} (the thesis, Secs 4.2.4, 5.1.1), "delta" x_{t+1} − x_t (PILCO).
    mean : {"zero", "linear"}
        "linear" adds a least-squares prior mean Wᵀz + b (Rasmussen & Williams, Sec. 2.7).

    Raises
    ------
    ValueError
        On an unknown ``gp`` type, ``target`` or ``mean``.
    """

    def __init__(self, gp: GPRegression, target: str = "next", mean: str = "zero"):
        check_type(gp, GPRegression, "gp", "an ExactGP, FITC or VFE")
        super().__init__(target)
        if mean not in ("zero", "linear"):
            raise ValueError(f"mean: expected 'zero' or 'linear', got {mean!r}")
        self.gp = gp
        self.mean = mean
        self.linear_weights: torch.Tensor | None = None
        self.state_dim = self.control_dim = 0
        self._predictor: GPPredictor | None = None

    def __repr__(self) -> str:
        sizes = f"state_dim={self.state_dim}, control_dim={self.control_dim}"
        sizes = sizes if self._predictor is not None else "unfitted"
        mean = "" if self.mean == "zero" else f", mean={self.mean!r}"
        return f"ForwardModel(target={self.target!r}{mean}, {sizes}, gp={self.gp!r})"

    @property
    def delta(self) -> bool:
        return self.target == "delta"

    @property
    def predictor(self) -> GPPredictor:
        if self._predictor is None:
            raise RuntimeError("ForwardModel: call fit() first")
        return self._predictor

    def _fit(self, x: np.ndarray, u: np.ndarray, xn: np.ndarray, rng) -> None:
        self.state_dim, self.control_dim = x.shape[1], u.shape[1]
        y = xn - x if self.delta else xn
        z = np.hstack([x, u])
        if self.mean == "linear":
            z1 = np.hstack([z, np.ones((z.shape[0], 1))])
            w, *_ = np.linalg.lstsq(z1, y, rcond=None)  # (D + 1, E): [W; bᵀ]
            y = y - z1 @ w
            self.linear_weights = torch.as_tensor(w, dtype=DTYPE)
        self.gp.fit(z, y, rng)
        self._predictor = self.gp.predictor
        if self.linear_weights is not None:
            self.linear_weights = self.linear_weights.to(self._predictor.device)

    def to(self, device=None, dtype: torch.dtype | None = None) -> ForwardModel:
        out = self.with_predictor(self.predictor.to(device, dtype))
        if self.linear_weights is not None:
            out.linear_weights = self.linear_weights.to(out._predictor.device, out._predictor.dtype)
        return out

    def with_predictor(self, predictor) -> ForwardModel:
        """A shallow copy predicting with ``predictor`` (anything with ``moments``)."""
        out = ForwardModel.__new__(ForwardModel)
        out.__dict__.update(self.__dict__)
        out._predictor = predictor
        return out

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor) -> Moments:
        """Per-dimension p(x_{t+1} | x_t, u_t): :class:`Moments` (n, n_x)."""
        z = torch.cat([x, u], dim=-1)
        m = self.predictor.moments(z)
        if self.linear_weights is not None:
            w = self.linear_weights.to(z.device, z.dtype)
            m = m._replace(mean=m.mean + (z @ w[:-1] + w[-1]))
        return m._replace(mean=x + m.mean) if self.delta else m

    def predict(self, states, controls) -> tuple[np.ndarray, np.ndarray]:
        """Per-dimension moments of p(x_{t+1} | x_t, u_t).

        Parameters
        ----------
        states : array_like, shape (n, n_x)
        controls : array_like, shape (n, n_u)

        Returns
        -------
        mean, var : ndarray, shape (n, n_x)

        Raises
        ------
        RuntimeError
            Before :meth:`fit`.
        """
        pred = self.predictor
        with torch.no_grad():
            m = self.next_state_moments(*self._queries(states, controls, pred.dtype, pred.device))
        warn_if_clamped("ForwardModel", m.worst, m.n_clamped)
        return m.mean.cpu().numpy(), m.var.cpu().numpy()
