"""python-can interface plugin ``canhub``: a ``can.BusABC`` client of ``bridges.can_io.hub``.

Registered in pyproject.toml under the ``can.interface`` entry point, so after
``pip install -e .`` any python-can user can write::

    can.Bus(interface="canhub", channel="127.0.0.1:29536", receive_own_messages=False)

The channel is ``"HOST:PORT"`` (or just ``"PORT"``) of a running hub; the host must be a
loopback address. See ``bridges/can_io/hub.py`` for the wire format.

Semantics, as close to a real bus as the hub allows: every frame sent by another client is
received once, in order; own frames only with ``receive_own_messages=True``. ``send`` writes
straight to the socket (nothing is queued in this process, so ``flush_tx_buffer`` is a
no-op) and only blocks if the hub stops reading, for at most ``send_timeout_s``. If the hub
goes away, that is said once (a warning on this module's logger), ``state`` becomes
``BusState.ERROR``, ``recv`` behaves like a silent bus and ``send`` raises
``CanOperationError``: a python-can ``Notifier`` keeps running (an exception from ``recv``
would end its thread with a traceback in any client without an ``on_error`` listener), and
the application learns of it where it acts, on its next send. After ``shutdown()`` both
raise ``CanOperationError`` (a thread blocked in ``recv`` is woken with it). ``fileno()`` is not
offered because several frames may be buffered per socket read; python-can's Notifier then
uses a thread.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import select
import socket
import threading
import time
from typing import Any

import can
from can.typechecking import CanFilters

from bridges.can_io.hub import (
    BANNER,
    FLAG_BRS,
    FLAG_ERROR,
    FLAG_ESI,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    HEADER,
    HubProtocolError,
    parse_channel,
    split_records,
)

INTERFACE_NAME = "canhub"
log = logging.getLogger(__name__)


def pack_message(msg: can.Message) -> bytes:
    """One hub record for ``msg``."""
    flags = (
        (FLAG_EXTENDED if msg.is_extended_id else 0)
        | (FLAG_REMOTE if msg.is_remote_frame else 0)
        | (FLAG_ERROR if msg.is_error_frame else 0)
        | (FLAG_FD if msg.is_fd else 0)
        | (FLAG_BRS if msg.bitrate_switch else 0)
        | (FLAG_ESI if msg.error_state_indicator else 0)
    )
    data = bytes(msg.data or b"")
    return HEADER.pack(msg.arbitration_id, flags, msg.dlc, len(data), 0) + data


def unpack_records(buf: bytes | bytearray, timestamp: float, channel: str) -> list[can.Message]:
    """Messages from a buffer holding whole records only."""
    out, pos = [], 0
    while pos < len(buf):
        can_id, flags, dlc, length, _ = HEADER.unpack_from(buf, pos)
        start = pos + HEADER.size
        out.append(
            can.Message(
                timestamp=timestamp,
                arbitration_id=can_id,
                is_extended_id=bool(flags & FLAG_EXTENDED),
                is_remote_frame=bool(flags & FLAG_REMOTE),
                is_error_frame=bool(flags & FLAG_ERROR),
                is_fd=bool(flags & FLAG_FD),
                bitrate_switch=bool(flags & FLAG_BRS),
                error_state_indicator=bool(flags & FLAG_ESI),
                dlc=dlc,
                data=bytes(buf[start : start + length]),
                channel=channel,
                is_rx=True,
            )
        )
        pos = start + length
    return out


class CanHubBus(can.BusABC):
    """python-can bus over a ``CanHub`` on 127.0.0.1."""

    def __init__(
        self,
        channel: str | int = "127.0.0.1:29536",
        can_filters: CanFilters | None = None,
        receive_own_messages: bool = False,
        connect_timeout_s: float = 2.0,
        send_timeout_s: float = 1.0,
        **kwargs: Any,
    ) -> None:
        host, port = parse_channel(channel)
        try:
            sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as e:
            raise can.CanInitializationError(f"canhub: cannot connect to {host}:{port}: {e}") from e
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            _read_banner(sock)
        except (OSError, HubProtocolError) as e:
            sock.close()
            raise can.CanInitializationError(f"canhub: no hub at {host}:{port}: {e}") from e
        sock.settimeout(send_timeout_s)
        self._sock = sock
        self._send_lock = threading.Lock()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)  # a full wake pipe already means "wake up"
        self._rbuf = bytearray()
        self._rx: collections.deque[can.Message] = collections.deque()
        self._own = receive_own_messages
        self._peer_gone = False
        self.channel_info = f"canhub {host}:{port}"
        self._channel_name = f"{host}:{port}"
        super().__init__(channel=self._channel_name, can_filters=can_filters, **kwargs)
        self._can_protocol = can.CanProtocol.CAN_FD

    @property
    def state(self) -> can.BusState:
        """``ERROR`` once the hub is gone, else ``ACTIVE``."""
        return can.BusState.ERROR if self._peer_gone else can.BusState.ACTIVE

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        raise NotImplementedError("canhub: the bus state follows the hub; it cannot be set")

    def _gone(self, why: str) -> None:
        """The hub is lost: say so once; from now on a silent bus that refuses to send."""
        if not self._peer_gone:
            self._peer_gone = True
            log.warning("canhub: hub %s %s: receiving nothing more, send raises CanOperationError",
                        self._channel_name, why)  # fmt: skip

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Write one frame to the hub. ``timeout`` is bounded by ``send_timeout_s``."""
        if self._is_shutdown:
            raise can.CanOperationError("canhub: bus is shut down")
        if self._peer_gone:
            raise can.CanOperationError(f"canhub: hub {self._channel_name} is gone")
        record = pack_message(msg)
        try:
            with self._send_lock:  # whole records only, even with several sending threads
                self._sock.sendall(record)
        except OSError as e:
            # A timed-out sendall may have written part of a record: the stream is lost.
            self._gone(f"refused a frame ({e})")
            raise can.CanOperationError(f"canhub: send failed: {e}") from e
        if self._own:
            own = can.Message(
                timestamp=time.time(),
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                is_fd=msg.is_fd,
                dlc=msg.dlc,
                data=msg.data,
                channel=self._channel_name,
                is_rx=False,
            )
            self._rx.append(own)
            with contextlib.suppress(OSError):
                self._wake_w.send(b"o")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._is_shutdown:  # python-can's recv(None) would spin on (None, False)
                raise can.CanOperationError("canhub: bus was shut down")
            if self._rx:
                return self._rx.popleft(), False
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            watch = [self._wake_r] if self._peer_gone else [self._sock, self._wake_r]
            try:
                ready, _, _ = select.select(watch, [], [], remaining)
                if self._is_shutdown:
                    raise can.CanOperationError("canhub: bus was shut down")
                if self._wake_r in ready:
                    with contextlib.suppress(BlockingIOError):
                        self._wake_r.recv(4096)
                if self._sock in ready:
                    self._read_socket()
            except (OSError, ValueError) as e:
                if self._is_shutdown:
                    raise can.CanOperationError("canhub: bus was shut down") from e
                self._gone(f"failed ({e})")
                continue  # now a silent bus: wait out the timeout on the wake pipe
            if not ready and not self._rx:
                return None, False

    def _read_socket(self) -> None:
        data = self._sock.recv(1 << 16)
        if not data:
            self._gone("closed the connection")
            return
        self._rbuf += data
        try:
            whole, _ = split_records(self._rbuf)
        except HubProtocolError as e:
            self._gone(f"broke the protocol ({e})")
            return
        if whole:
            self._rx.extend(unpack_records(self._rbuf[:whole], time.time(), self._channel_name))
            del self._rbuf[:whole]

    def flush_tx_buffer(self) -> None:
        """Nothing is queued in this process: ``send`` writes through to the socket."""

    def shutdown(self) -> None:
        """Close the connection; wakes a thread blocked in ``recv``. Idempotent."""
        if self._is_shutdown:
            return
        super().shutdown()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"q")
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        self._wake_w.close()
        self._wake_r.close()


def _read_banner(sock: socket.socket) -> None:
    got = b""
    while len(got) < len(BANNER):
        chunk = sock.recv(len(BANNER) - len(got))
        if not chunk:
            break
        got += chunk
    if got != BANNER:
        raise HubProtocolError(f"expected banner {BANNER!r}, got {got!r}")
