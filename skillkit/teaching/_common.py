"""Helpers the chapter modules share: sizes per scale, rounding for tables, drawing a list of
series, and argument checks."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from skillkit._validation import check_choice
from skillkit.experiments.registry import SCALES
from skillkit.viz.figures import draw  # noqa: F401  (the chapters draw with it)


def per_scale(cls, **columns: tuple) -> dict:
    """``{scale: cls(**sizes)}`` from columns field → (smoke, quick, paper)."""
    return {s: cls(**{k: v[i] for k, v in columns.items()}) for i, s in enumerate(SCALES)}


def at_scale(table: Mapping, scale: str):
    """``table[scale]``, or a ``ValueError`` naming ``scale``."""
    return table[check_choice(scale, "scale", tuple(table))]


def sig(value: float, digits: int = 4) -> float:
    """``value`` rounded to ``digits`` significant digits (for tables)."""
    return float(f"{float(value):.{digits}g}")


def xy(points: np.ndarray) -> tuple[list, list]:
    """The columns of ``points`` (n, 2) as two lists."""
    return points[:, 0].tolist(), points[:, 1].tolist()


def index(value, name: str, n: int) -> int:
    """An integer in [0, n), or a ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < n:
        raise ValueError(f"{name}: expected an integer in [0, {n}), got {value!r}")
    return int(value)


def index_pair(value, name: str, n: int, what: str) -> tuple[int, int]:
    """Two different integers in [0, n), or a ``ValueError`` naming ``name``."""
    ok = (
        isinstance(value, (tuple, list))
        and len(value) == 2
        and all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in value)
        and all(0 <= i < n for i in value)
        and value[0] != value[1]
    )
    if not ok:
        raise ValueError(f"{name}: expected two different {what} in [0, {n}), got {value!r}")
    return int(value[0]), int(value[1])
