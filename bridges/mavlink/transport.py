"""The datagram socket (or byte stream) under a MAVLink port, and where its sends go.

:class:`UdpTransport` owns one UDP socket: ``udpin:HOST:PORT`` / ``udp:HOST:PORT`` bind it,
``udpout:HOST:PORT`` sends to one remote from an ephemeral port (bound to loopback when the
remote is on loopback). It keeps the :class:`~bridges.mavlink.peers.PeerTable`; ``write``
(pymavlink's file interface, called under the port's send lock) sends one frame to an
immutable snapshot of the peers, so a table change on the dispatch thread never disturbs a
send in progress. One peer's send error is counted and the others still get the frame.

:class:`StreamTransport` wraps a pymavlink byte stream (``tcp:``, a serial device): one
source, always trusted, no peer table of our own.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import socket
from collections.abc import Sequence
from typing import Any

from bridges.mavlink.config import parse_host_port
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.peers import Address, PeerTable, TrafficLimits

logger = logging.getLogger(__name__)

MAX_DATAGRAM = 65535
RECEIVE_BUFFER = 4 * 1024 * 1024  # absorbs a burst while the dispatch thread is busy
STREAM_SOURCE: Address = ("stream", 0)


def _resolve(key: str, host: str, port: int, family: int = 0) -> tuple[int, Address]:
    host = host.strip("[]")
    try:
        info = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as e:
        raise LinkConfigError(f"{key}: cannot resolve {host!r}: {e}") from None
    fam, _, _, _, sockaddr = info[0]
    return fam, (str(sockaddr[0]), int(sockaddr[1]))


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class UdpTransport:
    """One UDP socket and its peer table (module docstring)."""

    def __init__(
        self,
        connection: str,
        peers: Sequence[str] = (),
        relays: Sequence[str] = (),
        limits: TrafficLimits | None = None,
    ) -> None:
        scheme, _, rest = connection.partition(":")
        host, port = parse_host_port("connection", rest)
        family, addr = _resolve("connection", host, port)
        configured = [_resolve("peers", *parse_host_port("peers", p), family)[1] for p in peers]
        relay_addrs = [_resolve("relay", *parse_host_port("relay", p), family)[1] for p in relays]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            with contextlib.suppress(OSError):
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            if scheme == "udpout":
                configured = [addr]
                if _is_loopback(addr[0]):
                    self.sock.bind((addr[0], 0))
            else:
                self.sock.bind(addr)
        except OSError as e:
            self.sock.close()
            raise LinkConfigError(f"connection: cannot open {connection!r}: {e}") from e
        self.table = PeerTable(tuple(configured), tuple(relay_addrs), limits or TrafficLimits())
        self.send_errors = 0
        self.family = family
        # Set by the port under its send lock for one send: only to this address, or to
        # every peer but this one (None: every peer).
        self.only: Address | None = None
        self.skip: Address | None = None

    def resolve(self, key: str, values: Sequence[str]) -> tuple[Address, ...]:
        """``host:port`` strings as the addresses datagrams from them carry (this socket's
        family); LinkConfigError naming ``key`` if one does not parse or resolve."""
        return tuple(_resolve(key, *parse_host_port(key, v), self.family)[1] for v in values)

    @property
    def local_address(self) -> Address:
        """The bound (host, port)."""
        name = self.sock.getsockname()
        return str(name[0]), int(name[1])

    def receive(self, timeout_s: float) -> tuple[bytes, Address] | None:
        """One datagram and its source, or None after ``timeout_s`` without one."""
        self.sock.settimeout(timeout_s)
        try:
            data, sockaddr = self.sock.recvfrom(MAX_DATAGRAM)
        except (TimeoutError, BlockingIOError):
            return None
        return data, (str(sockaddr[0]), int(sockaddr[1]))

    def write(self, buf: bytes) -> None:
        """Send one frame to every peer of the current snapshot (pymavlink's ``file.write``),
        or to ``only``, or to every peer but ``skip``."""
        if self.only is not None:
            self.send_to(buf, self.only)
            return
        for addr in self.table.peers:
            if addr != self.skip:
                self.send_to(buf, addr)

    def send_to(self, buf: bytes | bytearray, addr: Address) -> bool:
        """One datagram to ``addr``; a refusal is counted, never raised."""
        try:
            self.sock.sendto(buf, addr)
        except OSError as e:
            self.send_errors += 1
            logger.debug("send to %s failed: %s", addr, e)
            return False
        return True

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self.sock.close()


class StreamTransport:
    """A pymavlink byte stream (``tcp:``, serial): one trusted source, no peer table."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self.table = PeerTable((STREAM_SOURCE,))
        self.send_errors = 0
        self.only: Address | None = None  # a stream has one far end: both are moot
        self.skip: Address | None = None

    def receive(self, timeout_s: float) -> tuple[bytes, Address] | None:
        """Whatever bytes the stream has (frames may span reads), or None after a wait."""
        data = self.conn.recv(4096)
        if not data:
            self.conn.select(timeout_s)
            return None
        return bytes(data), STREAM_SOURCE

    def write(self, buf: bytes) -> None:
        """Send one frame on the stream."""
        try:
            self.conn.write(buf)
        except OSError:
            self.send_errors += 1

    def resolve(self, key: str, values: Sequence[str]) -> tuple[Address, ...]:
        """A stream has one source, whatever ``values`` say."""
        return (STREAM_SOURCE,)

    def send_to(self, buf: bytes | bytearray, addr: Address) -> bool:
        """Streams have one far end: ``addr`` is ignored."""
        self.write(bytes(buf))
        return True

    def close(self) -> None:
        """Close the stream."""
        with contextlib.suppress(OSError):
            self.conn.close()
