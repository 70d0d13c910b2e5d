"""A CAN bus simulated on 127.0.0.1 TCP: a hub every ``CanHubBus`` client connects to.

For machines without SocketCAN (no ``vcan``): every frame one client sends reaches every
other connected client, in order, like on a real bus. Loopback only, never multicast.

The clients are ``bridges.can_io.hub_bus.CanHubBus``, a python-can interface plugin
registered under the ``can.interface`` entry point name ``canhub`` (why not an existing
remote-CAN transport: docs/decisions.md). Both ends are ours, so the wire is a fixed 8-byte
binary header per frame, TCP_NODELAY on both sides, one ``select`` wake-up per batch, clean
shutdown, and no handshake race: the hub sends its banner only after the client joined the
broadcast set, so once a ``CanHubBus`` is constructed it receives every later frame.

Wire format, both directions, little-endian; the hub speaks first with ``BANNER``::

    u32 arbitration_id | u8 flags | u8 dlc | u8 length (0..64) | u8 reserved | data[length]

The hub is one thread with a selector. A client that does not read has frames dropped for
it (counted) once ``max_queue_bytes`` are queued, like a CAN controller's RX overrun, so one
stalled process never blocks the others.

Run as a process: ``ftcap-hil can-hub --port 29536`` (``--port 0`` picks a free
port); it prints ``can_hub listening on 127.0.0.1:PORT`` once ready and exits cleanly on
SIGINT/SIGTERM. Embedded: ``with CanHub(port=0).start() as hub: ... hub.channel``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import selectors
import socket
import struct
import threading
from dataclasses import dataclass, field

from ftcap_hil.core.errors import MalformedMessage

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 29536
BANNER = b"FTCANHB1"
HEADER = struct.Struct("<IBBBB")
MAX_DATA = 64
FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR, FLAG_FD, FLAG_BRS, FLAG_ESI = 1, 2, 4, 8, 16, 32


class HubProtocolError(MalformedMessage):
    """A peer sent bytes that are not a hub record."""


def check_loopback(host: str) -> str:
    """Return ``host`` if it is a loopback IPv4 literal (or ``localhost``); else raise."""
    if host == "localhost":
        return DEFAULT_HOST
    try:
        addr = ipaddress.ip_address(host)
    except ValueError as e:
        raise ValueError(f"can hub host: need a loopback IP literal, got {host!r}") from e
    if addr.version != 4 or not addr.is_loopback:
        raise ValueError(f"can hub host: only 127.0.0.0/8 is allowed, got {host!r}")
    return host


def parse_channel(channel: str | int) -> tuple[str, int]:
    """``"127.0.0.1:29536"``, ``"29536"`` or ``29536`` -> (host, port)."""
    text = str(channel).strip()
    host, _, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError as e:
        raise ValueError(f"can hub channel: expected 'HOST:PORT' or 'PORT', got {channel!r}") from e
    if not 0 < port < 65536:
        raise ValueError(f"can hub channel: port out of range in {channel!r}")
    return check_loopback(host or DEFAULT_HOST), port


def split_records(buf: bytearray) -> tuple[int, int]:
    """(length, count) of the longest prefix of ``buf`` made of whole records."""
    pos, count, n = 0, 0, len(buf)
    while n - pos >= HEADER.size:
        length = buf[pos + 6]
        if length > MAX_DATA:
            raise HubProtocolError(f"record data length {length} > {MAX_DATA}")
        end = pos + HEADER.size + length
        if end > n:
            break
        pos = end
        count += 1
    return pos, count


@dataclass
class _Client:
    sock: socket.socket
    name: str
    rbuf: bytearray = field(default_factory=bytearray)
    wbuf: bytearray = field(default_factory=bytearray)
    dropped_bytes: int = 0
    want_write: bool = False


class CanHub:
    """Broadcast hub on ``host:port`` (loopback only). ``start()`` returns self."""

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = 0,
        max_queue_bytes: int = 1 << 20,
        sndbuf_bytes: int | None = None,
    ) -> None:
        """``max_queue_bytes``: per-client backlog in the hub before frames are dropped for
        that client; ``sndbuf_bytes``: SO_SNDBUF of client sockets (None: kernel default)."""
        self._host = check_loopback(host)
        self._requested_port = port
        self._max_queue = max_queue_bytes
        self._sndbuf = sndbuf_bytes
        self._sel = selectors.DefaultSelector()
        self._clients: dict[socket.socket, _Client] = {}
        self._listener: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_w.setblocking(False)
        self._thread: threading.Thread | None = None
        self._stop = False
        self._closed = False
        self.records_in = 0
        self.bytes_dropped = 0

    @property
    def port(self) -> int:
        """The TCP port listened on (the chosen one when started with ``port=0``)."""
        if self._listener is None:
            raise RuntimeError("CanHub.port: hub not started")
        return int(self._listener.getsockname()[1])

    @property
    def channel(self) -> str:
        """The ``CanHubBus`` channel string for this hub, ``"127.0.0.1:PORT"``."""
        return f"{self._host}:{self.port}"

    @property
    def client_count(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    def start(self) -> CanHub:
        """Bind, listen and start the hub thread (idempotent); OSError if the port is taken."""
        if self._closed:
            raise RuntimeError("CanHub.start: hub was shut down")
        if self._thread is not None:
            return self
        lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            lsock.bind((self._host, self._requested_port))
        except OSError:
            lsock.close()
            raise
        lsock.listen(16)
        lsock.setblocking(False)
        self._listener = lsock
        self._sel.register(lsock, selectors.EVENT_READ, "accept")
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._thread = threading.Thread(target=self._run, name=f"can-hub:{self.port}", daemon=True)
        self._thread.start()
        log.info("can hub listening on %s", self.channel)
        return self

    def shutdown(self, timeout_s: float = 2.0) -> None:
        """Stop the loop, close every connection. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop = True
        if self._thread is not None:
            with contextlib.suppress(OSError):
                self._wake_w.send(b"x")
            self._thread.join(timeout_s)
        for client in list(self._clients.values()):
            self._drop_client(client, "hub shutdown")
        if self._listener is not None:
            self._listener.close()
        self._sel.close()
        self._wake_r.close()
        self._wake_w.close()

    def __enter__(self) -> CanHub:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def _run(self) -> None:
        while not self._stop:
            for key, events in self._sel.select(timeout=1.0):
                if key.data == "accept":
                    self._accept()
                elif key.data == "wake":
                    return
                else:
                    client = self._clients.get(key.fileobj)  # type: ignore[call-overload]
                    if client is not None:
                        self._serve(client, events)

    def _serve(self, client: _Client, events: int) -> None:
        try:
            if events & selectors.EVENT_WRITE:
                self._flush(client)
            if events & selectors.EVENT_READ and client.sock in self._clients:
                self._read(client)
        except Exception as e:  # noqa: BLE001 - one bad client must not stop the bus
            log.exception("can hub: unexpected error serving %s", client.name)
            self._drop_client(client, f"internal error: {e}")

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, addr = self._listener.accept()
        except BlockingIOError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self._sndbuf is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self._sndbuf)
        sock.setblocking(False)
        client = _Client(sock, f"{addr[0]}:{addr[1]}")
        self._clients[sock] = client
        self._sel.register(sock, selectors.EVENT_READ, "client")
        # The banner goes out after the client is in the broadcast set: see module doc.
        self._queue(client, BANNER)
        log.info("can hub: client %s joined (%d connected)", client.name, len(self._clients))

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(1 << 16)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            self._drop_client(client, f"recv failed: {e}")
            return
        if not data:
            self._drop_client(client, "disconnected")
            return
        client.rbuf += data
        try:
            whole, count = split_records(client.rbuf)
        except HubProtocolError as e:
            self._drop_client(client, f"protocol error: {e}")
            return
        if whole == 0:
            return
        batch = bytes(client.rbuf[:whole])
        del client.rbuf[:whole]
        self.records_in += count
        for other in list(self._clients.values()):
            if other is not client:
                self._queue(other, batch)

    def _queue(self, client: _Client, batch: bytes) -> None:
        if len(client.wbuf) > self._max_queue:
            client.dropped_bytes += len(batch)
            self.bytes_dropped += len(batch)
            return
        was_empty = not client.wbuf
        client.wbuf += batch
        if was_empty:
            self._flush(client)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.wbuf)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError as e:
            self._drop_client(client, f"send failed: {e}")
            return
        del client.wbuf[:sent]
        if bool(client.wbuf) != client.want_write:  # epoll_ctl only when interest changes
            client.want_write = bool(client.wbuf)
            events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.want_write else 0)
            self._sel.modify(client.sock, events, "client")

    def _drop_client(self, client: _Client, why: str) -> None:
        if self._clients.pop(client.sock, None) is None:
            return
        try:
            self._sel.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()
        log.info(
            "can hub: client %s left (%s), %d bytes dropped for it",
            client.name,
            why,
            client.dropped_bytes,
        )
