"""Figures (plotly HTML, matplotlib PNG) and the viser viewer of task scenes."""

DEFAULT_HOST = "127.0.0.1"
"""The viewer binds to this machine only unless told otherwise."""
DEFAULT_PORT = 8080
