"""Screenshots of an :func:`skillkit.viz.explore.explore` slider in live JupyterLab, before and
after moving it.

The machinery of ``tests/viz/test_live_widgets.py``: JupyterLab headless on 127.0.0.1, a
one-cell notebook with the REPS-weights figure and its ε slider, opened and run in Debian's
headless Chromium; ε is then typed into the slider's readout (default 1.5). Run from the repository
root::

    python docs/make_live_slider_screenshots.py

Writes ``docs/notebook_live_slider_before.png`` and ``docs/notebook_live_slider_after.png``.
Needs ``/usr/bin/chromium`` and the ``websockets`` package (a viser dependency).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "viz"))
from headless_browser import (  # noqa: E402  (tests/viz/headless_browser.py)
    HeadlessBrowser,
    JupyterLab,
    evaluate,
    run_notebook_in_lab,
    type_into_slider,
)
from test_live_widgets import wait_for_title, write_slider_notebook  # noqa: E402

#: Scroll the notebook so that its first cell starts at the top of the page.
SCROLL_TO_CELL = "document.querySelector('.jp-Notebook .jp-Cell').scrollIntoView(); true"


def save(image, out: Path) -> None:
    """Save a screenshot scaled to 900 px wide with a 128-colour palette."""
    image = Image.fromarray(image)
    image = image.resize((900, round(900 * image.height / image.width)), Image.LANCZOS)
    image.convert("P", palette=Image.ADAPTIVE, colors=128).save(out, optimize=True)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs"), help="folder of the PNG files")
    parser.add_argument("--epsilon", default="1.5", help="the value typed into the slider")
    args = parser.parse_args()
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        notebook = write_slider_notebook(Path(tmp))
        with JupyterLab(tmp) as lab, HeadlessBrowser(size=(1100, 1480)) as browser:
            run_notebook_in_lab(browser, lab, notebook.name, timeout=90)
            wait_for_title(browser, "ε = 0.5:", timeout=60)
            evaluate(browser, SCROLL_TO_CELL)
            save(browser.settled_screenshot(timeout=60), out / "notebook_live_slider_before.png")
            type_into_slider(browser, args.epsilon)
            wait_for_title(browser, f"ε = {args.epsilon}:", timeout=60)
            evaluate(browser, "document.activeElement.blur(); true")
            evaluate(browser, SCROLL_TO_CELL)
            save(browser.settled_screenshot(timeout=60), out / "notebook_live_slider_after.png")


if __name__ == "__main__":
    main()
