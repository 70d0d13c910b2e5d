"""Cross-process CAN bus on 127.0.0.1 for machines without SocketCAN.

Every ``canhub`` client (``interface = "canhub"``, ``channel = "127.0.0.1:PORT"``) connected
to this hub sees every frame the others send. Prints ``can_hub listening on HOST:PORT`` when
ready; stops on SIGINT/SIGTERM. Same as ``python -m bridges.can_hub``.
"""

from __future__ import annotations

from .can_hub import add_arguments, run

__all__ = ["add_arguments", "run"]
