"""Conditional mean embeddings of distributions in an RKHS (thesis Secs. 2.4 and 5.1).

Notation follows the thesis. Training pairs :math:`\\{(z_i, y_i)\\}_{i=1}^N`, an input kernel
``g`` (``k`` in Sec. 2.4) with Gram matrix :math:`G_{ij} = g(z_i, z_j)` and a regulariser
:math:`\\lambda > 0` define the empirical conditional embedding operator (Eq. 2.38)

.. math:: \\hat{\\mathcal C}_{y|z} = \\Phi_y (G + \\lambda I)^{-1} \\Phi_z^\\top .

Every embedding over the training targets is a weight vector :math:`\\beta` with
:math:`\\mu_y = \\Phi_y \\beta` (Eq. 2.40). Weights are column vectors, as in the thesis:
shape ``(N,)`` for one embedding and ``(N, B)`` for a batch of ``B`` embeddings.

The module has two layers:

* pure torch functions (:func:`regularized_cholesky`, :func:`conditional_weights`,
  :func:`initial_weights`, :func:`rollout_weights`) that hold the linear algebra once; the
  prediction code and the differentiable training objectives of
  :mod:`skillkit.models.embedding_training` both use them;
* :class:`ConditionalEmbedding`, a fitted operator with a numpy interface: weights for
  deterministic queries (Eq. 2.39) and for sample-represented distributions (Eqs. 5.6–5.7),
  composition with another operator (Eq. 2.42), expected function values (Eq. 2.43) and
  pre-image decoding (Eqs. 2.44–2.45, fixed-point iteration for SE kernels).

Kernels are the shared ones of :mod:`skillkit.models.kernels`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import gpytorch
import numpy as np
import torch

from skillkit._repr import number, span
from skillkit._validation import check_array, check_count, check_positive
from skillkit.models.kernels import Linear, SquaredExponential, gram

__all__ = [
    "ConditionalEmbedding",
    "conditional_weights",
    "initial_weights",
    "regularized_cholesky",
    "rkhs_expectation",
    "rollout_weights",
]

Transition = torch.Tensor | Callable[[int], torch.Tensor]


# --------------------------------------------------------------------------- pure torch core
def regularized_cholesky(gram_matrix: torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Lower Cholesky factor of :math:`G + \\lambda I` (the matrix inverted in Eq. 2.38).

    Parameters
    ----------
    gram_matrix : Tensor, shape (N, N)
        Symmetric positive semi-definite Gram matrix G.
    lam : float or Tensor (scalar)
        Regulariser λ > 0 (a tensor may carry gradients).

    Returns
    -------
    Tensor, shape (N, N)

    Raises
    ------
    numpy.linalg.LinAlgError
        If :math:`G + \\lambda I` is not numerically positive definite (λ too small for the
        round-off in G); the message names ``lam``.
    """
    n = gram_matrix.shape[-1]
    eye = torch.eye(n, dtype=gram_matrix.dtype, device=gram_matrix.device)
    chol, info = torch.linalg.cholesky_ex(gram_matrix + lam * eye)
    if int(info.max()) > 0:
        lam_v = float(lam.detach()) if isinstance(lam, torch.Tensor) else float(lam)
        raise np.linalg.LinAlgError(
            f"lam: G + λI is not numerically positive definite at λ={lam_v:.3g} (N={n}); "
            "increase lam"
        )
    return chol


def conditional_weights(chol: torch.Tensor, cross: torch.Tensor) -> torch.Tensor:
    """Embedding weights :math:`\\beta = (G + \\lambda I)^{-1} g` (Eqs. 2.39, 5.6, 5.7).

    Parameters
    ----------
    chol : Tensor, shape (N, N)
        :func:`regularized_cholesky` of G.
    cross : Tensor, shape (..., N, B)
        Kernel values between the training inputs and the query (for Eq. 5.6: the average
        over the query samples; for Eq. 2.42: :math:`\\tilde G \\alpha`).

    Returns
    -------
    Tensor, shape (..., N, B)
    """
    return torch.cholesky_solve(cross, chol)


def initial_weights(
    chol: torch.Tensor, gram_matrix: torch.Tensor, mean_cross: torch.Tensor, project: bool = True
) -> torch.Tensor:
    """Weights of the first predicted state embedding, Eqs. (5.6) and (5.9).

    The initial distribution, given by samples z_l, is embedded over the observed inputs,
    :math:`\\mu_{z_1} = \\Phi_z \\alpha` with :math:`\\alpha = (G + \\lambda I)^{-1}
    \\langle g(z_l) \\rangle_l` (Eq. 5.6); the dynamics operator maps it to the embedding of
    the successor over the observed successors (Eq. 5.9),

    .. math:: \\mu_{x_2} = \\Phi_{x'} (G + \\lambda I)^{-1} G \\alpha = \\Phi_{x'} \\beta.

    With ``project=False`` the operator is applied to the query features themselves,
    :math:`\\beta = (G + \\lambda I)^{-1} \\langle g(z_l) \\rangle_l` (Eq. 5.7, the
    regression read-out); the two agree as λ → 0 ("β₂ = β₁ for sufficiently small λ").

    Parameters
    ----------
    chol : Tensor, shape (N, N)
        :func:`regularized_cholesky` of G.
    gram_matrix : Tensor, shape (N, N)
        G over the observed inputs (used only with ``project``).
    mean_cross : Tensor, shape (N, B)
        :math:`\\langle g(z_i, z_l) \\rangle_l` per initial distribution (column).
    project : bool
        Apply Eq. (5.9)'s :math:`(G + \\lambda I)^{-1} G` to the Eq. (5.6) weights.

    Returns
    -------
    Tensor, shape (N, B)
    """
    alpha = conditional_weights(chol, mean_cross)
    if not project:
        return alpha
    return conditional_weights(chol, gram_matrix @ alpha)


def rollout_weights(
    chol: torch.Tensor, beta1: torch.Tensor, transition: Transition, n_steps: int
) -> torch.Tensor:
    """Propagate embedding weights through time, Eqs. (5.11) and (5.14).

    .. math:: \\beta_{t+1} = (G + \\lambda I)^{-1} \\tilde G_t \\beta_t,
              \\qquad \\tilde G_t = \\Phi_z^\\top \\Phi_{z_t^\\pi},

    where :math:`\\Phi_{z_t^\\pi}` are the features of the points over which the current
    embedding is expressed (the observed successor states ``X'`` for a fixed policy, Table
    5.1; ``[X', π(X', t)]`` for an arbitrary policy, Table 5.2).

    Parameters
    ----------
    chol : Tensor, shape (N, N)
        :func:`regularized_cholesky` of G.
    beta1 : Tensor, shape (N, B)
        Weights of the first predicted embedding.
    transition : Tensor or callable
        :math:`\\tilde G_t`: a tensor of shape (N, N) shared by the whole batch, or
        (B, N, N) with one matrix per batch column (one policy per query), used at every
        step; or a callable ``t -> tensor`` (t = 1, …, n_steps − 1) for time-dependent
        policies, returning the matrix that maps β_t to β_{t+1}.
    n_steps : int
        Number of weight vectors to return (β_1, …, β_{n_steps}), ≥ 1.

    Returns
    -------
    Tensor, shape (n_steps, N, B)
    """
    n_steps = check_count(n_steps, "n_steps")
    betas = [beta1]
    beta = beta1
    for t in range(1, n_steps):
        g_t = transition(t) if callable(transition) else transition
        if g_t.ndim == 2:
            v = g_t @ beta
        elif g_t.ndim == 3:
            v = torch.einsum("bij,jb->ib", g_t, beta)
        else:
            raise ValueError(
                f"transition: expected shape (N, N) or (B, N, N), got {tuple(g_t.shape)}"
            )
        beta = conditional_weights(chol, v)
        betas.append(beta)
    return torch.stack(betas)


def rkhs_expectation(beta, alpha, gram_matrix) -> np.ndarray:
    """Expected value of an RKHS function under an embedding, Eq. (2.43).

    For :math:`f = \\Phi_x \\alpha` and :math:`\\mu = \\Phi_x \\beta`,
    :math:`\\mathbb E[f] = \\langle f, \\mu \\rangle = \\beta^\\top K \\alpha`.

    Parameters
    ----------
    beta : array_like, shape (N,) or (N, B)
    alpha : array_like, shape (N,)
    gram_matrix : array_like, shape (N, N)
        K over the points both expansions use.

    Returns
    -------
    ndarray, shape () or (B,)
    """
    k = check_array(gram_matrix, "gram_matrix", ndim=2)
    n = k.shape[0]
    if k.shape != (n, n):
        raise ValueError(f"gram_matrix: expected a square matrix, got shape {k.shape}")
    a = check_array(alpha, "alpha", shape=(n,))
    b = check_array(beta, "beta", ndim=(1, 2))
    if b.shape[0] != n:
        raise ValueError(f"beta: expected {n} rows like gram_matrix, got shape {b.shape}")
    return b.T @ (k @ a)


# --------------------------------------------------------------------------- fitted operator
class ConditionalEmbedding:
    """Empirical conditional mean embedding :math:`\\mu_{y|z} = \\Phi_y (G+\\lambda I)^{-1} g(z)`.

    Fitted on pairs :math:`\\{(z_i, y_i)\\}` (Eqs. 2.38–2.40, 5.2–5.8). For dynamics, ``z`` is
    the state (fixed policy, Table 5.1) or the state-action ``[x, u]`` (Table 5.2) and ``y``
    the successor state ``x'``.

    Parameters
    ----------
    inputs : array_like, shape (N, d_z)
        Training inputs z_i.
    targets : array_like, shape (N, d_y)
        Training targets y_i.
    kernel : gpytorch Kernel
        Input kernel g (e.g. :class:`~skillkit.models.kernels.SquaredExponential`).
    lam : float
        Regulariser λ > 0.
    target_kernel : gpytorch Kernel, optional
        Kernel of the target features φ(y), used only by :meth:`preimage`. Defaults to
        ``kernel`` when targets and inputs have the same dimension (state → successor state).
    """

    def __init__(
        self,
        inputs,
        targets,
        kernel: gpytorch.kernels.Kernel,
        lam: float = 1e-3,
        target_kernel: gpytorch.kernels.Kernel | None = None,
    ):
        z = check_array(inputs, "inputs", ndim=2)
        y = check_array(targets, "targets", ndim=2)
        if y.shape[0] != z.shape[0]:
            raise ValueError(
                f"targets: expected {z.shape[0]} rows like inputs, got shape {y.shape}"
            )
        if z.shape[0] < 1:
            raise ValueError("inputs: expected at least one training pair, got none")
        self.lam = check_positive(lam, "lam")
        self.kernel = kernel
        if target_kernel is None and y.shape[1] == z.shape[1]:
            target_kernel = kernel
        self.target_kernel = target_kernel
        self.inputs = z
        self.targets = y
        self.gram = gram(kernel, z)
        self._z = torch.from_numpy(z)
        self._chol = regularized_cholesky(torch.from_numpy(self.gram), self.lam)

    def __repr__(self) -> str:
        kern = type(self.kernel).__name__
        ls = getattr(self.kernel, "lengthscale", None)
        if ls is not None:
            kern += f"(lengthscale={span(ls)})"
        return (
            f"ConditionalEmbedding(N={self.n}, input_dim={self.input_dim}, "
            f"target_dim={self.target_dim}, lam={number(self.lam)}, kernel={kern})"
        )

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of training pairs N."""
        return self.inputs.shape[0]

    @property
    def input_dim(self) -> int:
        return self.inputs.shape[1]

    @property
    def target_dim(self) -> int:
        return self.targets.shape[1]

    # ------------------------------------------------------------------ torch level
    @property
    def chol(self) -> torch.Tensor:
        """Cholesky factor of G + λI, shape (N, N)."""
        return self._chol

    def cross_kernel(self, points: torch.Tensor) -> torch.Tensor:
        """Kernel values g(z_i, p) between the training inputs and ``points``.

        Parameters
        ----------
        points : Tensor, shape (M, d_z) or (B, M, d_z)

        Returns
        -------
        Tensor, shape (N, M) or (B, N, M)
        """
        if points.shape[-1] != self.input_dim:
            raise ValueError(
                f"points: expected {self.input_dim} columns like the training inputs, "
                f"got shape {tuple(points.shape)}"
            )
        with torch.no_grad():
            return self.kernel.forward(self._z, points.to(torch.float64))

    # ------------------------------------------------------------------ weights
    def _points(self, value, name: str, ndim) -> np.ndarray:
        arr = check_array(value, name, ndim=ndim)
        if arr.shape[-1] != self.input_dim:
            raise ValueError(
                f"{name}: expected {self.input_dim} columns like the training inputs, "
                f"got shape {arr.shape}"
            )
        return arr

    def weights(self, queries) -> np.ndarray:
        """Weights of :math:`\\mu_{y|z_*}` for deterministic queries, Eqs. (2.39)–(2.40).

        Parameters
        ----------
        queries : array_like, shape (B, d_z)

        Returns
        -------
        ndarray, shape (N, B)
            Column b is :math:`(G + \\lambda I)^{-1} g(z_{*b})`.
        """
        q = torch.from_numpy(self._points(queries, "queries", 2))
        return conditional_weights(self._chol, self.cross_kernel(q)).numpy()

    def weights_from_samples(self, samples) -> np.ndarray:
        """Weights of :math:`\\mu_y^q` for inputs distributed as samples of q, Eqs. (5.6)–(5.7).

        .. math:: \\beta = (G + \\lambda I)^{-1} \\langle g(z_l^*) \\rangle_{l=1:L}

        Parameters
        ----------
        samples : array_like, shape (L, d_z) or (B, L, d_z)
            L samples of one input distribution, or of each of B distributions.

        Returns
        -------
        ndarray, shape (N,) or (N, B)
        """
        s = self._points(samples, "samples", (2, 3))
        single = s.ndim == 2
        st = torch.from_numpy(s[None] if single else s)  # (B, L, d)
        mean_k = self.cross_kernel(st).mean(-1).T  # (N, B)
        beta = conditional_weights(self._chol, mean_k).numpy()
        return beta[:, 0] if single else beta

    def operator(self, basis) -> np.ndarray:
        """The matrix :math:`C = (G + \\lambda I)^{-1} \\tilde G` of Table 5.1 / Eq. (2.42).

        Applied to the weights α of an embedding :math:`\\Phi_{\\text{basis}} \\alpha` it gives
        the weights (over this operator's targets) of the conditional's embedding.

        Parameters
        ----------
        basis : array_like, shape (M, d_z)
            Points over which the incoming embedding is expressed (:math:`\\tilde G_{ij} =
            g(z_i, \\text{basis}_j)`).

        Returns
        -------
        ndarray, shape (N, M)
        """
        b = torch.from_numpy(self._points(basis, "basis", 2))
        return conditional_weights(self._chol, self.cross_kernel(b)).numpy()

    def apply(self, alpha, basis) -> np.ndarray:
        """Compose this operator with an embedding :math:`\\Phi_{\\text{basis}}\\alpha`, Eq. (2.42).

        .. math:: \\hat\\mu_y^q = \\Phi_y (G + \\lambda I)^{-1} \\tilde G \\alpha

        Parameters
        ----------
        alpha : array_like, shape (M,) or (M, B)
        basis : array_like, shape (M, d_z)

        Returns
        -------
        ndarray, shape (N,) or (N, B)
        """
        b = self._points(basis, "basis", 2)
        a = check_array(alpha, "alpha", ndim=(1, 2))
        if a.shape[0] != b.shape[0]:
            raise ValueError(f"alpha: expected {b.shape[0]} rows like basis, got shape {a.shape}")
        g = self.cross_kernel(torch.from_numpy(b))
        at = torch.from_numpy(a.reshape(a.shape[0], -1))
        out = conditional_weights(self._chol, g @ at).numpy()
        return out[:, 0] if a.ndim == 1 else out

    # ------------------------------------------------------------------ read-outs
    def _beta(self, beta) -> np.ndarray:
        b = check_array(beta, "beta", ndim=(1, 2))
        if b.shape[0] != self.n:
            raise ValueError(
                f"beta: expected {self.n} rows (one per training pair), got shape {b.shape}"
            )
        return b

    def expected(self, values, beta) -> np.ndarray:
        """Expected value of a function known at the training targets: :math:`f'^\\top \\beta`.

        With a linear kernel on the function values (e.g. immediate rewards r'_i of the
        observed successors, Sec. 5.4) this is the exact read-out :math:`\\mathbb E[f] =
        \\langle \\Phi_f \\beta \\rangle`, e.g. :math:`\\mathbb E[r_t] = r'^\\top \\beta_t`.

        Parameters
        ----------
        values : array_like, shape (N,) or (N, k)
            f(y_i) at the training targets.
        beta : array_like, shape (N,) or (N, B)

        Returns
        -------
        ndarray, shape (), (B,), (k,) or (B, k)
        """
        b = self._beta(beta)
        v = check_array(values, "values", ndim=(1, 2))
        if v.shape[0] != self.n:
            raise ValueError(
                f"values: expected {self.n} rows (one per training pair), got shape {v.shape}"
            )
        return b.T @ v

    def mean(self, beta) -> np.ndarray:
        """Expected target under the embedding, :math:`Y^\\top \\beta` (linear read-out).

        Parameters
        ----------
        beta : array_like, shape (N,) or (N, B)

        Returns
        -------
        ndarray, shape (d_y,) or (B, d_y)
        """
        return self.expected(self.targets, beta)

    def preimage(self, beta, max_iter: int = 200, tol: float = 1e-10) -> np.ndarray:
        """Most likely target for an embedding :math:`\\Phi_y \\beta`, Eqs. (2.44)–(2.45).

        .. math:: y_* = \\arg\\min_y\\; k(y, y) - 2 \\beta^\\top k_Y(y)

        * Linear target kernel :math:`k(y, y') = \\sigma^2 y^\\top y' + c`: the closed form
          :math:`y_* = Y^\\top \\beta`.
        * SE target kernel (k(y, y) constant): the fixed-point iteration of the stationarity
          condition, started at the training target with the highest score
          :math:`\\beta^\\top k_Y(y_j)`, written as a mean shift
          :math:`y \\leftarrow y + \\sum_i w_i (y_i - y) / \\sum_i w_i`,
          :math:`w_i = \\beta_i k(y, y_i)`, so a one-hot β returns its training target
          exactly. If the local weight mass :math:`\\sum_i w_i` is not positive (negative
          weights dominate) or the iteration does not converge, the best iterate is returned
          and a ``RuntimeWarning`` says for how many columns.

        Parameters
        ----------
        beta : array_like, shape (N,) or (N, B)
        max_iter : int
            Fixed-point iterations (SE kernel).
        tol : float
            Convergence threshold on the step, relative to 1 + |y|.

        Returns
        -------
        ndarray, shape (d_y,) or (B, d_y)
        """
        b = self._beta(beta)
        kern = self.target_kernel
        if kern is None:
            raise ValueError(
                "target_kernel: a target kernel is needed for pre-images when "
                "targets and inputs differ in dimension"
            )
        if isinstance(kern, Linear):
            return self.mean(b)
        if not isinstance(kern, SquaredExponential):
            raise ValueError(
                "target_kernel: pre-images are implemented for SquaredExponential "
                f"and Linear kernels, got {type(kern).__name__}"
            )
        single = b.ndim == 1
        x, ok = _se_preimage(self.targets, b.reshape(self.n, -1), kern, int(max_iter), float(tol))
        if not np.all(ok):
            warnings.warn(
                f"preimage: fixed-point iteration stopped early for {int(np.sum(~ok))} "
                f"of {ok.size} embedding(s) (non-positive local weight mass or no "
                "convergence); returned the best iterate",
                RuntimeWarning,
                stacklevel=2,
            )
        return x[0] if single else x


def _se_preimage(
    y: np.ndarray, beta: np.ndarray, kern: SquaredExponential, max_iter: int, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-point pre-image for an SE kernel; returns (points (B, d), converged (B,)).

    The score β^T k_Y(y) equals the local weight mass Σ_i w_i, so it is tracked for free.
    The step Σ_i w_i (y_i − y) / Σ_i w_i is evaluated as (w Y − (Σ_i w_i) y) / Σ_i w_i, which
    is exactly 0 for a one-hot β at its training point; only unfinished columns are iterated.
    """
    yt = torch.from_numpy(y)
    bt = torch.from_numpy(beta).T.contiguous()  # (B, N)
    with torch.no_grad():
        scores = bt @ kern.forward(yt, yt)  # (B, N): β^T k_Y(y_j)
        best_score, start = scores.max(dim=1)
        best = yt[start].clone()  # (B, d)
        converged = torch.zeros(best.shape[0], dtype=torch.bool)
        idx = torch.arange(best.shape[0])  # unfinished columns
        x = best.clone()
        for _ in range(max_iter):
            w = kern.forward(x, yt) * bt[idx]  # β_i k(y, y_i)
            mass = w.sum(dim=1)  # = score at x
            better = mass >= best_score[idx]
            best[idx[better]] = x[better]
            best_score[idx[better]] = mass[better]
            ok = mass > 0  # else: stop, keep the best
            idx, x, w, mass = idx[ok], x[ok], w[ok], mass[ok]
            if idx.numel() == 0:
                break
            step = (w @ yt - mass[:, None] * x) / mass[:, None]
            done = step.norm(dim=1) <= tol * (1.0 + x.norm(dim=1))
            converged[idx[done]] = True
            keep = ~done
            idx, x = idx[keep], (x + step)[keep]
            if idx.numel() == 0:
                break
    return best.numpy(), converged.numpy()
