"""The notebook site in headless Chromium: every page loads without console errors, its
equations are typeset and every figure is drawn; the pages link to each other.

``SKILLKIT_SITE_NOTEBOOKS`` names a folder where the repository's ``conftest.py`` keeps each
notebook nbmake executed; ``.ci/run`` sets it for the test run and then runs
``test_the_site_of_the_executed_notebooks`` on all of them.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import nbformat
import pytest
from headless_browser import CHROMIUM, NEEDS_CHROMIUM, HeadlessBrowser

from skillkit.viz.site import build_site, notebook_title

pytestmark = NEEDS_CHROMIUM
NOTEBOOKS = sorted((Path(__file__).resolve().parents[2] / "notebooks").glob("*.ipynb"))

#: Records console errors and uncaught exceptions of a page before any of its scripts run.
_RECORD_ERRORS = """
window.__errors = [];
window.addEventListener('error', e => window.__errors.push(String(e.message)));
const _error = console.error;
console.error = (...args) => { window.__errors.push(args.map(String).join(' ')); _error(...args); };
"""


def _figure_count(nb) -> tuple[int, int]:
    """(plotly figures, images) among a notebook's outputs."""
    plotly = images = 0
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            plotly += "application/vnd.plotly.v1+json" in data
            images += "image/png" in data
    return plotly, images


def _has_math(nb) -> bool:
    return any(c.cell_type == "markdown" and "$" in c.source for c in nb.cells)


def _evaluate(browser: HeadlessBrowser, expression: str):
    reply = browser.call("Runtime.evaluate", expression=expression, returnByValue=True)
    return reply["result"].get("value")


def _open(browser: HeadlessBrowser, page: Path) -> None:
    """Navigate and wait until ``page`` itself (not the one before it) has loaded."""
    browser.open(page.as_uri())
    deadline = time.monotonic() + 60
    expression = f"location.href === {page.as_uri()!r} && document.readyState === 'complete'"
    while not _evaluate(browser, expression):
        assert time.monotonic() < deadline, f"{page.name} did not load"
        time.sleep(0.2)


def check_site(index: Path, notebooks: list[Path]) -> None:
    """Open the index and every page; assert the properties the module docstring lists."""
    with HeadlessBrowser(size=(1200, 900), executable=str(CHROMIUM)) as browser:
        browser.call("Page.enable")
        browser.call("Page.addScriptToEvaluateOnNewDocument", source=_RECORD_ERRORS)
        _open(browser, index)
        links = _evaluate(browser, "[...document.links].map(a => a.getAttribute('href'))")
        assert links == [f"{p.stem}.html" for p in notebooks]
        for path in notebooks:
            nb = nbformat.read(path, as_version=4)
            page = index.parent / f"{path.stem}.html"
            _open(browser, page)
            plotly, images = _figure_count(nb)
            deadline = time.monotonic() + 120
            state = {}
            while time.monotonic() < deadline:
                state = _evaluate(
                    browser,
                    "({plots: document.querySelectorAll('.plotly-graph-div .main-svg').length,"
                    " divs: document.querySelectorAll('.plotly-graph-div').length,"
                    " images: [...document.images].filter(i => i.naturalWidth > 0).length,"
                    " math: document.querySelectorAll('.MathJax_MathML math').length,"
                    " queued: window.MathJax ? MathJax.Hub.queue.pending : 1,"
                    " errors: window.__errors})",
                )
                ready = state["divs"] >= plotly and state["queued"] == 0
                if ready and (not _has_math(nb) or state["math"] > 0):
                    break
                time.sleep(0.5)
            name = path.name
            assert state["errors"] == [], f"{name}: console errors {state['errors'][:3]}"
            assert state["divs"] >= plotly, f"{name}: {state['divs']} of {plotly} plotly figures"
            assert state["plots"] >= state["divs"], f"{name}: a plotly figure was not drawn"
            assert state["images"] >= images, f"{name}: {state['images']} of {images} images"
            text = _evaluate(browser, "document.body.innerText")
            assert "Math Processing Error" not in text, name
            if _has_math(nb):
                assert state["math"] > 0, f"{name}: no equation typeset"
                assert not re.search(r"\$\$", text), f"{name}: an untypeset $$ equation"
            nav = _evaluate(browser, "document.querySelector('nav.skillkit-site').innerText")
            assert nav.startswith("index")


def _tiny_notebook(path: Path, title: str) -> Path:
    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_markdown_cell(f"# {title}\n\nThe dual $g(\\eta) = \\eta\\epsilon$."),
        nbformat.v4.new_code_cell(
            "import plotly.graph_objects as go\nimport plotly.io as pio\n"
            'pio.renderers.default = "plotly_mimetype+notebook"\n'
            "go.Figure(go.Scatter(y=[1, 3, 2]))"
        ),
    ]
    nbformat.write(nb, path)
    return path


def test_a_site_of_two_notebooks_links_and_renders(tmp_path):
    notebooks = [
        _tiny_notebook(tmp_path / "a.ipynb", "First"),
        _tiny_notebook(tmp_path / "b.ipynb", "Second"),
    ]
    from nbclient import NotebookClient

    for path in notebooks:
        nb = nbformat.read(path, as_version=4)
        NotebookClient(nb, resources={"metadata": {"path": str(tmp_path)}}).execute()
        nbformat.write(nb, path)
    index = build_site(notebooks, tmp_path / "site")
    assert notebook_title(notebooks[1]) == "Second"
    page = (tmp_path / "site" / "a.html").read_text()
    assert 'href="b.html">Second →</a>' in page and "← " not in page
    check_site(index, notebooks)


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match="notebooks: expected at least one"):
        build_site([], tmp_path)
    nb = _tiny_notebook(tmp_path / "a.ipynb", "A")
    (tmp_path / "x").mkdir()
    twin = _tiny_notebook(tmp_path / "x" / "a.ipynb", "A")
    with pytest.raises(ValueError, match="share a name"):
        build_site([nb, twin], tmp_path / "site")


def test_the_site_of_the_executed_notebooks(tmp_path):
    folder = os.environ.get("SKILLKIT_SITE_NOTEBOOKS")
    executed = sorted(Path(folder).glob("*.ipynb")) if folder else []
    if not executed:
        pytest.skip("SKILLKIT_SITE_NOTEBOOKS holds no executed notebooks (.ci/run sets it)")
    assert [p.name for p in executed] == [p.name for p in NOTEBOOKS]
    check_site(build_site(executed, tmp_path / "site"), executed)


def test_the_check_catches_a_console_error(tmp_path):
    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("display(HTML(...))")
    html = '<div>x</div><script>console.error("boom")</script>'
    cell.outputs = [nbformat.v4.new_output("display_data", data={"text/html": html})]
    nb.cells = [nbformat.v4.new_markdown_cell("# Broken"), cell]
    nbformat.write(nb, tmp_path / "broken.ipynb")
    index = build_site([tmp_path / "broken.ipynb"], tmp_path / "site")
    with pytest.raises(AssertionError, match="console errors.*boom"):
        check_site(index, [tmp_path / "broken.ipynb"])


def test_the_command_exports_a_folder_of_notebooks(tmp_path, capsys):
    from skillkit.cli import main

    (tmp_path / "nbs").mkdir()
    _tiny_notebook(tmp_path / "nbs" / "a.ipynb", "Only")
    assert (
        main(["site", str(tmp_path / "out"), "--notebooks", str(tmp_path / "nbs"), "--executed"])
        == 0
    )
    assert (tmp_path / "out" / "index.html").exists() and (tmp_path / "out" / "a.html").exists()
    assert main(["site", str(tmp_path / "out"), "--notebooks", str(tmp_path / "none")]) == 2
    assert "--notebooks: no .ipynb file" in capsys.readouterr().err
