"""skillkit.viz.explore: controls that redraw a figure made by library calls."""

from __future__ import annotations

import pytest

from skillkit.viz.explore import Slider, explore


def test_default_figure_is_drawn_and_set_redraws_with_the_changed_value():
    calls = []

    def draw(a, n):
        calls.append((a, n))
        return (a, n)

    shown = explore(draw, a=Slider(0.0, 2.0, 0.5), n=Slider(1, 9, 3))
    assert shown.figure == (0.5, 3) and calls == [(0.5, 3)]
    assert shown.set(n=4) == (0.5, 4)
    assert shown.values == {"a": 0.5, "n": 4}


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        (lambda: Slider(1.0, 0.0, 0.5), "low, high"),
        (lambda: Slider(0.0, 1.0, 2.0), "default"),
        (lambda: Slider(0.0, 1.0, 0.5, log=True), "log slider"),
        (lambda: Slider(0.0, float("nan"), 0.5), "high"),
    ],
)
def test_bad_controls_are_named(spec, match):
    with pytest.raises(ValueError, match=match):
        spec()


def test_bad_explore_arguments_are_named():
    with pytest.raises(ValueError, match="specs"):
        explore(lambda: 0)
    with pytest.raises(ValueError, match="a: expected a Slider"):
        explore(lambda a: a, a=3)
    shown = explore(lambda a: a, a=Slider(0, 10, 3))
    with pytest.raises(ValueError, match="unknown control"):
        shown.set(b=1)


def test_integer_and_log_sliders_make_the_matching_widget():
    w = pytest.importorskip("ipywidgets")
    assert isinstance(Slider(1, 10, 3).widget("n"), w.IntSlider)
    assert isinstance(Slider(1e-3, 1.0, 0.1, log=True).widget("s"), w.FloatLogSlider)
    assert isinstance(Slider(0.0, 1.0, 0.1).widget("e"), w.FloatSlider)
