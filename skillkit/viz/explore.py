"""Sliders that redraw a figure in a notebook (the default figure stays for exported pages).

>>> from skillkit.viz.explore import Slider, explore
>>> def draw(epsilon):                     # any function returning a figure
...     ...
>>> shown = explore(draw, epsilon=Slider(0.05, 2.0, 0.5))   # doctest: +SKIP
>>> shown.set(epsilon=1.0)                 # what a slider does, callable from code
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from skillkit._validation import check_type

__all__ = ["Exploration", "Slider", "explore"]

_WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"
#: A widget view of no model: ipywidgets front ends hide it, nbconvert skips it.
_NO_WIDGET = {"model_id": "", "version_major": 2, "version_minor": 0}


@dataclass(frozen=True)
class Slider:
    """A numeric control: range ``low < high`` (both > 0 when ``log``, a ``FloatLogSlider``),
    ``default`` within it, ``step`` of a linear slider (default: 1/100 of the range; an int
    slider when ``low``, ``high``, ``default`` and ``step`` are all ints)."""

    low: float
    high: float
    default: float
    step: float | None = None
    log: bool = False

    def __post_init__(self) -> None:
        for name in ("low", "high", "default"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name}: expected a finite number, got {v!r}")
        if not self.low < self.high:
            raise ValueError(f"low, high: expected low < high, got {self.low}, {self.high}")
        if not self.low <= self.default <= self.high:
            msg = f"default: expected a value in [{self.low}, {self.high}], got {self.default}"
            raise ValueError(msg)
        if self.log and self.low <= 0:
            raise ValueError(f"low: a log slider needs low > 0, got {self.low}")
        if self.step is not None and not self.step > 0:
            raise ValueError(f"step: expected a positive number, got {self.step!r}")

    def widget(self, description: str):
        """The ipywidgets slider."""
        import ipywidgets as w

        common = {"description": description, "continuous_update": False}
        common["style"] = {"description_width": "initial"}
        if self.log:
            lo, hi = math.log10(self.low), math.log10(self.high)
            return w.FloatLogSlider(
                value=self.default, base=10, min=lo, max=hi, step=(hi - lo) / 100, **common
            )
        nums = (self.low, self.high, self.default, self.step or 1)
        kind = w.IntSlider if all(isinstance(v, int) for v in nums) else w.FloatSlider
        step = self.step or (1 if kind is w.IntSlider else (self.high - self.low) / 100)
        return kind(value=self.default, min=self.low, max=self.high, step=step, **common)


@dataclass
class Exploration:
    """What :func:`explore` returns: ``draw``, the current ``values``, the last ``figure`` and
    the ipywidgets box of the ``controls`` (None without ipywidgets)."""

    draw: Callable[..., Any]
    values: dict[str, Any]
    figure: Any = None
    controls: Any = None
    _handle: Any = field(default=None, repr=False)
    _output: Any = field(default=None, repr=False)

    def set(self, **values) -> Any:
        """Redraw with some values changed (what moving a control does); returns the figure."""
        unknown = set(values) - set(self.values)
        if unknown:
            msg = f"values: unknown control(s) {sorted(unknown)}; known {sorted(self.values)}"
            raise ValueError(msg)
        self.values.update(values)
        self.figure = self.draw(**self.values)
        if self._output is not None:
            self._output.outputs = (_display_output(self.figure),)
        elif self._handle is not None:
            self._handle.update(self.figure)
        return self.figure

    def _moved(self, name: str, value) -> None:
        """A control's callback: redraw, or show in the figure's place why that failed."""
        try:
            self.set(**{name: value})
        except Exception as err:
            text = f"{name} = {value!r}: {type(err).__name__}: {err}\n"
            self._output.outputs = ({"output_type": "stream", "name": "stderr", "text": text},)


def _display_output(obj) -> dict:
    """``obj`` as one ``display_data`` output, IPython's ``_ipython_display_`` hook off."""
    from IPython import get_ipython

    formatter = get_ipython().display_formatter
    hook = formatter.ipython_display_formatter
    enabled, hook.enabled = hook.enabled, False
    try:
        data, metadata = formatter.format(obj)
    finally:
        hook.enabled = enabled
    return {"output_type": "display_data", "data": data, "metadata": metadata}


def explore(draw: Callable[..., Any], /, *, controls: bool = True, **specs) -> Exploration:
    """Show ``draw(**defaults)`` (anything Jupyter displays) and a :class:`Slider` per keyword
    of ``draw`` in ``specs`` that redraws it (``controls=False``: the static figure only)."""
    if not callable(draw):
        raise ValueError(f"draw: expected a callable, got {type(draw).__name__}")
    if not specs:
        raise ValueError("specs: expected at least one control (name=Slider(...))")
    for name, spec in specs.items():
        check_type(spec, Slider, name, "a Slider")
    shown = Exploration(draw, {k: s.default for k, s in specs.items()})
    shown.figure = draw(**shown.values)
    try:
        from IPython import get_ipython
        from IPython.display import display
    except ImportError:  # no IPython: nothing to display, the figure is returned
        return shown
    if get_ipython() is None:
        return shown
    w = None
    if controls:
        with contextlib.suppress(ImportError):
            import ipywidgets as w
    if w is None:
        shown._handle = display(shown.figure, display_id=True)
        if controls:
            display("(install ipywidgets to move the controls; the figure shows the defaults)")
        return shown
    figure = _display_output(shown.figure)
    # For pages without a live kernel: the default figure, hidden where widgets are live.
    display({**figure["data"], _WIDGET_VIEW: _NO_WIDGET}, metadata=figure["metadata"], raw=True)
    shown._output = w.Output(outputs=(figure,))
    sliders = {k: s.widget(k) for k, s in specs.items()}
    for k, slider in sliders.items():
        slider.observe(lambda change, k=k: shown._moved(k, change["new"]), names="value")
    shown.controls = w.VBox([shown._output, *sliders.values()])
    # an exported page without widget state shows text/plain: name the controls there
    bundle = dict(shown.controls._repr_mimebundle_() or {})
    names = ", ".join(specs)
    bundle["text/plain"] = f"(controls for {names}: run the notebook in Jupyter to move them)"
    display(bundle, raw=True)
    return shown
