"""The viewer inside a Jupyter notebook: an inline frame on a running viser server, or a static
screenshot of the task's scene when no server can start (a headless CI kernel, a port that is
taken, a remote kernel whose ports the browser cannot reach).

>>> shown = show_viewer("throwing")             # doctest: +SKIP
>>> shown                                        # the cell shows the live 3-D scene
>>> shown.viewer.add_prediction_layer("gp", samples)  # doctest: +SKIP
>>> shown.stop()                                 # doctest: +SKIP
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass
from pathlib import Path

__all__ = ["NotebookViewer", "scene_screenshot", "show_viewer"]

#: Where the documentation keeps one screenshot per task (``docs/scene_<task>.png``).
SCREENSHOT_DIR = Path(__file__).resolve().parents[2] / "docs"


def scene_screenshot(task_name: str) -> Path | None:
    """The documentation's screenshot of a task's scene (its base variant), or None.

    ``throwing-noisy`` falls back to ``throwing``, ``hockey-real`` to ``hockey``.
    """
    name = str(task_name)
    while name:
        path = SCREENSHOT_DIR / f"scene_{name}.png"
        if path.exists():
            return path
        if "-" not in name:
            return None
        name = name.rsplit("-", 1)[0]
    return None


@dataclass
class NotebookViewer:
    """What :func:`show_viewer` returns: displays as an inline frame on the live server, or as
    the static screenshot with the reason the server did not start.

    Attributes
    ----------
    viewer : Viewer or None
        The running viewer (None when it could not start).
    screenshot : Path or None
        The static fallback image.
    reason : str
        Why there is no live viewer ("" when there is one).
    height : int
        Height of the frame or image in pixels.
    """

    viewer: object | None
    screenshot: Path | None
    reason: str = ""
    height: int = 480

    @property
    def live(self) -> bool:
        return self.viewer is not None

    def stop(self) -> None:
        """Stop the server (idempotent); the cell then shows the screenshot."""
        if self.viewer is not None:
            self.viewer.stop()
            self.viewer = None
            self.reason = "the viewer was stopped"

    def _repr_html_(self) -> str:
        if self.viewer is not None:
            url = html.escape(self.viewer.url)
            return (
                f'<iframe src="{url}" width="100%" height="{self.height}" '
                f'style="border:0"></iframe><div><small>live viewer at '
                f'<a href="{url}" target="_blank">{url}</a></small></div>'
            )
        note = html.escape(f"static screenshot: {self.reason}")
        if self.screenshot is None:
            reason = html.escape(self.reason)
            return f"<div><small>no viewer and no screenshot ({reason})</small></div>"
        data = base64.b64encode(self.screenshot.read_bytes()).decode()
        return (
            f'<img src="data:image/png;base64,{data}" style="max-height:{self.height}px"/>'
            f"<div><small>{note}</small></div>"
        )

    def __repr__(self) -> str:
        if self.viewer is not None:
            return f"NotebookViewer(live at {self.viewer.url})"
        return f"NotebookViewer(screenshot={self.screenshot}, reason={self.reason!r})"


def show_viewer(
    task,
    *,
    live: bool = True,
    height: int = 480,
    environment: bool = False,
    **viewer_kwargs,
) -> NotebookViewer:
    """Start a :class:`~skillkit.viz.viewer.Viewer` for ``task`` on a free port and show it
    inline; fall back to the task's static screenshot when it cannot start.

    Parameters
    ----------
    task : Task or str
        The task or its registry name.
    live : bool
        Try to start a server (False: show the screenshot straight away, e.g. in CI).
    height : int
        Frame height in pixels (positive).
    environment : bool
        viser's HDRI lighting (slow in browsers without a GPU; off by default here).
    **viewer_kwargs
        Passed to :class:`~skillkit.viz.viewer.Viewer` (policy, context, history, seed, host).

    Returns
    -------
    NotebookViewer
        Call ``.stop()`` when done (or let the kernel end).
    """
    from skillkit.viz.viewer import Viewer

    if isinstance(height, bool) or not isinstance(height, int) or height <= 0:
        raise ValueError(f"height: expected a positive number of pixels, got {height!r}")
    name = task if isinstance(task, str) else getattr(task, "name", "")
    screenshot = scene_screenshot(name)
    if not live:
        return NotebookViewer(None, screenshot, "live=False", height)
    viewer = Viewer(task, port=0, environment=environment, **viewer_kwargs)
    try:
        viewer.start()
    except OSError as exc:  # no free port, no network
        viewer.stop()
        return NotebookViewer(None, screenshot, f"the server could not start ({exc})", height)
    return NotebookViewer(viewer, screenshot, "", height)
