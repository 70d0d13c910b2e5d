"""Lifecycle, send and receive plumbing shared by the DroneCAN adapters (``adapters.py``).

``CanPort``: optional bus ownership, idempotent ``shutdown()``, context manager, ``stale``
flag logged on transitions. ``CanSender``: message -> frames -> ``bus.send`` with transfer
IDs and a NodeStatus schedule. ``CanReceiver``: a python-can ``Listener`` that reassembles
transfers in the Notifier thread and hands complete ones to ``_handle``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from typing import Self

import can

from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.codec import (
    CanFrame,
    DataType,
    Message,
    Received,
    TransferIds,
    encode,
    with_transfer_id,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.ports.transitions import TransitionLog, log_to

log = logging.getLogger(__name__)


class CanPort:
    """Shared lifecycle: optional bus ownership, idempotent shutdown, context manager."""

    def __init__(self, bus: can.BusABC, owns_bus: bool, name: str) -> None:
        self.bus = bus
        self.name = name
        self._owns_bus = owns_bus
        self._closing = False
        self._closed = False
        self._transitions = TransitionLog(log_to(log))

    @property
    def stale(self) -> bool:
        """The last send or receive failed (and none succeeded since)."""
        return self._transitions["stale"]

    def _mark(self, stale: bool, why: str = "") -> None:
        if stale == self.stale:  # every frame sent or received: no texts to build
            return
        self._transitions.update(
            "stale", stale, f"{self.name}: port stale: {why}", f"{self.name}: port recovered"
        )

    def _close(self) -> None:
        pass

    def shutdown(self) -> None:
        """Stop this port (and the bus if it owns it). Idempotent."""
        if self._closing:
            return
        self._closing = True
        try:
            self._close()
        finally:
            self._closed = True
        if self._owns_bus:
            self.bus.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class CanSender(CanPort):
    """Serializes messages to frames and writes them; NodeStatus heartbeat schedule."""

    def __init__(
        self,
        bus: can.BusABC,
        owns_bus: bool,
        name: str,
        send_timeout_s: float,
        status_period_s: float,
    ) -> None:
        super().__init__(bus, owns_bus, name)
        self._tids = TransferIds()
        self._lock = threading.Lock()
        self._send_timeout_s = send_timeout_s
        self._period_ns = int(status_period_s * 1e9)
        self._start_ns = time.monotonic_ns()
        self._next_status_ns: int | None = None
        self.transfers_sent = 0
        self.send_errors = 0
        self._last_encoded: tuple[tuple[Message, int, int], list[CanFrame]] | None = None

    def _send(self, msg: Message, node_id: int, data_type: DataType, priority: int) -> bool:
        with self._lock:
            if self._closed:
                return False
            tid = self._tids.next(node_id, data_type)
            key = (msg, node_id, priority)
            if self._last_encoded is not None and self._last_encoded[0] == key:
                frames = with_transfer_id(self._last_encoded[1], tid)  # a repeat: no DSDL work
            else:
                frames = encode(msg, source_node_id=node_id, transfer_id=tid, priority=priority)
                self._last_encoded = (key, frames)
            try:
                for f in frames:
                    self.bus.send(
                        can.Message(arbitration_id=f.can_id, data=f.data, is_extended_id=True),
                        timeout=self._send_timeout_s,
                    )
            except (can.CanError, OSError) as e:
                self.send_errors += 1
                self._mark(True, f"send failed: {e}")
                return False
            self.transfers_sent += 1
            self._mark(False)
            return True

    def _status_due(self, now_ns: int | None) -> bool:
        """NodeStatus due at ``now_ns``: on absolute deadlines, so the rate is the period's
        whatever the caller's tick (DroneCAN allows at most 1 s); after a stall of more than
        a period the schedule restarts from now."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        due = self._next_status_ns
        if due is not None and now < due:
            return False
        start = now if due is None or now - due >= self._period_ns else due
        self._next_status_ns = start + self._period_ns
        return True

    def _uptime_s(self) -> int:
        return (time.monotonic_ns() - self._start_ns) // 1_000_000_000


MAX_RECEIPT_AGE_S = 1.0  # an interface timestamp older than this is not trusted


def receipt_ns(timestamp: float, now_ns: int, wall_s: float) -> int:
    """Monotonic stamp of a frame's receipt by its interface.

    ``timestamp`` is python-can's ``Message.timestamp`` on the wall clock: for socketcan the
    kernel's SO_TIMESTAMPNS, taken when the frame reached the socket, before the receive
    thread waited for the scheduler and the GIL. Its age against ``wall_s`` (read together
    with ``now_ns``) moves the stamp back. A missing, future or implausibly old timestamp
    gives ``now_ns``. Why not the callback's own clock: docs/decisions.md.
    """
    age_s = wall_s - timestamp
    if timestamp <= 0.0 or not 0.0 <= age_s < MAX_RECEIPT_AGE_S:
        return now_ns
    return now_ns - int(age_s * 1e9)


class CanReceiver(CanPort, can.Listener):
    """Notifier listener: frames -> ``TransferAssembler`` -> ``_handle`` (in the rx thread)."""

    def __init__(
        self,
        bus: can.BusABC,
        owns_bus: bool,
        name: str,
        accept: Iterable[DataType],
        notifier: can.Notifier | None,
        poll_timeout_s: float,
    ) -> None:
        CanPort.__init__(self, bus, owns_bus, name)
        self._assembler = TransferAssembler(accept)
        self.malformed = 0
        self.receive_errors = 0
        self._own_notifier = notifier is None
        self._notifier = notifier if notifier is not None else can.Notifier(bus, [], poll_timeout_s)
        self._notifier.add_listener(self)

    @property
    def notifier(self) -> can.Notifier:
        """The Notifier this receiver listens on: give it to other listeners of the bus
        (python-can allows one Notifier per bus)."""
        return self._notifier

    @property
    def assembler(self) -> TransferAssembler:
        """The reassembler, for its counters (``pending``, ``orphans``, ``expired``,
        ``evicted``)."""
        return self._assembler

    def on_message_received(self, msg: can.Message) -> None:
        """python-can callback (Notifier thread): reassemble, decode, hand to ``_handle``;
        malformed input is counted and dropped."""
        if msg.is_error_frame or msg.is_remote_frame or self._closed:
            return
        now = receipt_ns(msg.timestamp, time.monotonic_ns(), time.time())
        try:
            got = self._assembler.feed(
                CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id), now
            )
            if got is not None:
                self._handle(got, now)
                self._mark(False)
        except MalformedMessage as e:
            self.malformed += 1
            self._count_malformed()
            log.debug("%s: dropped malformed input: %s", self.name, e)

    def on_error(self, exc: Exception) -> None:
        """python-can callback when the bus fails to receive: count it, mark the port stale."""
        self.receive_errors += 1
        self._mark(True, f"receive failed: {exc}")
        time.sleep(0.05)  # a bus that keeps failing must not spin the Notifier thread

    def _handle(self, got: Received, now_ns: int) -> None:
        raise NotImplementedError

    def _count_malformed(self) -> None:
        pass

    def stop(self) -> None:
        """Called by the Notifier when it stops; shutting down is ``shutdown()``'s job."""

    def _close(self) -> None:
        if self._own_notifier:
            self._notifier.stop()
        else:
            self._notifier.remove_listener(self)
