"""Input normalisation shared by every entry point: random generators and array checks.

Array checks raise :class:`ValueError` naming the offending argument.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def as_generator(
    rng: np.random.Generator | np.random.SeedSequence | int | None,
) -> np.random.Generator:
    """A :class:`numpy.random.Generator` for ``rng``: a generator unchanged (sharing its
    stream), an int ≥ 0 or a SeedSequence seeding a new PCG64, None fresh OS entropy."""
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


def check_array(
    value,
    name: str,
    *,
    ndim: int | Sequence[int] | None = None,
    shape: tuple[int | None, ...] | None = None,
    finite: bool = True,
    dtype=np.float64,
) -> np.ndarray:
    """Convert ``value`` to a ``dtype`` array and validate it (``ValueError`` naming ``name``).

    ``ndim``: allowed numbers of dimensions; ``shape``: expected shape (``None`` entries match
    any size); ``finite``: reject NaN and infinity. A complex array is refused for a real dtype.
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
    """An integer count ≥ ``minimum`` (not a bool), else ``ValueError`` naming ``name``."""
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


def check_choice(value, name: str, choices: Sequence):
    """``value`` if it is one of ``choices``, else a ``ValueError`` naming ``name``."""
    if value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_type(value, cls, name: str, what: str = ""):
    """``value`` if it is a ``cls`` (a class or tuple of classes), else a ``ValueError`` naming
    ``name`` and what was expected (``what``, default the class name)."""
    if not isinstance(value, cls):
        raise ValueError(f"{name}: expected {what or cls.__name__}, got {type(value).__name__}")
    return value
