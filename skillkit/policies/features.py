"""Context features φ(s) for linear-Gaussian upper-level policies and the REPS baseline.

``"linear"``: φ(s) = s (Eq. 3.13); ``"quadratic"``: φ(s) = [s, s_i s_j for i ≤ j], so the
REPS constraint (3.5) also matches second moments (Sec. 3.2). Neither has a constant: the
policy keeps its offset, and a constant would leave the REPS dual (3.9) a flat direction."""

from __future__ import annotations

from typing import Literal

import numpy as np

from skillkit._validation import check_array, check_choice, check_count

FeatureName = Literal["linear", "quadratic"]
FEATURES: tuple[str, ...] = ("linear", "quadratic")


def check_feature_name(name: str, argname: str = "features") -> str:
    """``name`` if it names a feature map, else a ``ValueError`` naming ``argname``."""
    return check_choice(name, argname, FEATURES)


def feature_dim(context_dim: int, name: FeatureName = "linear") -> int:
    """Number of features F of the map ``name`` for contexts of dimension n = ``context_dim`` ≥ 0:
    n (linear) or n + n(n+1)/2 (quadratic); ``ValueError`` on a bad ``name`` or ``context_dim``."""
    check_feature_name(name)
    n = check_count(context_dim, "context_dim", 0)
    return n if name == "linear" else n + n * (n + 1) // 2


def context_features(contexts, name: FeatureName = "linear") -> np.ndarray:
    """Context features φ(s) of contexts (n, context_dim) or (context_dim,): shape (n, F), or (F,)
    for one context. Quadratic products s_i s_j (i ≤ j) follow s in row-major order."""
    check_feature_name(name)
    s = check_array(contexts, "contexts", ndim=(1, 2))
    single = s.ndim == 1
    s2 = s[None, :] if single else s
    if name == "linear":
        phi = s2.copy()
    else:
        iu, ju = np.triu_indices(s2.shape[1])
        phi = np.concatenate([s2, s2[:, iu] * s2[:, ju]], axis=1)
    return phi[0] if single else phi
