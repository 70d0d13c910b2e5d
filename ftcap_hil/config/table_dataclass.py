"""A dataclass read from a :class:`~ftcap_hil.config.tables.Table`, one key per field, each
by the getter its annotation calls for (``Table.dataclass``)."""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from ftcap_hil.config.tables import Table

D = TypeVar("D")


def read_dataclass(
    t: Table,
    cls: type[D],
    choices: Mapping[str, Sequence[str]],
    exclude: set[str],
    defaults: Mapping[str, Any],
) -> D:
    """``cls`` from ``t``: every init field but ``exclude`` is a valid key, read as its
    annotation says (float, int, bool, str, an Enum, ``tuple[float, ...]``, any of them
    ``| None``) or as one of ``choices[field]``; ``defaults`` replace the dataclass's own.
    A TypeError or ValueError of ``cls`` (its own checks) becomes a ConfigError naming the
    table."""
    hints = typing.get_type_hints(cls)
    given: dict[str, Any] = dict(defaults)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in exclude or not f.init:
            continue
        t.allow(f.name)
        if t.has(f.name):
            given[f.name] = _typed(t, f.name, hints[f.name], choices.get(f.name))
    try:
        return cls(**given)
    except (TypeError, ValueError) as e:
        raise t.error(None, str(e)) from e


def _typed(t: Table, key: str, hint: Any, choices: Sequence[str] | None) -> Any:
    if types.NoneType in typing.get_args(hint):  # ``X | None``: read as X
        hint = next(a for a in typing.get_args(hint) if a is not types.NoneType)
    if choices is not None:
        return t.choice(key, choices)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return t.enum(key, hint)
    if typing.get_origin(hint) is tuple and typing.get_args(hint) == (float, ...):
        return tuple(float(x) for x in t.vector(key))
    getter: dict[Any, Callable[[str], Any]] = {
        float: t.number,
        int: t.integer,
        bool: t.boolean,
        str: t.string,
    }
    if hint not in getter:
        raise TypeError(f"Table.dataclass: no getter for {key}: {hint}")
    return getter[hint](key)
