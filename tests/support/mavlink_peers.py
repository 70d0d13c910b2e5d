"""Helpers for the MAVLink contract tests and benchmarks (no tests here; the fixtures are in
tests/contract/conftest.py).

The far end of every contract test is bare pymavlink (``RawPeer``) with the ftcap dialect,
on real loopback UDP: never our own transport pretending to be the other side.
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402

from bridges.mavlink import dialect as mavlink_dialect  # noqa: E402
from ftcap_hil.runtime.processes import free_ports  # noqa: E402
from ftcap_hil.runtime.processes import wait_until as poll_until  # noqa: E402

DIALECT = mavlink_dialect.load()


def free_udp_ports(n: int) -> list[int]:
    """``n`` distinct UDP ports free on 127.0.0.1 right now."""
    return free_ports(socket.SOCK_DGRAM, n)


class RawPeer:
    """A bare pymavlink endpoint; one receive loop that keeps every message (no drops)."""

    def __init__(self, connection: str, ids: tuple[int, int] = (255, 190)) -> None:
        self.conn = mavutil.mavlink_connection(
            connection, source_system=ids[0], source_component=ids[1]
        )
        self.conn.mav = DIALECT.MAVLink(self.conn, srcSystem=ids[0], srcComponent=ids[1])
        self.conn.mav.robust_parsing = True
        self.conn.WIRE_PROTOCOL_VERSION = "2.0"
        self.conn.first_byte = False
        self.mav = self.conn.mav
        self.received: list[Any] = []

    def pump(self, timeout_s: float) -> None:
        """Receive everything that arrives within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.conn.recv_msg()
            if msg is None:
                self.conn.select(0.01)
            elif msg.get_type() != "BAD_DATA":
                self.received.append(msg)

    def wait_for(
        self,
        mtype: str,
        predicate: Callable[[Any], bool] = lambda m: True,
        timeout_s: float = 3.0,
        since: int = 0,
    ) -> Any | None:
        """First message of ``mtype`` (index >= ``since``) matching ``predicate``."""
        deadline = time.monotonic() + timeout_s
        while True:
            for msg in self.received[since:]:
                if msg.get_type() == mtype and predicate(msg):
                    return msg
            if time.monotonic() > deadline:
                return None
            self.pump(0.02)

    def of_type(self, mtype: str, since: int = 0) -> list[Any]:
        return [m for m in self.received[since:] if m.get_type() == mtype]

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> RawPeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def param_number(msg: Any) -> float:
    """A PARAM_VALUE's value as the components encode it: INT32 byte-wise (C-cast in the
    answer to a C-cast set: the two readings never overlap below 2**24), REAL32 as is."""
    if msg.param_type == DIALECT.MAV_PARAM_TYPE_INT32:
        bytewise = float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
        return bytewise if abs(bytewise) <= 2**24 else float(msg.param_value)
    return float(msg.param_value)


def send_datagram(port: int, payload: bytes) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(payload, ("127.0.0.1", port))


def wait_until(predicate: Callable[[], bool], timeout_s: float = 3.0) -> bool:
    return poll_until(predicate, timeout_s, 0.005)


def mavlink_threads() -> list[threading.Thread]:
    """The dispatch threads of MAVLink links still alive."""
    return [t for t in threading.enumerate() if t.name.startswith("mavlink-")]
