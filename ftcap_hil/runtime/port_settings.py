"""What a process needs to open its ports: the [can], [mavlink] and [zenoh] tables of its
configuration file, validated by ``ftcap_hil.config.bridges`` (the allocator daemon's and
the simulated vessel's alike). Plain values; the bridges are opened from them elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

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
    """

    interface: str = "canhub"
    channel: str = "127.0.0.1:29536"
    node_id: int = 10
    esc_node_ids: tuple[int, ...] | None = None
    deadband_n: float = 0.0
    esc_monitor: bool = True
    start_hub: bool = False


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
    file and the ``KEY:VALUE`` overrides applied to it (in order)."""

    vessel: str
    config: Path
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class PortSettings:
    """Every port of one process; ``mavlink`` / ``zenoh`` None: that bridge is disabled."""

    can: CanSettings
    mavlink: MavlinkSettings | None
    zenoh: ZenohSettings | None
