"""Figures (plotly HTML, matplotlib PNG) and, later, viser scenes."""
