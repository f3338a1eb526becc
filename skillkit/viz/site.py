"""A browsable site of executed notebooks (``skillkit site OUT``): one HTML page each
(:func:`~skillkit.viz.notebook.export_html`), an index, and a bar linking the index and the
previous and next notebook.
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from pathlib import Path

from skillkit.viz.notebook import export_html

__all__ = ["build_site", "notebook_title"]

_NAV_STYLE = (
    "position:sticky;top:0;z-index:1000;background:#f6f8fa;border-bottom:1px solid #d0d7de;"
    "padding:6px 16px;font:14px sans-serif"
)


def notebook_title(notebook: str | Path) -> str:
    """The first Markdown heading of a notebook (its file stem if it has none)."""
    import nbformat

    nb = nbformat.read(notebook, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            match = re.search(r"^#+\s+(.+)$", cell.source, re.MULTILINE)
            if match:
                return match.group(1).strip()
    return Path(notebook).stem


def build_site(
    notebooks: Sequence[str | Path],
    out_dir: str | Path,
    *,
    execute: bool = False,
    timeout: int = 600,
) -> Path:
    """Export ``notebooks`` to ``out_dir`` as linked HTML pages with an ``index.html``.

    Parameters
    ----------
    notebooks : sequence of str or Path
        ``.ipynb`` files in the site's order; executed first (in their folder) if ``execute``,
        ``timeout`` seconds per cell.
    out_dir : str or Path
        Output folder (created) of the pages, ``index.html`` and one ``mathjax/`` copy.

    Returns
    -------
    Path
        The index page.
    """
    paths = [Path(p) for p in notebooks]
    if not paths:
        raise ValueError("notebooks: expected at least one .ipynb file")
    stems = [p.stem for p in paths]
    if len(set(stems)) != len(stems):
        raise ValueError(f"notebooks: two notebooks share a name: {sorted(stems)}")
    out = Path(out_dir)
    pages = [(f"{p.stem}.html", notebook_title(p)) for p in paths]
    for i, path in enumerate(paths):
        page = export_html(path, out, execute=execute, timeout=timeout)
        text = page.read_text(encoding="utf-8")
        body = re.search(r"<body[^>]*>", text)
        if body is None:
            raise RuntimeError(f"build_site: no <body> in the export of {path.name}")
        links = ['<a href="index.html">index</a>']
        if i > 0:
            links.append(f'<a href="{pages[i - 1][0]}">← {html.escape(pages[i - 1][1])}</a>')
        if i + 1 < len(pages):
            links.append(f'<a href="{pages[i + 1][0]}">{html.escape(pages[i + 1][1])} →</a>')
        nav = f'<nav class="skillkit-site" style="{_NAV_STYLE}">' + " · ".join(links) + "</nav>"
        text = text[: body.end()] + nav + text[body.end() :]
        page.write_text(text, encoding="utf-8")
    items = "\n".join(
        f'<li><a href="{name}">{html.escape(title)}</a></li>' for name, title in pages
    )
    index = out / "index.html"
    index.write_text(
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>skillkit notebooks</title>"
        "</head><body style='font:16px sans-serif;max-width:50em;margin:2em auto'>"
        f"<h1>skillkit notebooks</h1>\n<ol>\n{items}\n</ol></body></html>\n",
        encoding="utf-8",
    )
    return index
