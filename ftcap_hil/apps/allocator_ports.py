"""The allocator daemon's ports opened from its configuration and handed to the daemon
(:class:`~ftcap_hil.runtime.daemon.Ports`): CAN (thruster commands out, ESC status in),
MAVLink and Zenoh (setpoints and telemetry in, status out), and the MAVLink parameter table
read as the daemon's live tunables.

The bridges are imported here, lazily, so that building the ``ftcap-hil`` parser does not
import the networking stacks. Everything opened is entered into the caller's ``ExitStack``
and closes, newest first, when it closes.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from ftcap_hil.config.bridges import CanSettings, PortSettings
from ftcap_hil.config.daemon import DaemonConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.messages import EscStatus
from ftcap_hil.core.status import AllocatorStatus, Severity
from ftcap_hil.ports.mailbox import EventQueue
from ftcap_hil.runtime.command_log import CommandLog, LoggedSink
from ftcap_hil.runtime.daemon import Ports
from ftcap_hil.runtime.telemetry_guard import OdometryMailbox

log = logging.getLogger(__name__)


class AllocatorSettings(Protocol):
    """What the wiring reads: the daemon's settings and its ports' settings, validated by
    ``config.bridges`` (``config.daemon.LoadedConfig`` is one)."""

    @property
    def daemon(self) -> DaemonConfig: ...
    @property
    def ports(self) -> PortSettings: ...
    @property
    def source(self) -> str: ...


def open_can(cfg: AllocatorSettings, stack: contextlib.ExitStack) -> tuple[Any, Any, Any]:
    """The CAN bus, the thruster sink on it (zero on close; its ESC command stream is
    started by ``build_ports``), the ESC status source (None with ``[can] esc_monitor =
    false``) and the node's GetNodeInfo server (which also sees a second node on our ID)."""
    from bridges.can_io.adapters import CanEscStatusSource, CanThrusterSink
    from bridges.can_io.bus import open_can_bus

    c = cfg.ports.can
    ths = cfg.daemon.thrusters
    bus = stack.enter_context(open_can_bus(c.interface, c.channel))
    sink = CanThrusterSink(bus, _force_map(c, ths), node_id=c.node_id, zero_on_shutdown=True)
    stack.enter_context(sink)
    esc = None
    if c.esc_monitor:
        esc = stack.enter_context(CanEscStatusSource(bus, ths.m, esc_node_ids=c.esc_node_ids))
    server = _serve_node_info(c, bus, sink, None if esc is None else esc.notifier, stack)
    return sink, esc, server


def _force_map(c: CanSettings, ths: ThrusterSet) -> Any:
    """The curves' map if ``[can]`` names thruster curves, else the linear one."""
    from bridges.can_io.force_map import CurveForceMap, ForceRawMap

    if c.curves is not None:
        return CurveForceMap.create(c.curves, c.deadband_n)
    return ForceRawMap.from_limits(ths.u_min, ths.u_max, c.deadband_n)


def _serve_node_info(
    c: CanSettings, bus: Any, sink: Any, notifier: Any, stack: contextlib.ExitStack
) -> Any:
    """Answer GetNodeInfo as ``c.node_name`` (on the ESC source's notifier: one per bus)."""
    from bridges.can_io.node import CanNodeServer, NodeInfo, unique_id_for

    info = NodeInfo(c.node_name, unique_id=unique_id_for(c.node_name, c.node_id))
    server = CanNodeServer(bus, {c.node_id: info}, sink.current_status, notifier=notifier)
    stack.callback(server.shutdown)
    return server


class NodeHealthSink:
    """The allocator's DroneCAN NodeStatus health and mode follow its status
    (``bridges.can_io.node.health_for``: WARNING when a thruster is flagged, ERROR when the
    allocation is degraded or an ESC is silent)."""

    def __init__(self, sink: Any) -> None:
        from bridges.can_io.node import health_for, mode_for

        self._sink, self._health_for, self._mode_for = sink, health_for, mode_for

    def publish(self, status: AllocatorStatus) -> None:
        self._sink.set_status(self._health_for(status), self._mode_for(status))

    def announce(self, text: str, severity: Severity) -> None:
        """NodeStatus carries no text."""


def _latest_of(esc: Any) -> Callable[[], list[EscStatus | None]]:
    """The latest ``EscStatus`` per thruster of a ``CanEscStatusSource`` (None: never)."""

    def latest() -> list[EscStatus | None]:
        return [None if (slot := box.latest()) is None else slot.value for box in esc.mailboxes]

    return latest


def _every_status(esc: Any, wanted: bool) -> EventQueue[EscStatus] | None:
    """Every ``esc.Status`` of a ``CanEscStatusSource`` with its receipt stamp, for the
    drives' diagnosis (None: no source, or no drive data sheets to judge them by)."""
    if esc is None or not wanted:
        return None
    queue: EventQueue[EscStatus] = EventQueue("esc-status", maxlen=64 * len(esc.mailboxes))
    for box in esc.mailboxes:
        box.history = queue
    return queue


def build_ports(
    cfg: AllocatorSettings,
    stack: contextlib.ExitStack,
    cmd_log: CommandLog | None,
) -> tuple[Ports, Any]:
    """The daemon's ports from ``cfg``'s [can], [mavlink] and [zenoh] tables, and the
    MAVLink parameter table as live tunables (None without MAVLink). The ESC command stream (unless
    ``esc_rate_hz = 0``) re-sends the latest command from here on."""
    sink, esc, server = open_can(cfg, stack)
    node_id = cfg.ports.can.node_id
    ports = Ports(
        setpoints=[],
        telemetry=[],
        thrusters=LoggedSink(sink, cfg.daemon.thrusters.m, cmd_log),
        status=[NodeHealthSink(sink)],
        esc_ages=esc.ages_s if esc is not None else None,
        esc_latest=_latest_of(esc) if esc is not None else None,
        bus_conflict=lambda now_ns: bool(server.in_conflict(node_id, now_ns)),
        esc_reports=_every_status(esc, cfg.daemon.drives is not None),
    )
    params = open_mavlink(cfg, stack, ports)
    open_zenoh(cfg, stack, ports)
    c = cfg.ports.can
    if c.esc_rate_hz > 0.0:  # last: opening the others must not stall its first ticks
        sink.start_stream(
            c.esc_rate_hz, c.esc_hold_s, esc_timeout_s=c.esc_command_timeout_s,
            restart_from_zero=True,  # the daemon takes the lapses (AllocatorDaemon.cycle)
        )  # fmt: skip
    return ports, params


def open_mavlink(cfg: AllocatorSettings, stack: contextlib.ExitStack, ports: Ports) -> Any:
    """MAVLink setpoints, manual input, odometry and status onto ``ports`` (unless
    ``[mavlink] enabled = false``); the link's parameter table as live tunables, or None."""
    mav_cfg = cfg.ports.mavlink
    if mav_cfg is None:
        return None
    from bridges.mavlink import allocator as mav
    from bridges.mavlink.allocator_params import AllocatorTunables, allocator_param_specs
    from bridges.mavlink.status import MavlinkStatusSink

    if mav_cfg.warning is not None:
        log.warning("%s", mav_cfg.warning)
    d = cfg.daemon
    odometry = OdometryMailbox("mavlink.odometry")
    link = stack.enter_context(
        mav.MavlinkAllocatorLink(
            mav.AllocatorLinkConfig(
                d.thrusters.m,
                mav_cfg.max_wrench,
                mav_cfg.wrench_limit,
                u_max=tuple(float(v) for v in d.thrusters.u_max),
                telemetry_from=mav_cfg.telemetry_from,
            ),
            mav_cfg.endpoint,
            allocator_param_specs(
                d.core,
                d.setpoint_timeout_s,
                d.telemetry_timeout_s,
                d.esc_timeout_s,
                d.rate_hz,
                float(np.max(d.thrusters.u_max)),
            ),
            odometry=odometry,
        )
    )
    ports.setpoints += [link.setpoint, link.manual]
    ports.telemetry.append(link.odometry)  # trusted: the vessel's inbox address only
    latest = ports.esc_latest
    volts = None
    if latest is not None:
        volts = lambda: [math.nan if e is None else e.voltage_v for e in latest()]  # noqa: E731
    ports.status.append(MavlinkStatusSink(link, volts))
    return AllocatorTunables(link.params)


def open_zenoh(cfg: AllocatorSettings, stack: contextlib.ExitStack, ports: Ports) -> None:
    """The Zenoh router session's setpoints, odometry and status onto ``ports`` (unless
    ``[zenoh] enabled = false``); with ``ros2 = true`` also its ROS 2 setpoints, odometry
    and mode requests."""
    z_cfg = cfg.ports.zenoh
    if z_cfg is None:
        return
    from bridges.zenoh_io import link as zenoh_link
    from bridges.zenoh_io.ros2.endpoints import Ros2Settings
    from bridges.zenoh_io.status import ZenohStatusSink

    conf = zenoh_link.load_config(z_cfg.config, list(z_cfg.overrides), z_cfg.allow_unauthenticated)
    ros2 = Ros2Settings(z_cfg.domain_id, z_cfg.namespace) if z_cfg.ros2 else None
    zl = stack.enter_context(
        zenoh_link.ZenohAllocatorLink(
            z_cfg.vessel,
            conf,
            wrench_limit=z_cfg.wrench_limit,
            ros2=ros2,
            odometry=OdometryMailbox("zenoh.odometry"),
            ros2_odometry=OdometryMailbox("ros2.odometry"),
        )
    )
    # Without access control any local process may put odometry: untrusted, used only
    # while no trusted port is fresh (runtime.telemetry_guard).
    telemetry = ports.telemetry if zenoh_link.authenticates(conf) else ports.untrusted_telemetry
    ports.setpoints.append(zl.setpoints)
    telemetry.append(zl.odometry)
    if ros2 is not None:  # its own mailboxes: the vessel sends its odometry both ways
        ports.setpoints.append(zl.ros2_setpoints)
        telemetry.append(zl.ros2_odometry)
        ports.modes.append(zl.modes)
    ports.status.append(ZenohStatusSink(zl))
