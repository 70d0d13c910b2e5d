"""MAVLink endpoints: who binds which UDP port, who sends where, system/component ids.

Topology (defaults, all on 127.0.0.1; every address and id comes from config)::

                  +------------------------------------------+
                  | ground station            MavlinkGcsLink |
                  | sys 255 comp 190          binds :14550   |
                  | peers: 14570, 14560                      |
                  +------------------------------------------+
     WRENCH_SETPOINT |   ^ HEARTBEAT           COMMAND_LONG |   ^ HEARTBEAT, ODOMETRY
     MANUAL_CONTROL  |   | ACTUATOR_OUTPUT_STATUS  PARAM_*   |   | COMMAND_ACK
     PARAM_*         |   | FTCAP_STATUS                      |   | PARAM_VALUE
                     |   | STATUSTEXT, PARAM_VALUE           |   | STATUSTEXT
                     v   |                                   v   |
     +--------------------------------+            +--------------------------------+
     | allocator MavlinkAllocatorLink |<-ODOMETRY--| vessel       MavlinkVesselLink |
     | sys 1 comp 191  binds :14570   |            | sys 1 comp 1    binds :14560   |
     | peers: 14550, relay: 14560     |            | peers: 14570, 14550            |
     +--------------------------------+            +--------------------------------+

Each process binds one UDP "inbox" on 127.0.0.1 and sends from that same socket to the
inboxes of its configured peers, so a link can send before it has heard from anyone and
start order does not matter; replies come back to the sender's inbox. Every message goes to
every peer; receivers filter on target and source ids, as MAVLink routing does. The vessel
and the allocator share system id 1 (one vessel, two components);
MAV_COMP_ID_ONBOARD_COMPUTER (191) is the allocator.

Anyone else who sends to an inbox (MAVProxy, QGroundControl, MAVSDK) becomes a peer only
once it has sent an accepted frame (MAVLink 2, signed when ``key_file`` is set, from one of
``authorized_systems``), for as long as it keeps talking (:mod:`bridges.mavlink.peers`).
The allocator also fronts the vessel (``relay``): what such a learnt peer sends that is not
for the allocator alone goes on to the vessel's inbox, and what the vessel sends to the
allocator goes on to the learnt peers, so that one ground-station link to the allocator's
inbox (``mavproxy.py --master=udpout:127.0.0.1:14570``) reaches both components.

Security (per endpoint, all off or loopback by default): ``key_file`` turns on MAVLink 2
signing (:mod:`bridges.mavlink.signing`): unsigned frames are then refused; MAVLink 1
frames are always refused; ``authorized_systems`` lists the system ids whose setpoints,
parameter requests and commands are obeyed (default: the ground station, 255); a bind on
all interfaces (0.0.0.0, ::) is refused unless ``bind_all_interfaces`` is true; a link that
reaches beyond loopback (:func:`exposure`) needs ``key_file`` (the daemon's and the vessel's
start refuse it otherwise, unless ``allow_unauthenticated``: ftcap_hil/config/bridges.py).

Protocol: MAVLink 2 only, with the ftcap dialect (common.xml + WRENCH_SETPOINT,
FTCAP_STATUS) from :mod:`bridges.mavlink.dialect`, set explicitly on every connection.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from dataclasses import dataclass

from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.geodesy import GeodeticOrigin

LOCALHOST = "127.0.0.1"
GCS_PORT = 14550
VESSEL_PORT = 14560
ALLOCATOR_PORT = 14570
VESSEL_IDS = (1, 1)  # MAV_COMP_ID_AUTOPILOT1
ALLOCATOR_IDS = (1, 191)  # MAV_COMP_ID_ONBOARD_COMPUTER
GCS_IDS = (255, 190)  # MAV_COMP_ID_MISSIONPLANNER
MAVSDK_SYSTEM_ID = 245  # MAVSDK's default own system id (a client with its defaults)
GROUND_STATIONS = (GCS_IDS[0], MAVSDK_SYSTEM_ID)  # obeyed by default: QGC/MAVProxy, MAVSDK


def parse_host_port(key: str, value: str) -> tuple[str, int]:
    """``"host:port"`` -> (host, port); LinkConfigError naming ``key`` otherwise."""
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise LinkConfigError(f"{key}: expected 'host:port', got {value!r}")
    return host, int(port)


_ALL_INTERFACES = {"", "0.0.0.0", "::", "[::]", "*"}
_BINDING = ("udpin:", "udp:", "tcpin:")


def _ids(key: str, values: object) -> tuple[int, ...]:
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise LinkConfigError(f"{key}: expected a list of system ids in 1..255, got {values!r}")
    for v in values:
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= 255:
            raise LinkConfigError(f"{key}: expected system ids in 1..255, got {v!r}")
    return tuple(values)


def bind_host(connection: str) -> str | None:
    """The host a binding connection (``udpin:``, ``udp:``, ``tcpin:``) binds, else None."""
    if not connection.startswith(_BINDING):
        return None
    rest = connection.split(":", 1)[1]
    host = rest.rpartition(":")[0]
    return host


_NETWORK = ("udpin", "udp", "udpout", "udpbcast", "tcp", "tcpin")


def is_loopback_host(host: str) -> bool:
    """``host`` is this machine's loopback: 127.0.0.0/8, ::1 or ``localhost``."""
    name = host.strip("[]").split("%", 1)[0]
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:  # another host name: resolved elsewhere, not known to be loopback
        return False


def exposure(endpoint: MavlinkEndpoint) -> str | None:
    """Why the link reaches beyond this machine's loopback (the setting and its value): a
    network connection bound or aimed elsewhere, a peer or relay inbox elsewhere; None if it
    does not. A serial device is a wire, not a network: None."""
    scheme, sep, rest = endpoint.connection.partition(":")
    if sep and scheme in _NETWORK and not is_loopback_host(rest.rpartition(":")[0]):
        return f"connection = {endpoint.connection!r}"
    for key in ("peers", "relay"):
        for value in getattr(endpoint, key):
            if not is_loopback_host(parse_host_port(key, value)[0]):
                return f"{key} contains {value!r}"
    return None


@dataclass(frozen=True)
class MavlinkEndpoint:
    """Where one link binds, whom it sends to, who it is, and whom it trusts.

    ``connection`` is a pymavlink-style connection string: ``udpin:HOST:PORT`` (the default
    topology: bind HOST:PORT, send to ``peers``), ``udpout:HOST:PORT`` (send to HOST:PORT
    from an ephemeral port) or another pymavlink transport (``tcp:``, a serial device), which
    must leave ``peers`` and ``relay`` empty. ``peers`` and ``relay`` are ``host:port``
    inboxes (module docstring). ``key_file``: MAVLink 2 signing passphrase file (None: no
    signing). ``authorized_systems``: system ids obeyed (None: the link's default).
    ``bind_all_interfaces`` must be true for a bind on 0.0.0.0 or ::. ``geodetic_origin``:
    ``(lat_deg, lon_deg[, alt_m])`` of the NED origin, for the vessel's GLOBAL_POSITION_INT
    (:mod:`bridges.mavlink.geodesy`; other links ignore it).
    """

    connection: str
    system_id: int
    component_id: int
    peers: tuple[str, ...] = ()  # (the [mavlink] table is read by ftcap_hil.config.bridges)
    relay: tuple[str, ...] = ()
    key_file: str | None = None
    authorized_systems: tuple[int, ...] | None = None
    bind_all_interfaces: bool = False
    geodetic_origin: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        for key, value in (("system_id", self.system_id), ("component_id", self.component_id)):
            if not isinstance(value, int) or not 1 <= value <= 255:
                raise LinkConfigError(f"{key}: expected an integer in 1..255, got {value!r}")
        if not isinstance(self.connection, str) or not self.connection:
            raise LinkConfigError(
                f"connection: expected a pymavlink string, got {self.connection!r}"
            )
        for key in ("peers", "relay"):
            values = getattr(self, key)
            if values and not self.connection.startswith(("udpin:", "udp:")):
                raise LinkConfigError(
                    f"{key}: only a 'udpin:' connection can have {key}, connection is "
                    f"{self.connection!r}"
                )
            for peer in values:
                parse_host_port(key, peer)
        if self.authorized_systems is not None:
            _ids("authorized_systems", self.authorized_systems)
        if self.key_file is not None and (not isinstance(self.key_file, str) or not self.key_file):
            raise LinkConfigError(f"key_file: expected a file name, got {self.key_file!r}")
        if not isinstance(self.bind_all_interfaces, bool):
            raise LinkConfigError(
                f"bind_all_interfaces: expected true or false, got {self.bind_all_interfaces!r}"
            )
        if self.geodetic_origin is not None:
            GeodeticOrigin.from_value(self.geodetic_origin)
        if bind_host(self.connection) in _ALL_INTERFACES and not self.bind_all_interfaces:
            raise LinkConfigError(
                f"connection: {self.connection!r} listens on all interfaces; bind a single "
                "address (127.0.0.1) or set bind_all_interfaces = true"
            )

    @classmethod
    def inbox(
        cls,
        port: int,
        ids: tuple[int, int],
        peers: tuple[int, ...] = (),
        host: str = LOCALHOST,
        *,
        relay: tuple[int, ...] = (),
    ) -> MavlinkEndpoint:
        """Endpoint binding ``host:port`` and sending to ``host:p`` for each p in ``peers``
        (and relaying to ``host:p`` for each p in ``relay``)."""
        return cls(
            f"udpin:{host}:{port}",
            ids[0],
            ids[1],
            tuple(f"{host}:{p}" for p in peers),
            tuple(f"{host}:{p}" for p in relay),
        )


def default_gcs_endpoint() -> MavlinkEndpoint:
    """The ground station's inbox, sending to the allocator and the vessel."""
    return MavlinkEndpoint.inbox(GCS_PORT, GCS_IDS, (ALLOCATOR_PORT, VESSEL_PORT))


def default_allocator_endpoint() -> MavlinkEndpoint:
    """The allocator's inbox, sending to the ground station and fronting the vessel."""
    return MavlinkEndpoint.inbox(ALLOCATOR_PORT, ALLOCATOR_IDS, (GCS_PORT,), relay=(VESSEL_PORT,))


def default_vessel_endpoint() -> MavlinkEndpoint:
    """The vessel's inbox, sending to the allocator and the ground station."""
    return MavlinkEndpoint.inbox(VESSEL_PORT, VESSEL_IDS, (ALLOCATOR_PORT, GCS_PORT))
