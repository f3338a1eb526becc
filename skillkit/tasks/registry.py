"""A tagged registry of task factories, like dm_control's ``suite``.

Task variants (thesis setting, real-robot setting, noisy) are factory functions registered
by name; :func:`make` builds one.
"""

from __future__ import annotations

from collections.abc import Callable

_FACTORIES: dict[str, Callable] = {}
_TAGS: dict[str, frozenset[str]] = {}


def register(name: str, *tags: str) -> Callable[[Callable], Callable]:
    """Decorator registering ``factory`` under ``name`` with optional tags."""

    def deco(factory: Callable) -> Callable:
        if name in _FACTORIES and _FACTORIES[name] is not factory:
            raise ValueError(f"name: task {name!r} is already registered")
        _FACTORIES[name] = factory
        _TAGS[name] = frozenset(tags)
        return factory

    return deco


def names(tag: str | None = None) -> list[str]:
    """Registered task names, optionally only those carrying ``tag``."""
    return sorted(n for n in _FACTORIES if tag is None or tag in _TAGS[n])


def tags(name: str) -> frozenset[str]:
    """The tags of a registered task."""
    _check(name)
    return _TAGS[name]


def make(name: str, **kwargs):
    """Build the task registered as ``name`` (keyword arguments go to its factory)."""
    _check(name)
    return _FACTORIES[name](**kwargs)


def _check(name: str) -> None:
    if name not in _FACTORIES:
        known = ", ".join(names()) or "none"
        raise ValueError(f"task: unknown task {name!r}; registered tasks: {known}")
