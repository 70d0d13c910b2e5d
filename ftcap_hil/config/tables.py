"""Reading TOML tables: typed values with errors that name the file, the table and the key."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import numpy as np

from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.messages import FloatArray


def get(table: dict[str, Any], key: str, where: str, default: Any = ...) -> Any:
    if key in table:
        return table[key]
    if default is ...:
        raise ConfigError(f"{where}.{key}: missing")
    return default


def number(table: dict[str, Any], key: str, where: str, default: Any = ...) -> float:
    v = get(table, key, where, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def vector(v: Any, where: str, length: int | None = None) -> FloatArray:
    try:
        arr = np.atleast_1d(np.asarray(v, dtype=np.float64))
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected numbers, got {v!r}") from None
    if arr.ndim != 1 or (length is not None and arr.size != length) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}: expected {length or 'some'} finite numbers, got {v!r}")
    return arr


def dataclass_from_table(cls: type, table: dict[str, Any], where: str, **extra: Any) -> Any:
    known = {f.name for f in fields(cls)}
    unknown = set(table) - known
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(known)})")
    try:
        return cls(**{**table, **extra})
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from e
