"""A strict reader of TOML tables: typed getters, and an error for every key nobody read.

Every loader reads its file through one :class:`Table` per TOML table::

    with Table.document(doc) as root:            # doc: a TomlFile (file name for messages)
        d = root.table("daemon")
        rate_hz = d.number("rate_hz", 3.5, positive=True)
        mode = d.enum("mode", Mode, Mode.FTCAP)
        faults = [(f.number("from"), f.number("until", None)) for f in root.tables("fault")]
    # leaving the block: ConfigError for any key of any table above that no getter asked for

A getter marks its key as known whether or not the key is present (an absent key takes the
default), so the keys a loader asks about are exactly the valid keys. Every message names
the file, the table and the key; a bad value adds the value and the expected form, an
unknown key the nearest valid key (difflib) and the valid keys::

    allocator.toml: [daemon] unknown key 'rate_hzz' (did you mean 'rate_hz'?); valid keys: ...
    scenario.toml: [[fault]][0] unknown key 'untill' (did you mean 'until'?); valid keys: ...
    scenario.toml: [scenario] dt: expected a number > 0, got -0.5
"""

from __future__ import annotations

import difflib
import enum
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Self, TypeVar, overload

import numpy as np

from ftcap_hil.config.toml import TomlFile
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.messages import FloatArray

E = TypeVar("E", bound=enum.Enum)


class _Missing(enum.Enum):
    MISSING = enum.auto()


MISSING = _Missing.MISSING  # "no default": the key is required


def nearest(word: str, candidates: Iterable[str]) -> str | None:
    """The candidate closest to ``word`` (difflib ratio >= 0.6), None if none is close."""
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return close[0] if close else None


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _bounds_text(lo: float | None, hi: float | None, positive: bool = False) -> str:
    """`` > 0``, `` in 0..1``, `` >= 1`` or ``""``: how a bound reads in a message."""
    if lo is not None and hi is not None and not positive:
        return f" in {lo:g}..{hi:g}"
    parts = ["> 0"] if positive else []
    if lo is not None and not (positive and lo <= 0):
        parts.append(f">= {lo:g}")
    if hi is not None:
        parts.append(f"<= {hi:g}")
    return " " + " and ".join(parts) if parts else ""


class Table:
    """One table of a configuration file, read key by key (module docstring).

    ``data``: the table's mapping; ``file``: the file's name for messages; ``name``: the
    dotted table path (``""`` for the document itself); ``index``: the element's position
    when the table is one entry of an array of tables (``[[fault]][0]``).
    """

    def __init__(
        self, data: Mapping[str, Any], file: str, name: str = "", index: int | None = None
    ) -> None:
        self.data = data
        self.file = file
        self.name = name
        self.index = index
        self._known: set[str] = set()
        self._children: list[Table] = []
        self._finished = False

    @classmethod
    def document(cls, doc: TomlFile) -> Table:
        """The top level of a parsed TOML file."""
        return cls(doc.data, doc.source)

    # ----------------------------------------------------------------- messages

    @property
    def label(self) -> str:
        """``[daemon]``, ``[[fault]][0]`` or ``""`` for the document itself."""
        if self.index is not None:
            return f"[[{self.name}]][{self.index}]"
        return f"[{self.name}]" if self.name else ""

    def where(self, key: str | None = None) -> str:
        """``file: [table] key`` (the prefix of every message about this table)."""
        parts = [p for p in (self.label, key) if p]
        return f"{self.file}: {' '.join(parts)}" if parts else self.file

    def error(self, key: str | None, problem: str) -> ConfigError:
        """A ConfigError ``file: [table] key: problem`` (``file: [table] problem`` without
        a key)."""
        if key is None:
            return ConfigError(f"{self.file}: {self.label + ' ' if self.label else ''}{problem}")
        return ConfigError(f"{self.where(key)}: {problem}")

    def _bad(self, key: str, expected: str, value: object) -> ConfigError:
        return self.error(key, f"expected {expected}, got {value!r}")

    # ----------------------------------------------------------------- raw access

    def has(self, key: str) -> bool:
        """Whether the file gives ``key`` (does not mark it as read)."""
        return key in self.data

    def allow(self, *keys: str) -> None:
        """Mark ``keys`` as valid without reading them (read elsewhere, or ignored on purpose)."""
        self._known.update(keys)

    def value(self, key: str, default: Any = MISSING) -> Any:
        """The raw value; ``default`` if absent; ConfigError ``missing`` if required."""
        self._known.add(key)
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            raise self.error(key, f"missing{self._typo_of(key)}")
        return default

    def _typo_of(self, key: str) -> str:
        """`` ('kye' is given: a typo?)`` for a given, unread key very close to ``key``."""
        unread = [k for k in self.data if k not in self._known]
        close = difflib.get_close_matches(key, unread, n=1, cutoff=0.8)
        return f" ({close[0]!r} is given: a typo?)" if close else ""

    def _missing_table(self, key: str, array: bool) -> ConfigError:
        self._known.add(key)
        name = f"{self.name}.{key}" if self.name else key
        table = f"[[{name}]]" if array else f"[{name}]"
        within = f" in {self.label}" if self.index is not None else ""
        return ConfigError(f"{self.file}: {table} missing{within}{self._typo_of(key)}")

    def renamed(self, old: str, new: str) -> None:
        """Refuse ``old``, a key (or, at the top of a file, a table) now called ``new``."""
        if old not in self.data:
            return
        self._known.add(old)
        if not self.name and isinstance(self.data[old], dict | list):
            raise self.error(None, f"table [{old}] is now called [{new}] (same keys)")
        raise self.error(old, f"this key is now called {new!r}")

    # ----------------------------------------------------------------- scalars

    @overload
    def number(
        self,
        key: str,
        default: float | _Missing = ...,
        *,
        lo: float | None = ...,
        hi: float | None = ...,
        positive: bool = ...,
    ) -> float: ...
    @overload
    def number(
        self,
        key: str,
        default: None,
        *,
        lo: float | None = ...,
        hi: float | None = ...,
        positive: bool = ...,
    ) -> float | None: ...
    def number(
        self,
        key: str,
        default: float | None | _Missing = MISSING,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> float | None:
        """A finite number (an integer is accepted) within ``lo``/``hi`` (and > 0 if
        ``positive``); ``default`` if absent (not checked, may be None)."""
        v = self.value(key, default)
        if key not in self.data:
            return None if v is None else float(v)
        ok = _is_number(v) and math.isfinite(v)
        ok = ok and not (positive and v <= 0) and not (lo is not None and v < lo)
        if not ok or (hi is not None and v > hi):
            raise self._bad(key, f"a finite number{_bounds_text(lo, hi, positive)}", v)
        return float(v)

    @overload
    def integer(
        self, key: str, default: int | _Missing = ..., *, lo: int | None = ..., hi: int | None = ...
    ) -> int: ...
    @overload
    def integer(
        self, key: str, default: None, *, lo: int | None = ..., hi: int | None = ...
    ) -> int | None: ...
    def integer(
        self,
        key: str,
        default: int | None | _Missing = MISSING,
        *,
        lo: int | None = None,
        hi: int | None = None,
    ) -> int | None:
        """An integer (not a bool, not 2.0) within ``lo``..``hi``; ``default`` if absent."""
        v = self.value(key, default)
        if key not in self.data:
            return v
        ok = isinstance(v, int) and not isinstance(v, bool)
        if not ok or (lo is not None and v < lo) or (hi is not None and v > hi):
            raise self._bad(key, f"an integer{_bounds_text(lo, hi)}", v)
        return int(v)

    def boolean(self, key: str, default: bool | _Missing = MISSING) -> bool:
        """``true`` or ``false`` (not 0/1)."""
        v = self.value(key, default)
        if not isinstance(v, bool):
            raise self._bad(key, "true or false", v)
        return v

    @overload
    def string(self, key: str, default: str | _Missing = ...) -> str: ...
    @overload
    def string(self, key: str, default: None) -> str | None: ...
    def string(self, key: str, default: str | None | _Missing = MISSING) -> str | None:
        """A non-empty string; ``default`` if absent."""
        v = self.value(key, default)
        if key not in self.data:
            return v
        if not isinstance(v, str) or not v:
            raise self._bad(key, "a non-empty string", v)
        return v

    def choice(self, key: str, choices: Sequence[str], default: str | _Missing = MISSING) -> str:
        """One of ``choices``; a bad value names the choices (and the nearest one)."""
        v = self.value(key, default)
        if not isinstance(v, str) or v not in choices:
            near = nearest(v, choices) if isinstance(v, str) else None
            hint = f" (did you mean {near!r}?)" if near else ""
            shown = ", ".join(repr(c) for c in choices)
            raise self.error(key, f"{v!r} is not one of {shown}{hint}")
        return v

    def enum(
        self, key: str, cls: type[E], default: E | _Missing = MISSING, exclude: Iterable[E] = ()
    ) -> E:
        """A member of the string-valued Enum ``cls`` (by value), ``exclude`` left out."""
        left_out = set(exclude)
        values = [m.value for m in cls if m not in left_out]
        text = self.choice(key, values, default.value if isinstance(default, cls) else MISSING)
        return cls(text)

    # ----------------------------------------------------------------- sequences

    def vector(
        self,
        key: str,
        n: int | None = None,
        default: Sequence[float] | _Missing = MISSING,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> FloatArray:
        """A list of ``n`` (any number if None, at least one) finite numbers within bounds."""
        v = self.value(key, default)
        ok = isinstance(v, list | tuple) and all(_is_number(x) for x in v)
        arr = np.array(v, dtype=np.float64) if ok else np.zeros(0)
        ok = ok and arr.size > 0 and (n is None or arr.size == n) and bool(np.all(np.isfinite(arr)))
        ok = (
            ok and not (positive and np.any(arr <= 0)) and not (lo is not None and np.any(arr < lo))
        )
        if not ok or (hi is not None and np.any(arr > hi)):
            count = "some" if n is None else str(n)
            raise self._bad(key, f"{count} finite numbers{_bounds_text(lo, hi, positive)}", v)
        return arr

    def integers(
        self,
        key: str,
        n: int | None = None,
        default: Sequence[int] | _Missing = MISSING,
        *,
        lo: int | None = None,
        hi: int | None = None,
    ) -> tuple[int, ...]:
        """A list of ``n`` (any number if None) integers within ``lo``..``hi``."""
        v = self.value(key, default)
        ok = isinstance(v, list | tuple) and (n is None or len(v) == n)
        ok = ok and all(isinstance(x, int) and not isinstance(x, bool) for x in v)
        ok = ok and all((lo is None or x >= lo) and (hi is None or x <= hi) for x in v)
        if not ok:
            count = "" if n is None else f"{n} "
            raise self._bad(key, f"a list of {count}integers{_bounds_text(lo, hi)}", v)
        return tuple(v)

    def strings(self, key: str, default: Sequence[str] | _Missing = MISSING) -> tuple[str, ...]:
        """A list of strings (a single string is not a list)."""
        v = self.value(key, default)
        if not isinstance(v, list | tuple) or not all(isinstance(x, str) for x in v):
            raise self._bad(key, "a list of strings", v)
        return tuple(v)

    # ----------------------------------------------------------------- nested tables

    def _child(self, key: str, data: Mapping[str, Any], index: int | None = None) -> Table:
        name = f"{self.name}.{key}" if self.name else key
        for child in self._children:  # read twice: the same reader, the same read keys
            if child.name == name and child.index == index and child.data is data:
                return child
        child = Table(data, self.file, name, index)
        self._children.append(child)
        return child

    def table(self, key: str, required: bool = False) -> Table:
        """The sub-table ``[key]`` (an empty one if absent and not required)."""
        if required and key not in self.data:
            raise self._missing_table(key, array=False)
        v = self.value(key, {})
        if not isinstance(v, dict):
            raise self._bad(key, "a table", v)
        return self._child(key, v)

    def tables(self, key: str, required: bool = False) -> list[Table]:
        """The array of tables ``[[key]]`` (empty if absent and not required)."""
        if required and key not in self.data:
            raise self._missing_table(key, array=True)
        v = self.value(key, [])
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise self._bad(key, f"an array of tables [[{key}]]", v)
        if required and not v:
            raise self.error(key, f"expected at least one [[{key}]], got none")
        return [self._child(key, x, i) for i, x in enumerate(v)]

    # ----------------------------------------------------------------- the end

    def unknown(self) -> list[str]:
        """Keys of this table no getter asked for, in file order."""
        return [k for k in self.data if k not in self._known]

    def finish(self) -> None:
        """ConfigError for the first unknown key of this table or any table read from it."""
        if self._finished:
            return
        for key in self.unknown():
            raise self._unknown_error(key)
        for child in self._children:
            child.finish()
        self._finished = True

    def _unknown_error(self, key: str) -> ConfigError:
        is_table = not self.name and isinstance(self.data[key], dict | list)
        what = "table" if is_table else "key"
        near = nearest(key, self._known)
        hint = f" (did you mean {near!r}?)" if near else ""
        valid = ", ".join(sorted(self._known)) or "none"
        return self.error(None, f"unknown {what} {key!r}{hint}; valid {what}s: {valid}")

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        if exc_type is None:
            self.finish()
