"""Exact GP regression and GP forward models (thesis 2.3, 4.2; Eqs 2.24–2.28).

* :class:`ExactGP` — one GP per output, batched in one GPyTorch ``ExactGP`` (batch shape
  ``(E,)``) with the SE-ARD kernel of Eq. (2.25). θ = {w, σ_f, σ_ε} maximises the log marginal
  likelihood (2.28) summed over outputs, with L-BFGS (default) or Adam on GPyTorch's raw
  (softplus) parameters, i.e. unconstrained like the thesis's log-parameters (App. B.1). The
  objective is exact (Cholesky, no CG/Lanczos) with an analytic gradient
  (:func:`neg_log_marginal_likelihood`).
* :class:`GPPredictor` — the trained model frozen for prediction (PILCO's ``beta``, ``iK``):
  for a query x and output a

  .. math:: \\mu_a(x) = k_a(x)^\\top \\beta_a, \\qquad
            \\sigma_a^2(x) = \\sigma_{f,a}^2 - k_a(x)^\\top iK_a\\, k_a(x)
                             + \\sigma_{\\varepsilon,a}^2
            = \\sigma_{f,a}^2 - \\|R_a k_a(x)\\|^2 + \\sigma_{\\varepsilon,a}^2

  with ``beta = (K + σ_ε²I)⁻¹y``, ``iK = (K + σ_ε²I)⁻¹``, ``R = L⁻¹`` (K + σ_ε²I = L Lᵀ):
  Eqs (2.26)–(2.27). The sparse GPs of :mod:`skillkit.models.sparse` fill the same fields
  (``iK = K_mm⁻¹ − Σ``, RᵀR = iK). Predictions use the factor form (round-off grows with
  √cond(K), not cond(K)); moment matching uses ``iK``.
* :class:`ForwardModel` — a GP on transitions (x_t, u_t) → x_{t+1}, learning x_{t+1} as the
  thesis does (``target="next"``, Secs 4.2.4, 5.1.1) or Δx as PILCO does (``"delta"``).

Numerical safeguards are explicit. A handled event goes through :func:`report_event`: counted
by kind inside :func:`record_numerical_events`, else a :class:`GPNumericalWarning`; each fit
lists its own in ``diagnostics["numerical_events"]``.

* **Standardisation.** Targets become ``(y − m)/s`` per output (``standardize=True``), so the
  prior mean is the training mean; a constant output keeps s = 1
  (``diagnostics["constant_outputs"]``).
* **Additive target noise (Sec. 4.2.3).** N(0, (α·10⁻²·std(y))²) per output before training
  (``additive_noise=α``, default 1; 0 disables), drawn from ``rng``.
* **Noise floor.** σ_ε² ≥ ``noise_floor``·s² (a ``GreaterThan`` constraint). Ending within 1 %
  of it lists the output in ``diagnostics["noise_at_floor"]`` (a ``"noise_at_floor"`` event).
* **Jitter.** :func:`robust_cholesky` adds 10⁻¹² … 10⁻⁴ × mean(diag) only if a factorisation
  fails (``diagnostics["jitter"]``, a ``"jitter_increased"`` event). Training adds none: an
  unfactorisable evaluation is a failed step.
* **Optimisation safety.** :func:`optimize` returns the last accepted L-BFGS iterate; a failed
  evaluation stops it and restores that iterate (``diagnostics["stopped_early"]``, a
  ``"restored_iterate"`` event).
* **Hyper-parameter curb (optional, off by default).** :class:`HyperCurb`, PILCO's penalty.
* **Variance clamping.** Negative latent variances σ_f² − ‖Rk‖² (round-off near training
  inputs) are set to 0 and counted (``Moments.n_clamped``); one below −10⁻⁶ σ_f² is a
  ``"negative_variance_clipped"`` event.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import NamedTuple

import gpytorch
import numpy as np
import torch
from gpytorch.constraints import GreaterThan
from linear_operator.utils.errors import NanError, NotPSDError

from skillkit._repr import number, span
from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.models.kernels import (
    SquaredExponential,
    se_kernel,
    se_operands,
)

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
    "as_device",
    "record_numerical_events",
    "report_event",
    "robust_cholesky",
]

DTYPE = torch.float64
#: Latent variances below −VARIANCE_TOL·σ_f² are reported as beyond round-off.
VARIANCE_TOL = 1e-6
#: Reduced precision (float32) only: kernel entries below exp(−FLUSH_EXPONENT)·σ_f² are raised
#: to that value (see :meth:`GPPredictor.kernel_vectors`).
FLUSH_EXPONENT = 40.0
#: Float64: kernel entries below exp(−FLOOR_EXPONENT_FLOAT64)·σ_f², and below
#: exp(−FLOOR_EXPONENT_FLOAT64), are raised to that value, so that ``exp`` never underflows and
#: no product with a weight above ~1e-47 is denormal (see :meth:`GPPredictor.kernel_vectors`).
FLOOR_EXPONENT_FLOAT64 = 600.0
#: Per predictor dtype: (e, b) with the kernel exponent log k raised to at least
#: max(log σ_f² − e, b) (never above log σ_f²) in :meth:`GPPredictor.kernel_vectors`.
_KERNEL_FLOOR = {
    torch.float32: (FLUSH_EXPONENT, math.log(torch.finfo(torch.float32).tiny) + 7.0),
    torch.float64: (FLOOR_EXPONENT_FLOAT64, -FLOOR_EXPONENT_FLOAT64),
}
_JITTER_LEVELS = (1e-12, 1e-10, 1e-8, 1e-6, 1e-4)


class GPNumericalWarning(RuntimeWarning):
    """A numerical safeguard (jitter, noise floor, variance clamp, early stop) kicked in.

    Handled events are issued through :func:`report_event`: inside
    :func:`record_numerical_events` they are counted instead.
    """


class GPNumericalError(RuntimeError):
    """A matrix stayed non-positive-definite even with the largest allowed jitter."""


# ---------------------------------------------------------------------------- numerical events
#: The numerical events the models handle themselves, and what each means. They are counted
#: (:func:`record_numerical_events`), or warned about where nothing counts them
#: (:func:`report_event`).
EVENT_KINDS = {
    "restored_iterate": "an objective evaluation failed; the optimiser kept its last completed "
    "iterate (optimize)",
    "jitter_increased": "a matrix was factorised only with diagonal jitter (robust_cholesky)",
    "noise_at_floor": "a fit ended with a noise variance at its floor: the data look noise-free "
    "to the model",
    "negative_variance_clipped": "predictive variances below -1e-6 sigma_f^2 (beyond round-off) "
    "were set to 0",
}


@dataclass
class NumericalEvents:
    """Handled numerical events counted by kind (:data:`EVENT_KINDS`), and the largest jitter.

    What :func:`record_numerical_events` yields, what a fit stores in
    ``diagnostics["numerical_events"]`` (as :meth:`to_dict`) and what the experiment runner
    reports per trial and in a run's summary.

    Attributes
    ----------
    counts : dict of str to int
        Events of each kind of :data:`EVENT_KINDS` (every kind present, 0 if none).
    max_jitter : float
        The largest relative jitter :func:`robust_cholesky` needed (0.0 if none).
    """

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(EVENT_KINDS, 0))
    max_jitter: float = 0.0

    @property
    def total(self) -> int:
        """Events of all kinds."""
        return sum(self.counts.values())

    def add(self, kind: str, jitter: float = 0.0) -> None:
        """Count one event of ``kind`` (that needed relative ``jitter``, if any)."""
        if kind not in EVENT_KINDS:
            raise ValueError(f"kind: expected one of {tuple(EVENT_KINDS)}, got {kind!r}")
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.max_jitter = max(self.max_jitter, float(jitter))

    def update(self, other: NumericalEvents | dict) -> NumericalEvents:
        """Add the counts of ``other`` (a record or its :meth:`to_dict`) to these; returns self."""
        other = other if isinstance(other, NumericalEvents) else NumericalEvents.from_dict(other)
        for kind, n in other.counts.items():
            self.counts[kind] = self.counts.get(kind, 0) + int(n)
        self.max_jitter = max(self.max_jitter, other.max_jitter)
        return self

    def copy(self) -> NumericalEvents:
        """An independent copy."""
        return NumericalEvents(dict(self.counts), self.max_jitter)

    def since(self, mark: NumericalEvents) -> NumericalEvents:
        """The events counted after ``mark`` (an earlier :meth:`copy` of this record).

        ``max_jitter`` is this record's if it grew since ``mark``, else 0.0 (the jitter of the
        events in between did not exceed an earlier one).
        """
        counts = {k: n - mark.counts.get(k, 0) for k, n in self.counts.items()}
        jitter = self.max_jitter if self.max_jitter > mark.max_jitter else 0.0
        return NumericalEvents(counts, jitter)

    def to_dict(self) -> dict:
        """``{kind: count, ..., "max_jitter": j}`` (plain JSON types)."""
        return {**{k: int(n) for k, n in self.counts.items()}, "max_jitter": float(self.max_jitter)}

    @classmethod
    def from_dict(cls, data: dict) -> NumericalEvents:
        """The record :meth:`to_dict` wrote."""
        data = dict(data)
        jitter = float(data.pop("max_jitter", 0.0) or 0.0)
        for kind in data:
            if kind not in EVENT_KINDS:
                raise ValueError(f"kind: expected one of {tuple(EVENT_KINDS)}, got {kind!r}")
        counts = dict.fromkeys(EVENT_KINDS, 0)
        counts.update({k: int(n) for k, n in data.items()})
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
    """Count the handled numerical events reported inside the block instead of warning.

    Every event of :data:`EVENT_KINDS` goes through :func:`report_event`: each active recorder
    counts it, and a :class:`GPNumericalWarning` is issued only when none of them is ``quiet``
    (a direct ``fit`` call warns; the experiment runner wraps each trial in a recorder).
    Problems a user must act on (e.g. float32 sampling too imprecise) stay warnings and are
    never counted. Recorders nest (an event counts in every enclosing one) and are local to
    the current ``contextvars`` context.

    Parameters
    ----------
    quiet : bool
        True (default): events inside are counted, not warned about. False: counted, and
        still warned about unless an enclosing recorder is quiet (how a fit collects its own
        ``diagnostics["numerical_events"]``).

    Yields
    ------
    NumericalEvents
        The counts of this block, updated as events happen.

    Examples
    --------
    >>> with record_numerical_events() as events:               # doctest: +SKIP
    ...     gp = ExactGP().fit(X, Y, rng=0)
    >>> events.to_dict()["jitter_increased"]                    # doctest: +SKIP
    """
    events = NumericalEvents()
    token = _RECORDERS.set((*_RECORDERS.get(), (events, bool(quiet))))
    try:
        yield events
    finally:
        _RECORDERS.reset(token)


def report_event(kind: str, message: str, *, jitter: float = 0.0, stacklevel: int = 1) -> None:
    """Report a handled numerical event of ``kind`` (:data:`EVENT_KINDS`).

    Counted by every active :func:`record_numerical_events` block; warned about as a
    :class:`GPNumericalWarning` with ``message`` when none of them is quiet (in particular
    when there is none). ``stacklevel`` is that of ``warnings.warn`` called where
    ``report_event`` is; ``jitter`` the relative jitter a factorisation needed.
    """
    if kind not in EVENT_KINDS:
        raise ValueError(f"kind: expected one of {tuple(EVENT_KINDS)}, got {kind!r}")
    active = _RECORDERS.get()
    for events, _ in active:
        events.add(kind, jitter)
    if not any(quiet for _, quiet in active):
        warnings.warn(message, GPNumericalWarning, stacklevel=stacklevel + 1)


def as_device(device, name: str = "device") -> torch.device:
    """The torch device for ``device`` (``None``: the CPU), checked before any work is done.

    Everything is computed in float64 (:data:`DTYPE`), so only CPU and CUDA devices qualify.

    Parameters
    ----------
    device : str, torch.device or None
        E.g. ``"cpu"``, ``"cuda"`` (the current CUDA device) or ``"cuda:1"``.
    name : str
        Argument name used in error messages.

    Returns
    -------
    torch.device
        As tensors made there report it: ``"cpu:0"`` → ``cpu``, ``"cuda"`` → ``cuda:<current
        device>``, so it compares equal to ``tensor.device``.

    Raises
    ------
    ValueError
        If ``device`` is not a device, is neither a CPU nor a CUDA device, or names a CUDA
        device this machine does not have.
    """
    if device is None:
        return torch.device("cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(
            f"{name}: expected a device such as 'cpu', 'cuda' or 'cuda:0', got {device!r}"
        ) from None
    if dev.type == "cpu":
        return torch.device("cpu")
    if dev.type != "cuda":
        raise ValueError(f"{name}: expected a CPU or CUDA device (float64), got {device!r}")
    if not torch.cuda.is_available():
        raise ValueError(f"{name}: {device!r} requested but CUDA is not available")
    if dev.index is None:
        return torch.device("cuda", torch.cuda.current_device())
    if dev.index >= torch.cuda.device_count():
        raise ValueError(
            f"{name}: {device!r} requested but only {torch.cuda.device_count()} CUDA "
            "device(s) are available"
        )
    return dev


# ---------------------------------------------------------------------------- linear algebra
def robust_cholesky(A: torch.Tensor, what: str = "matrix") -> tuple[torch.Tensor, float]:
    """Cholesky factor of a (batch of) symmetric positive-definite matrices, jitter only if needed.

    Policy: factorise ``A``; if that fails for any batch entry, add ``j · mean(diag A) · I``
    to the failing entries with ``j`` = 1e-12, 1e-10, 1e-8, 1e-6, 1e-4 in turn (a
    ``"jitter_increased"`` event, :func:`report_event`, gives the level that worked).

    Parameters
    ----------
    A : Tensor, shape (..., n, n)
    what : str
        Name of the matrix for messages.

    Returns
    -------
    L : Tensor, shape (..., n, n)
        Lower-triangular factor, ``L Lᵀ = A + jitter``.
    jitter : float
        The relative jitter j that was needed (0.0 if none).

    Raises
    ------
    GPNumericalError
        If ``A`` has non-finite entries or is not positive definite even with j = 1e-4.
    """
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
        f"{what}: not positive definite even with jitter {_JITTER_LEVELS[-1]:.0e} x mean(diag)"
    )


# ---------------------------------------------------------------------------- predictor
class Moments(NamedTuple):
    """Per-output predictive moments of a batch of queries.

    Attributes
    ----------
    mean, var : Tensor, shape (n, E)
        Predictive mean and variance (raw target units).
    n_clamped : Tensor, shape ()
        How many latent variances were negative (round-off) and set to 0.
    worst : Tensor, shape ()
        The most negative latent variance relative to σ_f² (0 if none).
    """

    mean: torch.Tensor
    var: torch.Tensor
    n_clamped: torch.Tensor
    worst: torch.Tensor


@dataclass(frozen=True)
class GPPredictor:
    """A trained SE-kernel GP (exact or sparse) frozen for prediction, batched over E outputs.

    Query-independent quantities are precomputed, so a prediction is two batched matrix
    products (the sampler calls :meth:`moments` every step; moment matching reads the fields).

    Attributes
    ----------
    support : Tensor, shape (E, M, d)
        Training inputs (exact GP, M = N, shared by all outputs) or pseudo-inputs (sparse).
    lengthscale : Tensor, shape (E, d)
        ARD length-scales w (Eq. 2.25).
    outputscale : Tensor, shape (E,)
        σ_f² in standardised units.
    noise : Tensor, shape (E,)
        σ_ε² in standardised units.
    beta : Tensor, shape (E, M)
        Mean weights: μ = kᵀβ (Eq. 2.26: β = (K + σ_ε²I)⁻¹y).
    iK : Tensor, shape (E, M, M)
        Variance matrix: σ² = σ_f² − kᵀ iK k + σ_ε² (Eq. 2.27: iK = (K + σ_ε²I)⁻¹; for
        FITC/VFE iK = K_mm⁻¹ − Σ).
    var_factor : Tensor, shape (E, M, M)
        R with RᵀR = iK (L⁻¹ for the exact GP), used for the predictive variance.
    y_mean, y_scale : Tensor, shape (E,)
        Target standardisation: raw = y_mean + y_scale · standardised.
    """

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
        expected = {
            "lengthscale": (E, d),
            "outputscale": (E,),
            "noise": (E,),
            "beta": (E, M),
            "iK": (E, M, M),
            "var_factor": (E, M, M),
            "y_mean": (E,),
            "y_scale": (E,),
        }
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(
                    f"{name}: expected shape {shape}, got {tuple(getattr(self, name).shape)}"
                )
        self._set_caches(self)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_reduced"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if "_query_scale" not in state:  # pickled without the float32 caches: rebuild them
            self._set_caches(self)

    def _set_caches(self, source: GPPredictor) -> None:
        """Step-invariant caches: the SE support operand and [Rᵀ | β] (one product gives v and μ).

        Computed in float64 from ``source`` (``self`` or the predictor :meth:`to` converted
        from); only ``_weights`` is cast to this dtype (see :meth:`kernel_vectors`).
        """
        hi = torch.float64

        def setup(name: str) -> torch.Tensor:
            return getattr(source, name).to(device=self.device, dtype=hi)

        lengthscale = setup("lengthscale")[:, None, :]
        outputscale = setup("outputscale")
        object.__setattr__(
            self,
            "_support_operand",
            se_operands(setup("support"), lengthscale, outputscale).contiguous(),
        )
        object.__setattr__(self, "_log_outputscale", torch.log(outputscale))
        object.__setattr__(self, "_query_scale", lengthscale)
        object.__setattr__(
            self,
            "_weights",
            flush_tiny(
                torch.cat([setup("var_factor").transpose(-1, -2), setup("beta")[..., None]], -1)
                .contiguous()
                .to(self.dtype)
            ),
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
        """A copy on ``device`` / in ``dtype`` (self if nothing changes).

        Converting to float32 casts every field, but the step-invariant caches are computed
        from this predictor's float64 values and cast once (see :meth:`kernel_vectors`); the
        converted copy is cached (not pickled).

        Raises
        ------
        ValueError
            If ``dtype`` is neither ``torch.float64`` nor ``torch.float32`` (the dtypes whose
            kernel floor :meth:`kernel_vectors` defines).
        """
        device = self.device if device is None else as_device(device)
        dtype = self.dtype if dtype is None else dtype
        if dtype not in _KERNEL_FLOOR:
            raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
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
        """k_a(x, support_a) for every output: Tensor (E, n, M), for queries x of shape (n, d).

        The exponent ``log k = −½‖(x − z)/w‖² + log σ_f²`` is one float64 product of the
        augmented operands (:func:`~skillkit.models.kernels.se_operands`), clamped to
        [max(log σ_f² − e, b), log σ_f²] (``_KERNEL_FLOOR``) and exponentiated in this
        predictor's dtype, so ``exp`` never underflows and no product k · weight is denormal
        (both are many times slower than normal arithmetic):

        * float32: e = 40 (:data:`FLUSH_EXPONENT`), b = log(tiny) + 7 ≈ −80, and weights below
          1e-15 of their largest are zero (:func:`flush_tiny`). The exponent stays in float64
          because its round-off ε (‖x/w‖² + ‖z/w‖²) in float32 visibly biases means near the
          data. The floor changes kᵀβ and ‖Rk‖² by less than float32's resolution unless
          M·max|β| or M·max|R|² exceed ~1e10 / σ_f² (a model too ill-conditioned for float32;
          ``sample_trajectories`` reports the float32 error on visited states).
        * float64: e = −b = 600 (:data:`FLOOR_EXPONENT_FLOAT64`, e^{−600} ≈ 3e-261). The
          raised entries change kᵀβ by at most M·max|β|·e^{−600}σ_f² and ‖Rk‖² by less,
          ~250 orders of magnitude below float64's resolution of any mean or variance not
          itself below 1e-240; sampled trajectories are bit-identical with and without the
          floor (``data/README.md``). A lower floor (e^{−700}) would produce denormals.
        """
        query = se_operands(x.unsqueeze(0).to(self._support_operand.dtype), self._query_scale)
        e = query @ self._support_operand.transpose(-1, -2)
        lim = self._log_outputscale[:, None, None]
        below, bound = _KERNEL_FLOOR[self.dtype]
        floor = torch.minimum((lim - below).clamp_min(bound), lim)
        if torch.is_grad_enabled() and e.requires_grad:
            return torch.clamp(e, floor, lim).to(self.dtype).exp()
        return torch.clamp(e, floor, lim, out=e).to(self.dtype).exp_()

    def moments(self, x: torch.Tensor, include_noise: bool = True) -> Moments:
        """Predictive mean and variance (Eqs 2.26–2.27) at queries ``x``.

        Parameters
        ----------
        x : Tensor, shape (n, d)
            Queries on this predictor's device and dtype (not validated: hot path).
        include_noise : bool
            Add σ_ε² (the distribution of a noisy observation y) or not (latent f).

        Returns
        -------
        Moments
            ``mean`` and ``var`` of shape (n, E) in raw target units.
        """
        k = self.kernel_vectors(x)  # (E, n, M)
        out = torch.bmm(k, self._weights)  # [(R k)ᵀ, kᵀβ], (E, n, M + 1)
        mean = out[..., -1]
        quad = torch.linalg.vector_norm(out[..., :-1], dim=-1).square()  # ‖R k‖²
        var = self.outputscale[:, None] - quad
        rel = var / self.outputscale[:, None]
        neg = rel < 0
        n_clamped = neg.sum()
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
        """Joint posterior covariance of f at queries x: Tensor (E, n, n), raw units.

        ``K(x, x) − K(x, Z) iK K(Z, x)``, the covariance of p(f_* | x_*, D) used to draw
        posterior function samples (Fig. 2.12).
        """
        xs = x.unsqueeze(0).expand(self.output_dim, *x.shape)
        kxx = se_kernel(xs, xs, self.lengthscale[:, None, :], self.outputscale)
        k = self.kernel_vectors(x)
        v = k @ self.var_factor.transpose(-1, -2)
        cov = kxx - v @ v.transpose(-1, -2)
        cov = 0.5 * (cov + cov.transpose(-1, -2))
        return self.y_scale[:, None, None] ** 2 * cov


def flush_tiny(weights: torch.Tensor) -> torch.Tensor:
    """Reduced precision: weights below 1e-15 of their output's largest set to 0 (float64: as is).

    Their contribution is below float32's resolution, and a product of a small kernel entry
    with such a weight would be a (slow) denormal number.
    """
    if weights.dtype == torch.float64:
        return weights
    top = weights.abs().amax((-2, -1), keepdim=True)
    return weights.masked_fill(weights.abs() < 1e-15 * top, 0.0)


def warn_if_clamped(m: Moments, where: str) -> None:
    """Report (:func:`report_event`) a latent variance that was negative beyond round-off."""
    worst = float(m.worst)
    if worst < -VARIANCE_TOL:
        report_event(
            "negative_variance_clipped",
            f"{where}: {int(m.n_clamped)} predictive variance(s) were negative (worst "
            f"{worst:.2e} x sigma_f^2, beyond round-off) and were set to 0; the model is "
            "ill-conditioned (raise noise_floor or additive_noise)",
            stacklevel=3,
        )


# ---------------------------------------------------------------------------- hyper-parameter curb
@dataclass(frozen=True)
class HyperCurb:
    """A soft box on the SE hyper-parameters: the PILCO toolbox's penalty (``hypCurb.m``).

    Added to the negative log marginal likelihood (2.28) of each output a:

    .. math:: \\sum_d \\Big(\\frac{\\log w_{ad} - \\log \\mathrm{std}(x_d)}{\\log r_w}\\Big)^p
              + \\Big(\\frac{\\log \\sigma_{f,a} - \\log \\sigma_{\\varepsilon,a}}
              {\\log r_s}\\Big)^p

    with r_w = ``lengthscale_ratio``, r_s = ``snr`` and an even power p = ``power``. Each term is
    below 10⁻⁹ while the length-scale is within √r_w of the input's spread (and the
    signal-to-noise ratio within √r_s), equals 1 at the limits w = r_w std(x_d) (or std/r_w)
    and σ_f/σ_ε = r_s, and grows as 2^p = 10⁹ at twice the limit in log space: a wall.

    Near an equilibrium the inputs [x, u] of a forward model lie close to a linear subspace
    and maximum likelihood drives the SE kernel to its linear limit (w → ∞, σ_f² → ∞): the
    latent variance off the data explodes and sampled predictions diverge. The thesis does
    not say how it trained; the defaults are the PILCO toolbox's (Rasmussen & McHutchon).

    Parameters
    ----------
    lengthscale_ratio : float
        r_w > 1.
    snr : float
        r_s > 1 (bounds σ_f/σ_ε, not its square).
    power : int
        Even p ≥ 2.
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
        """The penalty summed over outputs.

        Parameters
        ----------
        lengthscale : Tensor, shape (E, d)
        outputscale, noise : Tensor, shape (E,)
            σ_f² and σ_ε² (same units; only their ratio matters).
        input_std : Tensor, shape (d,)
            std(x_d) of the training inputs.

        Returns
        -------
        Tensor, shape ()
        """
        p = int(self.power)
        ls = (torch.log(lengthscale) - torch.log(input_std)) / math.log(self.lengthscale_ratio)
        snr = 0.5 * (torch.log(outputscale) - torch.log(noise)) / math.log(self.snr)
        return ls.pow(p).sum() + snr.pow(p).sum()


# ---------------------------------------------------------------------------- training helpers
class _Diverged(Exception):
    pass


TOLERANCE_CHANGE = 1e-12
"""L-BFGS stops when the objective changes by less than this in one iteration."""


def optimize(
    parameters: list[torch.nn.Parameter],
    loss_fn: Callable[[], torch.Tensor],
    n_steps: int,
    method: str = "lbfgs",
    learning_rate: float = 0.05,
) -> dict:
    """Minimise ``loss_fn`` over ``parameters``; the result is always a completed iterate.

    L-BFGS (strong-Wolfe line search) runs one iteration per ``torch.optim.LBFGS.step`` call,
    so the parameters between calls are the iterates the line search *accepted*. If an
    evaluation fails (a non-finite objective or gradient, or a failed Cholesky
    factorisation) the last accepted iterate is restored (a ``"restored_iterate"`` event,
    :func:`report_event`). A line-search trial point is never
    returned, even when its objective was lower (such points can be degenerate, σ_f² → 0,
    ℓ → 0). Evaluations at accepted points are cached, so iterates, evaluation budget and
    result equal a single ``step`` call with ``max_iter = n_steps``. Adam keeps its best
    iterate.

    Parameters
    ----------
    parameters : list of Parameter
        Unconstrained (raw) parameters.
    loss_fn : callable
        Returns the scalar objective (e.g. the negative log marginal likelihood per datum).
    n_steps : int
        L-BFGS iterations (at most ``1.25 n_steps + 5`` objective evaluations in all) or Adam
        steps. 0 leaves the parameters unchanged.
    method : {"lbfgs", "adam"}
    learning_rate : float
        Adam step size (L-BFGS uses unit steps with a line search).

    Returns
    -------
    dict
        ``trace`` (objective per evaluation, trial points included), ``n_evaluations``,
        ``n_iterations`` (accepted iterates), ``best`` (the objective of the returned
        parameters) and ``stopped_early`` (reason or None).
    """
    _check_method(method)
    trace: list[float] = []
    stopped = None
    cache: dict[bytes, tuple[float, list[torch.Tensor | None]]] = {}

    def key() -> bytes:
        return b"".join(p.detach().cpu().numpy().tobytes() for p in parameters)

    def evaluate() -> torch.Tensor:
        try:
            loss = loss_fn()
        except (GPNumericalError, NotPSDError, NanError) as exc:
            raise _Diverged(str(exc)) from exc
        value = float(loss.detach())
        if not math.isfinite(value):
            raise _Diverged(f"non-finite objective {value}")
        trace.append(value)
        return loss

    def snapshot() -> list[torch.Tensor]:
        return [p.detach().clone() for p in parameters]

    def restore(state: list[torch.Tensor]) -> None:
        with torch.no_grad():
            for p, v in zip(parameters, state, strict=True):
                p.copy_(v)

    best_state, best_value = snapshot(), math.nan
    n_iter = 0
    if n_steps > 0:
        try:
            if method == "lbfgs":
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

                def closure():
                    k = key()
                    if k in cache:  # an accepted point: its value and gradient are known
                        value, grads = cache[k]
                        for p, g in zip(parameters, grads, strict=True):
                            p.grad = None if g is None else g.clone()
                        return torch.tensor(value, dtype=DTYPE)
                    opt.zero_grad()
                    loss = evaluate()
                    loss.backward()
                    for p in parameters:
                        if p.grad is not None and not torch.isfinite(p.grad).all():
                            raise _Diverged("non-finite gradient")
                    cache[k] = (
                        float(loss.detach()),
                        [None if p.grad is None else p.grad.clone() for p in parameters],
                    )
                    return loss

                k_prev = key()
                while n_iter < n_steps and len(trace) < max_eval:
                    opt.step(closure)  # one iteration: the parameters end on an accepted point
                    k = key()
                    value0, value = cache[k_prev][0], cache[k][0]
                    best_state, best_value = snapshot(), value
                    if k == k_prev:  # no step (gradient or directional derivative ~ 0)
                        break
                    n_iter += 1
                    # torch's lack-of-progress tests (a max_iter=1 call returns before them)
                    if abs(value - value0) < TOLERANCE_CHANGE:
                        break
                    cache = {k: cache[k]}
                    k_prev = k
            else:
                opt = torch.optim.Adam(parameters, lr=learning_rate)
                best_value = math.inf
                for _ in range(n_steps):
                    opt.zero_grad()
                    loss = evaluate()
                    if trace[-1] < best_value:
                        best_state, best_value = snapshot(), trace[-1]
                    loss.backward()
                    opt.step()
                    n_iter += 1
        except _Diverged as exc:
            stopped = str(exc)
    restore(best_state)
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
    }


def _check_method(method: str) -> str:
    if method not in ("lbfgs", "adam"):
        raise ValueError(f"optimizer: expected 'lbfgs' or 'adam', got {method!r}")
    return method


# ---------------------------------------------------------------------------- GP base
class GPRegression:
    """Shared plumbing of :class:`ExactGP` and the sparse GPs: validation, additive noise,
    standardisation, training loop, predictor, diagnostics. Subclasses implement
    ``_build``, ``_loss``, ``_parameters`` and ``_make_predictor``."""

    #: Where training happens (set by ``__init__``; this default serves objects pickled in
    #: checkpoints without a ``device``).
    device = torch.device("cpu")

    def __init__(
        self,
        *,
        lengthscale=None,
        outputscale: float | None = None,
        noise: float | None = None,
        noise_floor: float = 1e-6,
        additive_noise: float = 1.0,
        n_steps: int = 150,
        optimizer: str = "lbfgs",
        learning_rate: float = 0.05,
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
        self.optimizer = _check_method(optimizer)
        self.learning_rate = check_positive(learning_rate, "learning_rate")
        self.standardize = bool(standardize)
        self.predictor: GPPredictor | None = None
        self.diagnostics: dict = {}

    def _size_repr(self) -> str:
        """Data size for :meth:`__repr__` (the sparse GPs add M)."""
        return f"N={self.X.shape[0]}"

    def __repr__(self) -> str:
        name = type(self).__name__
        if self.predictor is None:
            return (
                f"{name}(unfitted, n_steps={self.n_steps}, optimizer={self.optimizer!r}, "
                f"additive_noise={number(self.additive_noise)})"
            )
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

    # -- fitting
    def fit(self, X, Y, rng=None) -> GPRegression:
        """Fit hyper-parameters and cache the predictor.

        Parameters
        ----------
        X : array_like, shape (N, d)
            Training inputs.
        Y : array_like, shape (N, E) or (N,)
            Training targets (one independent GP per column).
        rng : Generator, int or None
            Randomness of the additive target noise and of pseudo-input initialisation.

        Returns
        -------
        self
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
        # Additive target noise (Sec. 4.2.3): sigma_add = alpha * 1e-2 * std(y), per output.
        raw_std = Y.std(axis=0)
        sigma_add = self.additive_noise * 1e-2 * raw_std
        if self.additive_noise > 0:
            Y = Y + sigma_add * rng.standard_normal(Y.shape)
        diag["additive_noise_std"] = sigma_add
        # Standardisation.
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
        self._init = self._initial_hypers(X)
        self._build(rng)
        sd = X.std(axis=0)
        input_std = torch.as_tensor(np.where(sd > 0, sd, 1.0), dtype=DTYPE, device=self.device)
        curb = getattr(self, "curb", None)  # objects pickled without a curb have none

        def objective() -> torch.Tensor:
            loss = self._loss()
            if curb is not None:
                loss = loss + curb.penalty(*self._hypers(), input_std)
            return loss / N

        # Events handled on the way (restored iterate, jitter, noise floor) are counted in
        # diagnostics["numerical_events"], and warned about unless a quiet recorder is active.
        with record_numerical_events(quiet=False) as events:
            res = optimize(
                self._parameters(), objective, self.n_steps, self.optimizer, self.learning_rate
            )
            with torch.no_grad():
                self.predictor, extra = self._make_predictor()
            noise = self.predictor.noise.cpu().numpy()
            at_floor = np.flatnonzero(noise < 1.01 * self.noise_floor).tolist()
            if at_floor:
                report_event(
                    "noise_at_floor",
                    f"noise variance of output(s) {at_floor} is at the floor noise_floor="
                    f"{self.noise_floor:g} (x std(y)^2 when standardised): the data look "
                    "noise-free to the model",
                    stacklevel=2,
                )
        diag.update(
            {
                "objective_trace": res["trace"],
                "n_evaluations": res["n_evaluations"],
                "n_iterations": res["n_iterations"],
                "stopped_early": res["stopped_early"],
            }
        )
        diag.update(extra)
        ls, os_, nz = (t.detach() for t in self._hypers())
        diag["max_lengthscale_ratio"] = float((ls / input_std).max())
        diag["max_signal_to_noise"] = float((os_ / nz).sqrt().max())
        diag["curb_penalty"] = None if curb is None else float(curb.penalty(ls, os_, nz, input_std))
        diag["noise_at_floor"] = at_floor
        diag["numerical_events"] = events.to_dict()
        self.diagnostics = diag
        return self

    def _initial_hypers(self, X: np.ndarray) -> dict:
        """Initial values in standardised units.

        PILCO's rule: w = std(x), σ_f² = var(y), σ_ε² = σ_f²/100.
        """
        E, d = self.Y.shape[0], X.shape[1]
        if self.init_lengthscale is None:
            sd = X.std(axis=0)
            ls = np.where(sd > 0, sd, 1.0)
        else:
            ls = self.init_lengthscale
        try:
            ls = np.broadcast_to(ls, (E, d)).copy()
        except ValueError:
            raise ValueError(
                f"lengthscale: expected a scalar, shape ({d},) or ({E}, {d}), got shape "
                f"{np.shape(self.init_lengthscale)}"
            ) from None
        scale2 = self.y_scale**2
        os = np.ones(E) if self.init_outputscale is None else self.init_outputscale / scale2
        nz = 1e-2 * os if self.init_noise is None else self.init_noise / scale2
        nz = np.maximum(nz, 1.5 * self.noise_floor)
        return {"lengthscale": ls, "outputscale": np.broadcast_to(os, (E,)).copy(), "noise": nz}

    # -- prediction
    def _check_fitted(self) -> GPPredictor:
        if self.predictor is None:
            raise RuntimeError(f"{type(self).__name__}: call fit() before predicting")
        return self.predictor

    def predict(self, X, include_noise: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean and variance (Eqs 2.26–2.27) at ``X``.

        Parameters
        ----------
        X : array_like, shape (n, d)
        include_noise : bool
            Include σ_ε² (predict y) or not (predict f).

        Returns
        -------
        mean, var : ndarray, shape (n, E) (or (n,) if fitted on 1-D targets)
        """
        pred = self._check_fitted()
        x = check_array(X, "X", ndim=2)
        if x.shape[1] != pred.input_dim:
            raise ValueError(f"X: expected {pred.input_dim} columns, got shape {x.shape}")
        with torch.no_grad():
            m = pred.moments(
                torch.as_tensor(x, dtype=pred.dtype, device=pred.device), include_noise
            )
        warn_if_clamped(m, type(self).__name__)
        mean, var = m.mean.cpu().numpy(), m.var.cpu().numpy()
        return (mean[:, 0], var[:, 0]) if self._squeeze else (mean, var)

    def sample(self, X, n_samples: int, rng, include_noise: bool = True) -> np.ndarray:
        """Independent draws from the predictive marginals N(μ(x), σ²(x)) (Eqs 2.26–2.27).

        Each query and output is drawn on its own (no correlation between queries: this is
        not a function sample, see ``latent_covariance`` for those); what an event model
        needs to propagate one sampled outcome per trajectory.

        Parameters
        ----------
        X : array_like, shape (n, d)
        n_samples : int
            L ≥ 1 draws per query.
        rng : Generator, int or None
            One ``standard_normal((n, L, E))`` is drawn from it.
        include_noise : bool
            Draw y (with σ_ε²) or the latent f.

        Returns
        -------
        ndarray, shape (n, L, E) (or (n, L) if fitted on 1-D targets)
        """
        mean, var = self.predict(X, include_noise)
        mean, var = mean.reshape(mean.shape[0], -1), var.reshape(var.shape[0], -1)
        L = check_count(n_samples, "n_samples")
        eps = as_generator(rng).standard_normal((mean.shape[0], L, mean.shape[1]))
        draws = mean[:, None] + np.sqrt(np.maximum(var, 0.0))[:, None] * eps
        return draws[..., 0] if self._squeeze else draws

    @property
    def hyperparameters(self) -> dict[str, np.ndarray]:
        """Trained θ = {w (E, d), σ_f² (E,), σ_ε² (E,)} in raw target units."""
        pred = self._check_fitted()
        s2 = torch.as_tensor(self.y_scale**2, dtype=pred.dtype)
        return {
            "lengthscale": pred.lengthscale.cpu().numpy(),
            "outputscale": (pred.outputscale.cpu() * s2).numpy(),
            "noise": (pred.noise.cpu() * s2).numpy(),
        }

    def _standardisation_tensors(self) -> tuple[torch.Tensor, torch.Tensor]:
        return (
            torch.as_tensor(self.y_mean, dtype=DTYPE, device=self.device),
            torch.as_tensor(self.y_scale, dtype=DTYPE, device=self.device),
        )

    def _hyper_modules(self, E: int, d: int) -> tuple[SquaredExponential, gpytorch.Module]:
        """The SE-ARD kernel and Gaussian likelihood (batch (E,)) at the initial values, on
        :attr:`device` in float64."""

        def tensor(name: str) -> torch.Tensor:
            return torch.as_tensor(self._init[name], dtype=DTYPE, device=self.device)

        kernel = SquaredExponential(d, batch_shape=torch.Size([E])).to(self.device)
        kernel.lengthscale = tensor("lengthscale")[:, None, :]
        kernel.outputscale = tensor("outputscale")
        likelihood = gpytorch.likelihoods.GaussianLikelihood(
            batch_shape=torch.Size([E]), noise_constraint=GreaterThan(self.noise_floor)
        ).to(self.device, DTYPE)
        likelihood.noise = tensor("noise")[:, None]
        return kernel, likelihood


# ---------------------------------------------------------------------------- exact GP
class _SENegLogML(torch.autograd.Function):
    """Σ_a −log p(y_a | X, θ_a), Eq. (2.28) per output a, with its analytic gradient.

    With K_y = K_f + σ_ε²I, α = K_y⁻¹y and W = K_y⁻¹ − ααᵀ, the gradient of the negative log
    marginal likelihood w.r.t. K_y is ½W (Rasmussen & Williams Eq. 5.9); chained through
    the SE kernel (the derivatives of App. B.1), with P = W ∘ K_f:

    * ∂/∂σ_ε² = ½ tr W
    * ∂/∂σ_f² = ½ ΣP / σ_f²
    * ∂/∂w_d = ½ Σ_ij P_ij (x_id − x_jd)² / w_d³ = (Σ_i x_id² (P1)_i − x_dᵀ P x_d) / w_d³

    One Cholesky factorisation and one inverse per evaluation (about half the cost of
    autograd through a generic Cholesky backward).
    """

    @staticmethod
    def forward(ctx, lengthscale, outputscale, noise, X, Y):
        K = se_kernel(X, X, lengthscale[:, None, :], outputscale)
        K.diagonal(dim1=-2, dim2=-1).add_(noise[:, None])
        L, info = torch.linalg.cholesky_ex(K)
        K.diagonal(dim1=-2, dim2=-1).sub_(noise[:, None])  # back to K_f (saves an N x N copy)
        if torch.any(info):
            raise GPNumericalError(
                "K + noise*I is not numerically positive definite at these hyper-parameters"
            )
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
    """−Σ_a log p(y_a | X, θ_a) of Eq. (2.28) for E independent SE-kernel GPs (differentiable).

    Parameters
    ----------
    X : Tensor, shape (N, d)
        Inputs shared by all outputs.
    Y : Tensor, shape (E, N)
        Targets, one row per output.
    lengthscale : Tensor, shape (E, d)
    outputscale, noise : Tensor, shape (E,)

    Returns
    -------
    Tensor, shape ()
        The summed negative log marginal likelihood; its gradient w.r.t. the three
        hyper-parameter tensors is analytic (see :class:`_SENegLogML`).
    """
    return _SENegLogML.apply(lengthscale, outputscale, noise, X, Y)


class _BatchedExactGP(gpytorch.models.ExactGP):
    """E independent zero-mean SE-ARD GPs, batched (GPyTorch batch-independent outputs)."""

    def __init__(self, x: torch.Tensor, y: torch.Tensor, likelihood, kernel):
        super().__init__(x, y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean(batch_shape=y.shape[:1])
        self.covar_module = kernel

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class ExactGP(GPRegression):
    """Standard (full) GP regression, one GP per output, batched in one GPyTorch model.

    The hyper-parameters live in a GPyTorch ``ExactGP`` (``self.model``, batch shape (E,),
    kernel :class:`~skillkit.models.kernels.SquaredExponential`, ``GaussianLikelihood`` with
    the noise floor as its constraint), so GPyTorch tools apply to it unchanged. Training
    minimises the negative of Eq. (2.28) summed over outputs via
    :func:`neg_log_marginal_likelihood` (same value as GPyTorch's
    ``ExactMarginalLogLikelihood``, analytic gradient) w.r.t. GPyTorch's raw parameters.

    Parameters
    ----------
    lengthscale : float or array_like, shape (d,) or (E, d), optional
        Initial ARD length-scales (default: per-input standard deviation).
    outputscale, noise : float, optional
        Initial σ_f² and σ_ε² in raw target units (default: 1 and 1/100 in standardised
        units, i.e. var(y) and var(y)/100, or 1 and 1/100 with ``standardize=False``). An
        initial σ_ε² below 1.5 × the noise floor is raised to that value (the optimiser
        starts inside the constraint).
    noise_floor : float
        Lower bound of σ_ε² relative to var(y) (default 1e-6); with ``standardize=False``
        targets are not scaled and the bound is absolute (σ_ε² ≥ noise_floor).
    additive_noise : float
        α of Sec. 4.2.3: targets get N(0, (α·10⁻²·std(y))²) noise before training (default 1;
        0 disables).
    n_steps : int
        Optimisation steps on the log marginal likelihood (2.28) (default 150, the thesis's
        setting; 0 keeps the initial values).
    optimizer : {"lbfgs", "adam"}
    learning_rate : float
        Adam step size.
    standardize : bool
        Centre and scale targets per output (default True).
    curb : HyperCurb, optional
        A penalty keeping length-scales and the signal-to-noise ratio in a sane range
        (:class:`HyperCurb`, PILCO's); default None: plain maximum likelihood (2.28). The
        final ``diagnostics`` give ``max_lengthscale_ratio`` (w / std(x)),
        ``max_signal_to_noise`` (σ_f/σ_ε) and ``curb_penalty`` either way.
    device : str or torch.device, optional
        Where the hyper-parameters are optimised and the predictor lives, e.g. ``"cuda"``
        (default: the CPU); float64 throughout. Randomness is drawn in numpy, so the draws
        do not depend on the device; results come back as numpy arrays.

    Examples
    --------
    >>> gp = ExactGP(additive_noise=0.0).fit(X, Y, rng=0)      # doctest: +SKIP
    >>> mean, var = gp.predict(X_test)                          # doctest: +SKIP
    """

    def _build(self, rng: np.random.Generator) -> None:
        E, N = self.Y.shape
        d = self.X.shape[1]
        kernel, likelihood = self._hyper_modules(E, d)
        self.model = _BatchedExactGP(self.X.expand(E, N, d), self.Y, likelihood, kernel).to(
            self.device, DTYPE
        )
        self.likelihood = likelihood

    def _parameters(self) -> list[torch.nn.Parameter]:
        return list(self.model.parameters())

    def _hypers(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        kern = self.model.covar_module
        return kern.lengthscale[:, 0, :], kern.outputscale, self.likelihood.noise[:, 0]

    def _loss(self) -> torch.Tensor:
        """Negative log marginal likelihood (2.28), summed over outputs (standardised units)."""
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


# ---------------------------------------------------------------------------- forward model
class ForwardModel:
    """A GP forward model of the dynamics fitted on transitions (Sec. 4.2).

    ``target="next"`` (default): x_{t+1} = f(x_t, u_t) + ε, the thesis's model (Secs 4.2.4,
    5.1.1; the prior mean is the training mean of x_{t+1}).
    ``target="delta"``: x_{t+1} = x_t + f(x_t, u_t) + ε, the GP learns Δx (PILCO's choice;
    the prior predicts "no change" far from data). Only with x′ targets does the conditional
    embedding of Ch. 5 beat the GP near the data, as the thesis reports (balancing data). For
    the thesis's hyper-parameter treatment give the GP a :class:`HyperCurb`
    (``FITC(..., curb=HyperCurb())``).
    The GP input is z = [x_t, u_t]; each state dimension has its own GP.

    ``mean="linear"`` gives the GP a linear prior mean (Rasmussen & Williams 2006, Sec. 2.7):
    the target is y = Wᵀ z + b + f(z) + ε with W, b from least squares on the training data
    and f the GP of the residuals. Near an equilibrium of stiff, unstable dynamics a zero-mean
    SE GP on little data can predict worse than the linear part alone (Table 4.2's
    experiment). Everything that predicts (the sampler, :meth:`predict`, moment matching and
    linearisation) adds the linear part exactly.

    Parameters
    ----------
    gp : ExactGP, FITC or VFE
        An unfitted GP regression object (its settings are used as given).
    target : {"delta", "next"}
    mean : {"zero", "linear"}
        The GP's prior mean function.
    """

    def __init__(self, gp: GPRegression, target: str = "next", mean: str = "zero"):
        if not isinstance(gp, GPRegression):
            raise ValueError(
                f"gp: expected an ExactGP, FITC or VFE instance, got {type(gp).__name__}"
            )
        if target not in ("delta", "next"):
            raise ValueError(f"target: expected 'delta' or 'next', got {target!r}")
        if mean not in ("zero", "linear"):
            raise ValueError(f"mean: expected 'zero' or 'linear', got {mean!r}")
        self.gp = gp
        self.target = target
        self.mean = mean
        self.linear_weights: torch.Tensor | None = None
        self.state_dim = 0
        self.control_dim = 0
        self._predictor: GPPredictor | None = None

    def __repr__(self) -> str:
        sizes = (
            f"state_dim={self.state_dim}, control_dim={self.control_dim}"
            if self._predictor is not None
            else "unfitted"
        )
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

    def fit(self, states, controls, next_states, rng=None) -> ForwardModel:
        """Fit the GP on transitions (x_t, u_t) → x_{t+1}.

        Parameters
        ----------
        states : array_like, shape (N, n_x)
        controls : array_like, shape (N, n_u)
        next_states : array_like, shape (N, n_x)
        rng : Generator, int or None
            Passed to the GP (additive noise, pseudo-input initialisation).
        """
        x = check_array(states, "states", ndim=2)
        u = check_array(controls, "controls", ndim=2)
        xn = check_array(next_states, "next_states", ndim=2)
        if u.shape[0] != x.shape[0]:
            raise ValueError(
                f"controls: expected {x.shape[0]} rows like states, got shape {u.shape}"
            )
        if xn.shape != x.shape:
            raise ValueError(f"next_states: expected shape {x.shape} like states, got {xn.shape}")
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
        return self

    def linear_mean(self, z: torch.Tensor) -> torch.Tensor | float:
        """Wᵀ z + b of ``mean="linear"`` for inputs z (..., D); 0 for the zero mean."""
        if self.linear_weights is None:
            return 0.0
        w = self.linear_weights.to(z.device, z.dtype)
        return z @ w[:-1] + w[-1]

    def to(self, device=None, dtype: torch.dtype | None = None) -> ForwardModel:
        """A shallow copy whose predictor lives on ``device`` in ``dtype``."""
        out = ForwardModel.__new__(ForwardModel)
        out.__dict__.update(self.__dict__)
        out._predictor = self.predictor.to(device, dtype)
        if self.linear_weights is not None:
            out.linear_weights = self.linear_weights.to(out._predictor.device, out._predictor.dtype)
        return out

    def with_predictor(self, predictor) -> ForwardModel:
        """A shallow copy that predicts with ``predictor`` (same targets, mean and sizes).

        ``predictor`` is a :class:`GPPredictor` or anything with its ``moments(z)``, e.g. the
        pathwise function draws of :mod:`skillkit.models.pathwise`.
        """
        out = ForwardModel.__new__(ForwardModel)
        out.__dict__.update(self.__dict__)
        out._predictor = predictor
        return out

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor) -> Moments:
        """Per-dimension Gaussian p(x_{t+1} | x_t, u_t) for a batch (tensors, hot path).

        Parameters
        ----------
        x : Tensor, shape (n, n_x)
        u : Tensor, shape (n, n_u)

        Returns
        -------
        Moments
            mean and var of shape (n, n_x).
        """
        z = torch.cat([x, u], dim=-1)
        m = self.predictor.moments(z)
        if self.linear_weights is not None:
            m = m._replace(mean=m.mean + self.linear_mean(z))
        return m._replace(mean=x + m.mean) if self.delta else m

    def predict(self, states, controls) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of x_{t+1} for arrays of states (n, n_x) and controls (n, n_u)."""
        pred = self.predictor
        x = check_array(states, "states", shape=(None, self.state_dim))
        u = check_array(controls, "controls", shape=(x.shape[0], self.control_dim))
        with torch.no_grad():
            m = self.next_state_moments(
                torch.as_tensor(x, dtype=pred.dtype, device=pred.device),
                torch.as_tensor(u, dtype=pred.dtype, device=pred.device),
            )
        warn_if_clamped(m, "ForwardModel")
        return m.mean.cpu().numpy(), m.var.cpu().numpy()
