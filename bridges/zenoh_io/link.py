"""Zenoh adapters of ftcap: allocator, simulated vessel and ground station (the only zenoh import).

Each link owns one session opened from a checked config (see :mod:`bridges.zenoh_io.config`),
declares its publishers, subscribers and queryable once, and is closed by an idempotent
``shutdown()`` (or by leaving its ``with`` block). Callbacks run on zenoh-python's threads, only
decode, then ``put`` into a :class:`~ftcap_hil.ports.mailbox.Mailbox` (or an ``EventQueue``);
a payload that fails to decode is counted there (``malformed``) and dropped, never raised.
Publishing methods return False instead of raising when encoding or the session fails, so
the caller's loop can mark the port stale and carry on.

=====================  ============================================  =========================
link                   inputs (callbacks -> where)                   outputs (methods)
=====================  ============================================  =========================
ZenohAllocatorLink     setpoint/wrench -> ``setpoints`` mailbox       publish_thruster_command
(router)               telemetry/odometry -> ``odometry`` mailbox     publish_status,
                       queryable allocator/state <- snapshot          set_status_snapshot
ZenohVesselLink        fault/inject -> ``faults`` (EventQueue)        publish_odometry
(client)               thrusters/command -> ``commands`` (optional)
ZenohGcsLink           telemetry/odometry -> ``odometry`` mailbox     publish_setpoint,
(client)               allocator/status -> ``status`` mailbox         inject_fault, query_state
=====================  ============================================  =========================
"""

from __future__ import annotations

import atexit
import functools
import json
import logging
import threading
import time
import weakref
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, Self, TypeVar

import zenoh

from bridges.zenoh_io.codec import (
    ZenohKeys,
    decode_fault_injection,
    decode_odometry,
    decode_status,
    decode_thruster_command,
    decode_wrench_setpoint,
    encode_fault_injection,
    encode_odometry,
    encode_status,
    encode_thruster_command,
    encode_wrench_setpoint,
)
from bridges.zenoh_io.config import (
    CHECKED_KEYS,
    DEFAULT_PORT,
    LOOPBACK,
    ZenohConfigError,
    ZenohRole,
    check_settings,
    parse_override,
    role_settings,
    shipped_config_path,
)
from ftcap_hil.core.errors import MalformedMessage, PortError
from ftcap_hil.core.messages import FaultInjection, Odometry, ThrusterCommand, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.ports.mailbox import EventQueue, Mailbox

log = logging.getLogger(__name__)
T = TypeVar("T")
T_contra = TypeVar("T_contra", contravariant=True)
_JSON = zenoh.Encoding.APPLICATION_JSON


class ZenohLinkError(PortError):
    """The session could not be opened (router unreachable, port taken, ...)."""


# --------------------------------------------------------------------------- configuration


def apply_overrides(conf: zenoh.Config, overrides: Sequence[str] | Mapping[str, str]) -> None:
    """Insert ``KEY:VALUE`` strings (as zenoh examples' ``--cfg``) or a key -> JSON5 mapping."""
    pairs = overrides.items() if isinstance(overrides, Mapping) else map(parse_override, overrides)
    for key, value in pairs:
        try:
            conf.insert_json5(key, value)
        except zenoh.ZError as e:
            raise ZenohConfigError(f"zenoh config key {key!r} = {value!r}: {e}") from e


def validate_config(conf: zenoh.Config, source: str = "zenoh config") -> ZenohRole:
    """Apply :func:`bridges.zenoh_io.config.check_settings` to a zenoh.Config; return its role."""
    return check_settings({key: _get_json(conf, key) for key in CHECKED_KEYS}, source)


def make_config(
    role: ZenohRole | str,
    port: int = DEFAULT_PORT,
    host: str = LOOPBACK,
    overrides: Sequence[str] = (),
) -> zenoh.Config:
    """A checked config: a router listening on ``tcp/host:port`` or a client/peer connecting."""
    conf = zenoh.Config()
    apply_overrides(conf, role_settings(role, port, host))
    apply_overrides(conf, overrides)
    validate_config(conf, f"{ZenohRole(role).value} config")
    return conf


def load_config(path: str | Path, overrides: Sequence[str] = ()) -> zenoh.Config:
    """Load a JSON5 file, apply ``KEY:VALUE`` overrides, check it; ZenohConfigError if bad."""
    try:
        conf = zenoh.Config.from_file(str(path))
    except zenoh.ZError as e:
        raise ZenohConfigError(f"zenoh config file {path}: {e}") from e
    apply_overrides(conf, overrides)
    validate_config(conf, f"zenoh config {path}")
    return conf


def _get_json(conf: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except zenoh.ZError:
        return None


def _matched(publisher: zenoh.Publisher) -> bool:
    # typed bool in the stubs, but zenoh 1.x returns a MatchingStatus (always truthy)
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


# --------------------------------------------------------------------------- sinks


class _Sink(Protocol[T_contra]):
    def put(self, value: T_contra, stamp_ns: int | None = None) -> None: ...
    def count_malformed(self) -> None: ...


# --------------------------------------------------------------------------- links

# A link left open hangs interpreter exit: zenoh-python runs callbacks on non-daemon Python
# threads that end only when the session closes (zenoh-python #434), and the interpreter joins
# those threads before running atexit hooks. threading._register_atexit (what
# concurrent.futures uses) runs before that join; plain atexit is the fallback.
_OPEN_LINKS: weakref.WeakSet[_ZenohLink] = weakref.WeakSet()


def _shutdown_open_links() -> None:
    for link in list(_OPEN_LINKS):
        link.shutdown()


getattr(threading, "_register_atexit", atexit.register)(_shutdown_open_links)


class _ZenohLink:
    """Session lifecycle shared by the three links: open, declare, publish, shutdown."""

    _shipped: str = ""

    def __init__(self, vessel: str, config: zenoh.Config | None) -> None:
        self.keys = ZenohKeys.for_vessel(vessel)
        if config is None:
            config = load_config(shipped_config_path(self._shipped))
        else:
            validate_config(config, f"{type(self).__name__} config")
        self.publish_errors = 0
        self._entities: list[Any] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._failing: set[str] = set()  # ports whose last message failed: log transitions only
        self._closed = False
        self._close_lock = threading.Lock()
        try:
            self._session = zenoh.open(config)
        except zenoh.ZError as e:
            raise ZenohLinkError(f"{type(self).__name__}: cannot open zenoh session: {e}") from e
        _OPEN_LINKS.add(self)

    def _subscribe(self, key: str, decode: Callable[[bytes], T], sink: _Sink[T]) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:  # pyo3 enums: `is` is always False
                return
            try:
                value = decode(sample.payload.to_bytes())
            except MalformedMessage as e:
                sink.count_malformed()
                self._transition(key, failed=True, detail=f"dropped malformed sample: {e}")
                return
            sink.put(value)
            if key in self._failing:
                self._transition(key, failed=False, detail="valid samples again")

        self._entities.append(self._session.declare_subscriber(key, on_sample))

    def _declare_publisher(self, key: str, *, urgent: bool = False, reliable: bool = False) -> None:
        """urgent: real-time priority, no batching, drop when congested (latest value wins)."""
        if urgent:
            priority, express = zenoh.Priority.REAL_TIME, True
        else:
            priority, express = zenoh.Priority.DATA, False
        congestion = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
        publisher = self._session.declare_publisher(
            key, encoding=_JSON, priority=priority, express=express, congestion_control=congestion
        )
        self._publishers[key] = publisher
        self._entities.append(publisher)

    def _publish(self, key: str, encode: Callable[[T], bytes], msg: T) -> bool:
        try:
            payload = encode(msg)
        except (ValueError, TypeError) as e:  # MalformedMessage is a ValueError
            self._fail(key, f"cannot encode: {e}")
            return False
        return self._put(key, payload)

    def _put(self, key: str, payload: bytes) -> bool:
        if self._closed:
            return False
        try:
            self._publishers[key].put(payload)
        except zenoh.ZError as e:
            self._fail(key, f"publish failed: {e}")
            return False
        if key in self._failing:
            self._transition(key, failed=False, detail="publishing again")
        return True

    def _fail(self, key: str, detail: str) -> None:
        self.publish_errors += 1
        self._transition(key, failed=True, detail=detail)

    def _transition(self, key: str, *, failed: bool, detail: str) -> None:
        if failed and key not in self._failing:
            self._failing.add(key)
            log.warning("%s: %s", key, detail)
        elif not failed and key in self._failing:
            self._failing.discard(key)
            log.info("%s: %s", key, detail)
        else:
            log.debug("%s: %s", key, detail)

    def subscribers_matched(self, key: str | None = None, timeout_s: float = 0.0) -> bool:
        """True once the publisher on ``key`` (None: every publisher of this link) has a
        matching remote subscriber; waits up to ``timeout_s``.

        A sample published before the match can be lost, so a process that must not lose
        its first message waits on this first.
        """
        publishers = list(self._publishers.values()) if key is None else [self._publishers[key]]
        deadline = time.monotonic() + timeout_s
        while True:
            if not self._closed and all(map(_matched, publishers)):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    @property
    def closed(self) -> bool:
        return self._closed

    def shutdown(self) -> None:
        """Undeclare everything and close the session; safe to call more than once."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        _OPEN_LINKS.discard(self)
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except zenoh.ZError as e:
                log.debug("undeclare %s: %s", entity, e)
        self._entities.clear()
        try:
            self._session.close()
        except zenoh.ZError as e:
            log.warning("closing zenoh session: %s", e)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.shutdown()


class ZenohAllocatorLink(_ZenohLink):
    """The allocator daemon's side; by default the router (``allocator.json5``).

    Mailboxes ``setpoints`` (WrenchSetpoint) and ``odometry`` (Odometry) are filled by
    callbacks; pass your own to share them with the loop. The queryable on
    ``allocator/state`` answers with the last snapshot (``publish_status`` or
    ``set_status_snapshot``), or with an error reply before the first one.
    """

    _shipped = "allocator"

    def __init__(
        self,
        vessel: str,
        config: zenoh.Config | None = None,
        *,
        setpoints: Mailbox[WrenchSetpoint] | None = None,
        odometry: Mailbox[Odometry] | None = None,
    ) -> None:
        super().__init__(vessel, config)
        self.setpoints = setpoints if setpoints is not None else Mailbox("setpoint")
        self.odometry = odometry if odometry is not None else Mailbox("odometry")
        self.queries_answered = 0
        self._snapshot: bytes | None = None
        k = self.keys
        self._subscribe(k.setpoint_wrench, decode_wrench_setpoint, self.setpoints)
        self._subscribe(k.odometry, decode_odometry, self.odometry)
        self._declare_publisher(k.thruster_command, urgent=True)
        self._declare_publisher(k.status)
        self._entities.append(self._session.declare_queryable(k.state, self._answer_state))

    def publish_thruster_command(self, cmd: ThrusterCommand) -> bool:
        return self._publish(self.keys.thruster_command, encode_thruster_command, cmd)

    def publish_status(self, status: AllocatorStatus) -> bool:
        """Publish on ``allocator/status`` and keep it as the snapshot answered to queries."""
        if not self.set_status_snapshot(status):
            return False
        assert self._snapshot is not None
        return self._put(self.keys.status, self._snapshot)

    def set_status_snapshot(self, status: AllocatorStatus) -> bool:
        """Encode now (the caller may reuse its arrays) and answer queries with it."""
        try:
            self._snapshot = encode_status(status)
        except (ValueError, TypeError) as e:
            self._fail(self.keys.status, f"cannot encode status: {e}")
            return False
        return True

    def _answer_state(self, query: zenoh.Query) -> None:
        snapshot = self._snapshot  # one reference read: no lock needed
        with query:
            try:
                if snapshot is None:
                    query.reply_err(b"no allocator status yet")
                else:
                    query.reply(self.keys.state, snapshot, encoding=_JSON)
                    self.queries_answered += 1
            except zenoh.ZError as e:
                log.debug("%s: reply failed: %s", self.keys.state, e)


class ZenohVesselLink(_ZenohLink):
    """The simulated vessel's side; by default a client (``vessel.json5``).

    ``faults`` (an ``EventQueue``) receives fault injections; ``commands`` (Mailbox of
    ThrusterCommand) is filled only with ``monitor_commands=True``; pass your own to share them.
    ``n_thrusters`` makes the decoders refuse a command of another length or a fault on a
    thruster that does not exist.
    """

    _shipped = "vessel"

    def __init__(
        self,
        vessel: str,
        config: zenoh.Config | None = None,
        *,
        n_thrusters: int | None = None,
        monitor_commands: bool = False,
        faults: EventQueue[FaultInjection] | None = None,
        commands: Mailbox[ThrusterCommand] | None = None,
    ) -> None:
        super().__init__(vessel, config)
        self.faults = faults if faults is not None else EventQueue[FaultInjection]("zenoh.fault")
        self.commands = commands if commands is not None else Mailbox("thruster_command")
        k = self.keys
        decode_fault = functools.partial(decode_fault_injection, m=n_thrusters)
        self._subscribe(k.fault_inject, decode_fault, self.faults)
        if monitor_commands:
            decode_command = functools.partial(decode_thruster_command, m=n_thrusters)
            self._subscribe(k.thruster_command, decode_command, self.commands)
        self._declare_publisher(k.odometry, urgent=True)

    def publish_odometry(self, odom: Odometry) -> bool:
        return self._publish(self.keys.odometry, encode_odometry, odom)


class ZenohGcsLink(_ZenohLink):
    """The ground station's side; by default a client (``gcs.json5``).

    Mailboxes ``odometry`` (Odometry) and ``status`` (AllocatorStatus) are filled by callbacks
    (pass your own to share them).
    Fault injections are published reliably (blocking on congestion): they are events.
    """

    _shipped = "gcs"

    def __init__(
        self,
        vessel: str,
        config: zenoh.Config | None = None,
        *,
        odometry: Mailbox[Odometry] | None = None,
        status: Mailbox[AllocatorStatus] | None = None,
    ) -> None:
        super().__init__(vessel, config)
        self.odometry = odometry if odometry is not None else Mailbox("odometry")
        self.status = status if status is not None else Mailbox("status")
        k = self.keys
        self._subscribe(k.odometry, decode_odometry, self.odometry)
        self._subscribe(k.status, decode_status, self.status)
        self._declare_publisher(k.setpoint_wrench, urgent=True)
        self._declare_publisher(k.fault_inject, reliable=True)

    def publish_setpoint(self, setpoint: WrenchSetpoint) -> bool:
        return self._publish(self.keys.setpoint_wrench, encode_wrench_setpoint, setpoint)

    def inject_fault(self, fault: FaultInjection) -> bool:
        return self._publish(self.keys.fault_inject, encode_fault_injection, fault)

    def query_state(self, timeout_s: float = 1.0) -> AllocatorStatus | None:
        """Ask the allocator for its current status; None if no valid answer in time."""
        if self._closed:
            return None
        try:
            for reply in self._session.get(self.keys.state, timeout=timeout_s):
                if reply.ok is None:
                    log.debug("%s: error reply", self.keys.state)
                    continue
                try:
                    return decode_status(reply.ok.payload.to_bytes())
                except MalformedMessage as e:
                    self.status.count_malformed()
                    log.warning("%s: malformed reply dropped: %s", self.keys.state, e)
        except zenoh.ZError as e:
            log.warning("%s: query failed: %s", self.keys.state, e)
        return None
