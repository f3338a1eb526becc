r"""A probabilistic ensemble of neural networks as a forward model (PETS, Chua et al. 2018).

K MLPs, each fitted on its own bootstrap resample with Adam on the Gaussian negative
log-likelihood, predict p_k(y | z) = N(μ_k(z), diag σ_k²(z)), z = [x_t, u_t], in
standardised units, the log-variance smoothly clamped to trained bounds (PETS, App. A.1).
Sampling is TS-∞ (PETS, Sec. 4.2): row i of a batch uses member i mod K throughout."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from skillkit._repr import number
from skillkit._validation import as_generator, check_count, check_positive, check_type
from skillkit.models.gp import DTYPE, Moments, TransitionModel, as_device, check_dtype

__all__ = ["LOGVAR_INIT", "LOGVAR_PENALTY", "EnsembleSettings", "ProbabilisticEnsemble"]

#: Initial (l_min, l_max) of the bounded log-variance, standardised units (PETS's values).
LOGVAR_INIT = (-10.0, 0.5)
#: Weight of Σ l_max − Σ l_min in the training loss (PETS's value).
LOGVAR_PENALTY = 0.01

_Layer = tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class EnsembleSettings:
    """Settings of :class:`ProbabilisticEnsemble`: SiLU ``hidden_sizes``, K = ``n_members``
    networks (PETS: 5), ``epochs`` over each resample, Adam's ``lr``, the coupled L2
    ``weight_decay`` on the weight matrices and ``batch_size`` transitions per minibatch."""

    hidden_sizes: tuple[int, ...] = (64, 64)
    n_members: int = 5
    epochs: int = 100
    lr: float = 1e-3
    weight_decay: float = 1e-4
    batch_size: int = 64

    def __post_init__(self) -> None:
        if not isinstance(self.hidden_sizes, tuple) or not self.hidden_sizes:
            raise ValueError(f"hidden_sizes: expected a non-empty tuple, got {self.hidden_sizes!r}")
        for h in self.hidden_sizes:
            check_count(h, "hidden_sizes")
        check_count(self.n_members, "n_members")
        check_count(self.epochs, "epochs")
        check_positive(self.lr, "lr")
        check_positive(self.weight_decay, "weight_decay", allow_zero=True)
        check_count(self.batch_size, "batch_size")


class ProbabilisticEnsemble(TransitionModel):
    """K bootstrap MLPs with Gaussian outputs: a forward model x_{t+1} ~ p(· | x_t, u_t).

    Usable wherever a GP forward model is sampled, e.g.
    ``TrajectoryRewardModel(task, make_model=ProbabilisticEnsemble)``.

    Parameters
    ----------
    settings : EnsembleSettings, optional
        Network and training settings (default ``EnsembleSettings()``).
    target : {"delta", "next"}, default "delta"
        Learn Δx (PETS) or x_{t+1}.
    device : str or torch.device, optional
    dtype : torch.float64 or torch.float32, default float64
    """

    def __init__(
        self,
        settings: EnsembleSettings | None = None,
        target: str = "delta",
        device=None,
        dtype: torch.dtype = DTYPE,
    ):
        settings = EnsembleSettings() if settings is None else settings
        check_type(settings, EnsembleSettings, "settings")
        super().__init__(target)
        check_dtype(dtype)
        self.settings = settings
        self.device = as_device(device)
        self.dtype = dtype
        self.state_dim = self.control_dim = self.n_data = 0
        #: Final training loss of each member on its resample (the loss ℓ_k, standardised
        #: units, without the penalties), shape (K,); None before :meth:`fit`.
        self.train_loss: np.ndarray | None = None
        self._layers: list[_Layer] | None = None
        self._logvar_bounds: tuple[torch.Tensor, torch.Tensor] | None = None
        self._z_mean = self._z_scale = self._y_mean = self._y_scale = None

    @property
    def n_members(self) -> int:
        return self.settings.n_members

    _min_rows = 2

    def _fit(self, x: np.ndarray, u: np.ndarray, xn: np.ndarray, rng) -> None:
        """Fit the members on bootstrap resamples (``rng``: resamples, weights, minibatches)."""
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

    def _check_fitted(self) -> None:
        if self._layers is None:
            raise RuntimeError("ProbabilisticEnsemble: call fit() first")

    def to(self, device=None, dtype: torch.dtype | None = None) -> ProbabilisticEnsemble:
        """A shallow copy predicting on ``device`` in ``dtype``."""
        self._check_fitted()
        dtype = self.dtype if dtype is None else check_dtype(dtype)
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
        """Every member's mean and noise variance at x (n, n_x), u (n, n_u): Tensors (K, n, n_x)."""
        self._check_fitted()
        z = self._standardized(x, u)
        mean, logvar = _forward(self._layers, self._logvar_bounds, z.expand(self.n_members, -1, -1))
        return self._raw(x, mean, logvar)

    def next_state_moments(self, x: torch.Tensor, u: torch.Tensor) -> Moments:
        """Row i's next-state :class:`Moments` under member i mod K (TS-∞)."""
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
        return Moments.exact(*self._raw(x, mean, logvar))

    def predict(self, states, controls) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance (n, n_x) of the equal-weight mixture (1/K) Σ_k N(μ_k, σ_k²): the mean
        of the σ_k² plus the variance of the μ_k."""
        self._check_fitted()
        x, u = self._queries(states, controls, self.dtype, self.device)
        with torch.no_grad():
            mean, var = self.member_moments(x, u)
            mu = mean.mean(0)
            total = var.mean(0) + ((mean - mu) ** 2).mean(0)
        return tuple(t.cpu().numpy().astype(np.float64) for t in (mu, total))

    def _standardized(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return (torch.cat([x, u], dim=-1) - self._z_mean) / self._z_scale

    def _raw(self, x, mean, logvar) -> tuple[torch.Tensor, torch.Tensor]:
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


def _standardizer(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means and scales (std; 1 for a constant column)."""
    mean, std = a.mean(0), a.std(0)
    constant = std <= 1e-12 * np.maximum(1.0, np.abs(mean))
    return mean, np.where(constant, 1.0, std)


def _init_layer(K: int, d_in: int, d_out: int, gen: torch.Generator, dtype, device) -> _Layer:
    """K layers uniform on ±1/√d_in (``torch.nn.Linear``'s), drawn in float64 on the CPU."""
    bound = 1.0 / math.sqrt(d_in)
    w = (2 * torch.rand((K, d_in, d_out), generator=gen, dtype=DTYPE) - 1) * bound
    b = (2 * torch.rand((K, 1, d_out), generator=gen, dtype=DTYPE) - 1) * bound
    return tuple(t.to(dtype=dtype, device=device).requires_grad_() for t in (w, b))


def _forward(
    layers: list[_Layer], bounds: tuple[torch.Tensor, torch.Tensor], z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Members' standardised mean and bounded log-variance: (K, n, D) → (K, n, E)."""
    h = z
    for w, b in layers[:-1]:
        h = F.silu(torch.baddbmm(b, h, w))
    w, b = layers[-1]
    mean, raw = torch.baddbmm(b, h, w).chunk(2, dim=-1)
    lo, hi = bounds
    logvar = hi - F.softplus(hi - raw)
    return mean, lo + F.softplus(logvar - lo)


def _nll(mean: torch.Tensor, logvar: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """PETS's Gaussian loss per member: (K, n, E) → (K,)."""
    return ((y - mean) ** 2 * torch.exp(-logvar) + logvar).mean(dim=(1, 2))
