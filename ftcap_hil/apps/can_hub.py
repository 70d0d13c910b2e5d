"""Cross-process CAN bus on 127.0.0.1 for machines without SocketCAN.

Every ``canhub`` client (``interface = "canhub"``, ``channel = "127.0.0.1:PORT"``) connected
to this hub sees every frame the others send. Prints ``can_hub listening on HOST:PORT`` when
ready; once a second logs the bytes dropped for slow clients if more were (the hub itself
logs a client's drops only when it leaves); stops on SIGINT/SIGTERM (exit 0; a second one:
at once, 130). A port that cannot be bound exits 1.
"""

from __future__ import annotations

import argparse
import logging
import sys

from bridges.can_io.hub import DEFAULT_HOST, DEFAULT_PORT, CanHub
from ftcap_hil.core.errors import PortError
from ftcap_hil.runtime.loop import DeadlineLoop
from ftcap_hil.runtime.signals import capture_signals

log = logging.getLogger(__name__)
REPORT_PERIOD_NS = 1_000_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the hub process (also the ``ftcap-hil can-hub`` subcommand)."""
    parser.add_argument("--host", default=DEFAULT_HOST, help="loopback address to bind")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port, 0 = any free")
    parser.add_argument("--max-queue-bytes", type=int, default=1 << 20)


class DropReport:
    """The loop's tick: a warning when the hub dropped more bytes since the last tick."""

    def __init__(self, hub: CanHub) -> None:
        self._hub = hub
        self._dropped = 0

    def __call__(self, now_ns: int) -> None:
        dropped = self._hub.bytes_dropped
        if dropped > self._dropped:
            log.warning("can hub: %d bytes dropped for slow clients so far", dropped)
            self._dropped = dropped


def run(args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM; print the ready line first. Returns the exit code."""
    loop = DeadlineLoop(REPORT_PERIOD_NS)
    with capture_signals(loop.request_exit):
        try:
            hub = CanHub(args.host, args.port, args.max_queue_bytes).start()
        except (OSError, ValueError) as e:
            raise PortError(f"cannot listen on {args.host}:{args.port}: {e}") from e
        with hub:
            sys.stdout.write(f"can_hub listening on {hub.channel}\n")
            sys.stdout.flush()
            loop.run(DropReport(hub), first_deadline_ns=loop.clock() + REPORT_PERIOD_NS)
    return 0
