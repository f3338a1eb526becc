r"""A probabilistic ensemble of neural networks as a forward model (PETS, Chua et al. 2018).

K small MLPs, each fitted to its own bootstrap resample of the transitions, each predicting

.. math:: p_k(y \mid z) = \mathcal{N}\big(\mu_k(z), \operatorname{diag}\sigma_k^2(z)\big),
          \qquad z = [x_t, u_t],

with y = x_{t+1} (``target="next"``) or x_{t+1} − x_t (``"delta"``), as
:class:`~skillkit.models.gp.ForwardModel`. Member disagreement is the epistemic uncertainty,
σ_k² the aleatoric noise.

* **Standardisation.** z and y are centred and scaled per column (a constant column keeps
  scale 1); predictions are in raw units.
* **Members.** SiLU hidden layers, a linear output of 2E numbers (mean, raw log-variance);
  all K stacked (weights (K, d_in, d_out)) and evaluated in one batched product per layer.
* **Bounded log-variance** (PETS, App. A.1): log σ² = l_max − softplus(l_max − r), then
  l_min + softplus(· − l_min), a smooth clamp of r to [l_min, l_max]. The bounds are trained
  per member and output (from :data:`LOGVAR_INIT`, penalty :data:`LOGVAR_PENALTY` ·
  (Σ l_max − Σ l_min)); PETS shares them between members.
* **Training.** Each member minimises the Gaussian negative log-likelihood (standardised
  units) on minibatches of its resample D_k (N draws with replacement),

  .. math:: \ell_k = \operatorname{mean}_{(z, y) \in \text{batch}, e}
            \Big[\frac{(y_e - \mu_{k,e}(z))^2}{\sigma_{k,e}^2(z)} + \log\sigma_{k,e}^2(z)\Big],

  with Adam and L2 ``weight_decay`` on the weight matrices for a fixed number of epochs
  (no early stopping, no held-out split).
* **Randomness.** ``fit(rng=)`` draws the resamples and seeds one CPU
  :class:`torch.Generator` for initial weights and minibatch order: same seed, same model
  (same device and thread count). No global seed is used.

**Sampling: TS-∞** (PETS, Sec. 4.2). :meth:`ProbabilisticEnsemble.next_state_moments` returns
for row i the moments of member i mod K; since
:func:`~skillkit.models.sampling.sample_trajectories` keeps the row order, trajectory i uses
member i mod K throughout (stratified: with L a multiple of K each pair gets every member L/K
times). A ``stop`` rule drops rows and so changes members: do not combine it with TS-∞.
:meth:`ProbabilisticEnsemble.predict` gives the equal-weight mixture's mean and variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from skillkit._repr import number
from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.models.gp import DTYPE, Moments, as_device

__all__ = ["LOGVAR_INIT", "LOGVAR_PENALTY", "EnsembleSettings", "ProbabilisticEnsemble"]

#: Initial (l_min, l_max) of the bounded log-variance, standardised units (PETS's values).
LOGVAR_INIT = (-10.0, 0.5)
#: Weight of Σ l_max − Σ l_min in the training loss (PETS's value).
LOGVAR_PENALTY = 0.01

_Layer = tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class EnsembleSettings:
    """Settings of :class:`ProbabilisticEnsemble` (defaults: small networks for the thesis's
    tasks, 2–12 inputs and up to a few thousand transitions).

    Attributes
    ----------
    hidden_sizes : tuple of int
        Units of each hidden layer (≥ 1 layer, each ≥ 1); (64, 64). PETS used 3–4 layers of
        200–500 units on larger problems.
    n_members : int
        K ≥ 1 networks, each on its own bootstrap resample (5, as in PETS).
    epochs : int
        Passes over each member's resample (≥ 1); 100. The number of Adam steps is
        ``epochs · ceil(N / batch_size)``.
    lr : float
        Adam's step size (> 0); 1e-3.
    weight_decay : float
        L2 penalty (≥ 0) on the weight matrices (not the biases or log-variance bounds),
        Adam's coupled form: it adds ``weight_decay · W`` to the gradient; 1e-4.
    batch_size : int
        Transitions per minibatch and member (≥ 1); 64. A resample smaller than this is one
        batch.
    """

    hidden_sizes: tuple[int, ...] = (64, 64)
    n_members: int = 5
    epochs: int = 100
    lr: float = 1e-3
    weight_decay: float = 1e-4
    batch_size: int = 64

    def __post_init__(self) -> None:
        sizes = self.hidden_sizes
        if (
            not isinstance(sizes, tuple)
            or not sizes
            or any(isinstance(h, bool) or not isinstance(h, (int, np.integer)) for h in sizes)
            or min(sizes) < 1
        ):
            raise ValueError(
                f"hidden_sizes: expected a non-empty tuple of positive integers, got {sizes!r}"
            )
        check_count(self.n_members, "n_members")
        check_count(self.epochs, "epochs")
        check_positive(self.lr, "lr")
        check_positive(self.weight_decay, "weight_decay", allow_zero=True)
        check_count(self.batch_size, "batch_size")


class ProbabilisticEnsemble:
    """K bootstrap MLPs with Gaussian outputs: a forward model x_{t+1} ~ p(· | x_t, u_t).

    Implements what :func:`~skillkit.models.sampling.sample_trajectories` and
    :class:`~skillkit.search.gpreps.TrajectoryRewardModel` use (``fit``, ``state_dim``,
    ``control_dim``, ``to``, ``next_state_moments``), so it is a ``make_model`` of GPREPS:
    ``TrajectoryRewardModel(task, make_model=ProbabilisticEnsemble)``, or with settings
    ``functools.partial(ProbabilisticEnsemble, EnsembleSettings(epochs=200))``. Sampled
    trajectories follow TS-∞ (module notes): trajectory i of a batch uses member i mod K.

    Parameters
    ----------
    settings : EnsembleSettings, optional
        Network sizes and training (default: ``EnsembleSettings()``).
    target : {"delta", "next"}
        What the networks learn: Δx = x_{t+1} − x_t (default, as PETS; a network then need
        not reproduce the identity map) or x_{t+1}.
    device : str or torch.device, optional
        Where the networks are trained (default: the CPU).
    dtype : torch.float64 or torch.float32
        Precision of training and, unless :meth:`to` says otherwise, of predictions
        (default float64, the package's).
    """

    def __init__(
        self,
        settings: EnsembleSettings | None = None,
        target: str = "delta",
        device=None,
        dtype: torch.dtype = DTYPE,
    ):
        if settings is None:
            settings = EnsembleSettings()
        if not isinstance(settings, EnsembleSettings):
            raise ValueError(
                f"settings: expected an EnsembleSettings, got {type(settings).__name__}"
            )
        if target not in ("delta", "next"):
            raise ValueError(f"target: expected 'delta' or 'next', got {target!r}")
        if dtype not in (torch.float64, torch.float32):
            raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
        self.settings = settings
        self.target = target
        self.device = as_device(device)
        self.dtype = dtype
        self.state_dim = 0
        self.control_dim = 0
        self.n_data = 0
        #: Final training loss of each member on its resample (the loss ℓ_k, standardised
        #: units, without the penalties), shape (K,); None before :meth:`fit`.
        self.train_loss: np.ndarray | None = None
        self._layers: list[_Layer] | None = None
        self._logvar_bounds: tuple[torch.Tensor, torch.Tensor] | None = None
        self._z_mean = self._z_scale = self._y_mean = self._y_scale = None

    # ------------------------------------------------------------------ fitting
    @property
    def n_members(self) -> int:
        """K, the number of networks."""
        return self.settings.n_members

    def fit(self, states, controls, next_states, rng=None) -> ProbabilisticEnsemble:
        """Fit the K members on bootstrap resamples of the transitions (x_t, u_t) → x_{t+1}.

        Parameters
        ----------
        states : array_like, shape (N, n_x)
            x_t, N ≥ 2, n_x ≥ 1.
        controls : array_like, shape (N, n_u)
            u_t (n_u may be 0).
        next_states : array_like, shape (N, n_x)
            x_{t+1}.
        rng : Generator, int, SeedSequence or None
            The bootstrap resamples, initial weights and minibatch order.

        Returns
        -------
        ProbabilisticEnsemble
            Itself, fitted.
        """
        x = check_array(states, "states", ndim=2)
        u = check_array(controls, "controls", ndim=2)
        xn = check_array(next_states, "next_states", ndim=2)
        if x.shape[0] < 2 or x.shape[1] < 1:
            raise ValueError(
                f"states: expected at least 2 transitions of at least 1 dimension, got {x.shape}"
            )
        if u.shape[0] != x.shape[0]:
            raise ValueError(
                f"controls: expected {x.shape[0]} rows like states, got shape {u.shape}"
            )
        if xn.shape != x.shape:
            raise ValueError(f"next_states: expected shape {x.shape} like states, got {xn.shape}")
        rng = as_generator(rng)
        st = self.settings
        N, K = x.shape[0], st.n_members
        z = np.hstack([x, u])
        y = xn - x if self.target == "delta" else xn
        z_mean, z_scale = _standardizer(z)
        y_mean, y_scale = _standardizer(y)
        kw = {"dtype": self.dtype, "device": self.device}
        Z = torch.as_tensor((z - z_mean) / z_scale, **kw)
        Y = torch.as_tensor((y - y_mean) / y_scale, **kw)
        boot = torch.as_tensor(rng.integers(N, size=(K, N)), device=self.device)  # (K, N)
        gen = torch.Generator()  # CPU: the same draws whatever the device
        gen.manual_seed(int(rng.integers(2**63 - 1)))

        sizes = [Z.shape[1], *st.hidden_sizes, 2 * Y.shape[1]]
        layers = [
            _init_layer(K, a, b, gen, **kw) for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        ]
        lo, hi = LOGVAR_INIT
        bounds = tuple(torch.full((K, 1, Y.shape[1]), v, **kw).requires_grad_() for v in (lo, hi))
        weights = [w for w, _ in layers]
        others = [b for _, b in layers] + list(bounds)
        opt = torch.optim.Adam(
            [
                {"params": weights, "weight_decay": st.weight_decay},
                {"params": others, "weight_decay": 0.0},
            ],
            lr=st.lr,
        )
        batch = min(st.batch_size, N)
        for _ in range(st.epochs):
            order = boot.gather(1, torch.argsort(torch.rand((K, N), generator=gen), 1).to(boot))
            for start in range(0, N, batch):
                idx = order[:, start : start + batch]  # (K, b): each member's own rows
                mean, logvar = _forward(layers, bounds, Z[idx])
                loss = _nll(mean, logvar, Y[idx]).sum() + LOGVAR_PENALTY * (
                    bounds[1].sum() - bounds[0].sum()
                )
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

        self._layers = [(w.detach(), b.detach()) for w, b in layers]
        self._logvar_bounds = (bounds[0].detach(), bounds[1].detach())
        with torch.no_grad():
            mean, logvar = _forward(self._layers, self._logvar_bounds, Z[boot])
            self.train_loss = _nll(mean, logvar, Y[boot]).cpu().numpy().astype(np.float64)
        self._z_mean, self._z_scale, self._y_mean, self._y_scale = (
            torch.as_tensor(a, **kw) for a in (z_mean, z_scale, y_mean, y_scale)
        )
        self.state_dim, self.control_dim, self.n_data = x.shape[1], u.shape[1], N
        return self

    # ------------------------------------------------------------------ prediction
    def _check_fitted(self) -> None:
        if self._layers is None:
            raise RuntimeError("ProbabilisticEnsemble: call fit() first")

    def to(self, device=None, dtype: torch.dtype | None = None) -> ProbabilisticEnsemble:
        """A shallow copy that predicts on ``device`` in ``dtype`` (default: the CPU and the
        model's dtype); this model is unchanged.

        Parameters
        ----------
        device : str or torch.device, optional
        dtype : torch.float64 or torch.float32, optional
        """
        self._check_fitted()
        dtype = self.dtype if dtype is None else dtype
        if dtype not in (torch.float64, torch.float32):
            raise ValueError(f"dtype: expected torch.float64 or torch.float32, got {dtype!r}")
        kw = {"dtype": dtype, "device": as_device(device)}
        out = ProbabilisticEnsemble.__new__(ProbabilisticEnsemble)
        out.__dict__.update(self.__dict__)
        out.device, out.dtype = kw["device"], dtype
        out._layers = [(w.to(**kw), b.to(**kw)) for w, b in self._layers]
        out._logvar_bounds = tuple(t.to(**kw) for t in self._logvar_bounds)
        for name in ("_z_mean", "_z_scale", "_y_mean", "_y_scale"):
            setattr(out, name, getattr(self, name).to(**kw))
        return out

    def member_moments(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Every member's Gaussian p_k(x_{t+1} | x_t, u_t) at every query.

        Parameters
        ----------
        x : Tensor, shape (n, n_x)
        u : Tensor, shape (n, n_u)
            On the model's device, in its dtype.

        Returns
        -------
        mean, var : Tensor, shape (K, n, n_x)
            Raw units; ``var`` is member k's noise variance σ_k².
        """
        self._check_fitted()
        z = self._standardized(x, u)
        mean, logvar = _forward(self._layers, self._logvar_bounds, z.expand(self.n_members, -1, -1))
        return self._raw(x, mean, logvar)

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor) -> Moments:
        """Row i's next-state Gaussian under member i mod K (TS-∞ sampling, module notes).

        The sampler's hot path: one batched product per layer, each member evaluated on its
        own rows only (rows i ≡ k mod K go to member k).

        Parameters
        ----------
        x : Tensor, shape (n, n_x)
        u : Tensor, shape (n, n_u)
            On the model's device, in its dtype (:meth:`to`).

        Returns
        -------
        Moments
            ``mean`` and ``var`` of shape (n, n_x) in raw units; no variance is ever
            clamped (``n_clamped`` and ``worst`` are 0).
        """
        self._check_fitted()
        K, n = self.n_members, x.shape[0]
        z = self._standardized(x, u)
        m = -(-n // K)  # rows per member
        if m * K > n:
            z = torch.cat([z, z.new_zeros((m * K - n, z.shape[1]))])
        zk = z.reshape(m, K, -1).transpose(0, 1)  # (K, m, D): member k gets rows k, k + K, …
        mean, logvar = _forward(self._layers, self._logvar_bounds, zk)
        E = mean.shape[-1]
        mean = mean.transpose(0, 1).reshape(m * K, E)[:n]
        logvar = logvar.transpose(0, 1).reshape(m * K, E)[:n]
        mean, var = self._raw(x, mean, logvar)
        return Moments(
            mean,
            var,
            torch.zeros((), dtype=torch.int64, device=x.device),
            torch.zeros((), dtype=x.dtype, device=x.device),
        )

    def predict(self, states, controls) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of the ensemble's predictive distribution, the equal-weight
        mixture (1/K) Σ_k N(μ_k, σ_k²), per dimension:

        .. math:: \\bar\\mu = \\frac{1}{K}\\sum_k \\mu_k, \\qquad
                  \\bar\\sigma^2 = \\frac{1}{K}\\sum_k \\sigma_k^2
                  + \\frac{1}{K}\\sum_k (\\mu_k - \\bar\\mu)^2

        (noise plus the members' disagreement).

        Parameters
        ----------
        states : array_like, shape (n, n_x)
        controls : array_like, shape (n, n_u)

        Returns
        -------
        mean, var : ndarray, shape (n, n_x)
        """
        self._check_fitted()
        x = check_array(states, "states", shape=(None, self.state_dim))
        u = check_array(controls, "controls", shape=(x.shape[0], self.control_dim))
        kw = {"dtype": self.dtype, "device": self.device}
        with torch.no_grad():
            mean, var = self.member_moments(torch.as_tensor(x, **kw), torch.as_tensor(u, **kw))
            mu = mean.mean(0)
            total = var.mean(0) + ((mean - mu) ** 2).mean(0)
        return (
            mu.cpu().numpy().astype(np.float64),
            total.cpu().numpy().astype(np.float64),
        )

    def _standardized(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return (torch.cat([x, u], dim=-1) - self._z_mean) / self._z_scale

    def _raw(self, x, mean, logvar) -> tuple[torch.Tensor, torch.Tensor]:
        """Standardised (mean, log-variance) of y → raw next-state mean and variance."""
        mean = self._y_mean + self._y_scale * mean
        if self.target == "delta":
            mean = x + mean
        return mean, self._y_scale**2 * torch.exp(logvar)

    def __repr__(self) -> str:
        st = self.settings
        head = (
            f"ProbabilisticEnsemble(members={st.n_members}, hidden={st.hidden_sizes}, "
            f"target={self.target!r}"
        )
        if self._layers is None:
            return head + ", unfitted)"
        return (
            f"{head}, state_dim={self.state_dim}, control_dim={self.control_dim}, "
            f"n_data={self.n_data}, train_loss={number(self.train_loss.mean())})"
        )


# --------------------------------------------------------------------------- pure functions
def _standardizer(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means and scales (the standard deviation; 1 for a constant column)."""
    mean, std = a.mean(0), a.std(0)
    constant = std <= 1e-12 * np.maximum(1.0, np.abs(mean))
    return mean, np.where(constant, 1.0, std)


def _init_layer(K: int, d_in: int, d_out: int, gen: torch.Generator, dtype, device) -> _Layer:
    """K independent layers, weights and biases uniform on ±1/√d_in (torch.nn.Linear's
    default), drawn from ``gen`` on the CPU in float64."""
    bound = 1.0 / math.sqrt(d_in)
    w = (2 * torch.rand((K, d_in, d_out), generator=gen, dtype=DTYPE) - 1) * bound
    b = (2 * torch.rand((K, 1, d_out), generator=gen, dtype=DTYPE) - 1) * bound
    return (
        w.to(dtype=dtype, device=device).requires_grad_(),
        b.to(dtype=dtype, device=device).requires_grad_(),
    )


def _forward(
    layers: list[_Layer], bounds: tuple[torch.Tensor, torch.Tensor], z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Members' standardised mean and bounded log-variance for inputs z (K, n, D) → (K, n, E)."""
    h = z
    for w, b in layers[:-1]:
        h = F.silu(torch.baddbmm(b, h, w))
    w, b = layers[-1]
    mean, raw = torch.baddbmm(b, h, w).chunk(2, dim=-1)
    lo, hi = bounds
    logvar = hi - F.softplus(hi - raw)
    return mean, lo + F.softplus(logvar - lo)


def _nll(mean: torch.Tensor, logvar: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """PETS's Gaussian loss per member, mean over rows and outputs of
    (y − μ)² e^{−log σ²} + log σ²; shapes (K, n, E) → (K,)."""
    return ((y - mean) ** 2 * torch.exp(-logvar) + logvar).mean(dim=(1, 2))
