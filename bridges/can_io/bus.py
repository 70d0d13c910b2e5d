"""Open the python-can bus named in the configuration.

=============  ====================  =====================================================
interface      channel               use
=============  ====================  =====================================================
``socketcan``  ``can0``              production, a real CAN adapter
``socketcan``  ``vcan0``             Linux with a vcan interface (the VM harness)
``canhub``     ``127.0.0.1:29536``   machines without SocketCAN: ``bridges.can_io.hub`` on
                                     loopback TCP, processes on one simulated bus
``virtual``    any name              one process only (python-can's in-memory bus)
=============  ====================  =====================================================

``udp_multicast`` is refused: this project never uses multicast.

A ``canhub`` or ``socketcan`` bus comes wrapped in a :class:`~bridges.can_io.reconnect.
ReconnectingBus` (``retry_period_s``, default 0.25 s; None for the bare backend): when the hub
restarts or the interface goes down and up, the bus re-opens itself and says so in the log.
"""

from __future__ import annotations

import logging
from typing import Any

import can

from bridges.can_io.hub_bus import INTERFACE_NAME as HUB_INTERFACE
from bridges.can_io.hub_bus import CanHubBus
from bridges.can_io.reconnect import DEFAULT_RETRY_PERIOD_S, ReconnectingBus
from ftcap_hil.core.errors import PortError

log = logging.getLogger(__name__)

_FORBIDDEN = {"udp_multicast": "multicast is not allowed in ftcap-hil; use 'canhub' on loopback"}
_RECONNECTING = frozenset({HUB_INTERFACE, "socketcan"})


class CanBusError(PortError):
    """The configured CAN bus could not be opened (message names interface and channel)."""


def open_can_bus(
    interface: str,
    channel: str,
    *,
    retry_period_s: float | None = DEFAULT_RETRY_PERIOD_S,
    **opts: Any,
) -> can.BusABC:
    """Return an open python-can bus; the caller shuts it down (it is a context manager).

    ``opts`` go to the python-can backend unchanged (e.g. ``receive_own_messages``,
    ``can_filters``, ``fd``). ``retry_period_s``: how often a ``canhub``/``socketcan`` bus
    tries to re-open itself after a failure (None: no wrapper, a failure is final). Raises
    ``ValueError`` for an unknown or forbidden interface and ``CanBusError`` if the backend
    cannot open the channel now.
    """
    if interface in _FORBIDDEN:
        raise ValueError(f"can.interface={interface!r}: {_FORBIDDEN[interface]}")
    known = can.interfaces.VALID_INTERFACES | {HUB_INTERFACE}
    if interface not in known:
        raise ValueError(f"can.interface={interface!r}: not one of {sorted(known)}")

    def backend() -> can.BusABC:
        if interface == HUB_INTERFACE and HUB_INTERFACE not in can.interfaces.VALID_INTERFACES:
            # Entry point not registered (project not re-installed): the class works alone.
            log.debug("'%s' entry point not installed; constructing CanHubBus directly", interface)
            return CanHubBus(channel=channel, **opts)
        return can.Bus(interface=interface, channel=channel, **opts)

    try:
        if retry_period_s is None or interface not in _RECONNECTING:
            return backend()
        name = f"CAN bus {interface}:{channel}"
        return ReconnectingBus(backend, name=name, retry_period_s=retry_period_s)
    except (can.CanError, OSError, ValueError) as e:
        raise CanBusError(
            f"cannot open CAN bus interface={interface!r} channel={channel!r}: {e}"
        ) from e
