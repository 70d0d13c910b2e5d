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
     | peers: 14550                   |            | peers: 14570, 14550            |
     +--------------------------------+            +--------------------------------+

Each process binds one UDP "inbox" on 127.0.0.1 (pymavlink ``udpin``) and sends from that
same socket to the inboxes of its configured peers. The peers are registered with pymavlink
before the first receive, so a link can send before it has heard from anyone (a plain
``udpin`` cannot) and start order does not matter; replies come back to the sender's inbox.
Anyone else who sends to an inbox (e.g. MAVProxy) is added as a peer by pymavlink and gets
the same traffic. Every message goes to every peer; receivers filter on target and source
ids, as MAVLink routing does. The vessel and the allocator share system id 1 (one vessel,
two components); MAV_COMP_ID_ONBOARD_COMPUTER (191) is the allocator.

Protocol: MAVLink 2 only, with the ftcap dialect (common.xml + WRENCH_SETPOINT,
FTCAP_STATUS) from :mod:`bridges.mavlink.dialect`, set explicitly on every connection.
"""

from __future__ import annotations

from dataclasses import dataclass

from ftcap_hil.core.errors import ConfigError

LOCALHOST = "127.0.0.1"
GCS_PORT = 14550
VESSEL_PORT = 14560
ALLOCATOR_PORT = 14570
VESSEL_IDS = (1, 1)  # MAV_COMP_ID_AUTOPILOT1
ALLOCATOR_IDS = (1, 191)  # MAV_COMP_ID_ONBOARD_COMPUTER
GCS_IDS = (255, 190)  # MAV_COMP_ID_MISSIONPLANNER


class LinkConfigError(ConfigError):
    """A MAVLink endpoint is misconfigured (raised at start-up, names the key and value)."""


def parse_host_port(key: str, value: str) -> tuple[str, int]:
    """``"host:port"`` -> (host, port); LinkConfigError naming ``key`` otherwise."""
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise LinkConfigError(f"{key}: expected 'host:port', got {value!r}")
    return host, int(port)


@dataclass(frozen=True)
class MavlinkEndpoint:
    """Where one link binds, whom it sends to, and who it is on the MAVLink network.

    ``connection`` is a pymavlink connection string. With ``udpin:HOST:PORT`` (the default
    topology) ``peers`` lists the ``host:port`` inboxes to send to from the start; any other
    pymavlink transport (``udpout:``, ``tcp:``, a serial device) must leave ``peers`` empty.
    """

    connection: str
    system_id: int
    component_id: int
    peers: tuple[str, ...] = ()  # (the [mavlink] table is read by ftcap_hil.config.bridges)

    def __post_init__(self) -> None:
        for key, value in (("system_id", self.system_id), ("component_id", self.component_id)):
            if not isinstance(value, int) or not 1 <= value <= 255:
                raise LinkConfigError(f"{key}: expected an integer in 1..255, got {value!r}")
        if not isinstance(self.connection, str) or not self.connection:
            raise LinkConfigError(
                f"connection: expected a pymavlink string, got {self.connection!r}"
            )
        if self.peers and not self.connection.startswith(("udpin:", "udp:")):
            raise LinkConfigError(
                f"peers: only a 'udpin:' connection can have peers, connection is "
                f"{self.connection!r}"
            )
        for peer in self.peers:
            parse_host_port("peers", peer)

    @classmethod
    def inbox(
        cls, port: int, ids: tuple[int, int], peers: tuple[int, ...] = (), host: str = LOCALHOST
    ) -> MavlinkEndpoint:
        """Endpoint binding ``host:port`` and sending to ``host:p`` for each p in ``peers``."""
        return cls(f"udpin:{host}:{port}", ids[0], ids[1], tuple(f"{host}:{p}" for p in peers))


def default_gcs_endpoint() -> MavlinkEndpoint:
    """The ground station's inbox, sending to the allocator and the vessel."""
    return MavlinkEndpoint.inbox(GCS_PORT, GCS_IDS, (ALLOCATOR_PORT, VESSEL_PORT))


def default_allocator_endpoint() -> MavlinkEndpoint:
    """The allocator's inbox, sending to the ground station."""
    return MavlinkEndpoint.inbox(ALLOCATOR_PORT, ALLOCATOR_IDS, (GCS_PORT,))


def default_vessel_endpoint() -> MavlinkEndpoint:
    """The vessel's inbox, sending to the allocator and the ground station."""
    return MavlinkEndpoint.inbox(VESSEL_PORT, VESSEL_IDS, (ALLOCATOR_PORT, GCS_PORT))
