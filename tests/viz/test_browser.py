"""The viewer in a real browser: Debian's headless Chromium opens the page, the scene arrives,
the canvas is not blank and the scene tree lists the expected node names; likewise with a
GPREPS run's reward-model layers and their legend."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from headless_browser import (  # tests/viz/headless_browser.py
    CHROMIUM,
    NEEDS_CHROMIUM,
    HeadlessBrowser,
)

from skillkit.experiments import reproduce
from skillkit.viz.model_layers import load_gpreps_run, model_layers
from skillkit.viz.viewer import Viewer

pytestmark = NEEDS_CHROMIUM

EXPECTED_NODES = [
    "/arm/link3",
    "/arm/link7/blade",
    "/table",
    "/pucks/control",
    "/pucks/target",
    "/target",
    "/trails/effector",
    "/trails/target_puck",
]


def canvas(screenshot: np.ndarray) -> np.ndarray:
    """The 3-D canvas away from the GUI panel (right), the notification (top left) and the
    orientation gizmo (bottom left), as floats."""
    return screenshot[170:490, :460].astype(float)


def changed(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of canvas pixels that differ by more than 8 in some channel."""
    return float(np.any(np.abs(a - b) > 8, axis=-1).mean())


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_hockey_scene_renders_in_headless_chromium(tmp_path):
    # environment=False: no HDRI environment map, whose set-up takes Chromium's software WebGL
    # tens of seconds on a loaded machine; everything else is the viewer as users get it.
    with Viewer("hockey", context=[2.0, 0.75, 0.5], port=free_port(), environment=False) as viewer:
        t0, t1 = viewer.scene.time_range(viewer.trajectory)
        viewer.set_time(t0 + 0.2 * (t1 - t0))
        for name in EXPECTED_NODES:  # the server-side scene tree
            assert viewer.server.scene.get_handle_by_name(name) is not None, name
        with HeadlessBrowser(size=(800, 560), executable=str(CHROMIUM)) as browser:
            browser.open(viewer.url)
            # The page's DOM: the GUI's "Scene tree" folder lists the node paths.
            text = browser.wait_for_text([*EXPECTED_NODES, "reward R ="], timeout=120)
            assert "skillkit · hockey" in text
            assert viewer.server.get_clients(), "the page did not connect over the websocket"
            shown = browser.settled_screenshot(timeout=90)
            viewer.server.scene.set_global_visibility(False)
            hidden = browser.settled_screenshot(timeout=90)
    out = Path(os.environ.get("SKILLKIT_BROWSER_ARTIFACTS", tmp_path))
    out.mkdir(parents=True, exist_ok=True)
    from PIL import Image

    Image.fromarray(shown).save(out / "browser_hockey.png")
    Image.fromarray(hidden).save(out / "browser_hockey_hidden.png")

    assert shown.shape == (560, 800, 3)
    canvas_shown, canvas_hidden = canvas(shown), canvas(hidden)
    # With every scene node hidden the canvas is blank (one background colour) ...
    assert canvas_hidden.std() < 2.0, f"hidden scene not blank: std {canvas_hidden.std():.2f}"
    # ... and with the scene shown it is not: a good part of it was drawn by our nodes.
    drawn = changed(canvas_shown, canvas_hidden)
    assert drawn > 0.05, f"canvas looks blank: {drawn:.1%} of its pixels show the scene"
    assert canvas_shown.std() > 5.0


def test_gpreps_model_layers_render_in_headless_chromium(tmp_path):
    """A real GPREPS run folder (fig4.10 at smoke scale: the hockey event models fitted on its
    shots), as ``skillkit view hockey --gpreps RUN`` shows it: the run's last policy with the
    reward model's layers and their legend."""
    run = reproduce("fig4.10", scale="smoke", seed=0, out=tmp_path, html=False, progress=False)
    history, model = load_gpreps_run(run.path, 0)
    assert type(model).__name__ == "HockeyRewardModel"
    viewer = Viewer(
        "hockey", context=[2.0, 0.75, 0.5], history=history, port=free_port(), environment=False
    )
    with viewer:
        layers = viewer.add_model_layers(model, n_samples=10)
        specs = model_layers(model, viewer.context, history.policies[-1].mean_of(viewer.context))
        names = {spec["label"]: spec["name"] for spec in specs}
        assert len(names) >= 3
        t0, t1 = viewer.scene.time_range(viewer.trajectory)
        viewer.set_time(t0 + 0.5 * (t1 - t0))
        model_nodes = [
            f"/predictions/{name}/{node}" for name in names.values() for node in ("samples", "mean")
        ]
        for name in [*EXPECTED_NODES, *model_nodes]:
            assert viewer.server.scene.get_handle_by_name(name) is not None, name
        with HeadlessBrowser(size=(800, 560), executable=str(CHROMIUM)) as browser:
            browser.open(viewer.url)
            needles = [*model_nodes, *names, "simulator rollout", "HockeyRewardModel"]
            browser.wait_for_text(needles, timeout=120)
            shown = browser.settled_screenshot(timeout=90)
            for layer in layers:
                layer.checkbox.value = False  # as if unticked in the browser
            without = browser.settled_screenshot(timeout=90)
            viewer.server.scene.set_global_visibility(False)
            hidden = browser.settled_screenshot(timeout=90)
    out = Path(os.environ.get("SKILLKIT_BROWSER_ARTIFACTS", tmp_path))
    out.mkdir(parents=True, exist_ok=True)
    from PIL import Image

    Image.fromarray(shown).save(out / "browser_hockey_gpreps.png")
    shown, without, hidden = canvas(shown), canvas(without), canvas(hidden)
    assert hidden.std() < 2.0
    drawn = changed(shown, hidden)
    assert drawn > 0.05, f"canvas looks blank: {drawn:.1%} of its pixels show the scene"
    # the model's layers themselves are on the canvas: switching them off changes pixels
    predicted = changed(shown, without)
    assert predicted > 0.001, f"the model layers drew {predicted:.2%} of the canvas"


def test_exported_notebook_renders_its_equations_offline(tmp_path):
    """export_html loads MathJax from a local copy: the equation is typeset, no CDN needed."""
    import nbformat

    from skillkit.viz.notebook import export_html

    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_markdown_cell(
            r"Eq. (3.9): $$g(\eta) = \eta\epsilon$$ and $\{\mathbf{x}_i, \mathbf{x}'_i\}$"
        )
    ]
    source = tmp_path / "eq.ipynb"
    nbformat.write(nb, source)
    page = export_html(source, tmp_path / "html")
    text = page.read_text()
    assert "libs/mathjax" not in text and 'src="mathjax/MathJax.js?config=' in text
    with HeadlessBrowser(size=(800, 400), executable=str(CHROMIUM)) as browser:
        browser.open(page.as_uri())
        deadline = time.monotonic() + 60
        count = 0
        while time.monotonic() < deadline and count == 0:
            reply = browser.call(
                "Runtime.evaluate",
                expression="document.querySelectorAll('.MathJax_MathML math').length",
            )
            count = int(reply["result"].get("value", 0))
            time.sleep(0.2)
        time.sleep(1.0)  # the rest of the page typeset
        reply = browser.call(
            "Runtime.evaluate",
            expression="document.querySelectorAll('.MathJax_MathML math').length",
        )
        count = int(reply["result"].get("value", 0))
        text = browser.text()
    assert count == 2, f"MathJax typeset {count} of the 2 equations"
    assert "Math Processing Error" not in text


def test_export_html_names_bad_input(tmp_path):
    from skillkit.viz.notebook import export_html

    with pytest.raises(ValueError, match="notebook: expected an existing .ipynb"):
        export_html(tmp_path / "missing.ipynb")
