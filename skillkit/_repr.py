"""Short summaries of arrays (or torch tensors, duck-typed) for ``__repr__``."""

from __future__ import annotations

import numpy as np

__all__ = ["number", "span", "vector"]


def _flat(values) -> np.ndarray:
    if hasattr(values, "detach"):  # a torch tensor
        values = values.detach().cpu().numpy()
    return np.asarray(values, dtype=np.float64).ravel()


def number(value, spec: str = ".3g") -> str:
    """One number, formatted with ``spec`` (``"nan"``/``"inf"`` as Python writes them)."""
    return format(float(value), spec)


def span(values, spec: str = ".3g") -> str:
    """``"lo…hi"`` of the finite values (one number if equal, ``"-"`` if none), plus
    ``" (k non-finite)"``."""
    x = _flat(values)
    finite = x[np.isfinite(x)]
    if finite.size == 0:
        text = "-"
    else:
        lo, hi = number(finite.min(), spec), number(finite.max(), spec)
        text = lo if lo == hi else f"{lo}…{hi}"
    bad = x.size - finite.size
    return text + (f" ({bad} non-finite)" if bad else "")


def vector(values, spec: str = ".3g", max_items: int = 4) -> str:
    """``"[a, b, c]"`` for at most ``max_items`` values, else their :func:`span` and count."""
    x = _flat(values)
    if x.size <= max_items:
        return "[" + ", ".join(number(v, spec) for v in x) + "]"
    return f"{span(x, spec)} ({x.size} values)"
