"""Screenshot of one section of a chapter notebook exported to HTML, as a reader sees it.

Executes the notebook at ``SKILLKIT_SCALE=smoke``, exports it with
:func:`skillkit.viz.notebook.export_html` (MathJax from a local copy, so the equations are
typeset offline; plotly.js embedded, so the figures draw offline), opens the page in Debian's
headless Chromium, scrolls to the heading that starts with ``--section`` and keeps one
viewport from there. Run from the repository root::

    python docs/make_notebook_screenshot.py ch3_contextual_reps \\
        --section "(a) The dual" --out docs/notebook_ch3_dual.png

Several sections of one notebook: repeat ``--section`` and ``--out`` in pairs (one execution).
Needs ``/usr/bin/chromium`` and the ``websockets`` package (a viser dependency).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image

from skillkit.viz.notebook import export_html

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "viz"))
from headless_browser import HeadlessBrowser  # noqa: E402  (tests/viz/headless_browser.py)

WIDTH = 1100


def _evaluate(browser, expression: str):
    return browser.call("Runtime.evaluate", expression=expression)["result"].get("value")


def _wait_for_mathjax(browser, timeout: float = 90.0) -> None:
    """Until MathJax has typeset the page (its queue is idle after the first pass)."""
    script = (
        "(window.MathJax && MathJax.Hub && MathJax.Hub.queue && "
        "MathJax.Hub.queue.pending === 0 && MathJax.Hub.queue.running === 0 && "
        "document.querySelectorAll('.MathJax, .MathJax_MathML, .MathJax_SVG').length > 0)"
    )
    deadline = time.monotonic() + timeout
    while not _evaluate(browser, script):
        if time.monotonic() > deadline:
            raise TimeoutError("MathJax did not finish typesetting")
        time.sleep(0.5)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("notebook", help="name under notebooks/, without .ipynb")
    parser.add_argument("--section", action="append", required=True, help="heading prefix")
    parser.add_argument("--out", action="append", required=True, help="PNG per section")
    parser.add_argument("--height", type=int, default=1500, help="viewport height (px)")
    args = parser.parse_args()
    if len(args.section) != len(args.out):
        parser.error("give one --out per --section")
    os.environ["SKILLKIT_SCALE"] = "smoke"
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["SKILLKIT_RUNS"] = str(Path(tmp) / "runs")  # no old checkpoints resumed
        page = export_html(ROOT / "notebooks" / f"{args.notebook}.ipynb", tmp, execute=True)
        with HeadlessBrowser(size=(WIDTH, args.height), executable="/usr/bin/chromium") as b:
            b.open(page.as_uri())
            b.wait_for_text(["Exercises"])
            _wait_for_mathjax(b)
            for section, out in zip(args.section, args.out, strict=True):
                find = (
                    "(() => { const h = [...document.querySelectorAll('h1,h2,h3,h4')]"
                    f".find(e => e.textContent.trim().startsWith({json.dumps(section)}));"
                    " if (!h) return -1; h.scrollIntoView(); return window.scrollY; })()"
                )
                if _evaluate(b, find) == -1:
                    raise SystemExit(f"--section {section!r}: no heading starts with it")
                b.wait_frames(5)
                image = Image.fromarray(b.screenshot())
                image = image.resize((900, round(900 * image.height / image.width)), Image.LANCZOS)
                image.convert("P", palette=Image.ADAPTIVE, colors=128).save(out, optimize=True)
                print(f"wrote {out}")


if __name__ == "__main__":
    main()
