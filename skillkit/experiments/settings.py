"""Typed experiment settings: frozen dataclasses (:class:`Settings`) whose fields
(:func:`setting`) are documented and checked.

Construction checks every value against the field's annotation and range and normalises it
(lists become tuples, an ``int`` for a ``float`` field a ``float``, a mapping for a nested
settings field updates that field); anything else (a string for an int, a bool for a number,
NaN or ±inf, a value outside a ``Literal`` or the range) raises :class:`ValueError` naming the
field. :meth:`Settings.to_dict` is what ``result.json`` stores and checkpoints hash.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar, Union

import numpy as np

from skillkit._validation import check_type

__all__ = ["Settings", "apply_overrides", "describe", "scales", "setting", "type_name"]

_DOC = "doc"
S = TypeVar("S", bound="Settings")


def setting(
    default: Any,
    doc: str,
    *,
    minimum: float | None = None,
    above: float | None = None,
    maximum: float | None = None,
) -> Any:
    """A settings field: its ``default`` (the ``quick`` scale's), ``doc`` (meaning, unit, thesis
    section) and range (≥ ``minimum``, > ``above``, ≤ ``maximum``; every number of a list)."""
    if not isinstance(doc, str) or not doc.strip():
        raise ValueError("doc: every settings field needs a description")
    bounds = {"minimum": minimum, "above": above, "maximum": maximum}
    for name, b in bounds.items():
        if b is not None and (isinstance(b, bool) or not np.isfinite(b)):
            raise ValueError(f"{name}: expected a finite number or None, got {b!r}")
    meta: dict[str, Any] = {_DOC: doc.strip()}
    meta.update({k: v for k, v in bounds.items() if v is not None})
    return field(default=default, metadata=meta)


def _range_text(metadata: Mapping[str, Any]) -> str:
    """The field's range as ``skillkit settings`` and errors show it ("" without one)."""
    signs = {"minimum": "≥", "above": ">", "maximum": "≤"}
    return " and ".join(f"{sign} {metadata[k]:g}" for k, sign in signs.items() if k in metadata)


def _numbers(value: Any) -> list[float]:
    """The numbers in a field's value (itself, or the entries of a list, nested)."""
    if isinstance(value, (bool, np.bool_)) or value is None or isinstance(value, str):
        return []
    if isinstance(value, (int, float, np.integer, np.floating)):
        return [value]
    if isinstance(value, (tuple, list)):
        return [x for v in value for x in _numbers(v)]
    return []


def _in_range(value: Any, metadata: Mapping[str, Any]) -> bool:
    lo, above, hi = metadata.get("minimum"), metadata.get("above"), metadata.get("maximum")
    return all(
        (lo is None or x >= lo) and (above is None or x > above) and (hi is None or x <= hi)
        for x in _numbers(value)
    )


def type_name(tp: Any) -> str:
    """A readable name of a field type, as error messages and ``skillkit settings`` show it."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {type_name(args[0])}"
        return "list [" + ", ".join(type_name(a) for a in args) + "]"
    if origin in (Union, types.UnionType):
        return " or ".join(type_name(a) for a in args)
    if tp is type(None):
        return "null"
    if tp is float:
        return "finite float"
    if isinstance(tp, type) and issubclass(tp, Settings):
        return f"{tp.__name__} (a mapping of its fields)"
    return getattr(tp, "__name__", str(tp))


class _Mismatch(Exception):
    """A value does not fit a type (internal; turned into a ValueError naming the field)."""


def _coerce(value: Any, tp: Any, current: Any = None) -> Any:
    """``value`` checked against ``tp`` and normalised (see the module docstring)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return value
    if tp is type(None):
        if value is None:
            return None
        raise _Mismatch
    if origin is Literal:
        for a in args:
            if type(value) is type(a) and value == a:
                return value
        raise _Mismatch
    if origin in (Union, types.UnionType):
        for a in args:
            try:
                return _coerce(value, a, current)
            except (_Mismatch, ValueError):
                continue
        raise _Mismatch
    if origin is tuple:
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if not isinstance(value, (list, tuple)):
            raise _Mismatch
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0]) for v in value)
        if len(value) != len(args):
            raise _Mismatch
        return tuple(_coerce(v, a) for v, a in zip(value, args, strict=True))
    if tp in (bool, int, float, str):
        flag = isinstance(value, (bool, np.bool_))
        if tp is bool:
            fits = flag
        elif tp is int:
            fits = isinstance(value, (int, np.integer)) and not flag
        elif tp is float:  # not NaN or ±inf (``--set x=NaN`` parses as JSON)
            number = isinstance(value, (int, float, np.integer, np.floating)) and not flag
            fits = number and np.isfinite(value)
        else:
            fits = isinstance(value, str)
        if not fits:
            raise _Mismatch
        return value if tp is str else tp(value)
    if isinstance(tp, type) and issubclass(tp, Settings):
        if isinstance(value, tp):
            return value
        if isinstance(value, Mapping):
            base = current if isinstance(current, tp) else tp()
            return apply_overrides(base, dict(value))
        raise _Mismatch
    raise TypeError(f"settings: unsupported field type {tp!r}")


@dataclass(frozen=True)
class Settings:
    """Base class of the experiments' settings: fields declared with :func:`setting`,
    validated on construction (also by :func:`dataclasses.replace` and
    :func:`apply_overrides`)."""

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            try:
                norm = _coerce(value, hints[f.name], f.default)  # a mapping updates the default
            except _Mismatch:
                raise ValueError(
                    f"{f.name}: expected {type_name(hints[f.name])}, got {value!r} "
                    f"({type(value).__name__}) in {type(self).__name__}"
                ) from None
            if not _in_range(norm, f.metadata):
                raise ValueError(
                    f"{f.name}: expected {_range_text(f.metadata)}"
                    f"{' (every entry)' if isinstance(norm, tuple) else ''}, got {value!r} in "
                    f"{type(self).__name__}"
                )
            if norm is not value:
                object.__setattr__(self, f.name, norm)
        self.check()

    def check(self) -> None:
        """Checks beyond the field types (relations between fields), run on every
        construction; subclasses raise ``ValueError`` naming the field."""

    def to_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (``dataclasses.asdict``; sequences stay tuples)."""
        return dataclasses.asdict(self)


def apply_overrides(settings: Settings, overrides: Mapping[str, Any]) -> Settings:
    """``settings`` with the fields of ``overrides`` (name → value; a nested settings field
    also takes a mapping of some of its fields) replaced.

    Raises
    ------
    ValueError
        An unknown name (the message lists the valid ones) or a value of the wrong type (the
        message names the field and the expected type).
    """
    check_type(settings, Settings, "settings", "a Settings instance")
    names = [f.name for f in dataclasses.fields(settings)]
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ValueError(
            f"{', '.join(unknown)}: not a setting of {type(settings).__name__} "
            f"(settings: {', '.join(names)})"
        )
    hints = typing.get_type_hints(type(settings))
    values = {}
    for name, value in overrides.items():
        try:
            values[name] = _coerce(value, hints[name], getattr(settings, name))
        except _Mismatch:
            raise ValueError(
                f"{name}: expected {type_name(hints[name])}, got {value!r} ({type(value).__name__})"
            ) from None
        except ValueError as exc:  # a field of a nested settings mapping
            raise ValueError(f"{name}.{exc}") from None
    return dataclasses.replace(settings, **values)


def describe(cls: type[Settings]) -> list[tuple[str, str, str]]:
    """``(name, type, description)`` of every field of a settings class, in order."""
    hints = typing.get_type_hints(cls)
    return [
        (
            f.name,
            " ".join(filter(None, (type_name(hints[f.name]), _range_text(f.metadata)))),
            f.metadata.get(_DOC, ""),
        )
        for f in dataclasses.fields(cls)
    ]


def scales(
    base: S,
    *,
    smoke: Mapping[str, Any] | None = None,
    quick: Mapping[str, Any] | None = None,
    paper: Mapping[str, Any] | None = None,
    shared: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, S]:
    """``{"smoke": ..., "quick": ..., "paper": ...}``: ``base`` with each scale's changes
    (field name → value, checked as by :func:`apply_overrides`) applied, after the changes
    ``shared[scale]`` that a family of experiments has in common (a nested block's mapping
    changes only the fields it names, so both may change one block)."""
    changes = {"smoke": smoke, "quick": quick, "paper": paper}
    shared = shared or {}
    return {
        scale: apply_overrides(apply_overrides(base, dict(shared.get(scale) or {})), dict(c or {}))
        for scale, c in changes.items()
    }
