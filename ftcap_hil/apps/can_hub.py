"""Cross-process CAN bus on 127.0.0.1 for machines without SocketCAN.

Every ``canhub`` client (``interface = "canhub"``, ``channel = "127.0.0.1:PORT"``) connected
to this hub sees every frame the others send. Prints ``can_hub listening on HOST:PORT`` when
ready; stops on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from types import FrameType

from bridges.can_io.hub import DEFAULT_HOST, DEFAULT_PORT, CanHub

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the hub process (also the ``ftcap-hil can-hub`` subcommand)."""
    parser.add_argument("--host", default=DEFAULT_HOST, help="loopback address to bind")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port, 0 = any free")
    parser.add_argument("--max-queue-bytes", type=int, default=1 << 20)


def run(args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM; print the ready line first. Returns the exit code."""
    stop = threading.Event()

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            hub = CanHub(args.host, args.port, args.max_queue_bytes).start()
        except (OSError, ValueError) as e:
            log.error("can hub: cannot listen on %s:%s: %s", args.host, args.port, e)
            return 1
        with hub:
            sys.stdout.write(f"can_hub listening on {hub.channel}\n")
            sys.stdout.flush()
            while not stop.wait(0.5):
                pass
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 0
