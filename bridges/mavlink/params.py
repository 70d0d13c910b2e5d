"""A generic MAVLink parameter server: a table of parameters and the parameter protocol.

:class:`ParamServer` is pure (no I/O): a table of :class:`ParamSpec`, thread-safe reads for
the loop thread, and the rules that accept or refuse a new value. :class:`ParamService`
answers the MAVLink parameter protocol on a :class:`~bridges.mavlink.link.MavlinkPort`:

* ``PARAM_REQUEST_LIST`` -> one ``PARAM_VALUE`` per parameter, in table order;
* ``PARAM_REQUEST_READ`` -> ``PARAM_VALUE`` by index, or by name when ``param_index == -1``;
* ``PARAM_SET`` -> ``PARAM_VALUE`` with the new value, or, if refused, a ``PARAM_ERROR``
  (MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, or _READ_ONLY for a parameter not settable while
  running) to the requester, the unchanged ``PARAM_VALUE`` and a ``STATUSTEXT`` (WARNING)
  that says why: a client that knows PARAM_ERROR reports the refusal, others see the value
  did not change.

Only authorized systems (:meth:`MavlinkPort.authorized`) are answered; the answers are paid
from the requester's reply budget. Unknown names or indices get no answer (as the protocol
says) and are counted in ``PortStats.ignored``.

Encoding: integer parameters travel as ``MAV_PARAM_TYPE_INT32`` **byte-wise** (the int32's
four bytes in the float field), which is what every client assumes of a vehicle that does
not say it is ArduPilot (QGroundControl, MAVSDK), and what the components advertise in
AUTOPILOT_VERSION (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE``). A ``PARAM_SET`` of an
integer parameter is also understood when the client C-casts the value (MAVProxy, which
assumes ArduPilot's convention): for a parameter whose limits lie within +-2**24, the two
readings never overlap (a C-cast integer >= 1 has float bits above 2**29; a byte-wise one is
0 or a denormal), so the one within the limits is the one meant; the answer to a C-cast
set goes to its sender C-cast too (MAVProxy compares it with what it set), byte-wise to
everyone else. A client reading an INT32 value can tell the two apart the same way
(:func:`int_from_either`). Names are upper case, at most 16 characters (MAVLink's ``param_id``).

Limits are compared in float32, the wire's precision: 0.99 sent as float32 is
0.99000001, which is "0.99" to the sender, so it is taken as the limit itself.

Validators run on the dispatch thread: they must be quick and pure (check the value, return
``None`` to accept or a short reason to refuse); the loop thread reads values with
:meth:`ParamServer.get` and can watch :attr:`ParamServer.generation` for changes.
"""

from __future__ import annotations

import enum
import math
import re
import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from bridges.mavlink.codec import Severity
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.link import MavlinkPort, Route

_NAME = re.compile(r"^[A-Z][A-Z0-9_]{0,15}$")
_INT_LIMIT = 2.0**24  # integers above this are not exact as float32


def float32(value: float) -> float:
    """``value`` rounded to the nearest float32 (what it becomes on the wire)."""
    try:
        return float(struct.unpack("<f", struct.pack("<f", value))[0])
    except OverflowError:
        return math.copysign(math.inf, value)


def int_to_wire(value: int) -> float:
    """An int32 parameter value as the float whose bytes it is (byte-wise encoding)."""
    return float(struct.unpack("<f", struct.pack("<i", value))[0])


def int_from_wire(raw: float) -> int:
    """The int32 whose bytes a byte-wise-encoded float carries."""
    return int(struct.unpack("<i", struct.pack("<f", raw))[0])


def int_from_either(raw: float) -> int:
    """An INT32 parameter value sent byte-wise or C-cast: the byte-wise reading when it is
    within +-2**24, else the float itself (module docstring: the two never overlap)."""
    bytewise = int_from_wire(raw)
    if abs(bytewise) <= _INT_LIMIT or not math.isfinite(raw) or not float(raw).is_integer():
        return bytewise
    return int(raw)


class ParamType(enum.Enum):
    """How a parameter travels: MAV_PARAM_TYPE_REAL32 (FLOAT) or _INT32 (INT)."""

    FLOAT = "float"
    INT = "int"


Validator = Callable[[float], str | None]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name (<= 16 chars, upper case), type, default and limits (inclusive)."""

    name: str
    default: float
    kind: ParamType = ParamType.FLOAT
    min: float = -math.inf
    max: float = math.inf
    settable_while_running: bool = True
    validate: Validator | None = None
    description: str = ""


@dataclass(frozen=True)
class SetResult:
    """The outcome of :meth:`ParamServer.set` (``reason``: why it was refused)."""

    accepted: bool
    value: float  # the value in force after the attempt
    reason: str = ""


class ParamServer:
    """Thread-safe parameter table; see the module docstring for the rules."""

    def __init__(self, specs: Sequence[ParamSpec]) -> None:
        self._specs = tuple(specs)
        self._index = {spec.name: i for i, spec in enumerate(self._specs)}
        if len(self._index) != len(self._specs):
            names = [s.name for s in self._specs]
            dupes = sorted({n for n in names if names.count(n) > 1})
            raise LinkConfigError(f"params: duplicate names {dupes}")
        for spec in self._specs:
            self._check_spec(spec)
        self._values = [float(spec.default) for spec in self._specs]
        self._lock = threading.Lock()
        self._running = False
        self.generation = 0  # bumped on every accepted change

    @staticmethod
    def _check_spec(spec: ParamSpec) -> None:
        key = f"params.{spec.name}"
        if not _NAME.match(spec.name):
            raise LinkConfigError(f"{key}: name must be 1-16 chars of A-Z, 0-9, _ ({spec.name!r})")
        if not spec.min <= spec.default <= spec.max:
            raise LinkConfigError(f"{key}: default {spec.default} outside [{spec.min}, {spec.max}]")
        if spec.kind is ParamType.INT:
            if not float(spec.default).is_integer() or abs(spec.default) > _INT_LIMIT:
                raise LinkConfigError(f"{key}: default {spec.default} is not an int32 in +-2**24")

    @property
    def specs(self) -> tuple[ParamSpec, ...]:
        return self._specs

    def __len__(self) -> int:
        return len(self._specs)

    def index_of(self, name: str) -> int | None:
        """Table index of ``name``, or None if there is no such parameter."""
        return self._index.get(name)

    def get(self, name: str) -> float:
        """Current value; KeyError for an unknown name (a programming error)."""
        with self._lock:
            return self._values[self._index[name]]

    def get_index(self, index: int) -> float:
        """Current value by table index; IndexError outside the table."""
        with self._lock:
            return self._values[index]

    def values(self) -> dict[str, float]:
        """Every current value by name, in table order (a consistent snapshot)."""
        with self._lock:
            return {spec.name: v for spec, v in zip(self._specs, self._values, strict=True)}

    @property
    def running(self) -> bool:
        return self._running

    def set_running(self, running: bool) -> None:
        """While running, parameters with ``settable_while_running=False`` refuse sets."""
        self._running = bool(running)

    def _refusal(self, spec: ParamSpec, value: float) -> str | None:
        if not math.isfinite(value):
            return "value is not finite"
        if spec.kind is ParamType.INT and (not value.is_integer() or abs(value) > _INT_LIMIT):
            return f"{value:g} is not an integer within +-2**24"
        if not spec.min <= value <= spec.max:
            return f"{value:g} outside [{spec.min:g}, {spec.max:g}]"
        if self._running and not spec.settable_while_running:
            return "not settable while running"
        if spec.validate is not None:
            return spec.validate(value)
        return None

    @staticmethod
    def _snapped(spec: ParamSpec, value: float) -> float:
        """A float value within float32 rounding of a limit is that limit (module docstring)."""
        if spec.kind is ParamType.FLOAT and math.isfinite(value):
            for bound in (spec.min, spec.max):
                if math.isfinite(bound) and float32(value) == float32(bound):
                    return bound
        return value

    def set(self, name: str, value: float) -> SetResult:
        """Apply the rules and store ``value`` if accepted. KeyError for unknown names."""
        index = self._index[name]
        spec = self._specs[index]
        value = self._snapped(spec, float(value))
        reason = self._refusal(spec, value)
        with self._lock:
            if reason is not None:
                return SetResult(False, self._values[index], reason)
            self._values[index] = value
            self.generation += 1
        return SetResult(True, value)


def decode_set_value(spec: ParamSpec, raw: float) -> float:
    """The value a PARAM_SET means for ``spec``: float parameters as sent; integer ones
    byte-wise, or C-cast if that is the reading within the limits (module docstring)."""
    return _decode_set(spec, raw)[0]


def _decode_set(spec: ParamSpec, raw: float) -> tuple[float, bool]:
    """(:func:`decode_set_value`, whether it was read C-cast)."""
    if spec.kind is not ParamType.INT:
        return float(raw), False
    bytewise = float(int_from_wire(raw))
    if max(spec.min, -_INT_LIMIT) <= bytewise <= min(spec.max, _INT_LIMIT):
        return bytewise, False
    return float(raw), True


class ParamService:
    """Answers the parameter protocol for ``server`` on ``port``; see the module docstring."""

    def __init__(self, server: ParamServer) -> None:
        self.server = server
        self._port: MavlinkPort | None = None

    def routes(self) -> dict[str, Route]:
        """The PARAM_* handlers to put in a :class:`MavlinkPort`'s route table."""
        return {
            "PARAM_REQUEST_LIST": Route(self._on_request_list),
            "PARAM_REQUEST_READ": Route(self._on_request_read),
            "PARAM_SET": Route(self._on_set),
        }

    def attach(self, port: MavlinkPort) -> None:
        """The port that answers go out on (before it, requests are ignored)."""
        self._port = port

    def wire_value(self, index: int) -> tuple[float, int]:
        """(param_value, MAV_PARAM_TYPE) of parameter ``index`` as it goes on the wire."""
        assert self._port is not None
        dialect = self._port.dialect
        spec = self.server.specs[index]
        value = self.server.get_index(index)
        if spec.kind is ParamType.INT:
            return int_to_wire(int(value)), dialect.MAV_PARAM_TYPE_INT32
        return value, dialect.MAV_PARAM_TYPE_REAL32

    def _send_value(self, index: int, *, reply: bool = True, c_cast_to: Any = None) -> None:
        """PARAM_VALUE of ``index`` to every peer; with ``c_cast_to`` (an address), that one
        gets an integer C-cast and the others byte-wise."""
        port = self._port
        if port is None:
            return
        value, ptype = self.wire_value(index)
        name = self.server.specs[index].name.encode("ascii")
        count = len(self.server)

        def build(mav: Any, v: float = value) -> None:
            mav.param_value_send(name, v, ptype, count, index)

        if c_cast_to is not None:
            cast = self.server.get_index(index)
            port.send(lambda mav: build(mav, cast), only=c_cast_to)
            port.send(build, skip=c_cast_to)
            return
        port.reply(build) if reply else port.send(build)

    def _for_me(self, msg: Any) -> bool:
        port = self._port
        return (
            port is not None
            and port.accepts(msg.target_system, msg.target_component)
            and port.authorized(msg)
        )

    def _on_request_list(self, msg: Any, now_ns: int) -> None:
        if self._for_me(msg):
            for index in range(len(self.server)):
                self._send_value(index)

    def _on_request_read(self, msg: Any, now_ns: int) -> None:
        if not self._for_me(msg):
            return
        index: int | None = msg.param_index
        if index == -1:
            index = self.server.index_of(msg.param_id)
        if index is None or not 0 <= index < len(self.server):
            assert self._port is not None
            self._port.stats.ignored += 1
            return
        self._send_value(index)

    def _on_set(self, msg: Any, now_ns: int) -> None:
        if not self._for_me(msg):
            return
        assert self._port is not None
        index = self.server.index_of(msg.param_id)
        if index is None:
            self._port.stats.ignored += 1
            return
        spec = self.server.specs[index]
        value, c_cast = _decode_set(spec, float(msg.param_value))
        result = self.server.set(msg.param_id, value)
        if not result.accepted:
            self._param_error(msg, index, spec)
            self._port.send_statustext(f"{msg.param_id} not set: {result.reason}", Severity.WARNING)
        # the outcome of a set always goes out
        self._send_value(index, reply=False, c_cast_to=self._port.source if c_cast else None)

    def _param_error(self, msg: Any, index: int, spec: ParamSpec) -> None:
        """PARAM_ERROR for a refused set, to its sender."""
        port = self._port
        assert port is not None
        d = port.dialect
        read_only = self.server.running and not spec.settable_while_running
        error = d.MAV_PARAM_ERROR_READ_ONLY if read_only else d.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
        to = (msg.get_srcSystem(), msg.get_srcComponent())
        name = spec.name.encode("ascii")
        port.send(lambda mav: mav.param_error_send(*to, name, index, error), only=port.source)
