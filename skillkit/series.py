"""What an experiment measures and plots: :class:`Series` (one named curve, band, heatmap or
bar set of a figure panel), :func:`mean_band` (mean and band over trials), :func:`trial_band`
(the same with the band's meaning in words, for ``Series.band``) and :func:`band_text`.

Experiments build series in ``summarize`` and store them in ``result.json``
(``Series.to_dict``); the figures in :mod:`skillkit.viz.plots` draw them. The numbers computed
here are stored numbers, so this module is part of every experiment's code fingerprint
(:mod:`skillkit.experiments.provenance`); it sits at the bottom of the layers so that both the
experiments and the figures can import it. The format is documented in ``docs/formats.md``.
"""

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
        Coordinates (for ``kind="heatmap"``: the grid axes, with values in ``z``).
    panel : str
        Subplot the series belongs to (series with the same panel share axes).
    kind : {"line", "markers", "lines+markers", "heatmap", "bar"}
        How to draw it.
    lower, upper : list of float, optional
        A band around ``y`` (e.g. mean ± std or a 95% interval).
    band : str, optional
        What the band is, in words (e.g. ``"mean ± std over 20 trials"``, ``"95% interval of
        the mean"``); figures show it in the legend. None: the band is drawn unlabelled.
    z : list of list of float, optional
        Heatmap values, shape (len(y), len(x)).
    xlabel, ylabel : str
        Axis labels of the panel.
    log_x, log_y : bool
        Logarithmic axes.
    zmin, zmax : float, optional
        Colour range of a heatmap (give panels compared by eye the same range).
    dash : {"dash", "dot", "dashdot"}, optional
        Line style of a line series; None (the default) draws it solid. Mark a reference
        the other curves are compared with (a demonstration, a target) as ``"dash"`` so a
        close fit drawn over it does not hide it.
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
    """Mean and a band over trials for curves of shape (n_trials, n_points).

    ``kind="std"`` gives mean ± one standard deviation; ``kind="ci95"`` the 95% interval of
    the mean (normal approximation). A single curve gets a zero-width band.

    Raises
    ------
    ValueError
        ``curves`` not of shape (n ≥ 1, n_points), or ``kind`` not ``"std"`` or ``"ci95"``
        (``"gstd"``: :func:`trial_band`).
    """
    curves = np.asarray(curves, dtype=float)
    if curves.ndim != 2 or curves.shape[0] < 1:
        raise ValueError(f"curves: expected shape (n >= 1, n_points), got {curves.shape}")
    if kind not in ("std", "ci95"):
        raise ValueError(
            f"kind: expected 'std' or 'ci95' (for 'gstd' see trial_band), got {kind!r}"
        )
    m = curves.mean(axis=0)
    sd = curves.std(axis=0, ddof=1) if curves.shape[0] > 1 else np.zeros_like(m)
    half = sd if kind == "std" else 1.96 * sd / np.sqrt(max(curves.shape[0], 1))
    return m.tolist(), (m - half).tolist(), (m + half).tolist()


BAND_KINDS = ("std", "ci95", "gstd")
"""Bands over repeated curves: ``"std"`` mean ± one standard deviation (ddof = 1), ``"ci95"``
the 95% interval of the mean (mean ± 1.96 std / √n, normal approximation), ``"gstd"`` the
geometric mean ×/÷ one geometric standard deviation (mean ± std of log10, for log axes)."""


def band_text(n: int, over: str = "trials", kind: str = "std") -> str:
    """What a band over ``n`` curves is, in words (the ``Series.band`` of :func:`trial_band`).

    Parameters
    ----------
    n : int
        Number of curves the band is computed over, n ≥ 2 (one curve has no spread).
    over : str
        What the curves are, plural (``"trials"``, ``"runs"``, ``"start states"``).
    kind : {"std", "ci95", "gstd"}
        The statistic (:data:`BAND_KINDS`).

    Returns
    -------
    str
        E.g. ``"mean ± std over 20 trials"``.
    """
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
    """Mean curve over repeated curves and the :class:`Series` keywords of its band.

    Parameters
    ----------
    curves : array_like, shape (n, n_points)
        One curve per trial (run, start state, …); ``kind="gstd"`` needs positive values.
    over : str
        What the n curves are, plural (the band's text says "over n <over>").
    kind : {"std", "ci95", "gstd"}
        ``"std"`` and ``"ci95"`` as :func:`mean_band`; ``"gstd"``: m = 10^mean(log10 c),
        band 10^(mean(log10 c) ± std(log10 c)) (a geometric mean ×/÷ the geometric std).

    Returns
    -------
    mean : list of float, length n_points
        The mean (geometric for ``"gstd"``).
    band : dict
        ``lower``, ``upper`` (lists) and ``band`` (:func:`band_text`) to pass to
        :class:`Series`; empty for a single curve, whose spread is undefined (no band is
        drawn rather than a zero-width one).
    """
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
