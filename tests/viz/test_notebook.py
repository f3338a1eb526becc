"""The notebook viewer: a live frame when the server starts, the screenshot otherwise."""

from __future__ import annotations

import pytest

from skillkit.viz.notebook import NotebookViewer, scene_screenshot, show_viewer


def test_screenshots_exist_for_base_tasks_and_variants_fall_back():
    assert scene_screenshot("hockey").name == "scene_hockey.png"
    assert scene_screenshot("hockey-real") == scene_screenshot("hockey")
    assert scene_screenshot("throwing-noisy").name == "scene_throwing.png"
    assert scene_screenshot("no-such-task") is None


def test_static_fallback_embeds_the_png_and_says_why():
    shown = show_viewer("pendulum", live=False)
    assert not shown.live
    page = shown._repr_html_()
    assert page.startswith('<img src="data:image/png;base64,') and "live=False" in page


def test_live_viewer_shows_a_frame_and_stops_cleanly():
    shown = show_viewer("pendulum", height=300)
    try:
        assert shown.live
        page = shown._repr_html_()
        assert "<iframe" in page and shown.viewer.url in page and 'height="300"' in page
    finally:
        shown.stop()
    assert not shown.live and "stopped" in shown._repr_html_()
    shown.stop()  # idempotent


def test_bad_height():
    with pytest.raises(ValueError, match="height"):
        show_viewer("pendulum", live=False, height=0)
    assert "reason" in repr(NotebookViewer(None, None, "x"))
