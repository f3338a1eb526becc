"""Turn an experiment result (its ``series``) into a plotly HTML figure and a PNG.

The HTML embeds plotly.js so it opens offline. The PNG is drawn with matplotlib from the
same series (no browser needed), so both files always show the same numbers.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]


def _panels(series: list[dict]) -> list[str]:
    seen: list[str] = []
    for s in series:
        if s.get("panel", "") not in seen:
            seen.append(s.get("panel", ""))
    return seen


def plotly_figure(result: dict):
    """A plotly figure with one subplot per panel of ``result["series"]``."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    series = result["series"]
    panels = _panels(series)
    ncols = min(len(panels), 2)
    nrows = math.ceil(len(panels) / ncols)
    fig = make_subplots(rows=nrows, cols=ncols, subplot_titles=panels)
    colors: dict[str, str] = {}
    for s in series:
        idx = panels.index(s.get("panel", ""))
        row, col = idx // ncols + 1, idx % ncols + 1
        color = colors.setdefault(s["name"], _COLORS[len(colors) % len(_COLORS)])
        kind = s.get("kind", "line")
        show = sum(1 for t in fig.data if t.name == s["name"]) == 0
        if kind == "heatmap":
            fig.add_trace(
                go.Heatmap(
                    x=s["x"],
                    y=s["y"],
                    z=s["z"],
                    name=s["name"],
                    colorscale="Viridis",
                    zmin=s.get("zmin"),
                    zmax=s.get("zmax"),
                    showscale=idx == 0,
                ),
                row=row,
                col=col,
            )
        elif kind == "bar":
            fig.add_trace(
                go.Bar(x=s["x"], y=s["y"], name=s["name"], marker_color=color, showlegend=show),
                row=row,
                col=col,
            )
        else:
            if s.get("lower") is not None and s.get("upper") is not None:
                fig.add_trace(
                    go.Scatter(
                        x=list(s["x"]) + list(s["x"])[::-1],
                        y=list(s["upper"]) + list(s["lower"])[::-1],
                        fill="toself",
                        line={"width": 0},
                        fillcolor=color,
                        opacity=0.2,
                        hoverinfo="skip",
                        showlegend=False,
                        name=s["name"],
                    ),
                    row=row,
                    col=col,
                )
            mode = {"line": "lines", "markers": "markers"}.get(kind, kind)
            fig.add_trace(
                go.Scatter(
                    x=s["x"],
                    y=s["y"],
                    mode=mode,
                    name=s["name"],
                    line={"color": color},
                    marker={"color": color},
                    showlegend=show,
                ),
                row=row,
                col=col,
            )
        fig.update_xaxes(
            title_text=s.get("xlabel", ""), type="log" if s.get("log_x") else None, row=row, col=col
        )
        fig.update_yaxes(
            title_text=s.get("ylabel", ""), type="log" if s.get("log_y") else None, row=row, col=col
        )
    fig.update_layout(
        title=f"{result['id']}: {result['title']} ({result.get('scale', '')})",
        height=380 * nrows,
        width=560 * ncols,
        template="plotly_white",
    )
    return fig


def matplotlib_figure(result: dict):
    """The same figure drawn with matplotlib (used for the PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = result["series"]
    panels = _panels(series)
    ncols = min(len(panels), 2)
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.6 * ncols, 3.8 * nrows), squeeze=False)
    colors: dict[str, str] = {}
    for s in series:
        idx = panels.index(s.get("panel", ""))
        ax = axes[idx // ncols][idx % ncols]
        color = colors.setdefault(s["name"], _COLORS[len(colors) % len(_COLORS)])
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
            fig.colorbar(mesh, ax=ax)
        elif kind == "bar":
            ax.bar([str(v) for v in s["x"]], s["y"], color=color, label=s["name"])
        else:
            if s.get("lower") is not None and s.get("upper") is not None:
                ax.fill_between(s["x"], s["lower"], s["upper"], color=color, alpha=0.2, linewidth=0)
            style = {"line": "-", "markers": "o", "lines+markers": "-o"}.get(kind, "-")
            ax.plot(s["x"], s["y"], style, color=color, label=s["name"], markersize=3)
        ax.set_title(s.get("panel", ""), fontsize=10)
        ax.set_xlabel(s.get("xlabel", ""))
        ax.set_ylabel(s.get("ylabel", ""))
        if s.get("log_x"):
            ax.set_xscale("log")
        if s.get("log_y"):
            ax.set_yscale("log")
    for row in axes:
        for ax in row:
            handles, labels = ax.get_legend_handles_labels()
            if handles:
                ax.legend(fontsize=8)
    for k in range(len(panels), nrows * ncols):
        axes[k // ncols][k % ncols].axis("off")
    title = f"{result['id']}: {result['title']} ({result.get('scale', '')})"
    fig.suptitle(textwrap.fill(title, width=int(95 * ncols / 2) + 10), fontsize=10)
    fig.tight_layout()
    return fig


def write_figures(result: dict, folder: str | Path, html: bool = True) -> tuple[Path | None, Path]:
    """Write ``figure.html`` (plotly, self-contained; skipped with ``html=False``) and
    ``figure.png`` (matplotlib) into ``folder``."""
    import matplotlib.pyplot as plt

    folder = Path(folder)
    html_path = None
    if html:
        html_path = folder / "figure.html"
        plotly_figure(result).write_html(html_path, include_plotlyjs=True)
    png = folder / "figure.png"
    fig = matplotlib_figure(result)
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return html_path, png
