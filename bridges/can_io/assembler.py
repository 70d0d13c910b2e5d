"""Reassembly of DroneCAN (UAVCAN v0) transfers from CAN frames: :class:`TransferAssembler`.

The stateful part of the CAN codec (``bridges.can_io.codec`` holds the pure framing and the
DSDL encode/decode): one partial transfer per (source node, data type) session, bounded in
time and in number, every frame counted. No CAN library, no sockets, no clock (the caller
hands in the stamps).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass

from bridges.can_io.codec import CanFrame, DataType, FrameId, Received, decode_frames
from ftcap_hil.core.errors import MalformedMessage

#: A transfer of more frames than this is malformed (ours take 3 at most: RawCommand of 20).
MAX_FRAMES_PER_TRANSFER = 64


@dataclass
class _Pending:
    can_id: int
    transfer_id: int
    frames: list[CanFrame]
    started_ns: int


#: Partial transfers kept at once by default: one per (source node, data type) session is
#: all a DroneCAN v0 sender may have open, and 128 covers 42 nodes x 3 types of ours.
DEFAULT_MAX_PENDING = 128


class TransferAssembler:
    """Reassembles DroneCAN transfers from frames, several interleaved senders at once.

    Feed every received frame with a monotonic stamp; ``feed`` returns a ``Received`` when a
    transfer completes, None for frames that are not ours or not yet complete, and raises
    ``MalformedMessage`` for frames that break the protocol (the partial transfer is dropped).

    One partial transfer is kept per session (source node, data type), as DroneCAN v0
    receivers do: a new first frame of the same session replaces it. A continuation frame
    that matches no open transfer (we joined mid-transfer, or its CAN ID or transfer ID
    differ) is counted in ``orphans`` and ignored. The state is bounded: a partial transfer
    older than ``timeout_s`` is dropped (``expired``) and at most ``max_pending`` are kept,
    the oldest dropped first (``evicted``). Sessions are kept in start order, so expiry looks
    at the oldest only: the cost of a frame does not grow with the number pending.

    Every frame fed is counted (``frames``) and lands in one of ``ignored`` (not ours),
    ``orphans``, ``rejected`` (``feed`` raised) or ``consumed`` (taken into a transfer).
    """

    def __init__(
        self,
        accept: Iterable[DataType] = tuple(DataType),
        timeout_s: float = 1.0,
        max_pending: int = DEFAULT_MAX_PENDING,
    ) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0.0):
            raise ValueError(f"timeout_s: expected a finite time > 0 s, got {timeout_s!r}")
        if isinstance(max_pending, bool) or not isinstance(max_pending, int) or max_pending < 1:
            raise ValueError(f"max_pending: expected an int >= 1, got {max_pending!r}")
        self._accept = frozenset(int(t) for t in accept)
        self._timeout_ns = int(timeout_s * 1e9)
        self._max_pending = max_pending
        self._pending: OrderedDict[tuple[int, int], _Pending] = OrderedDict()
        self.frames = 0  # fed: ignored, orphans, rejected or consumed
        self.ignored = 0  # not ours (11-bit, services, anonymous, other types)
        self.orphans = 0
        self.rejected = 0  # broke the protocol: feed raised MalformedMessage
        self.expired = 0
        self.evicted = 0

    def feed(self, frame: CanFrame, stamp_ns: int) -> Received | None:
        """Take one frame received at ``stamp_ns`` (monotonic); see the class docstring."""
        self.frames += 1
        try:
            got = self._feed(frame, stamp_ns)
        except MalformedMessage:
            self.rejected += 1
            raise
        return got

    def _feed(self, frame: CanFrame, stamp_ns: int) -> Received | None:
        if not frame.extended:
            self.ignored += 1
            return None
        fid = FrameId.parse(frame.can_id)
        if fid is None or fid.data_type_id not in self._accept:
            self.ignored += 1
            return None
        if not frame.data or len(frame.data) > 8:
            raise MalformedMessage(f"frame 0x{frame.can_id:08X}: data length {len(frame.data)}")
        self._expire(stamp_ns)
        tail = frame.data[-1]
        sot, eot, toggle = bool(tail & 0x80), bool(tail & 0x40), bool(tail & 0x20)
        key = (fid.source_node_id, fid.data_type_id)
        if sot:
            return self._start(key, frame, stamp_ns, tail & 0x1F, eot=eot, toggle=toggle)
        pending = self._pending.get(key)
        if pending is None or pending.can_id != frame.can_id or pending.transfer_id != tail & 0x1F:
            self.orphans += 1
            return None
        if (
            toggle != bool(len(pending.frames) & 1)
            or len(pending.frames) >= MAX_FRAMES_PER_TRANSFER
        ):
            del self._pending[key]
            raise MalformedMessage(f"frame 0x{frame.can_id:08X}: toggle/sequence error")
        pending.frames.append(frame)
        if not eot:
            self._check_full(frame, key)
            return None
        del self._pending[key]
        return decode_frames(pending.frames)

    def _start(
        self, key: tuple[int, int], frame: CanFrame, stamp_ns: int, tid: int, *,
        eot: bool, toggle: bool,
    ) -> Received | None:  # fmt: skip
        self._pending.pop(key, None)
        if toggle:
            raise MalformedMessage(f"frame 0x{frame.can_id:08X}: toggle set on first frame")
        if eot:
            return decode_frames([frame])
        self._check_full(frame)
        if len(self._pending) >= self._max_pending:
            self._pending.popitem(last=False)
            self.evicted += 1
        self._pending[key] = _Pending(frame.can_id, tid, [frame], stamp_ns)
        return None

    def _check_full(self, frame: CanFrame, key: tuple[int, int] | None = None) -> None:
        if len(frame.data) != 8:  # only the last frame of a transfer may be short
            if key is not None:
                self._pending.pop(key, None)
            raise MalformedMessage(f"frame 0x{frame.can_id:08X}: short non-final frame")

    def _expire(self, now_ns: int) -> None:
        # Start order is insertion order (a restarted session is re-inserted at the end),
        # so only the front can be stale. A stamp older than the oldest start (an interface
        # clock step) expires nothing.
        while self._pending:
            oldest = next(iter(self._pending.values()))
            if now_ns - oldest.started_ns <= self._timeout_ns:
                return
            self._pending.popitem(last=False)
            self.expired += 1

    @property
    def consumed(self) -> int:
        """Frames taken into a transfer (completed, still pending, or later expired)."""
        return self.frames - self.ignored - self.orphans - self.rejected

    @property
    def pending(self) -> int:
        """Number of transfers started but not completed."""
        return len(self._pending)
