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

With ``ros2`` settings (:class:`~bridges.zenoh_io.ros2.endpoints.Ros2Settings`) the
allocator and the vessel are also ROS 2 nodes as rmw_zenoh sees them (``ftcap_allocator``,
``ftcap_vessel`` in the namespace, default ``/<vessel>``), beside the JSON keys:

=====================  ============================================  =========================
link                   subscribes (-> where)                          publishes
=====================  ============================================  =========================
ZenohAllocatorLink     setpoint/wrench WrenchStamped                  thrusters/command
                       -> ``ros2_setpoints``;                         Float64MultiArray,
                       odometry Odometry -> ``ros2_odometry``;        allocator/status
                       allocator/mode String -> ``modes``             ftcap_msgs/AllocatorStatus,
                                                                      /diagnostics
                                                                      DiagnosticArray
ZenohVesselLink        fault/inject ftcap_msgs/FaultInjection         odometry Odometry
                       -> ``faults``; thrusters/command -> ``commands``
                       (with ``monitor_commands``)
=====================  ============================================  =========================

Separate mailboxes for the ROS 2 inputs: the vessel sends its odometry both ways, and the
daemon takes the newest measurement over its telemetry ports (the same for setpoints).
"""

from __future__ import annotations

import functools
import logging
import math
import time

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
from bridges.zenoh_io.ros2 import messages as ros2_msg
from bridges.zenoh_io.ros2 import std_types as ros2_types
from bridges.zenoh_io.ros2.diagnostics import diagnostic_array
from bridges.zenoh_io.ros2.endpoints import Ros2Publisher, Ros2Settings
from bridges.zenoh_io.session import (
    JSON_ENCODING,
    ZenohLink,
    ZenohLinkError,
    apply_overrides,
    authenticates,
    load_config,
    make_config,
    validate_config,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import FaultInjection, Odometry, ThrusterCommand, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.ports.mailbox import EventQueue, Mailbox

__all__ = [
    "ZenohAllocatorLink",
    "ZenohGcsLink",
    "ZenohLink",
    "ZenohLinkError",
    "ZenohVesselLink",
    "apply_overrides",
    "authenticates",
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
        ros2: Ros2Settings | None = None,
        ros2_odometry: Mailbox[Odometry] | None = None,
    ) -> None:
        self.wrench_limit = _check_limit(wrench_limit)
        super().__init__(vessel, config)
        self.setpoints = setpoints if setpoints is not None else Mailbox("setpoint")
        self.odometry = odometry if odometry is not None else Mailbox("odometry")
        self.ros2_odometry = ros2_odometry or Mailbox[Odometry]("ros2.odometry")
        self.queries_answered = 0
        self._snapshot: bytes | None = None
        k = self.keys
        decode_setpoint = functools.partial(decode_wrench_setpoint, limit=self.wrench_limit)
        self._subscribe(k.setpoint_wrench, decode_setpoint, self.setpoints)
        self._subscribe(k.odometry, decode_odometry, self.odometry)
        self._declare_publisher(k.thruster_command, urgent=True)
        self._declare_publisher(k.status)
        self._entities.append(self._session.declare_queryable(k.state, self._answer_state))
        self.ros2_setpoints: Mailbox[WrenchSetpoint] = Mailbox("ros2.setpoint")
        self.modes = EventQueue[Mode]("ros2.mode")  # for the loop: daemon.set_mode
        self._ros2: dict[str, Ros2Publisher] = {} if ros2 is None else self._declare_ros2(ros2)

    def _declare_ros2(self, settings: Ros2Settings) -> dict[str, Ros2Publisher]:
        node = self._ros2_node("ftcap_allocator", settings)
        to_setpoint = functools.partial(ros2_msg.setpoint_from, limit=self.wrench_limit)
        t = ros2_types
        self._ros2_subscribe(node, "setpoint/wrench", t.WRENCH_STAMPED, to_setpoint,
                             self.ros2_setpoints)  # fmt: skip
        self._ros2_subscribe(node, "odometry", t.ODOMETRY, ros2_msg.odometry_from,
                             self.ros2_odometry)  # fmt: skip
        self._ros2_subscribe(node, "allocator/mode", t.STRING_MSG, ros2_msg.mode_from, self.modes)
        return {
            "command": self._ros2_publisher(node, "thrusters/command", t.FLOAT64_ARRAY),
            "status": self._ros2_publisher(node, "allocator/status", t.ALLOCATOR_STATUS),
            "diagnostics": self._ros2_publisher(node, "/diagnostics", t.DIAGNOSTIC_ARRAY),
        }

    @property
    def ros2_publishers(self) -> dict[str, Ros2Publisher]:
        """The ROS 2 publishers by role (empty without the ROS 2 mapping)."""
        return dict(self._ros2)

    def publish_thruster_command(self, cmd: ThrusterCommand) -> bool:
        """Put u (N) on ``thrusters/command`` (and its ROS 2 topic); False if it cannot be
        encoded or sent."""
        sent = self._publish(self.keys.thruster_command, encode_thruster_command, cmd)
        if "command" in self._ros2:
            value = ros2_msg.float64_array(cmd.u.tolist(), "thrusters")
            sent = self._publish_ros2(self._ros2["command"], value) and sent
        return sent

    def publish_status(self, status: AllocatorStatus) -> bool:
        """Publish on ``allocator/status`` and keep it as the snapshot answered to queries;
        with the ROS 2 mapping also its AllocatorStatus and DiagnosticArray."""
        if not self.set_status_snapshot(status):
            return False
        assert self._snapshot is not None
        sent = self._put(self.keys.status, self._snapshot)
        if self._ros2:
            now_s = time.time()
            value = ros2_msg.allocator_status_msg(status, now_s)
            sent = self._publish_ros2(self._ros2["status"], value) and sent
            value = diagnostic_array(status, self.keys.vessel, now_s)
            sent = self._publish_ros2(self._ros2["diagnostics"], value) and sent
        return sent

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
        ros2: Ros2Settings | None = None,
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
        self._ros2_odometry: Ros2Publisher | None = None
        if ros2 is not None:
            self._declare_ros2(ros2, n_thrusters, monitor_commands)

    def _declare_ros2(self, settings: Ros2Settings, m: int | None, monitor: bool) -> None:
        node = self._ros2_node("ftcap_vessel", settings)
        t = ros2_types
        to_fault = functools.partial(ros2_msg.fault_from, m=m)
        self._ros2_subscribe(node, "fault/inject", t.FAULT_INJECTION, to_fault, self.faults)
        if monitor:
            to_command = functools.partial(ros2_msg.thruster_command_from, m=m)
            self._ros2_subscribe(node, "thrusters/command", t.FLOAT64_ARRAY, to_command,
                                 self.commands)  # fmt: skip
        self._ros2_odometry = self._ros2_publisher(node, "odometry", t.ODOMETRY)

    def publish_odometry(self, odom: Odometry) -> bool:
        """Put eta (NED), nu (body) and sim time on ``telemetry/odometry`` (and as
        nav_msgs/Odometry with the ROS 2 mapping); False on failure."""
        sent = self._publish(self.keys.odometry, encode_odometry, odom)
        if self._ros2_odometry is not None:
            value = ros2_msg.odometry_msg(odom)
            sent = self._publish_ros2(self._ros2_odometry, value) and sent
        return sent


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
