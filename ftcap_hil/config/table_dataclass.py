"""A dataclass read from a :class:`~ftcap_hil.config.tables.Table`, one key per field, each
by the getter its annotation calls for::

    est = read_dataclass(root.table("estimator"), EstimatorConfig)

The dataclass's own defaults are the only defaults: an absent key leaves its field unset.
"""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, TypeVar

from ftcap_hil.config.tables import Table

D = TypeVar("D")


def read_dataclass(
    t: Table,
    cls: type[D],
    *,
    choices: Mapping[str, Sequence[Any]] | None = None,
    exclude: Iterable[str] = (),
    defaults: Mapping[str, Any] | None = None,
) -> D:
    """``cls`` from ``t``: every init field but ``exclude`` is a valid key, read as its
    annotation says (float, int, bool, str, an Enum by its value, ``tuple[float, ...]``, any
    of them ``| None``); ``choices[field]`` narrows a str field to those strings, an Enum
    field to those members. ``defaults`` replace the dataclass's own. A TypeError or
    ValueError of ``cls`` (its own checks) becomes a ConfigError naming the table."""
    hints = typing.get_type_hints(cls)
    given: dict[str, Any] = dict(defaults or {})
    left_out, narrowed = set(exclude), choices or {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in left_out or not f.init:
            continue
        t.allow(f.name)
        if t.has(f.name):
            given[f.name] = _typed(t, f.name, hints[f.name], narrowed.get(f.name))
    try:
        return cls(**given)
    except (TypeError, ValueError) as e:
        raise t.error(None, str(e)) from e


def defaults_of(cls: type) -> dict[str, Any]:
    """The defaults of the dataclass ``cls`` by field name (``default_factory`` called):
    what a loader falls back to for a key the file leaves out, so that each default is
    written once, in the dataclass."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def _typed(t: Table, key: str, hint: Any, choices: Sequence[Any] | None) -> Any:
    if types.NoneType in typing.get_args(hint):  # ``X | None``: read as X
        hint = next(a for a in typing.get_args(hint) if a is not types.NoneType)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        kept = set(hint) if choices is None else set(choices)
        return t.enum(key, hint, exclude=[m for m in hint if m not in kept])
    if choices is not None:
        return t.choice(key, choices)
    if typing.get_origin(hint) is tuple and typing.get_args(hint) == (float, ...):
        return tuple(float(x) for x in t.vector(key))
    getter: dict[Any, Callable[[str], Any]] = {
        float: t.number,
        int: t.integer,
        bool: t.boolean,
        str: t.string,
    }
    if hint not in getter:
        raise TypeError(f"read_dataclass: no getter for {key}: {hint}")
    return getter[hint](key)
