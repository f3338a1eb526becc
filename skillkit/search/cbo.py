"""Contextual Bayesian optimisation (BoTorch) behind the search interface.

:class:`ContextualBO` keeps every sample (s_i, ω_i, R_i) and fits BoTorch's ``SingleTaskGP``
(its default kernel, priors, noise and ``Standardize``; inputs normalised to the search box) to
R over z = [s, ω] after every update. For a context s it proposes
ω = argmax_ω UCB([s, ω]), UCB = μ + √β σ with s fixed (the contextual GP-UCB of Krause & Ong,
NIPS 2011); the policy mean is argmax_ω μ([s, ω]) (π₀'s mean in the box without data). The
box is, per dimension, the range of π₀'s mean over the context corners ± k standard
deviations; the first ``initial_batches`` batches are a scrambled Sobol design in it. A failed
rollout enters the GP with the lowest working reward; while all rewards are equal (e.g. every
rollout failed) there is no GP, and the Sobol design and π₀'s mean go on.

Randomness: ``policy.sample`` draws one seed per row from the loop's ``rng``; ``mean_of`` and
the GP fit use seeds from the algorithm's own ``rng``; every BoTorch call runs inside
``torch.random.fork_rng`` seeded with its seed, so global state is untouched.
"""

from __future__ import annotations

import contextlib
import itertools
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, fields

import numpy as np
import torch
from botorch.acquisition import PosteriorMean, UpperConfidenceBound
from botorch.acquisition.acquisition import AcquisitionFunction
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms.input import Normalize
from botorch.optim import optimize_acqf
from botorch.optim.initializers import gen_batch_initial_conditions
from botorch.utils.sampling import draw_sobol_samples
from gpytorch.mlls import ExactMarginalLogLikelihood
from numpy.typing import ArrayLike

from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.policies.gaussian import LinearGaussianPolicy, query_contexts
from skillkit.search.base import Batch, as_batch, check_policy, check_settings, fields_repr

#: Samples beyond which an update warns (once) that the exact GP's O(N³) fit dominates.
LARGE_N = 2000

_SEED_BOUND = 2**31  # seeds for torch and BoTorch's Sobol engine: non-negative int32


@dataclass(frozen=True)
class CBOSettings:
    """Settings of :class:`ContextualBO` (BoTorch's defaults where it has one).

    Attributes
    ----------
    beta, box_std : float
        β ≥ 0 of UCB on the standardised reward; k > 0 of the ω box (π₀'s mean range ± k std).
    initial_batches : int
        Batches proposed by a Sobol design before UCB takes over (≥ 1).
    num_restarts, raw_samples : int
        ``optimize_acqf``'s L-BFGS-B starts per proposal, and the Sobol points they come from.
    rollouts_per_update : int
        The batch size suggested for :func:`learn` (any works).
    max_observations : int or None
        Fit the GP on at most this many most recent samples (``None``: all; ≥ 2).
    """

    beta: float = 0.2
    box_std: float = 2.0
    initial_batches: int = 1
    num_restarts: int = 10
    raw_samples: int = 512
    rollouts_per_update: int = 10
    max_observations: int | None = None

    def __post_init__(self):
        check_positive(self.beta, "beta", allow_zero=True)
        check_positive(self.box_std, "box_std")
        check_count(self.initial_batches, "initial_batches")
        check_count(self.num_restarts, "num_restarts")
        if check_count(self.raw_samples, "raw_samples") < self.num_restarts:
            raise ValueError(f"raw_samples: expected ≥ num_restarts, got {self.raw_samples}")
        check_count(self.rollouts_per_update, "rollouts_per_update")
        if self.max_observations is not None:
            check_count(self.max_observations, "max_observations", 2)


@contextlib.contextmanager
def _seeded(seed: int, device: torch.device) -> Iterator[None]:
    """Torch's global generator (and ``device``'s) seeded with ``seed`` inside, restored on exit."""
    cuda = []
    if device.type == "cuda":
        cuda = [torch.cuda.current_device() if device.index is None else device.index]
    with torch.random.fork_rng(devices=cuda):
        torch.random.default_generator.manual_seed(seed)
        for index in cuda:
            with torch.cuda.device(index):
                torch.cuda.manual_seed(seed)
        yield


@dataclass(repr=False, eq=False)
class CBOPolicy:
    """One fitted GP (or none yet) as a policy: UCB proposals and the posterior-mean argmax.

    Made by :class:`ContextualBO` after every update: ``model`` is the GP over z = [s, ω]
    (``None`` before data, when the mean is π₀'s clipped to ``omega_bounds`` (2, d)),
    ``explore_randomly`` proposes a Sobol design, ``mean_seed`` seeds every ``mean_of`` search,
    and BoTorch runs on ``device`` in ``dtype``; ``sample_seconds`` and ``mean_seconds`` add up
    the time spent in :meth:`sample` and :meth:`mean_of`.
    """

    model: SingleTaskGP | None
    initial: LinearGaussianPolicy
    omega_bounds: np.ndarray
    explore_randomly: bool
    settings: CBOSettings
    mean_seed: int
    n_updates: int
    device: torch.device
    dtype: torch.dtype
    sample_seconds: float = 0.0
    mean_seconds: float = 0.0

    def __post_init__(self):
        self.dim, self.context_dim = self.initial.dim, self.initial.context_dim
        self.omega_bounds = np.array(self.omega_bounds, dtype=np.float64)
        self.omega_bounds.setflags(write=False)

    def _tensor(self, x) -> torch.Tensor:
        return torch.tensor(np.asarray(x), dtype=self.dtype, device=self.device)

    def _argmax(self, acqf: AcquisitionFunction, context: np.ndarray, seed: int) -> np.ndarray:
        """argmax_ω acqf([s, ω]) over the box with s fixed."""
        n_s = self.context_dim
        bounds = np.hstack([np.vstack([context, context]), self.omega_bounds])
        with _seeded(seed, self.device):
            z, _ = optimize_acqf(
                acqf,
                bounds=self._tensor(bounds),
                q=1,
                num_restarts=self.settings.num_restarts,
                raw_samples=self.settings.raw_samples,
                fixed_features={i: float(context[i]) for i in range(n_s)},
                options={"seed": seed},
            )
        omega = z.detach().cpu().numpy().astype(np.float64).reshape(-1)[n_s:]
        return np.clip(omega, *self.omega_bounds)  # no-op in float64; float32 may round out

    def _argmax_rows(
        self, acqf: AcquisitionFunction, contexts: np.ndarray, seeds: np.ndarray
    ) -> np.ndarray:
        """argmax_ω acqf([s_i, ω]) for every row, shape (n, d): starts per row from its seed,
        then one ``optimize_acqf`` call over all of them."""
        n_s, n = self.context_dim, contexts.shape[0]
        restarts = self.settings.num_restarts
        starts = []
        for context, seed in zip(contexts, seeds, strict=True):
            bounds = np.hstack([np.vstack([context, context]), self.omega_bounds])
            with _seeded(int(seed), self.device):
                starts.append(
                    gen_batch_initial_conditions(
                        acqf,
                        self._tensor(bounds),
                        q=1,
                        num_restarts=restarts,
                        raw_samples=self.settings.raw_samples,
                        fixed_features={i: float(context[i]) for i in range(n_s)} or None,
                        options={"seed": int(seed)},
                    )
                )
        fixed = {i: self._tensor(np.repeat(contexts[:, i], restarts)) for i in range(n_s)}
        low = np.concatenate([contexts.min(axis=0), self.omega_bounds[0]])
        high = np.concatenate([contexts.max(axis=0), self.omega_bounds[1]])
        with _seeded(int(seeds[0]), self.device):
            z, values = optimize_acqf(
                acqf,
                bounds=self._tensor(np.vstack([low, high])),
                q=1,
                num_restarts=n * restarts,
                batch_initial_conditions=torch.cat(starts),
                fixed_features=fixed or None,
                return_best_only=False,
            )
        best = values.reshape(n, restarts).argmax(dim=1)
        z = z.reshape(n, restarts, -1)[torch.arange(n, device=z.device), best]
        omega = z.detach().cpu().numpy().astype(np.float64)[:, n_s:]
        return np.clip(omega, *self.omega_bounds)  # no-op in float64; float32 may round out

    def sample(self, contexts: ArrayLike | None = None, rng=None) -> np.ndarray:
        """One proposal ω per context, shape (n, d) (or (d,) for one context or None).

        A Sobol design in the box while exploring randomly, else argmax_ω UCB([s, ω]) per row; the
        seeds come from ``rng``. ``ValueError`` when ``contexts`` do not fit.
        """
        s, single = query_contexts(contexts, self.context_dim)
        rng = as_generator(rng)
        start = time.perf_counter()
        if self.explore_randomly or self.model is None:
            seed = int(rng.integers(_SEED_BOUND))
            design = draw_sobol_samples(
                self._tensor(self.omega_bounds), n=s.shape[0], q=1, seed=seed
            )
            omega = design.reshape(s.shape[0], self.dim).cpu().numpy().astype(np.float64)
            omega = np.clip(omega, *self.omega_bounds)
        else:
            seeds = rng.integers(_SEED_BOUND, size=s.shape[0])
            acqf = UpperConfidenceBound(self.model, beta=self.settings.beta)
            omega = self._argmax_rows(acqf, s, seeds)
        self.sample_seconds += time.perf_counter() - start
        return omega[0] if single else omega

    def mean_of(self, contexts: ArrayLike | None = None) -> np.ndarray:
        """argmax_ω μ([s, ω]) per context with a fixed seed (π₀'s clipped mean without a GP), shape
        (n, d) or (d,)."""
        s, single = query_contexts(contexts, self.context_dim)
        start = time.perf_counter()
        if self.model is None:
            low, high = self.omega_bounds
            omega = np.clip(
                np.atleast_2d(self.initial.mean_of(s if self.context_dim else None)), low, high
            )
            omega = np.broadcast_to(omega, (s.shape[0], self.dim)).copy()
        else:
            acqf = PosteriorMean(self.model)
            omega = np.stack([self._argmax(acqf, si, self.mean_seed) for si in s])
        self.mean_seconds += time.perf_counter() - start
        return omega[0] if single else omega

    def __repr__(self) -> str:
        n = 0 if self.model is None else int(self.model.train_targets.shape[-1])
        mode = "Sobol design" if self.explore_randomly or self.model is None else "UCB"
        return (
            f"CBOPolicy(dim={self.dim}, context_dim={self.context_dim}, updates={self.n_updates}, "
            f"GP on {n} samples, proposals: {mode}, beta={self.settings.beta:.4g})"
        )


@dataclass(frozen=True)
class CBODiagnostics:
    """What one :meth:`ContextualBO.update` did.

    ``n_fitted`` of the ``n_observations`` samples fitted the GP (0: none yet); ``mean_reward`` is
    over the batch's rollouts, ``best_reward`` over every working rollout so far (NaN while there
    is none); ``random_batch`` says the batch was a Sobol design; ``acquisition_seconds`` is the
    proposing policy's time in ``sample``; ``lengthscales`` are in units of the normalised box,
    [s, ω] order; ``noise_std`` and ``signal_std`` in reward units.
    """

    n_updates: int
    n_observations: int
    n_fitted: int
    mean_reward: float
    best_reward: float
    n_failed: int
    random_batch: bool
    fit_seconds: float
    acquisition_seconds: float
    lengthscales: tuple[float, ...] = ()
    noise_std: float = float("nan")
    signal_std: float = float("nan")

    def __repr__(self) -> str:
        return fields_repr(self, *[f.name for f in fields(self) if f.name != "lengthscales"])


class ContextualBO:
    """Contextual Bayesian optimisation (BoTorch) as a policy-search algorithm for :func:`learn`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        π₀: the mean before any data and, with its standard deviations, the ω box.
    context_low, context_high : array_like, shape (context_dim,)
        The context range (required for a contextual policy; zero width is mapped to width 1).
    omega_low, omega_high : array_like, shape (d,), optional
        The ω box, low < high (default: from ``policy`` and ``settings.box_std``).
    settings : CBOSettings, optional
    rng : Generator, int or None
        The algorithm's own stream (GP fits and ``mean_of``).
    device, dtype : optional
        Where BoTorch computes (default CPU), in torch.float64 (default) or torch.float32.
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        *,
        context_low: ArrayLike | None = None,
        context_high: ArrayLike | None = None,
        omega_low: ArrayLike | None = None,
        omega_high: ArrayLike | None = None,
        settings: CBOSettings | None = None,
        rng: np.random.Generator | int | None = None,
        device: str | torch.device | None = None,
        dtype: torch.dtype = torch.float64,
    ):
        check_policy(policy)
        settings = check_settings(settings, CBOSettings)
        if dtype not in (torch.float64, torch.float32):
            raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
        try:
            self.device = torch.device("cpu" if device is None else device)
        except (RuntimeError, TypeError) as exc:
            raise ValueError(f"device: not a torch device ({exc})") from None
        self.dtype = dtype
        self.settings = settings
        self._rng = as_generator(rng)
        self._initial = policy
        self._context_bounds = self._check_context_bounds(policy, context_low, context_high)
        self._omega_bounds = self._check_omega_bounds(policy, omega_low, omega_high)
        d, n_s = policy.dim, policy.context_dim
        self._contexts = np.zeros((0, n_s))
        self._omegas = np.zeros((0, d))
        self._rewards = np.zeros(0)
        self._failed = np.zeros(0, dtype=bool)
        self.n_updates = 0
        self._warned_large = False
        self._policy = self._make_policy(None)

    def _check_context_bounds(self, policy, low, high) -> np.ndarray:
        n_s = policy.context_dim
        if n_s == 0:
            return np.zeros((2, 0))
        if low is None or high is None:
            raise ValueError("context_low, context_high: a contextual policy needs both")
        lo = check_array(low, "context_low", shape=(n_s,))
        hi = check_array(high, "context_high", shape=(n_s,))
        if np.any(hi < lo):
            raise ValueError(f"context_high: expected ≥ context_low, got {hi} < {lo}")
        return np.vstack([lo, np.where(hi > lo, hi, lo + 1.0)])

    def _check_omega_bounds(self, policy, low, high) -> np.ndarray:
        d = policy.dim
        if (low is None) != (high is None):
            raise ValueError("omega_low, omega_high: give both bounds, or neither")
        if low is not None:
            lo = check_array(low, "omega_low", shape=(d,))
            hi = check_array(high, "omega_high", shape=(d,))
            if np.any(hi <= lo):
                raise ValueError(f"omega_high: expected > omega_low, got {hi} ≤ {lo}")
            return np.vstack([lo, hi])
        if policy.context_dim and policy.features != "linear":
            raise ValueError(f"policy: the ω box needs linear features, got {policy.features!r}")
        if policy.context_dim:
            corners = np.array(list(itertools.product(*self._context_bounds.T)))
            means = policy.mean_of(corners)
        else:
            means = policy.mean[None, :]
        k_std = self.settings.box_std * np.sqrt(np.diag(policy.cov))
        return np.vstack([means.min(axis=0) - k_std, means.max(axis=0) + k_std])

    @classmethod
    def for_task(cls, task, policy: LinearGaussianPolicy | None = None, **kwargs) -> ContextualBO:
        """Contextual BO on a task's context range (default policy ``task.initial_policy()``)."""
        if task.context_dim:
            kwargs.setdefault("context_low", task.context_low)
            kwargs.setdefault("context_high", task.context_high)
        return cls(task.initial_policy() if policy is None else policy, **kwargs)

    # ----------------------------------------------------------------- state
    @property
    def policy(self) -> CBOPolicy:
        """The current :class:`CBOPolicy`."""
        return self._policy

    @property
    def rollouts_per_update(self) -> int:
        """The suggested N for :func:`learn`."""
        return self.settings.rollouts_per_update

    @property
    def omega_bounds(self) -> np.ndarray:
        """The ω box, shape (2, d)."""
        return self._omega_bounds.copy()

    @property
    def n_observations(self) -> int:
        """Samples kept so far."""
        return int(self._rewards.shape[0])

    def _make_policy(self, model: SingleTaskGP | None) -> CBOPolicy:
        return CBOPolicy(
            model=model,
            initial=self._initial,
            omega_bounds=self._omega_bounds,
            explore_randomly=self.n_updates < self.settings.initial_batches,
            settings=self.settings,
            mean_seed=int(self._rng.integers(_SEED_BOUND)),
            n_updates=self.n_updates,
            device=self.device,
            dtype=self.dtype,
        )

    # ----------------------------------------------------------------- update
    def update(self, batch: Batch) -> CBODiagnostics:
        """Add a batch to the samples, refit the GP and make the next policy.

        The batch's trajectories, if any, only say which rollouts failed.
        """
        pol = self._policy
        batch = as_batch(batch, pol.dim, pol.context_dim)
        trajs = batch.trajectories
        failed = np.array([t.failed for t in trajs]) if trajs else np.zeros(len(batch), bool)
        self._contexts = np.vstack([self._contexts, batch.contexts])
        self._omegas = np.vstack([self._omegas, batch.omegas])
        self._rewards = np.concatenate([self._rewards, batch.rewards])
        self._failed = np.concatenate([self._failed, failed])
        self.n_updates += 1

        start = time.perf_counter()
        model = self._fit()
        fit_seconds = time.perf_counter() - start
        self._policy = self._make_policy(model)
        working = self._rewards[~self._failed]
        return CBODiagnostics(
            n_updates=self.n_updates,
            n_observations=self.n_observations,
            n_fitted=0 if model is None else int(model.train_targets.shape[-1]),
            mean_reward=float(batch.rewards[: batch.n_rollouts].mean()),
            best_reward=float(working.max()) if working.size else float("nan"),
            n_failed=int(failed.sum()),
            random_batch=pol.explore_randomly or pol.model is None,
            fit_seconds=fit_seconds,
            acquisition_seconds=pol.sample_seconds,
            **_hyperparameters(model),
        )

    def _fit(self) -> SingleTaskGP | None:
        """The GP on the (most recent ``max_observations``) samples; ``None`` below two or while
        their rewards are all equal (a constant carries no information)."""
        seed = int(self._rng.integers(_SEED_BOUND))
        cap = self.settings.max_observations
        keep = slice(None) if cap is None else slice(-cap, None)
        s, w = self._contexts[keep], self._omegas[keep]
        r, failed = self._rewards[keep], self._failed[keep]
        if failed.any() and not failed.all():
            r = np.where(failed, r[~failed].min(), r)
        if r.shape[0] < 2 or np.all(r == r[0]):
            return None
        if cap is None and r.shape[0] > LARGE_N and not self._warned_large:
            self._warned_large = True
            warnings.warn(
                f"ContextualBO: the GP has {r.shape[0]} samples (> {LARGE_N}); its fit costs "
                "O(N³) per likelihood evaluation (set CBOSettings.max_observations to cap N)",
                RuntimeWarning,
                stacklevel=3,
            )
        z_bounds = np.hstack([self._context_bounds, self._omega_bounds])
        model = SingleTaskGP(
            self._tensor(np.hstack([s, w])),
            self._tensor(r[:, None]),
            input_transform=Normalize(d=z_bounds.shape[1], bounds=self._tensor(z_bounds)),
        )
        with _seeded(seed, self.device):
            fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
        return model.eval()

    _tensor = CBOPolicy._tensor

    def __repr__(self) -> str:
        d, n_s = self._initial.dim, self._initial.context_dim
        return (
            f"ContextualBO(dim={d}, context_dim={n_s}, beta={self.settings.beta:.4g}, "
            f"box_std={self.settings.box_std:.4g}, {self.n_updates} updates, "
            f"{self.n_observations} samples, device={self.device})"
        )


def _hyperparameters(model: SingleTaskGP | None) -> dict:
    """The GP's lengthscales (normalised units), noise and signal std (reward units)."""
    if model is None:
        return {}
    with torch.no_grad():
        kernel = model.covar_module
        outputscale = getattr(kernel, "outputscale", None)
        base = getattr(kernel, "base_kernel", kernel)
        y_std = model.outcome_transform.stdvs.reshape(-1)[0]
        scale = 1.0 if outputscale is None else outputscale.reshape(-1)[0].sqrt()
        return {
            "lengthscales": tuple(float(v) for v in base.lengthscale.reshape(-1).cpu()),
            "noise_std": float(model.likelihood.noise.reshape(-1)[0].sqrt() * y_std),
            "signal_std": float(scale * y_std),
        }
