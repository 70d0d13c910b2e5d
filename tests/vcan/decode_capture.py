"""Decode a ``candump -L`` capture into DroneCAN transfers, independently of ``bridges``.

Everything protocol-specific comes from the ``dronecan`` package: ``Frame`` (tail byte),
``TransferManager`` (reassembly by CAN ID and transfer ID), ``Transfer.from_frames``
(tail-bit checks, CRC of multi-frame transfers, DSDL deserialization) and the DSDL types;
none of ``bridges.can_io.codec`` is used, so a bug there cannot hide in its own check.

    python decode_capture.py capture.log      # one line per transfer, then counts

Library: ``parse_candump(text)`` -> frames, ``decode(frames)`` -> ``Decoded`` (transfers in
completion order, with the stamp of their last frame, plus the frames that did not decode).
"""

from __future__ import annotations

import re
import sys
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import dronecan
from dronecan.transport import Frame, Transfer, TransferError, TransferManager

# candump -L: "(1700000000.123456) vcan0 0804060A#0103FBFFF7C060C3"; 3 hex digits: 11-bit ID.
# python-can's log writer and ``candump -L -x`` end the line with " R" (received) or " T"
# (sent by this host); both are accepted and mean the same frame on the bus.
LINE = re.compile(
    r"^\((\d+\.\d+)\) (\S+) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#([0-9A-Fa-f]*)(?: [RT])?$"
)

RAW_COMMAND = "uavcan.equipment.esc.RawCommand"
ESC_STATUS = "uavcan.equipment.esc.Status"
NODE_STATUS = "uavcan.protocol.NodeStatus"


@dataclass(frozen=True)
class CapturedFrame:
    stamp: float  # candump's receive time (CLOCK_REALTIME, s)
    channel: str
    can_id: int
    extended: bool
    data: bytes


@dataclass(frozen=True)
class DroneCanTransfer:
    stamp: float  # of the frame that completed it
    source_node_id: int
    priority: int
    transfer_id: int
    type_name: str  # DSDL full name, e.g. uavcan.equipment.esc.RawCommand
    payload: Any  # the dronecan CompoundValue
    frames: int


@dataclass
class Decoded:
    transfers: list[DroneCanTransfer] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)  # frames/transfers that did not decode
    standard_frames: int = 0  # 11-bit frames (not DroneCAN; e.g. the capture's sync frame)
    incomplete: int = 0  # transfers started but never finished in the capture

    def of_type(self, type_name: str, source_node_id: int | None = None) -> list[DroneCanTransfer]:
        return [
            t
            for t in self.transfers
            if t.type_name == type_name
            and (source_node_id is None or t.source_node_id == source_node_id)
        ]

    def counts(self) -> dict[str, int]:
        c = Counter(f"{t.type_name}@{t.source_node_id}" for t in self.transfers)
        return dict(sorted(c.items()))


def parse_candump(text: str) -> list[CapturedFrame]:
    """``candump -L`` lines (optionally ending in `` R``/`` T``) -> frames; a line in any
    other format raises ValueError."""
    frames = []
    for n, line in enumerate(text.splitlines(), 1):
        match = LINE.match(line)
        if not match:
            raise ValueError(f"line {n}: not a candump -L classic-CAN line: {line!r}")
        stamp, channel, can_id, data = match.groups()
        frames.append(
            CapturedFrame(
                float(stamp), channel, int(can_id, 16), len(can_id) == 8, bytes.fromhex(data)
            )
        )
    return frames


def decode(frames: list[CapturedFrame]) -> Decoded:
    """Reassemble and deserialize every DroneCAN message transfer in ``frames``."""
    out = Decoded()
    manager = TransferManager()
    for f in frames:
        if not f.extended:
            out.standard_frames += 1
            continue
        if not f.data:
            out.errors.append(f"{f.stamp:.6f} {f.can_id:08X}: empty frame")
            continue
        done = manager.receive_frame(Frame(f.can_id, f.data, ts_real=f.stamp))
        if done is None:
            continue
        transfer = Transfer()
        try:
            transfer.from_frames(done)
        except (TransferError, ValueError, IndexError, KeyError) as e:
            out.errors.append(f"{f.stamp:.6f} {f.can_id:08X}: {e}")
            continue
        out.transfers.append(
            DroneCanTransfer(
                stamp=f.stamp,
                source_node_id=transfer.source_node_id,
                priority=transfer.transfer_priority,
                transfer_id=transfer.transfer_id,
                type_name=dronecan.get_dronecan_data_type(transfer.payload).full_name,
                payload=transfer.payload,
                frames=len(done),
            )
        )
    out.incomplete = len(manager.active_transfers)
    return out


def describe(t: DroneCanTransfer) -> str:
    p = t.payload
    if t.type_name == RAW_COMMAND:
        body = f"cmd={list(p.cmd)}"
    elif t.type_name == ESC_STATUS:
        body = f"esc_index={p.esc_index} rpm={p.rpm} current={p.current:.3f} A"
    elif t.type_name == NODE_STATUS:
        body = f"uptime={p.uptime_sec} s health={p.health} mode={p.mode}"
    else:
        body = str(p)
    return f"{t.stamp:.6f} node {t.source_node_id:3d} tid {t.transfer_id:2d} {t.type_name} {body}"


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    with open(argv[0]) as fh:
        decoded = decode(parse_candump(fh.read()))
    for t in decoded.transfers:
        print(describe(t))
    print(f"# transfers by type@node: {decoded.counts()}")
    print(f"# errors: {len(decoded.errors)}, incomplete: {decoded.incomplete}")
    for e in decoded.errors:
        print(f"# {e}")
    return 1 if decoded.errors else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
