"""Input normalisation shared by every entry point: random generators and array checks.

Every public function that takes randomness takes ``rng`` (a :class:`numpy.random.Generator`,
an ``int`` seed, a :class:`numpy.random.SeedSequence` or ``None``) and normalises it here, in
one place. Array checks raise :class:`ValueError` naming the offending argument.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def as_generator(
    rng: np.random.Generator | np.random.SeedSequence | int | None,
) -> np.random.Generator:
    """Return a :class:`numpy.random.Generator` for ``rng``.

    Parameters
    ----------
    rng : Generator, SeedSequence, int or None
        A generator is returned unchanged (so callers share its stream); an int or a
        SeedSequence seeds a new PCG64 generator; None draws fresh OS entropy.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng < 0:
            raise ValueError(f"rng: a seed must be a non-negative integer, got {rng}")
        return np.random.default_rng(int(rng))
    raise ValueError(
        "rng: expected a numpy Generator, SeedSequence, non-negative int or None, "
        f"got {type(rng).__name__}"
    )


def spawn_seeds(seed: int | None, n: int) -> list[np.random.SeedSequence]:
    """Independent child seed sequences, one per trial (same ``seed`` ⇒ same children)."""
    return np.random.SeedSequence(seed).spawn(n)


def check_array(
    value,
    name: str,
    *,
    ndim: int | Sequence[int] | None = None,
    shape: tuple[int | None, ...] | None = None,
    finite: bool = True,
    dtype=np.float64,
) -> np.ndarray:
    """Convert ``value`` to an array and validate it, raising ``ValueError`` that names ``name``.

    Parameters
    ----------
    value : array_like
        The input.
    name : str
        Argument name used in error messages.
    ndim : int or sequence of int, optional
        Allowed numbers of dimensions.
    shape : tuple, optional
        Expected shape; ``None`` entries match any size.
    finite : bool
        Reject NaN and infinity.
    dtype : numpy dtype
        Target dtype (float64 by default). A complex numpy array is refused for a real
        target (rather than losing its imaginary part).
    """
    if (
        isinstance(value, (np.ndarray, np.generic))
        and np.iscomplexobj(value)
        and dtype is not None
        and not np.issubdtype(np.dtype(dtype), np.complexfloating)
    ):  # numpy would only warn and drop the imaginary part
        raise ValueError(
            f"{name}: expected real numbers, got a complex array (dtype {value.dtype})"
        )
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name}: could not convert to a {np.dtype(dtype).name} array ({exc})"
        ) from None
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise ValueError(
                f"{name}: expected {' or '.join(map(str, allowed))} dimensions, "
                f"got shape {arr.shape}"
            )
    if shape is not None:
        if arr.ndim != len(shape) or any(
            s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)
        ):
            dims = ["?" if s is None else str(s) for s in shape]
            expected = "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"
            raise ValueError(f"{name}: expected shape {expected}, got {arr.shape}")
    if finite and arr.size and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name}: contains {bad} non-finite value(s) (NaN or inf)")
    return arr


def check_count(value, name: str = "n", minimum: int = 1) -> int:
    """An integer count ≥ ``minimum`` (an int or numpy integer, not a bool), or a
    ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: expected an integer ≥ {minimum}, got {value!r}")
    return int(value)


def check_positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    """Validate a positive finite scalar, raising ``ValueError`` that names ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a real number, got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name}: expected a finite number {bound}, got {value!r}")
    return v
