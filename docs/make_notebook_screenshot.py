"""Screenshot of a chapter notebook exported to HTML, as a reader sees it (docs/*.png).

Executes the notebook at ``SKILLKIT_SCALE=smoke`` with nbconvert, exports it to HTML (the
notebooks set plotly's renderer to ``plotly_mimetype+notebook``, so plotly.js is embedded and
the figures draw offline), opens the page in Debian's headless Chromium and keeps the part
with the first figures. Run from the repository root::

    python docs/make_notebook_screenshot.py [ch4_gpreps] [--out docs/notebook_ch4_html.png]

Needs ``/usr/bin/chromium``. LaTeX stays unrendered in the screenshot: the exported page loads
MathJax from a CDN, which this machine cannot reach (JupyterLab renders it).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("notebook", nargs="?", default="ch4_gpreps")
    parser.add_argument("--out", default=str(ROOT / "docs" / "notebook_ch4_html.png"))
    parser.add_argument("--crop", type=int, nargs=2, default=(700, 3300), help="rows to keep")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, SKILLKIT_SCALE="smoke")
        subprocess.run(
            ["jupyter", "nbconvert", "--to", "html", "--execute", f"{args.notebook}.ipynb",
             "--output-dir", tmp],
            cwd=ROOT / "notebooks", env=env, check=True, capture_output=True,
        )  # fmt: skip
        page, shot = Path(tmp) / f"{args.notebook}.html", Path(tmp) / "page.png"
        subprocess.run(
            ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             "--window-size=1200,7000", "--virtual-time-budget=15000",
             f"--screenshot={shot}", page.as_uri()],
            check=True, capture_output=True, timeout=300,
        )  # fmt: skip
        image = Image.open(shot).crop((0, args.crop[0], 1200, args.crop[1]))
        image = image.resize((900, round(900 * image.height / image.width)), Image.LANCZOS)
        image.convert("P", palette=Image.ADAPTIVE, colors=128).save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
