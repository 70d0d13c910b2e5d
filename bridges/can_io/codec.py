"""DroneCAN (UAVCAN v0) codec for the three message types ftcap-hil puts on CAN.

Pure functions; no CAN library, no sockets, no clock (the stateful reassembler of
multi-frame transfers is ``bridges.can_io.assembler.TransferAssembler``).
The DSDL serialization is the ``dronecan`` package's own (``dronecan.transport.Transfer``),
used standalone: its ``Node`` driver is not used.

Message types (DroneCAN default data type IDs):

* ``uavcan.equipment.esc.RawCommand`` (1030): ``int14[<=20] cmd``; allocator -> ESCs.
* ``uavcan.equipment.esc.Status`` (1034): rpm, current, voltage, ... ``esc_index``; ESC -> all.
* ``uavcan.protocol.NodeStatus`` (341): uptime, health, mode; every node at 1 Hz.

CAN framing (CAN 2.0B, 29-bit extended ID, classic 8-byte frames)::

    can_id = priority << 24 | data_type_id << 8 | 0 << 7 | source_node_id   (message frame)
    data   = payload[0:7] + tail,   tail = SOT << 7 | EOT << 6 | toggle << 5 | transfer_id

A payload longer than 7 bytes is split over several frames with a CRC-16 (seeded with the
data type signature) prepended; ``transfer_id`` counts 0..31 per (source node, data type)
and wraps. ``assembler.TransferAssembler`` reassembles interleaved multi-frame transfers.

Anything that cannot be decoded raises ``MalformedMessage``; frames that simply are not ours
(11-bit IDs, services, anonymous frames, other data types) are ignored, not counted.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import dronecan
from dronecan.transport import Frame, Transfer, TransferError

from bridges.can_io.force_map import MAX_THRUSTERS, RAW_MAX
from ftcap_hil.core.errors import MalformedMessage

# libcanard's named priorities (0 = highest, 31 = lowest).
PRIORITY_HIGH = 8
PRIORITY_MEDIUM = 16
PRIORITY_LOWEST = 31

_RAW_COMMAND = dronecan.uavcan.equipment.esc.RawCommand
_ESC_STATUS = dronecan.uavcan.equipment.esc.Status
_NODE_STATUS = dronecan.uavcan.protocol.NodeStatus

_INT18_MAX = (1 << 17) - 1
_UINT32_MAX = (1 << 32) - 1
_F16_MAX = 65504.0


class DataType(enum.IntEnum):
    """DroneCAN default data type IDs of the messages we speak."""

    NODE_STATUS = _NODE_STATUS.default_dtid
    RAW_COMMAND = _RAW_COMMAND.default_dtid
    ESC_STATUS = _ESC_STATUS.default_dtid


class Health(enum.IntEnum):
    """``uavcan.protocol.NodeStatus.health``."""

    OK = 0
    WARNING = 1
    ERROR = 2
    CRITICAL = 3


class Mode(enum.IntEnum):
    """``uavcan.protocol.NodeStatus.mode`` (4..6 are reserved)."""

    OPERATIONAL = 0
    INITIALIZATION = 1
    MAINTENANCE = 2
    SOFTWARE_UPDATE = 3
    OFFLINE = 7


@dataclass(frozen=True)
class CanFrame:
    """One classic CAN frame: 29-bit ``can_id`` when ``extended`` (DroneCAN always is)."""

    can_id: int
    data: bytes
    extended: bool = True


@dataclass(frozen=True)
class RawCommandMsg:
    """``esc.RawCommand``: one int14 per ESC, index = ESC index = thruster index."""

    raw: tuple[int, ...]


@dataclass(frozen=True)
class EscStatusMsg:
    """``esc.Status``. Floats are float16 on the wire; NaN means "unknown" (DSDL convention)."""

    esc_index: int
    rpm: int
    current_a: float
    voltage_v: float = math.nan
    temperature_k: float = math.nan
    error_count: int = 0
    power_rating_pct: int = 0


@dataclass(frozen=True)
class NodeStatusMsg:
    """``uavcan.protocol.NodeStatus``: uptime (s), health, mode, sub-mode (0..7), vendor."""

    uptime_s: int
    health: Health = Health.OK
    mode: Mode = Mode.OPERATIONAL
    sub_mode: int = 0
    vendor_status: int = 0


Message = RawCommandMsg | EscStatusMsg | NodeStatusMsg


@dataclass(frozen=True)
class Received:
    """A decoded transfer and where it came from."""

    message: Message
    source_node_id: int
    transfer_id: int
    priority: int


def check_node_id(name: str, node_id: int) -> int:
    """Validate a (non-anonymous) DroneCAN node ID, 1..127; raise naming the config key."""
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise ValueError(f"{name}: DroneCAN node ID must be an int in 1..127, got {node_id!r}")
    return node_id


def check_node_ids(name: str, node_ids: Iterable[int]) -> tuple[int, ...]:
    """:func:`check_node_id` on each of ``node_ids``, naming ``name[i]`` on error."""
    return tuple(check_node_id(f"{name}[{i}]", n) for i, n in enumerate(node_ids))


class TransferIds:
    """Transfer ID counters, one per (source node, data type), wrapping 31 -> 0."""

    def __init__(self) -> None:
        self._next: dict[tuple[int, int], int] = {}

    def next(self, source_node_id: int, data_type: DataType) -> int:
        """The transfer ID to use now for (``source_node_id``, ``data_type``), 0..31."""
        key = (source_node_id, int(data_type))
        tid = self._next.get(key, 0)
        self._next[key] = (tid + 1) & 0x1F
        return tid


def _to_dronecan(msg: Message) -> Any:
    if isinstance(msg, RawCommandMsg):
        if len(msg.raw) > MAX_THRUSTERS:
            raise ValueError(f"RawCommand: at most {MAX_THRUSTERS} elements, got {len(msg.raw)}")
        return _RAW_COMMAND(cmd=[max(-RAW_MAX, min(RAW_MAX, int(v))) for v in msg.raw])
    if isinstance(msg, EscStatusMsg):
        return _ESC_STATUS(
            error_count=max(0, min(_UINT32_MAX, int(msg.error_count))),
            voltage=_f16(msg.voltage_v),
            current=_f16(msg.current_a),
            temperature=_f16(msg.temperature_k),
            rpm=max(-_INT18_MAX, min(_INT18_MAX, int(msg.rpm))),
            power_rating_pct=max(0, min(127, int(msg.power_rating_pct))),
            esc_index=_esc_index(msg.esc_index),
        )
    return _NODE_STATUS(
        uptime_sec=max(0, min(_UINT32_MAX, int(msg.uptime_s))),
        health=int(msg.health),
        mode=int(msg.mode),
        sub_mode=max(0, min(7, int(msg.sub_mode))),
        vendor_specific_status_code=max(0, min(0xFFFF, int(msg.vendor_status))),
    )


def _f16(value: float) -> float:
    # NaN passes ("unknown"); finite values saturate rather than become inf.
    return value if math.isnan(value) else max(-_F16_MAX, min(_F16_MAX, float(value)))


def _esc_index(index: int) -> int:
    if not 0 <= int(index) <= 31:
        raise ValueError(f"esc_index must be in 0..31 (uint5), got {index}")
    return int(index)


def encode(
    msg: Message, *, source_node_id: int, transfer_id: int, priority: int = PRIORITY_LOWEST
) -> list[CanFrame]:
    """Serialize ``msg`` into the CAN frames of one transfer (1 or more, in bus order)."""
    check_node_id("source_node_id", source_node_id)
    if not 0 <= priority <= 31:
        raise ValueError(f"priority must be in 0..31, got {priority}")
    transfer = Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=source_node_id,
        payload=_to_dronecan(msg),
        transfer_priority=priority,
    )
    return [CanFrame(f.message_id, bytes(f.bytes)) for f in transfer.to_frames()]


def with_transfer_id(frames: Sequence[CanFrame], transfer_id: int) -> list[CanFrame]:
    """The same transfer with another transfer ID: only the tail bytes change (the CRC of a
    multi-frame transfer covers the payload, not the tail), so re-sending a message need
    not serialize it again."""
    tid = transfer_id & 0x1F
    return [CanFrame(f.can_id, f.data[:-1] + bytes([(f.data[-1] & 0xE0) | tid])) for f in frames]


def encode_raw_command(
    raw: Iterable[int], *, source_node_id: int, transfer_id: int, priority: int = PRIORITY_HIGH
) -> list[CanFrame]:
    """Frames of one ``esc.RawCommand`` transfer (multi-frame beyond 4 elements)."""
    return encode(
        RawCommandMsg(tuple(int(v) for v in raw)),
        source_node_id=source_node_id,
        transfer_id=transfer_id,
        priority=priority,
    )


@dataclass(frozen=True)
class FrameId:
    """Fields of a DroneCAN message-frame CAN ID."""

    priority: int
    data_type_id: int
    source_node_id: int

    @classmethod
    def parse(cls, can_id: int) -> FrameId | None:
        """None for service frames and anonymous frames (not used by ftcap-hil)."""
        if can_id & 0x80 or not can_id & 0x7F:
            return None
        return cls((can_id >> 24) & 0x1F, (can_id >> 8) & 0xFFFF, can_id & 0x7F)


def _payload_length_ok(data_type: int, n: int) -> bool:
    if data_type == DataType.RAW_COMMAND:
        k = (8 * n) // 14  # TAO int14 array: padding is always < 8 bits
        return k <= MAX_THRUSTERS and (14 * k + 7) // 8 == n
    if data_type == DataType.ESC_STATUS:
        return n == 14  # 110 bits
    return n == 7  # NodeStatus, 56 bits


def decode_frames(frames: Sequence[CanFrame]) -> Received:
    """Decode the complete frame list of one transfer; raise ``MalformedMessage`` if invalid."""
    if not frames or any(not f.data or not f.extended for f in frames):
        raise MalformedMessage("transfer: empty frame list, empty frame or 11-bit CAN ID")
    fid = FrameId.parse(frames[0].can_id)
    if fid is None or fid.data_type_id not in DataType._value2member_map_:
        raise MalformedMessage(f"transfer: not a known message, CAN ID 0x{frames[0].can_id:08X}")
    n = sum(len(f.data) - 1 for f in frames) - (2 if len(frames) > 1 else 0)
    if not _payload_length_ok(fid.data_type_id, n):
        raise MalformedMessage(f"{DataType(fid.data_type_id).name}: bad payload length {n}")
    transfer = Transfer()
    try:
        transfer.from_frames([Frame(f.can_id, f.data) for f in frames])
        message = _from_dronecan(DataType(fid.data_type_id), transfer.payload)
    except (TransferError, ValueError, IndexError, KeyError, struct.error) as e:
        raise MalformedMessage(f"{DataType(fid.data_type_id).name}: {e}") from e
    return Received(message, fid.source_node_id, transfer.transfer_id, fid.priority)


def _from_dronecan(data_type: DataType, p: Any) -> Message:
    if data_type == DataType.RAW_COMMAND:
        return RawCommandMsg(tuple(int(v) for v in p.cmd))
    if data_type == DataType.ESC_STATUS:
        return EscStatusMsg(
            esc_index=int(p.esc_index),
            rpm=int(p.rpm),
            current_a=float(p.current),
            voltage_v=float(p.voltage),
            temperature_k=float(p.temperature),
            error_count=int(p.error_count),
            power_rating_pct=int(p.power_rating_pct),
        )
    try:
        mode = Mode(int(p.mode))
    except ValueError as e:  # modes 4..6 are reserved
        raise MalformedMessage(f"NODE_STATUS: reserved mode {int(p.mode)}") from e
    return NodeStatusMsg(
        uptime_s=int(p.uptime_sec),
        health=Health(int(p.health)),
        mode=mode,
        sub_mode=int(p.sub_mode),
        vendor_status=int(p.vendor_specific_status_code),
    )
