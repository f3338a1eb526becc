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
import shutil
from dataclasses import dataclass
from pathlib import Path

__all__ = ["NotebookViewer", "export_html", "scene_screenshot", "show_viewer"]

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


#: MathJax 2.7 as a local copy (the ``jupyter_server_mathjax`` package): the configuration an
#: exported page loads from the folder ``mathjax/`` beside it.
MATHJAX_CONFIG = "TeX-AMS-MML_HTMLorMML-full,Safe"

#: MathJax 2.7's HTML-CSS output fails on a prime after a bold symbol (``\mathbf{x}'_i``:
#: "Math Processing Error", fontInherit of undefined) in Chromium; the browser's own MathML
#: (MathJax's NativeMML output, in the same configuration) typesets it, at the price of bold
#: symbols shown upright. Registered before nbconvert's own MathJax configuration.
_MATHML_RENDERER = (
    '<script type="text/x-mathjax-config">MathJax.Hub.Register.StartupHook("End Jax", '
    'function () { return MathJax.Hub.setRenderer("NativeMML"); });</script>'
)


def export_html(notebook, out_dir=None, *, execute: bool = False, timeout: int = 600):
    """Export a notebook to HTML whose equations render offline.

    ``jupyter nbconvert --to html`` makes pages that load MathJax from a CDN, so without a
    network their equations stay raw ``$$``. This writes ``<out_dir>/<name>.html`` loading
    MathJax from ``<out_dir>/mathjax/`` (copied once from the installed
    ``jupyter_server_mathjax`` package, ≈ 10 MB): the page and that folder work offline and
    can be moved together.

    Parameters
    ----------
    notebook : str or Path
        An ``.ipynb`` file.
    out_dir : str or Path, optional
        Output folder (default: the notebook's folder); created if missing.
    execute : bool
        Execute the notebook first (in its own folder, with nbclient), as
        ``nbconvert --execute`` would.
    timeout : int
        Seconds per cell when executing.

    Returns
    -------
    Path
        The HTML file.
    """
    from pathlib import Path as _Path

    import jupyter_server_mathjax
    import nbformat
    from nbconvert import HTMLExporter

    source = _Path(notebook)
    if source.suffix != ".ipynb" or not source.is_file():
        raise ValueError(f"notebook: expected an existing .ipynb file, got {str(notebook)!r}")
    if isinstance(timeout, bool) or not isinstance(timeout, int) or timeout <= 0:
        raise ValueError(f"timeout: expected a positive number of seconds, got {timeout!r}")
    out = _Path(out_dir) if out_dir is not None else source.parent
    out.mkdir(parents=True, exist_ok=True)
    local = out / "mathjax"
    if not (local / "MathJax.js").is_file():
        static = _Path(jupyter_server_mathjax.__file__).parent / "static"
        shutil.copytree(static, local, dirs_exist_ok=True)
    nb = nbformat.read(source, as_version=4)
    if execute:
        from nbclient import NotebookClient

        NotebookClient(
            nb, timeout=timeout, resources={"metadata": {"path": str(source.parent)}}
        ).execute()
    exporter = HTMLExporter(mathjax_url=f"mathjax/MathJax.js?config={MATHJAX_CONFIG}")
    body, _ = exporter.from_notebook_node(nb)
    marker = '<script type="text/x-mathjax-config">'
    if marker not in body:
        raise RuntimeError("export_html: nbconvert's template no longer configures MathJax")
    body = body.replace(marker, _MATHML_RENDERER + marker, 1)
    target = out / f"{source.stem}.html"
    target.write_text(body, encoding="utf-8")
    return target
