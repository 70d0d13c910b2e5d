"""What a process needs to open its ports: the [can], [mavlink] and [zenoh] tables of its
configuration file, validated by ``ftcap_hil.config.bridges`` (the allocator daemon's and
the simulated vessel's alike). Plain values; the bridges are opened from them elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ftcap_hil.core.effectiveness.thruster_curve import ThrusterCurve

if TYPE_CHECKING:  # the CLI builds its parser without importing any bridge
    from bridges.mavlink.config import MavlinkEndpoint


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
    allocator also ``max_wrench`` (MANUAL_CONTROL full deflection [X N, Y N, N N*m]) and
    ``wrench_limit`` (WRENCH_SETPOINT components beyond are dropped as malformed)."""

    endpoint: MavlinkEndpoint
    max_wrench: tuple[float, float, float] = (0.3, 0.3, 0.06)
    wrench_limit: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class ZenohSettings:
    """``[zenoh]`` of an enabled session: the vessel name in the key expressions, the JSON5
    file and the ``KEY:VALUE`` overrides applied to it (in order); for the allocator
    ``wrench_limit`` (setpoints with a component beyond it are dropped as malformed).
    ``ros2``: also the ROS 2 topics as rmw_zenoh writes them, in ``domain_id`` under
    ``namespace`` (``""``: ``/<vessel>``; docs/ros2-and-foxglove.md)."""

    vessel: str
    config: Path
    overrides: tuple[str, ...] = ()
    wrench_limit: tuple[float, float, float] | None = None
    ros2: bool = False
    domain_id: int = 0
    namespace: str = ""


@dataclass(frozen=True)
class PortSettings:
    """Every port of one process; ``mavlink`` / ``zenoh`` None: that bridge is disabled."""

    can: CanSettings
    mavlink: MavlinkSettings | None
    zenoh: ZenohSettings | None
