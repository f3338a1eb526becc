"""A notebook slider in live JupyterLab: headless Chromium opens a tiny notebook calling
:func:`skillkit.viz.explore.explore`, runs it, types a new ε into the slider and checks that
the figure on the page was redrawn (its title names the new ε)."""

from __future__ import annotations

import time
from pathlib import Path

from headless_browser import (  # tests/viz/headless_browser.py
    CHROMIUM,
    NEEDS_CHROMIUM,
    HeadlessBrowser,
    JupyterLab,
    evaluate,
    run_notebook_in_lab,
    type_into_slider,
    wait_until,
)

pytestmark = NEEDS_CHROMIUM

#: The notebook's one cell: the REPS weights of ch3-weights with an ε slider.
SLIDER_CELL = """\
from functools import partial

import numpy as np
import plotly.io as pio

from skillkit.teaching.ch3 import weights_and_kl_figure
from skillkit.viz.explore import Slider, explore

pio.renderers.default = "plotly_mimetype+notebook"  # as in the chapters: plotly.js embedded
rewards = np.random.default_rng(0).normal(-3.0, 2.0, 60)
draw = partial(weights_and_kl_figure, rewards, None)
shown = explore(draw, epsilon=Slider(0.01, 10.0, 0.5, log=True))"""

#: The titles of the plotly figures in the notebook's outputs.
TITLES = (
    "[...document.querySelectorAll('.jp-Notebook .js-plotly-plot .gtitle')].map(e => e.textContent)"
)


def write_slider_notebook(folder: Path, name: str = "live_slider.ipynb") -> Path:
    """Write the one-cell notebook of :data:`SLIDER_CELL` into ``folder``."""
    import nbformat

    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {
        "name": "python3",
        "display_name": "Python 3",
        "language": "python",
    }
    nb.cells = [nbformat.v4.new_code_cell(SLIDER_CELL)]
    path = Path(folder) / name
    nbformat.write(nb, path)
    return path


def wait_for_title(browser: HeadlessBrowser, needle: str, timeout: float) -> list[str]:
    """Wait until a figure title on the page contains ``needle``; return the titles."""
    script = f"(() => {{ const t = {TITLES}; return t.some(s => s.includes({needle!r})) && t; }})()"
    return wait_until(browser, script, timeout, f"a figure titled with {needle!r}")


def test_moving_an_explore_slider_redraws_the_figure_in_jupyterlab(tmp_path):
    start = time.monotonic()
    notebook = write_slider_notebook(tmp_path)
    with (
        JupyterLab(tmp_path) as lab,
        HeadlessBrowser(size=(1100, 900), executable=str(CHROMIUM)) as browser,
    ):
        try:
            run_notebook_in_lab(browser, lab, notebook.name, timeout=60)
            before = wait_for_title(browser, "ε = 0.5:", timeout=30)
            assert len(before) == 1, f"expected one figure on the page, got titles {before}"
            type_into_slider(browser, "8.13")
            after = wait_for_title(browser, "ε = 8.13:", timeout=30)
        except (TimeoutError, RuntimeError) as err:
            raise AssertionError(f"{err}\npage titles: {evaluate(browser, TITLES)}") from err
    assert len(after) == 1 and "ε = 0.5:" not in after[0], after
    assert time.monotonic() - start < 90


def test_an_executed_and_exported_notebook_shows_the_default_figure(tmp_path):
    """nbconvert keeps the widget state of an executed notebook and then renders the controls'
    view (blank offline); the default figure is an output of its own that the page draws."""
    from skillkit.viz.notebook import export_html

    page = export_html(write_slider_notebook(tmp_path), tmp_path / "html", execute=True)
    text = page.read_text(encoding="utf-8")
    assert "application/vnd.jupyter.widget-state+json" in text  # the controls' state was kept
    assert text.count('class="plotly-graph-div"') == 1
    with HeadlessBrowser(size=(1100, 900), executable=str(CHROMIUM)) as browser:
        browser.open(page.as_uri())
        titles = wait_for_title(browser, "ε = 0.5:", timeout=30)
    assert len(titles) == 1, titles
