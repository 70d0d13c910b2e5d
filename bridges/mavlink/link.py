"""MAVLink transport shared by the allocator, vessel and ground-station links (pymavlink).

This is the only module that imports ``pymavlink.mavutil`` (the dialect generator in
:mod:`bridges.mavlink.dialect` imports ``pymavlink.generator``), and only for byte streams
(``tcp:``, serial): UDP goes through a socket of our own (:mod:`bridges.mavlink.transport`),
so that the port, not pymavlink, decides who is a peer. One :class:`MavlinkPort` owns one
transport, one dispatch thread and a send lock; the role adapters
(:mod:`bridges.mavlink.allocator`, :mod:`bridges.mavlink.vessel`, :mod:`bridges.mavlink.gcs`)
give it a table of handlers and only validate and drop values into mailboxes. Every
datagram passes :class:`~bridges.mavlink.gate.InboxGate` (rate limits, MAVLink 2 only,
signing, system ids, peer admission, relaying) before a handler sees it. The topology, ids
and security settings are in :mod:`bridges.mavlink.config`.

Protocol: MAVLink 2 only, with the ftcap dialect (common.xml + WRENCH_SETPOINT,
FTCAP_STATUS) from :mod:`bridges.mavlink.dialect`, set explicitly on every connection
rather than through mavutil's process-wide dialect. With a key file every frame sent is
signed (:mod:`bridges.mavlink.signing`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Self

os.environ.setdefault("MAVLINK20", "1")  # read by mavutil when it builds its default dialect

from pymavlink import mavutil  # noqa: E402  (must follow the MAVLINK20 switch)

from bridges.mavlink import dialect as mavlink_dialect  # noqa: E402
from bridges.mavlink.codec import Severity, SystemStatus  # noqa: E402
from bridges.mavlink.config import GROUND_STATIONS, MavlinkEndpoint  # noqa: E402
from bridges.mavlink.errors import LinkConfigError  # noqa: E402
from bridges.mavlink.gate import InboxGate, PortStats  # noqa: E402
from bridges.mavlink.peers import Address, PeerTable, TrafficLimits  # noqa: E402
from bridges.mavlink.signing import SignatureVerifier, load_signing_key, signing_timestamp  # noqa: E402
from bridges.mavlink.transport import StreamTransport, UdpTransport  # noqa: E402
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.ports.mailbox import Mailbox

logger = logging.getLogger(__name__)

Handler = Callable[[Any, int], None]
"""Called on the dispatch thread with (message, receive stamp from time.monotonic_ns())."""

_DECODE_ERRORS = (MalformedMessage, ValueError, TypeError, OverflowError, AttributeError)


@dataclass(frozen=True)
class Route:
    """A handler and the mailbox whose ``malformed`` counter its decode errors go to."""

    handler: Handler
    mailbox: Mailbox[Any] | None = None


@dataclass
class _Heartbeat:
    mav_type: int
    autopilot: int
    period_s: float
    status: SystemStatus = SystemStatus.STANDBY
    next_ns: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


class MavlinkPort:
    """One transport, one dispatch thread, a send lock and a 1 Hz HEARTBEAT.

    The thread starts in the constructor: build the handler table first. ``mav_type`` and
    ``autopilot`` are MAV_TYPE_* / MAV_AUTOPILOT_* names for the HEARTBEAT. ``tick``
    (optional) runs on the dispatch thread after every receive or poll timeout.
    ``default_authorized``: the system ids obeyed when the endpoint names none.
    """

    def __init__(
        self,
        endpoint: MavlinkEndpoint,
        *,
        role: str,
        mav_type: str,
        routes: Mapping[str, Route],
        autopilot: str = "MAV_AUTOPILOT_INVALID",
        status: SystemStatus = SystemStatus.STANDBY,
        heartbeat_period_s: float = 1.0,
        poll_s: float = 0.05,
        tick: Callable[[int], None] | None = None,
        default_authorized: tuple[int, ...] = GROUND_STATIONS,
        limits: TrafficLimits | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.role = role
        self.dialect = mavlink_dialect.load()
        self.stats = PortStats()
        self.authorized_systems = frozenset(endpoint.authorized_systems or default_authorized)
        key = None if endpoint.key_file is None else load_signing_key(endpoint.key_file)
        self._routes = dict(routes)
        self._poll_s = poll_s
        self._tick = tick
        self._t0_ns = time.monotonic_ns()
        self._next_expiry_ns = 0
        self._requester: Address | None = None
        self._heartbeat = _Heartbeat(
            getattr(self.dialect, mav_type),
            getattr(self.dialect, autopilot),
            heartbeat_period_s,
            status,
        )
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._closed = False
        self._close_lock = threading.Lock()
        self._transport = self._open(endpoint, limits)
        self._mav = self._sender(key)
        self._gate = InboxGate(
            self.dialect,
            self._transport,
            (endpoint.system_id, endpoint.component_id),
            self.authorized_systems,
            None if key is None else SignatureVerifier(key),
            self.stats,
            datagrams=isinstance(self._transport, UdpTransport),
        )
        self._thread = threading.Thread(target=self._run, name=f"mavlink-{role}", daemon=True)
        self._thread.start()

    @staticmethod
    def _open(endpoint: MavlinkEndpoint, limits: TrafficLimits | None) -> Any:
        if endpoint.connection.startswith(("udpin:", "udp:", "udpout:")):
            return UdpTransport(endpoint.connection, endpoint.peers, endpoint.relay, limits)
        try:
            conn = mavutil.mavlink_connection(
                endpoint.connection,
                source_system=endpoint.system_id,
                source_component=endpoint.component_id,
            )
        except (OSError, ValueError) as e:
            raise LinkConfigError(f"connection: cannot open {endpoint.connection!r}: {e}") from e
        return StreamTransport(conn)

    def _sender(self, key: bytes | None) -> Any:
        mav = self.dialect.MAVLink(
            self._transport, srcSystem=self.system_id, srcComponent=self.component_id
        )
        if key is not None:
            mav.signing.secret_key = key
            mav.signing.sign_outgoing = True
            mav.signing.timestamp = signing_timestamp(time.time())
        return mav

    @property
    def table(self) -> PeerTable:
        """Who this port trusts and sends to (:mod:`bridges.mavlink.peers`)."""
        return self._transport.table

    @property
    def signing(self) -> bool:
        """Frames are signed and unsigned ones refused (a key file is set)."""
        return self.endpoint.key_file is not None

    # --- identity and time ---

    @property
    def system_id(self) -> int:
        """Our MAVLink system id."""
        return self.endpoint.system_id

    @property
    def component_id(self) -> int:
        """Our MAVLink component id."""
        return self.endpoint.component_id

    def time_boot_ms(self) -> int:
        """Milliseconds since this port opened, wrapped to uint32 (MAVLink ``time_boot_ms``)."""
        return ((time.monotonic_ns() - self._t0_ns) // 1_000_000) & 0xFFFFFFFF

    def time_boot_us(self) -> int:
        """Microseconds since this port opened (MAVLink ``time_usec`` when no other clock)."""
        return (time.monotonic_ns() - self._t0_ns) // 1_000

    def addressed_to_me(self, target_system: int, target_component: int | None = None) -> bool:
        """MAVLink addressing: 0 is broadcast; ``None`` when the message has no component."""
        if target_system not in (0, self.system_id):
            return False
        return target_component is None or target_component in (0, self.component_id)

    def accepts(self, target_system: int, target_component: int | None = None) -> bool:
        """:meth:`addressed_to_me`, counting a message for someone else in ``stats.ignored``."""
        if self.addressed_to_me(target_system, target_component):
            return True
        self.stats.ignored += 1
        return False

    # --- sending (any thread) ---

    def send(
        self,
        build: Callable[[Any], None],
        *,
        only: Address | None = None,
        skip: Address | None = None,
    ) -> bool:
        """Call ``build(mav)`` (e.g. ``lambda mav: mav.heartbeat_send(...)``) under the lock.

        To every peer of the current snapshot (to ``only`` alone, or to all but ``skip``).
        False, counted in ``stats.send_errors``, if the port is closed, the value does not
        fit the wire type or a datagram was refused; never raises for transport errors.
        """
        with self._send_lock:
            if self._closed:
                self.stats.send_errors += 1
                return False
            refused = self._transport.send_errors
            self._transport.only, self._transport.skip = only, skip
            try:
                build(self._mav)
            except (OSError, OverflowError, ValueError, struct.error) as e:
                # OverflowError / struct.error: a value that does not fit the wire type
                # (e.g. 1e39 into a float32 field): the message is not sent, the caller goes on.
                self.stats.send_errors += 1
                logger.debug("%s: send failed: %s", self.role, e)
                return False
            finally:
                self._transport.only = self._transport.skip = None
            if self._transport.send_errors != refused:  # some peer's socket refused it
                self.stats.send_errors += 1
                return False
        return True

    def set_system_status(self, status: SystemStatus) -> None:
        """Status reported from the next HEARTBEAT on; a change is announced at once (the
        dispatch thread sends a HEARTBEAT within ``poll_s``) rather than up to a period late."""
        status = SystemStatus(status)
        with self._heartbeat.lock:
            if status != self._heartbeat.status:
                self._heartbeat.status = status
                self._heartbeat.next_ns = 0

    def send_heartbeat(self) -> bool:
        """One HEARTBEAT now with the current status (the dispatch thread sends them at 1 Hz)."""
        hb = self._heartbeat
        with hb.lock:
            status = int(hb.status)
        return self.send(lambda mav: mav.heartbeat_send(hb.mav_type, hb.autopilot, 0, 0, status))

    def send_statustext(self, text: str, severity: Severity = Severity.INFO) -> bool:
        """STATUSTEXT; text longer than 50 characters is sent as MAVLink 2 chunks."""
        raw = text.encode("ascii", errors="replace")
        if len(raw) <= 50:
            return self.send(lambda mav: mav.statustext_send(int(severity), raw))
        chunk_id = (self.time_boot_us() & 0xFFFE) + 1  # non-zero marks a chunked text
        # A chunk shorter than 50 characters ends the text; add an empty one if needed.
        chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)]
        if len(chunks[-1]) == 50:
            chunks.append(b"")
        ok = True
        for seq, chunk in enumerate(chunks):

            def build(mav: Any, chunk: bytes = chunk, seq: int = seq) -> None:
                mav.statustext_send(int(severity), chunk, chunk_id, seq)

            ok = self.send(build) and ok
        return ok

    def authorized(self, msg: Any) -> bool:
        """The sender's system id is one this port obeys; counts ``stats.unauthorized`` if
        not (handlers of setpoints, parameters and commands call this)."""
        if msg.get_srcSystem() in self.authorized_systems:
            return True
        self.stats.unauthorized += 1
        return False

    def resolve(self, key: str, values: tuple[str, ...]) -> tuple[Address, ...]:
        """``host:port`` strings as this transport's source addresses (LinkConfigError)."""
        resolved: tuple[Address, ...] = self._transport.resolve(key, values)
        return resolved

    @property
    def source(self) -> Address | None:
        """The (host, port) the message being dispatched came from (in a handler; else None)."""
        return self._requester

    def reply(self, build: Callable[[Any], None], cost: float = 1.0) -> bool:
        """:meth:`send` an answer, paid from the requester's reply budget (dispatch thread,
        inside a handler): a source that floods requests cannot make the port flood."""
        if not self.table.take_reply(self._requester, time.monotonic_ns(), cost):
            return False
        return self.send(build)

    # --- dispatch thread ---

    def _run(self) -> None:
        self._periodic(time.monotonic_ns())  # announce ourselves at once
        while not self._stop.is_set():
            try:
                item = self._transport.receive(self._poll_s)
            except OSError as e:
                if self._stop.is_set():
                    break
                self.stats.errors += 1
                logger.warning("%s: receive failed: %s", self.role, e)
                self._stop.wait(self._poll_s)
                continue
            now_ns = time.monotonic_ns()
            if item is not None:
                data, addr = item
                self._requester = addr
                for msg in self._gate.process(data, addr, now_ns):
                    self._dispatch(msg, now_ns)
                self._requester = None
            self._periodic(now_ns)

    def _periodic(self, now_ns: int) -> None:
        hb = self._heartbeat
        if now_ns >= hb.next_ns:
            hb.next_ns = now_ns + int(hb.period_s * 1e9)
            self.send_heartbeat()
        if now_ns >= self._next_expiry_ns:
            self._next_expiry_ns = now_ns + 1_000_000_000
            self.table.expire(now_ns)
        if self._tick is not None:
            self._tick(now_ns)

    def _dispatch(self, msg: Any, now_ns: int) -> None:
        mtype = msg.get_type()
        route = self._routes.get(mtype)
        if route is None:
            return
        try:
            route.handler(msg, now_ns)
        except _DECODE_ERRORS as e:
            logger.debug("%s: dropped %s: %s", self.role, mtype, e)
            if route.mailbox is not None:
                route.mailbox.count_malformed()
            else:
                self.stats.malformed += 1
        except Exception:  # the thread boundary: log, count, keep serving
            self.stats.errors += 1
            logger.exception("%s: handler for %s failed", self.role, mtype)

    # --- lifecycle ---

    @property
    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def shutdown(self, timeout_s: float = 2.0) -> None:
        """Stop the dispatch thread and close the connection. Idempotent."""
        with self._close_lock:
            if self._stop.is_set() and self._closed:
                return
            self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        with self._send_lock:
            if not self._closed:
                self._closed = True
                with contextlib.suppress(OSError):
                    self._transport.close()

    def __enter__(self) -> MavlinkPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class PortOwner:
    """Lifecycle shared by the links that own one :class:`MavlinkPort` as ``self._port``:
    statistics, liveness, idempotent shutdown and the context manager."""

    _port: MavlinkPort

    @property
    def stats(self) -> PortStats:
        return self._port.stats

    @property
    def is_alive(self) -> bool:
        return self._port.is_alive

    def send_statustext(self, text: str, severity: Severity = Severity.INFO) -> bool:
        """STATUSTEXT (chunked beyond 50 characters); False on a transport error."""
        return self._port.send_statustext(text, severity)

    def shutdown(self) -> None:
        """Stop the port's dispatch thread and close its connection. Idempotent."""
        self._port.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
