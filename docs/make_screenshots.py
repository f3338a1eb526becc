"""Screenshots of every task's viewer scene for the documentation: ``docs/scene_<task>.png``.

Starts a :class:`skillkit.viz.viewer.Viewer` per task (one task per task class, e.g. ``hockey``
but not its ``hockey-real`` variant), opens it in Debian's headless Chromium (the browser tests'
``HeadlessBrowser``, ``tests/viz/headless_browser.py``), waits until the scene has rendered and
saves small palette PNGs of the 3-D canvas (and of the whole page, GUI included, for one task).
Run from the repository root::

    python docs/make_screenshots.py                 # all tasks
    python docs/make_screenshots.py hockey --out /tmp

Needs ``/usr/bin/chromium`` (``apt-get install chromium``). Software WebGL is slow: expect
tens of seconds per task; ``--no-envmap`` trades the environment lighting for speed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def headless_browser():
    """The ``HeadlessBrowser`` class of the browser tests (``tests/viz/headless_browser.py``)."""
    folder = str(ROOT / "tests" / "viz")
    if folder not in sys.path:
        sys.path.insert(0, folder)
    from headless_browser import HeadlessBrowser

    return HeadlessBrowser


def default_tasks() -> list[str]:
    """One registered name per task class (the alphabetically first, i.e. the base variant)."""
    from skillkit.tasks import make, names

    seen, out = set(), []
    for name in names():
        cls = type(make(name))
        if cls not in seen:
            seen.add(cls)
            out.append(name)
    return out


def render(
    name: str,
    out: Path,
    *,
    size=(800, 480),
    fraction: float = 0.4,
    colors: int = 96,
    environment: bool = True,
    seed: int = 1,
    with_gui: bool = False,
) -> list[Path]:
    """Render task ``name`` in a context drawn with ``seed``, at ``fraction`` of its rollout's
    time range: ``scene_<name>.png`` (the 3-D canvas alone, rendered by the browser through
    viser's ``get_render``) and, with ``with_gui``, ``viewer_<name>.png`` (the whole page)."""
    from PIL import Image

    from skillkit.tasks import make
    from skillkit.viz.viewer import Viewer

    HeadlessBrowser = headless_browser()

    task = make(name)
    context = task.sample_context(np.random.default_rng(seed)) if task.context_dim else None
    width, height = size
    with Viewer(task, context=context, port=0, environment=environment) as viewer:
        t0, t1 = viewer.scene.time_range(viewer.trajectory)
        viewer.set_time(t0 + fraction * (t1 - t0))
        with HeadlessBrowser(size=(width + 160, height + 40)) as browser:
            browser.open(viewer.url)
            browser.wait_for_text(["reward R =", *sorted(viewer.scene.nodes)[:3]], timeout=300)
            browser.hide(".mantine-Notifications-root")  # the "software WebGL" notice
            page = browser.settled_screenshot(timeout=300)
            client = next(iter(viewer.server.get_clients().values()))
            rgba = client.get_render(height, width, transport_format="png", timeout=300)
    canvas = Image.new("RGBA", (width, height), (255, 255, 255, 255))
    canvas.alpha_composite(Image.fromarray(np.ascontiguousarray(rgba), "RGBA"))
    images = {f"scene_{name}.png": canvas.convert("RGB")}
    if with_gui:
        images[f"viewer_{name}.png"] = Image.fromarray(np.ascontiguousarray(page))
    paths = []
    for file, image in images.items():
        image.quantize(colors=colors).save(out / file, optimize=True)
        paths.append(out / file)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", help="task names (default: one per task class)")
    parser.add_argument("--out", default=str(ROOT / "docs"), help="output folder (default: docs/)")
    parser.add_argument(
        "--gui",
        default="hockey",
        help="task whose whole page (GUI included) is also saved (default hockey)",
    )
    parser.add_argument(
        "--no-envmap",
        action="store_true",
        help="no HDRI environment lighting (much faster in software WebGL)",
    )
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.tasks or default_tasks():
        for path in render(name, out, environment=not args.no_envmap, with_gui=name == args.gui):
            print(f"{path} ({path.stat().st_size / 1024:.0f} KB)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
