"""ROS 2 message definitions: the ``.msg`` subset this bridge uses, parsed into field lists.

One definition per type serves three purposes: the CDR codec walks its fields
(:mod:`bridges.zenoh_io.ros2.cdr`), the REP-2011 type hash is computed from it
(:mod:`bridges.zenoh_io.ros2.type_hash`), and an MCAP schema is its text with its
dependencies appended (:meth:`Registry.schema_text`, the ``ros2msg`` schema encoding).

The grammar read (the ``.msg`` format of ROS 2 interfaces, less what no type here needs):

* a field ``TYPE NAME`` or ``TYPE NAME DEFAULT`` (the default is kept as text: it is
  not part of the CDR bytes nor of the hash);
* a constant ``TYPE NAME=VALUE`` (no bytes, no hash: it is kept for the schema text);
* ``TYPE`` is a primitive (:data:`PRIMITIVES`), ``string``, ``string<=N``, or a nested
  type ``pkg/Name`` (``Name`` alone: the same package), followed by ``[]`` (an unbounded
  sequence) or ``[N]`` (a fixed array); a bounded sequence ``[<=N]`` is refused;
* ``#`` starts a comment (outside a string constant's value).

Type names are ``pkg/msg/Name`` throughout. Pure: no zenoh import.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

# .msg primitive -> (struct code, size in bytes). char is uint8 and byte is octet in ROS 2.
PRIMITIVES: dict[str, tuple[str, int]] = {
    "bool": ("?", 1),
    "byte": ("B", 1),
    "char": ("B", 1),
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}
STRING = "string"
_NAME = re.compile(r"[a-z][a-z0-9_]*")
_TYPE = re.compile(
    r"(?P<base>[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*)?)"
    r"(?:<=(?P<bound>\d+))?"
    r"(?:\[(?P<array>(?:<=)?\d*)\])?$"
)


class MsgDefError(ValueError):
    """A ``.msg`` text this parser cannot read; the message names the type and the line."""


@dataclass(frozen=True)
class Field:
    """One field: ``base`` is a primitive, ``string`` or a nested ``pkg/msg/Name``;
    ``array`` the fixed length (None: not an array), ``sequence`` an unbounded sequence,
    ``string_bound`` the bound of a ``string<=N`` (0: unbounded)."""

    name: str
    base: str
    array: int | None = None
    sequence: bool = False
    string_bound: int = 0
    default: str | None = None

    @property
    def nested(self) -> bool:
        """The field's element is a message (not a primitive or a string)."""
        return self.base not in PRIMITIVES and self.base != STRING


@dataclass(frozen=True)
class Constant:
    """``TYPE NAME=VALUE``: kept for the schema text only."""

    type: str
    name: str
    value: str


@dataclass(frozen=True)
class MsgDef:
    """A parsed message type ``name`` (``pkg/msg/Name``) and its ``.msg`` text."""

    name: str
    fields: tuple[Field, ...]
    constants: tuple[Constant, ...]
    text: str

    @property
    def package(self) -> str:
        return self.name.split("/", 1)[0]

    def nested_types(self) -> list[str]:
        """The nested types its fields name, in field order, each once."""
        return list(dict.fromkeys(f.base for f in self.fields if f.nested))


def full_name(base: str, package: str) -> str:
    """``pkg/Name`` or ``Name`` (of ``package``) as ``pkg/msg/Name``; ``Header`` alone is
    ``std_msgs/msg/Header``, as in ROS 1 era definitions."""
    if "/" in base:
        pkg, name = base.split("/", 1)
        return f"{pkg}/msg/{name}"
    if base == "Header":
        return "std_msgs/msg/Header"
    return f"{package}/msg/{base}"


def _strip_comment(line: str) -> str:
    if "=" in line.split("#", 1)[0]:  # a constant: a string value may hold '#'
        return line.rstrip()
    return line.split("#", 1)[0].rstrip()


def _field_type(text: str, package: str, where: str) -> tuple[str, int | None, bool, int]:
    match = _TYPE.match(text)
    if match is None:
        raise MsgDefError(f"{where}: cannot read the type {text!r}")
    base, bound, array = match.group("base"), match.group("bound"), match.group("array")
    if bound is not None and base != STRING:
        raise MsgDefError(f"{where}: only string takes a bound (<=N), got {text!r}")
    if array is not None and array.startswith("<="):
        raise MsgDefError(f"{where}: bounded sequences are not supported ({text!r})")
    if base not in PRIMITIVES and base != STRING:
        base = full_name(base, package)
    fixed = int(array) if array else None
    return base, fixed, array == "", int(bound or 0)


def parse(name: str, text: str) -> MsgDef:
    """Parse the ``.msg`` ``text`` of type ``name`` (``pkg/msg/Name``); MsgDefError if bad."""
    package = name.split("/", 1)[0]
    fields: list[Field] = []
    constants: list[Constant] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = _strip_comment(raw).strip()
        if not line:
            continue
        where = f"{name} line {number}"
        type_text, _, rest = line.partition(" ")
        rest = rest.strip()
        if "=" in rest.split(" ", 1)[0] or re.match(r"^[A-Z][A-Z0-9_]*\s*=", rest):
            const_name, _, value = rest.partition("=")
            if type_text != STRING:
                value = value.split("#", 1)[0]
            constants.append(Constant(type_text, const_name.strip(), value.strip()))
            continue
        field_name, _, default = rest.partition(" ")
        if not _NAME.fullmatch(field_name):
            raise MsgDefError(f"{where}: bad field name {field_name!r}")
        base, fixed, sequence, bound = _field_type(type_text, package, where)
        fields.append(Field(field_name, base, fixed, sequence, bound, default.strip() or None))
    if not fields:
        raise MsgDefError(f"{name}: no fields (empty messages are not supported)")
    return MsgDef(name, tuple(fields), tuple(constants), text)


class Registry:
    """Message definitions by ``pkg/msg/Name``; every nested type must be registered."""

    def __init__(self, defs: Iterable[MsgDef] = ()) -> None:
        self._defs: dict[str, MsgDef] = {}
        for d in defs:
            self.add(d)

    def add(self, msgdef: MsgDef) -> None:
        """Register (or replace) one definition."""
        self._defs[msgdef.name] = msgdef

    def __getitem__(self, name: str) -> MsgDef:
        try:
            return self._defs[name]
        except KeyError:
            raise MsgDefError(f"unknown message type {name!r}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._defs

    def names(self) -> list[str]:
        """Every registered type name, sorted."""
        return sorted(self._defs)

    def dependencies(self, name: str) -> list[str]:
        """Every type ``name`` refers to, directly or not, in depth-first field order."""
        seen: dict[str, None] = {}

        def visit(type_name: str) -> None:
            for nested in self[type_name].nested_types():
                if nested not in seen:
                    seen[nested] = None
                    visit(nested)

        visit(name)
        return list(seen)

    def schema_text(self, name: str) -> str:
        """The ``ros2msg`` schema of ``name`` as MCAP (and rosbag2) write it: its ``.msg``
        text, then per dependency a line of 80 ``=``, ``MSG: pkg/Name`` and its text."""
        parts = [self[name].text.strip()]
        for dep in self.dependencies(name):
            pkg, _, short = dep.split("/")
            parts.append(f"{'=' * 80}\nMSG: {pkg}/{short}\n{self[dep].text.strip()}")
        return "\n".join(parts) + "\n"


def dds_type_name(name: str) -> str:
    """``pkg/msg/Name`` as the DDS type name in key expressions: ``pkg::msg::dds_::Name_``."""
    pkg, kind, short = name.split("/")
    return f"{pkg}::{kind}::dds_::{short}_"
