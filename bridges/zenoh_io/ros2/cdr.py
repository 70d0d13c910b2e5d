"""CDR (XCDR1, as ROS 2 writes it) for the message types of a :class:`~.msgdef.Registry`.

A payload is the 4-byte encapsulation header, ``00 01 00 00`` (CDR, little endian; options
zero), then the fields in definition order, each primitive aligned to its own size (1, 2, 4
or 8 bytes) counted from the first byte after the header:

* a nested message is its fields in place (no alignment of its own, no length);
* a string is a uint32 length that counts a terminating NUL, the UTF-8 bytes, the NUL;
* an unbounded sequence is a uint32 element count, then the elements; a fixed array is its
  elements only.

Values are plain Python: a message is a dict by field name (a missing field is its zero:
0, False, "", an empty sequence, a zero message), a sequence or an array any iterable.
:func:`decode` reads little- and big-endian payloads (header ``00 01`` or ``00 00``) and
raises :class:`~ftcap_hil.core.errors.MalformedMessage` for anything else: another
encapsulation, a truncated payload, a count beyond the bytes left, a string without its NUL
or not UTF-8, a payload above :data:`MAX_PAYLOAD_BYTES`. Pure: no zenoh import.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping
from typing import Any

from bridges.zenoh_io.ros2.msgdef import PRIMITIVES, STRING, Field, Registry
from ftcap_hil.core.errors import MalformedMessage

CDR_LE = b"\x00\x01\x00\x00"
_ENCAPSULATIONS = {b"\x00\x01": "<", b"\x00\x00": ">"}
MAX_PAYLOAD_BYTES = 65536  # as the JSON payloads (fields.MAX_PAYLOAD_BYTES)


class _Writer:
    def __init__(self, registry: Registry) -> None:
        self.registry = registry
        self.buf = bytearray(CDR_LE)

    def align(self, size: int) -> None:
        """Pad to a multiple of ``size`` counted after the header."""
        self.buf += bytes(-(len(self.buf) - 4) % size)

    def primitives(self, base: str, values: Iterable[Any]) -> None:
        """Primitives of one type, aligned once (the rest fall in line)."""
        code, size = PRIMITIVES[base]
        items = list(values)
        if items:
            self.align(size)
            self.buf += struct.pack(f"<{len(items)}{code}", *items)

    def string(self, text: str) -> None:
        """Length (with the NUL), UTF-8 bytes, NUL."""
        data = text.encode("utf-8")
        self.primitives("uint32", (len(data) + 1,))
        self.buf += data + b"\x00"

    def message(self, name: str, value: Mapping[str, Any]) -> None:
        """The fields of type ``name`` in order (missing: zero)."""
        for f in self.registry[name].fields:
            self.field(f, value.get(f.name))

    def field(self, f: Field, value: Any) -> None:
        """One field: an element, a fixed array or a counted sequence."""
        if f.array is None and not f.sequence:
            self.element(f, value)
            return
        items = [] if value is None else list(value)
        if f.array is not None and len(items) != f.array:
            raise ValueError(f"{f.name}: expected {f.array} elements, got {len(items)}")
        if f.sequence:
            self.primitives("uint32", (len(items),))
        if f.base in PRIMITIVES:
            self.primitives(f.base, items)
        else:
            for item in items:
                self.element(f, item)

    def element(self, f: Field, value: Any) -> None:
        """One element of a field: a primitive, a string or a message."""
        if f.base in PRIMITIVES:
            self.primitives(f.base, (0 if value is None else value,))
        elif f.base == STRING:
            self.string("" if value is None else str(value))
        else:
            self.message(f.base, {} if value is None else value)


def encode(registry: Registry, name: str, value: Mapping[str, Any]) -> bytes:
    """``value`` (a dict by field name) of type ``name`` as a CDR payload with its header;
    ValueError for a value that does not fit its field (a wrong length, an int out of range)."""
    writer = _Writer(registry)
    try:
        writer.message(name, value)
    except struct.error as e:
        raise ValueError(f"{name}: {e}") from e
    return bytes(writer.buf)


class _Reader:
    def __init__(self, registry: Registry, payload: bytes, order: str) -> None:
        self.registry = registry
        self.data = payload
        self.pos = 4
        self.order = order

    def take(self, n: int) -> bytes:
        """The next ``n`` bytes; MalformedMessage past the end."""
        if n > len(self.data) - self.pos:
            raise MalformedMessage(f"CDR payload truncated at byte {self.pos} (needs {n} more)")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def primitives(self, base: str, count: int) -> tuple[Any, ...]:
        """``count`` primitives of one type, aligned once."""
        code, size = PRIMITIVES[base]
        if count == 0:
            return ()
        self.take(-(self.pos - 4) % size)
        return struct.unpack(f"{self.order}{count}{code}", self.take(size * count))

    def count(self, f: Field, element_size: int) -> int:
        """A sequence's element count, refused if the bytes left cannot hold it."""
        (n,) = self.primitives("uint32", 1)
        if n * element_size > len(self.data) - self.pos:
            raise MalformedMessage(f"{f.name}: {n} elements announced, the payload is shorter")
        return int(n)

    def string(self) -> str:
        """A string; MalformedMessage without its NUL or not UTF-8."""
        (n,) = self.primitives("uint32", 1)
        if n == 0:  # some writers send an empty string as length 0
            return ""
        data = self.take(n)
        if data[-1] != 0:
            raise MalformedMessage("CDR string without its terminating NUL")
        try:
            return data[:-1].decode("utf-8")
        except UnicodeDecodeError as e:
            raise MalformedMessage(f"CDR string is not UTF-8: {e}") from None

    def message(self, name: str) -> dict[str, Any]:
        """The fields of type ``name`` as a dict."""
        return {f.name: self.field(f) for f in self.registry[name].fields}

    def field(self, f: Field) -> Any:
        """One field: an element, a fixed array or a counted sequence."""
        if f.array is None and not f.sequence:
            return self.element(f)
        size = PRIMITIVES[f.base][1] if f.base in PRIMITIVES else 1
        n = self.count(f, size) if f.sequence else int(f.array or 0)
        if f.base in PRIMITIVES:
            return list(self.primitives(f.base, n))
        return [self.element(f) for _ in range(n)]

    def element(self, f: Field) -> Any:
        """One element: a primitive, a string or a message."""
        if f.base in PRIMITIVES:
            return self.primitives(f.base, 1)[0]
        if f.base == STRING:
            return self.string()
        return self.message(f.base)


def decode(registry: Registry, name: str, payload: bytes) -> dict[str, Any]:
    """The dict of a CDR payload of type ``name`` (module docstring); trailing bytes (a
    writer's padding) are ignored."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MalformedMessage(f"CDR payload of {len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    order = _ENCAPSULATIONS.get(bytes(payload[:2]))
    if order is None or len(payload) < 4:
        head = bytes(payload[:4]).hex(" ")
        raise MalformedMessage(f"not a plain CDR payload (encapsulation header {head!r})")
    try:
        return _Reader(registry, bytes(payload), order).message(name)
    except struct.error as e:  # cannot happen after take()'s checks; never a traceback
        raise MalformedMessage(f"CDR payload unreadable: {e}") from e
