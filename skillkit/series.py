"""What an experiment plots: :class:`Series` (stored in ``result.json``, format
``docs/formats.md``) and the bands over trials (:func:`mean_band`, :func:`trial_band`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["BAND_KINDS", "DASHES", "Series", "band_text", "mean_band", "trial_band"]

DASHES = ("solid", "dash", "dot", "dashdot")
"""Line styles of :attr:`Series.dash` (None is ``"solid"``)."""


@dataclass
class Series:
    """One plotted series.

    Attributes
    ----------
    name : str
        Legend label.
    x, y : list of float
        Coordinates (for a heatmap: the grid axes, values in ``z`` of shape (len(y), len(x))).
    panel : str
        Subplot (series of one panel share axes).
    kind : {"line", "markers", "lines+markers", "heatmap", "bar"}
    lower, upper, band : list of float, list of float, str, optional
        A band around ``y`` and what it is, in words (:func:`band_text`).
    xlabel, ylabel, log_x, log_y, zmin, zmax
        Axis labels, logarithmic axes and a heatmap's colour range.
    dash : {"dash", "dot", "dashdot"}, optional
        Line style (None: solid); ``"dash"`` marks a reference.
    """

    name: str
    x: list
    y: list
    panel: str = ""
    kind: str = "line"
    lower: list | None = None
    upper: list | None = None
    band: str | None = None
    z: list | None = None
    xlabel: str = ""
    ylabel: str = ""
    log_x: bool = False
    log_y: bool = False
    zmin: float | None = None
    zmax: float | None = None
    dash: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


def mean_band(curves: np.ndarray, kind: str = "std") -> tuple[list, list, list]:
    """Mean, lower and upper band (``kind`` "std" or "ci95", :data:`BAND_KINDS`) over curves
    of shape (n ≥ 1, n_points), as lists; at each point over the curves with a finite value
    (NaN where none has one), a single value giving a zero-width band."""
    curves = np.asarray(curves, dtype=float)
    if curves.ndim != 2 or curves.shape[0] < 1:
        raise ValueError(f"curves: expected shape (n >= 1, n_points), got {curves.shape}")
    if kind not in ("std", "ci95"):
        raise ValueError(
            f"kind: expected 'std' or 'ci95' (for 'gstd' see trial_band), got {kind!r}"
        )
    ok = np.isfinite(curves)
    k = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.where(ok, curves, 0.0).sum(axis=0) / k
        dev = np.where(ok, curves - m, 0.0)
        sd = np.where(k > 1, np.sqrt((dev * dev).sum(axis=0) / (k - 1)), 0.0)
    half = sd if kind == "std" else 1.96 * sd / np.sqrt(np.maximum(k, 1))
    return m.tolist(), (m - half).tolist(), (m + half).tolist()


BAND_KINDS = ("std", "ci95", "gstd")
"""Bands over repeated curves: ``"std"`` mean ± one standard deviation (ddof = 1), ``"ci95"``
the 95% interval of the mean (mean ± 1.96 std / √n, normal approximation), ``"gstd"`` the
geometric mean ×/÷ one geometric standard deviation (mean ± std of log10, for log axes)."""


def band_text(n: int, over: str = "trials", kind: str = "std") -> str:
    """What a band of ``kind`` over ``n`` ≥ 2 ``over`` is, e.g. ``"mean ± std over 20 trials"``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n: a band needs at least 2 curves, got {n!r}")
    if not isinstance(over, str) or not over:
        raise ValueError(f"over: expected a non-empty noun such as 'trials', got {over!r}")
    what = {
        "std": "mean ± std",
        "ci95": "95% interval of the mean",
        "gstd": "geometric mean ×/÷ geometric std",
    }
    if kind not in what:
        raise ValueError(f"kind: expected one of {BAND_KINDS}, got {kind!r}")
    return f"{what[kind]} over {int(n)} {over}"


def trial_band(curves, over: str = "trials", kind: str = "std") -> tuple[list, dict[str, Any]]:
    """Mean curve over curves (n, n_points) (geometric for ``kind="gstd"``) and the
    :class:`Series` keywords ``lower``, ``upper`` and ``band`` (none for a single curve)."""
    curves = np.asarray(curves, dtype=float)
    if curves.ndim != 2 or curves.shape[0] < 1:
        raise ValueError(f"curves: expected shape (n >= 1, n_points), got {curves.shape}")
    if kind not in BAND_KINDS:
        raise ValueError(f"kind: expected one of {BAND_KINDS}, got {kind!r}")
    if kind == "gstd":
        m, lo, hi = mean_band(np.log10(curves))
        m, lo, hi = [10**v for v in m], [10**v for v in lo], [10**v for v in hi]
    else:
        m, lo, hi = mean_band(curves, kind)
    n = curves.shape[0]
    if n == 1:
        return m, {}
    return m, {"lower": lo, "upper": hi, "band": band_text(n, over, kind)}
