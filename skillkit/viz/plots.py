"""Figures of experiment results: a result's ``series`` (:class:`~skillkit.series.Series`
fields), a subplot per panel, by :func:`plotly_figure` (``figure.html``) or
:func:`matplotlib_figure` (``figure.png``, without pyplot)."""

from __future__ import annotations

import io
import math
import re
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from skillkit._validation import check_choice, check_type
from skillkit.series import DASHES

_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
_BAND_SWATCH = "#9e9e9e"
BACKENDS = ("plotly", "matplotlib")
_LEGEND_INSIDE_MAX = 6  # legend entries drawn inside a matplotlib panel; more go below it

# the thresholds of robust_range (see there)
MAX_DECADES, HEADROOM_DECADES, GAP_DECADES = 10.0, 6.0, 2.0
LINEAR_SPAN_OVER_SPREAD, LINEAR_HEADROOM, LINEAR_GAP = 1000.0, 20.0, 5.0
MAX_CLIPPED_FRACTION = 0.25

_POINT_KINDS = ("line", "markers", "lines+markers")
_MPL_DASH = {"solid": "-", "dash": "--", "dot": ":", "dashdot": "-."}

#: Width (px) the plotly figures' text is wrapped for (a notebook cell); the figures are responsive.
REFERENCE_WIDTH = 820
#: Height (px) of one row of plotly panels (the plot area, without titles and tick labels).
PANEL_HEIGHT = 300


def subtitle(result: Mapping, width: int | None = None) -> str:
    """An experiment figure's subtitle: ``summary["statement"]``, else ``summary["verdict"]`` or
    "no verdict recorded"; "" without a ``summary``; wrapped to ``width`` unless None."""
    check_type(result, Mapping, "result", "a dict")
    summary = result.get("summary")
    if not isinstance(summary, Mapping) or not summary:
        return ""
    said = [summary[k].strip() for k in ("statement", "verdict") if isinstance(summary.get(k), str)]
    line = next(filter(None, said), "no verdict recorded")
    return line if width is None else textwrap.fill(line, width=max(int(width), 20))


def _title(result: Mapping) -> str:
    head = ": ".join(str(result[k]) for k in ("id", "title") if result.get(k))
    scale = result.get("scale")
    return f"{head} ({scale})" if scale else head


class NotebookFigure(Figure):
    """A :class:`matplotlib.figure.Figure` on an Agg canvas that shows itself in Jupyter
    (``_repr_png_``) with pyplot imported or not; pyplot never sees it."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        FigureCanvasAgg(self)

    def _repr_png_(self) -> bytes:
        buf = io.BytesIO()
        self.savefig(buf, format="png", dpi=90)
        return buf.getvalue()


@dataclass(frozen=True)
class AxisRange:
    """A readable range of one panel's y axis: ``lo``, ``hi`` the smallest and largest value
    shown to scale, ``axis`` the limits with a margin (data units), ``log`` a log axis."""

    lo: float
    hi: float
    axis: tuple[float, float]
    log: bool

    def clipped(self, y) -> tuple[np.ndarray, np.ndarray]:
        """Boolean masks (above, below) of the values of ``y`` outside the axis limits."""
        y = np.asarray(y, dtype=float)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(y) & ((y > 0) if self.log else True)
            return ok & (y > self.axis[1]), ok & (y < self.axis[0])


def robust_range(values, log: bool) -> AxisRange | None:
    """A readable y range for values that a few runaway points would otherwise stretch.

    Returns None when all values can be shown to scale: a log axis spanning at most
    :data:`MAX_DECADES` decades, or a linear one spanning at most
    :data:`LINEAR_SPAN_OVER_SPREAD` times its spread s = max(IQR, 10⁻³·|quartiles|).
    Otherwise, in t = log₁₀ y (log) or t = y (linear), with median m and quartiles q₁, q₃:
    the values in [min(m − H, q₁ − G), max(m + H, q₃ + G)] are kept, then every value within
    G of a kept one (so a continuous curve is never cut), where H, G are
    :data:`HEADROOM_DECADES`, :data:`GAP_DECADES` (log) or :data:`LINEAR_HEADROOM`·s,
    :data:`LINEAR_GAP`·s (linear). A side that would lose more than
    :data:`MAX_CLIPPED_FRACTION` of the values is not clipped.

    ``values`` are the panel's plotted values (non-finite ones, and non-positive ones on a log
    axis, are ignored).
    """
    t = np.asarray(values, dtype=float).ravel()
    t = t[np.isfinite(t)]
    if log:
        t = np.log10(t[t > 0])
    t = np.sort(t)
    if t.size < 4:
        return None
    span = t[-1] - t[0]
    q1, m, q3 = np.percentile(t, [25, 50, 75])
    if log:
        if span <= MAX_DECADES:
            return None
        head, gap = HEADROOM_DECADES, GAP_DECADES
    else:
        spread = max(q3 - q1, 1e-3 * max(abs(q1), abs(q3)))
        if spread == 0:
            spread = 1e-9 * span
        if span <= LINEAR_SPAN_OVER_SPREAD * spread:
            return None
        head, gap = LINEAR_HEADROOM * spread, LINEAR_GAP * spread
    hi = _extend(t, max(m + head, q3 + gap), gap)
    lo = -_extend(-t[::-1], -min(m - head, q1 - gap), gap)
    limit = MAX_CLIPPED_FRACTION * t.size
    if np.sum(t > hi) > limit:
        hi = t[-1]
    if np.sum(t < lo) > limit:
        lo = t[0]
    if hi == t[-1] and lo == t[0]:
        return None
    pad = 0.06 * (hi - lo) if hi > lo else (0.5 if log else max(abs(hi) * 0.1, 1.0))
    axis = (lo - pad, hi + pad)
    if log:
        return AxisRange(10.0**lo, 10.0**hi, (10.0 ** axis[0], 10.0 ** axis[1]), True)
    return AxisRange(float(lo), float(hi), (float(axis[0]), float(axis[1])), False)


def _extend(t: np.ndarray, start: float, gap: float) -> float:
    """Largest value of sorted ``t`` reached from ``start`` in steps of at most ``gap``."""
    kept = t[t <= start]
    top = kept[-1] if kept.size else start
    for v in t[t > start]:
        if v - top > gap:
            break
        top = v
    return float(top)


def _fmt(v: float) -> str:
    return re.sub(r"e\+?(-?)0*(\d)", r"e\1\2", f"{v:.2g}")  # 1e+40 -> 1e40, 1e-05 -> 1e-5


@dataclass
class _Panel:
    """What a panel draws beyond its series: the robust range and its notes."""

    name: str
    index: int
    xlabel: str
    ylabel: str
    log_y: bool
    range: AxisRange | None
    note: str
    bands: list[str]
    floor: float  # where a log panel's non-positive band bounds are drawn
    log_x: bool  # drawn log x axis (a log_x panel spanning < 1 decade is drawn linear)
    xaxis: tuple[float, float] | None  # x limits containing the data (None: automatic)
    yaxis: tuple[float, float] | None  # y limits: the robust range's, else around the data

    def cell(self, ncols: int) -> dict:
        """plotly's ``row`` and ``col`` of the panel in a grid of ``ncols`` columns."""
        return {"row": self.index // ncols + 1, "col": self.index % ncols + 1}


def _clip_note(points: list[dict], rng: AxisRange) -> str:
    """How many values lie off scale on each side, and the most extreme of them."""
    pairs = [(np.asarray(s["y"], dtype=float), rng.clipped(s["y"])) for s in points]
    parts, marks = [], ("(max {}) ▲ at the top edge", "(min {}) ▼ at the bottom edge")
    for side, word in enumerate(("above", "below")):
        off = np.concatenate([y[m[side]] for y, m in pairs])
        if off.size:
            extreme = _fmt(off.max() if side == 0 else off.min())
            head = f"{off.size} value{'s' * (off.size > 1)} {word} {_fmt(rng.axis[1 - side])}"
            parts.append(f"{head} {marks[side].format(extreme)}")
    return "; ".join(parts)


def _layout(series: list[dict]) -> list[_Panel]:
    """Per panel: labels, the robust range, the note on clipped values, the band texts."""
    out = []
    for i, name in enumerate(dict.fromkeys(s.get("panel", "") for s in series)):
        members = [s for s in series if s.get("panel", "") == name]
        log_y = any(s.get("log_y") for s in members)
        points = [s for s in members if s.get("kind", "line") in _POINT_KINDS]
        banded = [s for s in points if _has_band(s)]
        values = np.concatenate([np.asarray(s["y"], dtype=float).ravel() for s in points] or [[]])
        rng = robust_range(values, log_y)
        floor = 1.0
        if log_y:
            bounds = (s[k] for s in banded for k in ("lower", "upper"))
            every = np.concatenate([values] + [np.asarray(b, dtype=float).ravel() for b in bounds])
            every = every[np.isfinite(every) & (every > 0)]
            floor = rng.axis[0] if rng is not None else (float(every.min()) if every.size else 1.0)
        bands = list(dict.fromkeys(s["band"] for s in members if _has_band(s) and s.get("band")))
        xs = np.concatenate([_floats(s["x"]) for s in members] or [[]])
        xs = xs[np.isfinite(xs) & (xs > 0)]  # a log x axis needs a positive span of a decade
        log_x = any(s.get("log_x") for s in members) and bool(xs.size)
        log_x = log_x and float(xs.max()) >= 10.0 * float(xs.min())
        xaxis, yaxis = None, (rng.axis if rng is not None else None)
        if len(points) == len(members):  # no heatmap or bar
            xaxis = _limits(np.concatenate([_floats(s["x"]) for s in points]), log_x, pad=0.03)
            if rng is None:
                ys = [values] + [a for s in banded for a in _band_arrays(s, log_y, floor)]
                yaxis = _limits(np.concatenate(ys), log_y, pad=0.06)
        xl, yl = _axis_label(members, "xlabel", log_x), _axis_label(members, "ylabel", log_y)
        note = _clip_note(points, rng) if rng is not None else ""
        out.append(_Panel(name, i, xl, yl, log_y, rng, note, bands, floor, log_x, xaxis, yaxis))
    return out


def _floats(v) -> np.ndarray:
    """``v`` as a flat float array; entries that are not numbers (None, text) become NaN."""
    try:
        return np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        return np.array([_to_float(e) for e in np.asarray(v, dtype=object).ravel()])


def _to_float(e) -> float:
    try:
        return float(e)
    except (TypeError, ValueError):
        return math.nan


_LOG_WORDS = re.compile(
    r"\s*\(\s*log(?:arithmic)? scale\s*\)|log(?:arithmic)? scale\s*[;,]\s*|"
    r"\s*[;,]\s*log(?:arithmic)? scale",
    re.IGNORECASE,
)


def _axis_label(members: list[dict], key: str, log: bool) -> str:
    """The first ``key`` label of the panel's series; a linear axis drops "log scale"."""
    label = next((s[key] for s in members if s.get(key)), "")
    return label if log or not label else _LOG_WORDS.sub("", label).strip()


def _limits(v: np.ndarray, log: bool, pad: float) -> tuple[float, float] | None:
    """Limits around the finite (log: positive) values of ``v``, ``pad`` × span beyond."""
    v = np.asarray(v, dtype=float).ravel()
    v = v[np.isfinite(v) & ((v > 0) if log else True)]
    if not v.size:
        return None
    if log:
        v = np.log10(v)
    lo, hi = float(v.min()), float(v.max())
    margin = pad * (hi - lo) if hi > lo else (0.5 if log else max(abs(hi) * 0.1, 1.0))
    lo, hi = lo - margin, hi + margin
    return (10.0**lo, 10.0**hi) if log else (lo, hi)


def _has_band(s: Mapping) -> bool:
    kind = s.get("kind", "line")
    return kind in _POINT_KINDS and s.get("lower") is not None and s.get("upper") is not None


def _band_arrays(s: Mapping, log_y: bool, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper band; on a log axis non-positive lower bounds go to ``floor``."""
    lower, upper = (np.asarray(s[k], dtype=float) for k in ("lower", "upper"))
    if log_y:
        lower = np.where(np.isfinite(lower) & (lower > 0), lower, floor)
    return lower, upper


def _band_label(s: Mapping, panel: _Panel) -> str | None:
    """Legend text of a band; None when unlabelled or all the panel's bands say the same."""
    if not s.get("band") or len(panel.bands) == 1:
        return None
    return f"{s['name']}: shaded {s['band']}"


def _off_scale(panel: _Panel, s: Mapping):
    """(x, y at the axis edge, values, side: 0 above, 1 below) per side with values off scale."""
    if panel.range is None:
        return
    clipped = panel.range.clipped(s["y"])
    for side, (mask, edge) in enumerate(zip(clipped, panel.range.axis[::-1], strict=True)):
        if mask.any():
            ys = np.asarray(s["y"], dtype=float)[mask]
            yield np.asarray(s["x"])[mask], [edge] * int(mask.sum()), ys, side


def plotly_figure(result: dict):
    """A plotly figure, a subplot per panel of ``result["series"]``, titled ``"<id>: <title>
    (<scale>)"`` over :func:`subtitle`; a panel with runaway values gets a :func:`robust_range`,
    its clipped values drawn as triangles at the edge and counted in a note."""
    from plotly.subplots import make_subplots

    series = _check_result(result)
    panels = _layout(series)
    ncols = min(len(panels), 2)
    nrows = math.ceil(len(panels) / ncols)
    heat = any(s.get("kind") == "heatmap" for s in series)
    h_space = 0.2 if heat else 0.14
    col_px = REFERENCE_WIDTH * (1 - h_space * (ncols - 1)) / ncols - 60
    names = [_wrap_html(p.name, int(col_px / 7.2)) for p in panels]
    name_lines = max(n.count("<br>") + 1 for n in names)
    row_gap = 75 + 18 * name_lines  # tick labels and x title, then the next row's panel titles
    plot_h = nrows * PANEL_HEIGHT + (nrows - 1) * row_gap
    fig = make_subplots(
        rows=nrows,
        cols=ncols,
        subplot_titles=names,
        horizontal_spacing=h_space if ncols > 1 else 0.02,
        vertical_spacing=row_gap / plot_h if nrows > 1 else 0.3,
    )
    colors, by_name = _colors(series), {p.name: p for p in panels}
    shown: set[str] = set()
    # dashed series (references such as a demonstration) are drawn over the others, which
    # would hide them; the legend keeps the series' order (legendrank)
    for rank in sorted(range(len(series)), key=lambda i: _dashed(series[i])):
        s = series[rank]
        panel = by_name[s.get("panel", "")]
        cell = panel.cell(ncols)
        color = colors[s.get("_group", s["name"])]
        kind = s.get("kind", "line")
        if kind == "heatmap":
            sub = fig.get_subplot(**cell)
            x1, (y0, y1) = sub.xaxis.domain[1], sub.yaxis.domain
            name = s["name"].split(",")[0].strip() or s["name"]  # the colour bar's title
            bar = {
                "title": {"text": _wrap_html(name, 16), "side": "right"},
                "x": x1 + 0.01,
                "xanchor": "left",
                "y": (y0 + y1) / 2,
                "yanchor": "middle",
                "len": y1 - y0,
                "lenmode": "fraction",
                "thickness": 12,
                "ticks": "outside",
                "showticklabels": True,
                "exponentformat": "power",
            }
            fig.add_heatmap(
                x=s["x"],
                y=s["y"],
                z=s["z"],
                name=s["name"],
                colorscale="Viridis",
                zmin=s.get("zmin"),
                zmax=s.get("zmax"),
                showscale=True,
                colorbar=bar,
                **cell,
            )
            continue
        legend = {"showlegend": s["name"] not in shown, "legendrank": 1000 + rank}
        if kind == "bar":
            fig.add_bar(x=s["x"], y=s["y"], name=s["name"], marker_color=color, **legend, **cell)
            shown.add(s["name"])
            continue
        if _has_band(s):
            lower, upper = _band_arrays(s, panel.log_y, panel.floor)
            label = _band_label(s, panel)
            fig.add_scatter(
                x=list(s["x"]) + list(s["x"])[::-1],
                y=upper.tolist() + lower[::-1].tolist(),
                fill="toself",
                line={"width": 0},
                fillcolor=color,
                opacity=0.2,
                hoverinfo="skip",
                showlegend=label is not None and label not in shown,
                name=label or f"{s['name']} (band)",
                legendrank=1000 + rank,
                **cell,
            )
            if label:
                shown.add(label)
        mode = {"line": "lines", "markers": "markers"}.get(kind, kind)
        fig.add_scatter(
            x=s["x"],
            y=s["y"],
            mode="lines+markers" if _single_point(s) else mode,
            name=s["name"],
            line={"color": color, "dash": s.get("dash") or "solid"},
            marker={"color": color},
            **legend,
            **cell,
        )
        shown.add(s["name"])
        for x, y, ys, side in _off_scale(panel, s):
            symbol = ("triangle-up", "triangle-down")[side]
            fig.add_scatter(
                x=x.tolist(),
                y=y,
                mode="markers",
                marker={"color": color, "symbol": symbol, "size": 10},
                name=f"{s['name']} (off scale)",
                hoverinfo="text",
                cliponaxis=False,
                hovertext=[f"{s['name']}: {_fmt(v)} (off scale)" for v in ys],
                showlegend=False,
                **cell,
            )
    for panel in panels:
        cell = panel.cell(ncols)
        for update, label, log, lims in (
            (fig.update_xaxes, panel.xlabel, panel.log_x, panel.xaxis),
            (fig.update_yaxes, panel.ylabel, panel.log_y, panel.yaxis),
        ):
            update(
                title_text=label,
                type="log" if log else None,
                range=None if lims is None else [math.log10(v) if log else v for v in lims],
                exponentformat="power" if log else None,  # 10⁻⁶, not SI's "1µ"
                automargin=True,
                **cell,
            )
        if panel.note:
            fig.add_annotation(
                text=_wrap_html(panel.note, int(col_px / 5.5)),
                xref="x domain",
                yref="y domain",
                x=0.01,
                y=0.99,
                xanchor="left",
                yanchor="top",
                align="left",
                showarrow=False,
                font={"size": 10},
                bgcolor="rgba(255,255,255,0.8)",
                **cell,
            )
        if len(panel.bands) == 1 and (label := f"shaded: {panel.bands[0]}") not in shown:
            shown.add(label)
            fig.add_scatter(
                x=[None],
                y=[None],
                mode="markers",
                opacity=0.4,
                name=label,
                marker={"symbol": "square", "size": 12, "color": _BAND_SWATCH},
                legendrank=2000 + len(series),
                **cell,
            )
    fig.update_xaxes(automargin=True)
    fig.update_yaxes(automargin=True)
    for k in range(len(panels), nrows * ncols):  # an empty grid cell shows no axes
        fig.update_xaxes(visible=False, row=k // ncols + 1, col=k % ncols + 1)
        fig.update_yaxes(visible=False, row=k // ncols + 1, col=k % ncols + 1)
    for annotation in fig.layout.annotations[: len(panels)]:  # the panel titles
        annotation.font = {"size": 13}
    entries = [t.name for t in fig.data if t.showlegend is not False and t.name]
    named = {(s.get("panel", ""), s["name"]) for s in series}  # more than one in some panel
    show_legend = len(entries) >= 2 or len(named) > len(panels)
    rows, used = 1, 0.0  # of the horizontal legend: ~6.2 px a character + 45 an entry
    for w in (45 + 6.2 * len(name) for name in entries):
        if used and used + w > REFERENCE_WIDTH - 90:
            rows, used = rows + 1, 0.0
        used += w
    legend_h = 8 + 20 * rows if show_legend else 0
    sub = subtitle(result, width=int(REFERENCE_WIDTH / 6.4))
    sub_lines = sub.splitlines() if sub else []
    # the title stays left of the mode bar (top right, ~280 px)
    head_lines = textwrap.wrap(_title(result), width=int((REFERENCE_WIDTH - 280) / 8.5)) or [""]
    text = "<br>".join(head_lines)
    if sub_lines:
        text += "<br><span style='font-size:12px'>" + "<br>".join(sub_lines) + "</span>"
    # plotly spaces every line of the title by 1.3 × its font size (15 px), smaller spans too
    title_h = 24 + 19.5 * (len(head_lines) + len(sub_lines))
    top = int(title_h + 18 * name_lines + 16)
    bottom = 70 + legend_h
    fig.update_layout(
        title={
            "text": text,
            "x": 0.01,
            "xanchor": "left",
            "xref": "container",
            "y": 1 - 14 / (top + plot_h + bottom),
            "yanchor": "top",
            "yref": "container",
            "font": {"size": 15},
        },
        margin={"t": top, "b": bottom, "l": 70, "r": 80 if heat else 20, "autoexpand": True},
        height=top + plot_h + bottom,
        autosize=True,
        showlegend=show_legend,
        legend={
            "orientation": "h",
            "x": 0,
            "xanchor": "left",
            "y": -70 / plot_h,
            "yanchor": "top",
            "font": {"size": 11},
        },
        template="plotly_white",
    )
    return fig


def _colors(series: list[dict]) -> dict[str, str]:
    """The colour of each series group (``_group``, default its name), in order."""
    groups = dict.fromkeys(s.get("_group", s["name"]) for s in series)
    return {g: _COLORS[i % len(_COLORS)] for i, g in enumerate(groups)}


def _dashed(s: Mapping) -> bool:
    return s.get("dash") not in (None, "solid")


def _wrap_html(text: str, width: int) -> str:
    """``text`` wrapped to ``width`` characters with ``<br>`` (plotly's line break)."""
    return "<br>".join(textwrap.wrap(text, width=max(int(width), 12)) or [""])


def matplotlib_figure(result: dict):
    """The same figure as :func:`plotly_figure`, drawn with matplotlib (used for the PNG), as a
    :class:`NotebookFigure` (an Agg canvas: no pyplot, no backend change)."""
    from matplotlib.patches import Patch

    series = _check_result(result)
    panels = _layout(series)
    ncols = min(len(panels), 2)
    nrows = math.ceil(len(panels) / ncols)
    fig_w = max(5.6 * ncols, 8.0)  # one panel: wide enough that the verdict wraps to few lines
    sub_fs = 8.5
    chars = int(fig_w * 72 / (0.6 * sub_fs))
    sub = subtitle(result, width=chars)
    head = textwrap.fill(_title(result), width=chars)
    n_lines = len(head.splitlines()) + (len(sub.splitlines()) if sub else 0)
    fig = NotebookFigure(
        figsize=(fig_w, 3.8 * nrows + 0.15 + n_lines * sub_fs * 1.3 / 72), layout="constrained"
    )
    axes = fig.subplots(nrows, ncols, squeeze=False)
    colors, by_name = _colors(series), {p.name: p for p in panels}
    for s in series:
        panel = by_name[s.get("panel", "")]
        ax = axes[panel.index // ncols][panel.index % ncols]
        color = colors[s.get("_group", s["name"])]
        kind = s.get("kind", "line")
        if kind == "heatmap":
            mesh = ax.pcolormesh(
                s["x"],
                s["y"],
                s["z"],
                shading="auto",
                cmap="viridis",
                vmin=s.get("zmin"),
                vmax=s.get("zmax"),
            )
            bar = fig.colorbar(mesh, ax=ax)
            bar.set_label(s["name"].split(",")[0].strip() or s["name"], fontsize=8)
            continue
        if kind == "bar":
            ax.bar([str(v) for v in s["x"]], s["y"], color=color, label=s["name"])
            continue
        if _has_band(s):
            lower, upper = _band_arrays(s, panel.log_y, panel.floor)
            label = _band_label(s, panel) or "_nolegend_"
            ax.fill_between(s["x"], lower, upper, color=color, alpha=0.2, linewidth=0, label=label)
        ax.plot(
            s["x"],
            s["y"],
            color=color,
            label=s["name"],
            markersize=3,
            marker="o" if kind in ("markers", "lines+markers") or _single_point(s) else None,
            linestyle="none" if kind == "markers" else _MPL_DASH[s.get("dash") or "solid"],
            zorder=2.5 if _dashed(s) else 2,  # a dashed reference is drawn over the fit
        )
        for x, y, _, side in _off_scale(panel, s):
            ax.plot(x, y, "^v"[side], color=color, markersize=6, clip_on=False, label="_nolegend_")
    for panel in panels:
        ax = axes[panel.index // ncols][panel.index % ncols]
        ax.set_title(panel.name, fontsize=10)
        ax.set_xlabel(panel.xlabel)
        ax.set_ylabel(panel.ylabel)
        if panel.log_x:
            ax.set_xscale("log")
        if panel.log_y:
            ax.set_yscale("log")
        if panel.range is not None:
            ax.set_ylim(*panel.range.axis)
        if panel.note:
            ax.text(
                0.01,
                0.99,
                textwrap.fill(panel.note, width=70),
                transform=ax.transAxes,
                ha="left",
                va="top",
                fontsize=7,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.5},
            )
        handles, labels = ax.get_legend_handles_labels()
        if len(panel.bands) == 1:
            handles.append(Patch(color=_BAND_SWATCH, alpha=0.4, linewidth=0))
            labels.append(f"shaded: {panel.bands[0]}")
        below = {"loc": "upper center", "bbox_to_anchor": (0.5, -0.16), "ncol": 2, "frameon": False}
        if handles:  # a long legend would hide the data: below the axes
            place = below if len(handles) > _LEGEND_INSIDE_MAX else {}
            ax.legend(handles, labels, fontsize=7, **place)
    for k in range(len(panels), nrows * ncols):
        axes[k // ncols][k % ncols].axis("off")
    title, fontsize = (f"{head}\n{sub}", sub_fs) if sub else (head, 10)
    fig.suptitle(title, x=0.01, ha="left", fontsize=fontsize, multialignment="left")
    return fig


def write_figures(result: dict, folder: str | Path, html: bool = True) -> tuple[Path | None, Path]:
    """Write ``figure.html`` (plotly, self-contained; skipped with ``html=False``) and
    ``figure.png`` (matplotlib) into ``folder``; returns (html_path or None, png_path)."""
    folder = Path(folder)
    html_path = folder / "figure.html" if html else None
    if html:
        plotly_figure(result).write_html(html_path, include_plotlyjs=True)
    matplotlib_figure(result).savefig(folder / "figure.png", dpi=90)  # an Agg canvas
    return html_path, folder / "figure.png"


def _check_result(result) -> list[dict]:
    """The series as dicts; series of one ``"_group"`` (default: name) share a colour."""
    check_type(result, Mapping, "result", "a result dict")
    series = result.get("series")
    if not isinstance(series, Sequence) or isinstance(series, str) or not series:
        raise ValueError("result: expected a non-empty 'series' list of Series dicts")
    out = []
    for i, s in enumerate(series):
        s = s.to_dict() if hasattr(s, "to_dict") else s
        if not isinstance(s, Mapping) or not {"name", "x", "y"} <= set(s):
            raise ValueError(f"result: series[{i}] lacks 'name', 'x' or 'y'")
        if s.get("dash") is not None and s["dash"] not in DASHES:
            raise ValueError(f"result: series[{i}] dash {s['dash']!r} is not one of {DASHES}")
        out.append(dict(s))
    return out


def _single_point(s: Mapping) -> bool:
    """A line series with one finite point (drawn as a marker: a point line is invisible)."""
    return s.get("kind", "line") == "line" and int(np.isfinite(_floats(s["y"])).sum()) == 1


def draw_figure(result: dict, backend: str):
    """:func:`plotly_figure` or :func:`matplotlib_figure` of ``result``, by ``backend`` (one of
    :data:`BACKENDS`)."""
    check_choice(backend, "backend", BACKENDS)
    return (plotly_figure if backend == "plotly" else matplotlib_figure)(result)
