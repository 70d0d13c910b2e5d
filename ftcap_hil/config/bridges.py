"""The bridge tables of the allocator's and the vessel's files: ``[can]``, ``[mavlink]``,
``[zenoh]`` -> :class:`PortSettings`, what a process needs to open its ports (plain values:
the bridges are opened from them by the command that runs the process). A key left out
takes the settings type's default, written there only.

Same keys in both files except where the role differs: the allocator's ``[can]`` has
``node_id`` (its own node), ``node_name``, ``esc_monitor`` and the ESC command stream's
``esc_rate_hz`` (0: no stream), ``esc_hold_s``, ``esc_command_timeout_s``; the vessel's
``allocator_node_id`` (the only node it accepts commands from) and ``start_hub``; both
``thruster_curve`` and ``curve_thrust_max_n`` (:mod:`ftcap_hil.config.thruster_curves`).
The allocator's ``[mavlink]`` has ``max_wrench`` and ``wrench_limit``, its ``[zenoh]``
``wrench_limit`` (default 1000 per component). ``[zenoh] config`` is a JSON5 file or the name of a
shipped one (``allocator``, ``vessel``, ``gcs``), checked when the session opens
(:mod:`bridges.zenoh_io.config`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ftcap_hil.config.table_dataclass import defaults_of
from ftcap_hil.config.tables import Table
from ftcap_hil.config.thruster_curves import curves_from
from ftcap_hil.core.effectiveness.thruster_curve import ThrusterCurve

if TYPE_CHECKING:
    from bridges.mavlink.config import MavlinkEndpoint

# The bridges' pure config modules are imported when a file is read, not when ``ftcap-hil``
# builds its parser (tests/unit/test_sim_vessel.py: the CLI imports no bridge).
NODE_IDS = (1, 127)  # DroneCAN node IDs (0 is anonymous)
# Zenoh setpoints with a component beyond this are garbage, dropped as malformed (MAVLink's
# shipped wrench_limit): always bounded, a file may only choose the bound.
DEFAULT_WRENCH_LIMIT = (1000.0, 1000.0, 1000.0)


@dataclass(frozen=True)
class CanSettings:
    """``[can]``: the bus and the DroneCAN node IDs on it.

    ``node_id`` is the allocator's node (the allocator sends from it, the vessel accepts
    RawCommand from it only); ``esc_node_ids[i]`` is ESC i's node (None: the allocator
    accepts esc.Status from any node). ``deadband_n``: forces with ``|u|`` at most this (N)
    are sent as raw 0. ``esc_monitor`` (allocator): watch esc.Status; ``start_hub``
    (vessel): also run the ``canhub`` on ``channel``.

    ``curves``: one thruster curve per thruster (force <-> command), None for the linear
    map: on the allocator's side the curve it encodes with, on the vessel's the physical one
    its ESCs decode with. Allocator only: the ESC command stream's rate ``esc_rate_hz``
    (1..400 Hz; 0: no stream, one command per cycle), ``esc_hold_s`` (no allocation for
    this long: zero; at least 2.5 of the daemon's periods) and ``esc_command_timeout_s``
    (the ESCs' own timeout: no command on the bus for this long and they are at zero, the
    allocator restarts from zero); ``node_name``, what GetNodeInfo answers.
    """

    interface: str = "canhub"
    channel: str = "127.0.0.1:29536"
    node_id: int = 10
    esc_node_ids: tuple[int, ...] | None = None
    deadband_n: float = 0.0
    esc_monitor: bool = True
    start_hub: bool = False
    curves: tuple[ThrusterCurve, ...] | None = None
    esc_rate_hz: float = 100.0
    esc_hold_s: float = 1.0
    esc_command_timeout_s: float = 0.2
    node_name: str = "org.ftcap.allocator"


@dataclass(frozen=True)
class MavlinkSettings:
    """``[mavlink]`` of an enabled link: where it binds and whom it sends to; for the
    allocator also ``max_wrench`` (MANUAL_CONTROL full deflection [X N, Y N, N N*m]),
    ``wrench_limit`` (WRENCH_SETPOINT components beyond are dropped as malformed) and
    ``telemetry_from`` (the ``host:port`` inboxes ODOMETRY is accepted from; None: the
    ``relay`` inboxes, i.e. the vessel's). A link beyond loopback without ``key_file`` is an
    error unless ``allow_unauthenticated`` (:func:`unsigned_exposure`)."""

    endpoint: MavlinkEndpoint
    max_wrench: tuple[float, float, float] = (0.3, 0.3, 0.06)
    wrench_limit: tuple[float, float, float] | None = None
    telemetry_from: tuple[str, ...] | None = None
    # the link reaches beyond loopback unsigned, as ``allow_unauthenticated`` allows: what
    # does (warned at start), None otherwise
    unauthenticated: str | None = None

    @property
    def warning(self) -> str | None:
        """What to warn of at start, if the link is unsigned beyond loopback."""
        if self.unauthenticated is None:
            return None
        return (
            f"mavlink: {self.unauthenticated} reaches beyond loopback unsigned "
            "(allow_unauthenticated = true): anyone on that network can steer the thrusters"
        )


@dataclass(frozen=True)
class ZenohSettings:
    """``[zenoh]`` of an enabled session: the vessel name in the key expressions, the JSON5
    file and the ``KEY:VALUE`` overrides applied to it (in order); for the allocator
    ``wrench_limit`` (setpoints with a component beyond it are dropped as malformed).
    ``ros2``: also the ROS 2 topics as rmw_zenoh writes them, in ``domain_id`` under
    ``namespace`` (``""``: ``/<vessel>``; docs/ros2-and-foxglove.md). ``allow_unauthenticated``:
    bridges/zenoh_io/config.py's check_settings."""

    config: Path
    vessel: str = "ftcap1"
    overrides: tuple[str, ...] = ()
    wrench_limit: tuple[float, float, float] | None = None
    ros2: bool = False
    domain_id: int = 0
    namespace: str = ""
    # an endpoint beyond loopback without mutual TLS and access control is accepted (and
    # warned about at start) rather than refused
    allow_unauthenticated: bool = False


@dataclass(frozen=True)
class PortSettings:
    """Every port of one process; ``mavlink`` / ``zenoh`` None: that bridge is disabled."""

    can: CanSettings
    mavlink: MavlinkSettings | None
    zenoh: ZenohSettings | None


ENDPOINT_KEYS = (
    "connection", "peers", "system_id", "component_id", "relay", "key_file",
    "authorized_systems", "bind_all_interfaces", "geodetic_origin", "allow_unauthenticated",
)  # fmt: skip


def unsigned_exposure(t: Table, endpoint: MavlinkEndpoint) -> str | None:
    """Secure by default: a link that reaches beyond loopback (a bind, a peer, a relay or a
    target elsewhere) must sign its frames (``key_file``): anyone on that network could
    otherwise steer the thrusters. ``allow_unauthenticated = true`` is the explicit opt-out
    (returned, to be logged as a warning at start); an error naming the file, the table and
    ``key_file`` otherwise. None: loopback only, or signed."""
    from bridges.mavlink.config import exposure

    allow = t.boolean("allow_unauthenticated", False)
    reason = exposure(endpoint)
    if reason is None or endpoint.key_file is not None:
        return None
    if not allow:
        raise t.error(
            "key_file",
            f"unset, and {reason} reaches beyond loopback: unsigned, anyone on that network "
            "could steer the thrusters. Set key_file to a MAVLink 2 signing key "
            "(docs/security.md), or allow_unauthenticated = true to accept that",
        )
    return reason


def mavlink_endpoint_from(t: Table, default: MavlinkEndpoint) -> MavlinkEndpoint:
    """``connection``, ``peers``, ``system_id``, ``component_id``, ``relay``, ``key_file``,
    ``authorized_systems``, ``bind_all_interfaces``, ``geodetic_origin`` over ``default``."""
    from bridges.mavlink.config import MavlinkEndpoint
    from bridges.mavlink.errors import LinkConfigError

    authorized = default.authorized_systems
    if t.has("authorized_systems"):
        authorized = t.integers("authorized_systems", lo=1, hi=255)
    origin = default.geodetic_origin
    if t.has("geodetic_origin"):
        origin = tuple(float(v) for v in t.vector("geodetic_origin"))
    try:
        return MavlinkEndpoint(
            t.string("connection", default.connection),
            t.integer("system_id", default.system_id, lo=1, hi=255),
            t.integer("component_id", default.component_id, lo=1, hi=255),
            t.strings("peers", default.peers),
            relay=t.strings("relay", default.relay),
            key_file=t.string("key_file", default.key_file),
            authorized_systems=authorized,
            bind_all_interfaces=t.boolean("bind_all_interfaces", default.bind_all_interfaces),
            geodetic_origin=origin,
        )
    except LinkConfigError as e:
        raise t.error(None, str(e)) from e


def _mavlink(t: Table, allocator: bool) -> MavlinkSettings | None:
    from bridges.mavlink.config import (
        default_allocator_endpoint,
        default_vessel_endpoint,
        parse_host_port,
    )
    from bridges.mavlink.errors import LinkConfigError

    if not t.boolean("enabled", True):
        t.allow(*ENDPOINT_KEYS)
        t.allow(*(("max_wrench", "wrench_limit", "telemetry_from") if allocator else ()))
        return None
    if not allocator:
        endpoint = mavlink_endpoint_from(t, default_vessel_endpoint())
        return MavlinkSettings(endpoint, unauthenticated=unsigned_exposure(t, endpoint))
    endpoint = mavlink_endpoint_from(t, default_allocator_endpoint())
    unsigned = unsigned_exposure(t, endpoint)
    mx, my, mn = t.vector(
        "max_wrench", 3, defaults_of(MavlinkSettings)["max_wrench"], positive=True
    )
    limit = t.vector("wrench_limit", 3, positive=True) if t.has("wrench_limit") else None
    t.allow("wrench_limit")
    triple = None if limit is None else (float(limit[0]), float(limit[1]), float(limit[2]))
    sources = t.strings("telemetry_from") if t.has("telemetry_from") else None
    t.allow("telemetry_from")
    for text in sources or ():
        try:
            parse_host_port("telemetry_from", text)
        except LinkConfigError as e:
            raise t.error(None, str(e)) from e
    xyz = (float(mx), float(my), float(mn))
    return MavlinkSettings(endpoint, xyz, triple, sources, unauthenticated=unsigned)


def zenoh_config_path(t: Table, default: str) -> Path:
    """``config``: an existing file, else the name of a shipped config (``.json5`` optional)."""
    from bridges.zenoh_io.config import SHIPPED_CONFIGS, shipped_config_path

    name = t.string("config", default)
    if Path(name).is_file():
        return Path(name)
    if name.removesuffix(".json5") in SHIPPED_CONFIGS:
        return shipped_config_path(name.removesuffix(".json5"))
    shipped = ", ".join(SHIPPED_CONFIGS)
    raise t.error("config", f"{name!r}: no such file, nor a shipped config ({shipped})")


def _zenoh(t: Table, default_config: str, allocator: bool) -> ZenohSettings | None:
    from bridges.zenoh_io.config import ZenohConfigError, parse_override

    if not t.boolean("enabled", True):
        t.allow("vessel", "config", "connect", "overrides", "allow_unauthenticated")
        t.allow(*(("wrench_limit",) * allocator))
        t.allow(*ROS2_KEYS)
        return None
    path = zenoh_config_path(t, default_config)
    overrides = list(t.strings("overrides", ()))
    for text in overrides:
        try:
            parse_override(text)
        except ZenohConfigError as e:
            raise t.error("overrides", str(e)) from e
    if t.has("connect"):  # the router's endpoint(s), before the explicit overrides
        raw = t.value("connect")
        connect = t.strings("connect") if isinstance(raw, list) else (t.string("connect"),)
        overrides.insert(0, f"connect/endpoints:{json.dumps(list(connect))}")
    t.allow("connect")
    limit = None
    if allocator:
        lx, ly, ln = t.vector("wrench_limit", 3, DEFAULT_WRENCH_LIMIT, positive=True)
        limit = (float(lx), float(ly), float(ln))
    ros2, domain_id, namespace = _ros2(t)
    vessel = t.string("vessel", defaults_of(ZenohSettings)["vessel"])
    allow = t.boolean("allow_unauthenticated", False)
    from bridges.zenoh_io.session import check_config_file

    try:  # refused here, before any port is opened (the session checks it again)
        check_config_file(path, overrides, allow)
    except ZenohConfigError as e:
        raise t.error(None, str(e)) from e
    return ZenohSettings(path, vessel, tuple(overrides), limit, ros2, domain_id, namespace, allow)


ROS2_KEYS = ("ros2", "domain_id", "namespace")


def _ros2(t: Table) -> tuple[bool, int, str]:
    """``ros2`` (off by default), ``domain_id`` (0..232) and ``namespace`` of [zenoh]."""
    from bridges.zenoh_io.ros2.graph import check_namespace

    d = defaults_of(ZenohSettings)
    enabled = t.boolean("ros2", d["ros2"])
    domain_id = t.integer("domain_id", d["domain_id"], lo=0, hi=232)
    namespace = t.string("namespace", None) or ""
    if namespace:
        try:
            check_namespace(namespace)
        except ValueError as e:
            raise t.error("namespace", str(e)) from None
    return enabled, domain_id, namespace


def _can(t: Table, m: int, allocator: bool) -> CanSettings:
    lo, hi = NODE_IDS
    d = defaults_of(CanSettings)
    interface = t.string("interface", d["interface"])
    extra: dict[str, Any]
    if allocator:
        node = t.integer("node_id", d["node_id"], lo=lo, hi=hi)
        ids = t.integers("esc_node_ids", m, lo=lo, hi=hi) if t.has("esc_node_ids") else None
        t.allow("esc_node_ids")
        extra = {"esc_monitor": t.boolean("esc_monitor", d["esc_monitor"]), **_esc_stream(t, d)}
    else:
        node = t.integer("allocator_node_id", d["node_id"], lo=lo, hi=hi)
        ids = t.integers("esc_node_ids", m, [20 + i for i in range(m)], lo=lo, hi=hi)
        extra = {"start_hub": t.boolean("start_hub", d["start_hub"])}
        if extra["start_hub"] and interface != "canhub":
            raise t.error("start_hub", f"true needs interface 'canhub', got {interface!r}")
    if ids is not None and len(set(ids)) != len(ids):
        raise t.error("esc_node_ids", f"expected distinct node IDs, got {list(ids)}")
    t.allow("curve_thrust_max_n")
    return CanSettings(
        interface=interface,
        channel=t.string("channel", d["channel"]),
        node_id=node,
        esc_node_ids=ids,
        deadband_n=t.number("deadband_n", d["deadband_n"], lo=0.0),
        curves=curves_from(t, m),
        **extra,
    )


def _esc_stream(t: Table, d: dict[str, Any]) -> dict[str, Any]:
    """The allocator's ESC command stream and node keys over ``d``, CanSettings' defaults."""
    from bridges.can_io.esc_stream import check_rate

    rate = t.number("esc_rate_hz", d["esc_rate_hz"], lo=0.0)  # 0: no stream, one per cycle
    hold = t.number("esc_hold_s", d["esc_hold_s"], positive=True)
    timeout = t.number("esc_command_timeout_s", d["esc_command_timeout_s"], positive=True)
    try:
        if rate != 0.0:
            check_rate(rate, hold, timeout)
    except ValueError as e:
        raise t.error(None, str(e)) from e
    name = t.string("node_name", d["node_name"])
    if not 1 <= len(name) <= 80 or not name.isascii():
        raise t.error("node_name", f"expected 1..80 ASCII characters, got {name!r}")
    return {"esc_rate_hz": rate, "esc_hold_s": hold, "esc_command_timeout_s": timeout,
            "node_name": name}  # fmt: skip


def allocator_ports_from(root: Table, m: int) -> PortSettings:
    """The allocator daemon's [can], [mavlink], [zenoh] (m thrusters)."""
    return PortSettings(
        _can(root.table("can"), m, allocator=True),
        _mavlink(root.table("mavlink"), allocator=True),
        _zenoh(root.table("zenoh"), "allocator.json5", allocator=True),
    )


def vessel_ports_from(root: Table, m: int) -> PortSettings:
    """The simulated vessel's [can], [mavlink], [zenoh] (m thrusters)."""
    return PortSettings(
        _can(root.table("can"), m, allocator=False),
        _mavlink(root.table("mavlink"), allocator=False),
        _zenoh(root.table("zenoh"), "vessel.json5", allocator=False),
    )
