"""Context features φ(s) for linear-Gaussian upper-level policies and the REPS baseline.

Two feature maps, selected by name:

* ``"linear"``: φ(s) = s, so the policy mean a + Aφ(s) is affine in the context (Eq. 3.13)
  and the REPS constraint (3.5) matches the context mean.
* ``"quadratic"``: φ(s) = [s, upper triangle of s sᵀ (diagonal included)], so the REPS
  constraint (3.5) matches the mean and the second moments of μ(s) (Sec. 3.2).

Neither map contains a constant: the policy keeps its offset ``a`` separately, and a constant
feature would leave the REPS dual (3.9) with a flat direction (the baseline is defined only up to
a constant there).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from skillkit._validation import check_array

FeatureName = Literal["linear", "quadratic"]
FEATURES: tuple[str, ...] = ("linear", "quadratic")


def check_feature_name(name: str, argname: str = "features") -> str:
    """Return ``name`` if it names a feature map, else raise ``ValueError`` naming ``argname``."""
    if name not in FEATURES:
        raise ValueError(f"{argname}: expected one of {FEATURES}, got {name!r}")
    return name


def feature_dim(context_dim: int, name: FeatureName = "linear") -> int:
    """Number of features F of the map ``name`` for contexts of dimension ``context_dim``.

    ``linear``: F = n; ``quadratic``: F = n + n(n+1)/2.
    """
    check_feature_name(name)
    if (
        isinstance(context_dim, bool)
        or not isinstance(context_dim, (int, np.integer))
        or context_dim < 0
    ):
        raise ValueError(f"context_dim: expected a non-negative integer, got {context_dim!r}")
    n = int(context_dim)
    return n if name == "linear" else n + n * (n + 1) // 2


def context_features(
    contexts, name: FeatureName = "linear", context_dim: int | None = None
) -> np.ndarray:
    """Evaluate the feature map φ(s).

    Parameters
    ----------
    contexts : array_like, shape (n, context_dim) or (context_dim,)
        Contexts s, one per row (a single context may be given as a vector).
    name : {"linear", "quadratic"}
        The feature map.
    context_dim : int, optional
        Expected context dimension; checked when given.

    Returns
    -------
    ndarray, shape (n, F) or (F,)
        φ(s) per row; F = :func:`feature_dim` (context_dim, name). For ``"quadratic"`` the
        columns are s_1..s_n followed by s_i s_j for i ≤ j in row-major order.
    """
    check_feature_name(name)
    s = check_array(contexts, "contexts", ndim=(1, 2))
    single = s.ndim == 1
    s2 = s[None, :] if single else s
    if context_dim is not None and s2.shape[1] != context_dim:
        expected = f"({context_dim},)" if single else f"(n, {context_dim})"
        raise ValueError(f"contexts: expected shape {expected}, got {s.shape}")
    if name == "linear":
        phi = s2.copy()
    else:
        iu, ju = np.triu_indices(s2.shape[1])
        phi = np.concatenate([s2, s2[:, iu] * s2[:, ju]], axis=1)
    return phi[0] if single else phi
