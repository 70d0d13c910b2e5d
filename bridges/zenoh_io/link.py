"""Zenoh adapters of ftcap: allocator, simulated vessel and ground station.

Each link is a :class:`~bridges.zenoh_io.session.ZenohLink` (session lifecycle, decoding
callbacks that count and drop malformed payloads, publishing that returns False instead of
raising) with the keys, mailboxes and publishers of its role:

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

The config helpers (:func:`make_config`, :func:`load_config`, ...) live in
:mod:`bridges.zenoh_io.session` and are importable from here too.
"""

from __future__ import annotations

import functools
import logging
import math

import zenoh

from bridges.zenoh_io.codec import (
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
from bridges.zenoh_io.session import (
    JSON_ENCODING,
    ZenohLink,
    ZenohLinkError,
    apply_overrides,
    load_config,
    make_config,
    validate_config,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import FaultInjection, Odometry, ThrusterCommand, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.ports.mailbox import EventQueue, Mailbox

__all__ = [
    "ZenohAllocatorLink",
    "ZenohGcsLink",
    "ZenohLink",
    "ZenohLinkError",
    "ZenohVesselLink",
    "apply_overrides",
    "load_config",
    "make_config",
    "validate_config",
]

log = logging.getLogger(__name__)


class ZenohAllocatorLink(ZenohLink):
    """The allocator daemon's side; by default the router (``allocator.json5``).

    Mailboxes ``setpoints`` (WrenchSetpoint) and ``odometry`` (Odometry) are filled by
    callbacks; pass your own to share them with the loop. The queryable on
    ``allocator/state`` answers with the last snapshot (``publish_status`` or
    ``set_status_snapshot``), or with an error reply before the first one.
    ``wrench_limit`` (N, N, N*m): setpoints with a component beyond +-this are dropped as
    malformed, the sanity bound MAVLink's ``wrench_limit`` applies (None: no bound).
    """

    _shipped = "allocator"

    def __init__(
        self,
        vessel: str,
        config: zenoh.Config | None = None,
        *,
        setpoints: Mailbox[WrenchSetpoint] | None = None,
        odometry: Mailbox[Odometry] | None = None,
        wrench_limit: tuple[float, float, float] | None = None,
    ) -> None:
        self.wrench_limit = _check_limit(wrench_limit)
        super().__init__(vessel, config)
        self.setpoints = setpoints if setpoints is not None else Mailbox("setpoint")
        self.odometry = odometry if odometry is not None else Mailbox("odometry")
        self.queries_answered = 0
        self._snapshot: bytes | None = None
        k = self.keys
        decode_setpoint = functools.partial(decode_wrench_setpoint, limit=self.wrench_limit)
        self._subscribe(k.setpoint_wrench, decode_setpoint, self.setpoints)
        self._subscribe(k.odometry, decode_odometry, self.odometry)
        self._declare_publisher(k.thruster_command, urgent=True)
        self._declare_publisher(k.status)
        self._entities.append(self._session.declare_queryable(k.state, self._answer_state))

    def publish_thruster_command(self, cmd: ThrusterCommand) -> bool:
        """Put u (N) on ``thrusters/command``; False if it cannot be encoded or sent."""
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
                    query.reply(self.keys.state, snapshot, encoding=JSON_ENCODING)
                    self.queries_answered += 1
            except zenoh.ZError as e:
                log.debug("%s: reply failed: %s", self.keys.state, e)


def _check_limit(limit: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
    if limit is None:
        return None
    values = tuple(float(v) for v in limit)
    if len(values) != 3 or not all(math.isfinite(v) and v > 0.0 for v in values):
        raise ValueError(f"zenoh.wrench_limit: expected 3 finite values > 0, got {limit!r}")
    return (values[0], values[1], values[2])


class ZenohVesselLink(ZenohLink):
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
        """Put eta (NED), nu (body) and sim time on ``telemetry/odometry``; False on failure."""
        return self._publish(self.keys.odometry, encode_odometry, odom)


class ZenohGcsLink(ZenohLink):
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
        """Put a body wrench [X (N), Y (N), N (N*m)] on ``setpoint/wrench``; False on failure."""
        return self._publish(self.keys.setpoint_wrench, encode_wrench_setpoint, setpoint)

    def inject_fault(self, fault: FaultInjection) -> bool:
        """Put one fault injection on ``fault/inject`` (reliable); False on failure."""
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
                except (MalformedMessage, ValueError, TypeError, OverflowError) as e:
                    self.status.count_malformed()
                    log.warning("%s: malformed reply dropped: %s", self.keys.state, e)
        except zenoh.ZError as e:
            log.warning("%s: query failed: %s", self.keys.state, e)
        return None
