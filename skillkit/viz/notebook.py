"""The viewer inside a Jupyter notebook: an inline frame on a running viser server, or the
task's static screenshot when no server can start; and :func:`export_html` for offline pages.

>>> shown = show_viewer("throwing")             # doctest: +SKIP
>>> shown                                        # the cell shows the live 3-D scene
>>> shown.viewer.add_prediction_layer("gp", samples)  # doctest: +SKIP
>>> shown.stop()                                 # doctest: +SKIP
"""

from __future__ import annotations

import base64
import html
import shutil
from dataclasses import dataclass
from pathlib import Path

__all__ = ["NotebookViewer", "export_html", "scene_screenshot", "show_viewer"]

#: Where the documentation keeps one screenshot per task (``docs/scene_<task>.png``).
SCREENSHOT_DIR = Path(__file__).resolve().parents[2] / "docs"


def scene_screenshot(task_name: str) -> Path | None:
    """The documentation's screenshot of a task's scene (its base variant: ``throwing-noisy``
    falls back to ``throwing``), or None."""
    parts = str(task_name).split("-")
    for k in range(len(parts), 0, -1):
        path = SCREENSHOT_DIR / f"scene_{'-'.join(parts[:k])}.png"
        if path.exists():
            return path
    return None


@dataclass
class NotebookViewer:
    """What :func:`show_viewer` returns: an inline frame on the live ``viewer``, or the static
    ``screenshot`` with the ``reason`` the server did not start; ``height`` in pixels."""

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
    task, *, live: bool = True, height: int = 480, environment: bool = False, **viewer_kwargs
) -> NotebookViewer:
    """A :class:`~skillkit.viz.viewer.Viewer` for ``task`` (or its name) on a free port, shown
    inline, else (or with ``live=False``) the task's screenshot; ``height`` in pixels,
    ``environment`` viser's HDRI lighting, ``viewer_kwargs`` to the Viewer. ``.stop()`` it."""
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


#: The MathJax 2.7 configuration an exported page loads from the folder ``mathjax/`` beside it
#: (a local copy of the ``jupyter_server_mathjax`` package).
MATHJAX_CONFIG = "TeX-AMS-MML_HTMLorMML-full,Safe"

#: MathJax 2.7's HTML-CSS output fails on a prime after a bold symbol (``\mathbf{x}'_i``) in
#: Chromium; the browser's own MathML (NativeMML output) typesets it. Registered before
#: nbconvert's own MathJax configuration.
_MATHML_RENDERER = (
    '<script type="text/x-mathjax-config">MathJax.Hub.Register.StartupHook("End Jax", '
    'function () { return MathJax.Hub.setRenderer("NativeMML"); });</script>'
)


def export_html(notebook, out_dir=None, *, execute: bool = False, timeout: int = 600):
    """Export a notebook to ``<out_dir>/<name>.html`` (default: its folder) loading MathJax from
    ``<out_dir>/mathjax/`` (copied from ``jupyter_server_mathjax``), so it renders offline;
    ``execute`` runs it first (nbclient, ``timeout`` seconds a cell). Returns the HTML file."""
    import jupyter_server_mathjax
    import nbformat
    from nbconvert import HTMLExporter

    source = Path(notebook)
    if source.suffix != ".ipynb" or not source.is_file():
        raise ValueError(f"notebook: expected an existing .ipynb file, got {str(notebook)!r}")
    if isinstance(timeout, bool) or not isinstance(timeout, int) or timeout <= 0:
        raise ValueError(f"timeout: expected a positive number of seconds, got {timeout!r}")
    out = Path(out_dir) if out_dir is not None else source.parent
    out.mkdir(parents=True, exist_ok=True)
    local = out / "mathjax"
    if not (local / "MathJax.js").is_file():
        static = Path(jupyter_server_mathjax.__file__).parent / "static"
        shutil.copytree(static, local, dirs_exist_ok=True)
    nb = nbformat.read(source, as_version=4)
    if execute:
        from nbclient import NotebookClient

        resources = {"metadata": {"path": str(source.parent)}}
        NotebookClient(nb, timeout=timeout, resources=resources).execute()
    exporter = HTMLExporter(mathjax_url=f"mathjax/MathJax.js?config={MATHJAX_CONFIG}")
    body, _ = exporter.from_notebook_node(nb)
    marker = '<script type="text/x-mathjax-config">'
    if marker not in body:
        raise RuntimeError("export_html: nbconvert's template no longer configures MathJax")
    body = body.replace(marker, _MATHML_RENDERER + marker, 1)
    target = out / f"{source.stem}.html"
    target.write_text(body, encoding="utf-8")
    return target
