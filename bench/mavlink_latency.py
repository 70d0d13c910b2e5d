"""MAVLink loopback latency: WRENCH_SETPOINT send -> Mailbox put, against raw pymavlink.

Measured in one run, interleaved sample by sample so both paths see the same machine load:

* ``link``: a bare pymavlink sender (``udpout``) -> ``MavlinkAllocatorLink`` dispatch thread
  -> ``setpoint`` Mailbox; latency = Mailbox stamp (taken inside ``put``) - send time
  (transport + MAVLink decode + addressing check + validation + put).
* ``raw``: the same message from a second bare sender to a bare pymavlink ``udpin``
  receiver thread running ``recv_msg()`` / ``select()``, stamped as soon as the message
  is decoded (the baseline: pymavlink alone).

Both senders, both receivers and the clock are in this process (one UDP loopback hop each,
sharing one GIL). Usage: ``python bench/mavlink_latency.py [--samples 2000] [--gap-ms 1]``.
"""

from __future__ import annotations

import argparse
import os
import socket
import threading
import time
from typing import Any

import numpy as np

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402

from bridges.mavlink import dialect as mavlink_dialect  # noqa: E402
from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink  # noqa: E402
from bridges.mavlink.config import ALLOCATOR_IDS, MavlinkEndpoint  # noqa: E402
from ftcap_hil.runtime.processes import free_ports

WARMUP = 100
DIALECT = mavlink_dialect.load()


def _free_ports(n: int) -> list[int]:
    return free_ports(socket.SOCK_DGRAM, n)


def _connection(url: str) -> Any:
    conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
    conn.mav = DIALECT.MAVLink(conn, srcSystem=255, srcComponent=190)
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False
    return conn


class RawReceiver:
    """Bare pymavlink receive loop; records the decode time of each WRENCH_SETPOINT."""

    def __init__(self, port: int) -> None:
        self.conn = _connection(f"udpin:127.0.0.1:{port}")
        self.count = 0
        self.stamp_ns = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="raw-receiver", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_msg()
            if msg is None:
                self.conn.select(0.05)
            elif msg.get_type() == "WRENCH_SETPOINT":
                self.stamp_ns = time.monotonic_ns()
                self.count += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


def _wait(counter: Any, before: int, timeout_s: float = 1.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while counter() == before:
        if time.monotonic() > deadline:
            return False
        time.sleep(20e-6)
    return True


def run(samples: int, gap_s: float) -> dict[str, np.ndarray]:
    link_port, raw_port = _free_ports(2)
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(100.0, 50.0, 200.0))
    link = MavlinkAllocatorLink(config, MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS))
    raw = RawReceiver(raw_port)
    to_link = _connection(f"udpout:127.0.0.1:{link_port}")
    to_raw = _connection(f"udpout:127.0.0.1:{raw_port}")
    lat: dict[str, list[float]] = {"link": [], "raw": []}
    lost = {"link": 0, "raw": 0}
    try:
        for i in range(WARMUP + samples):
            for name in ("raw", "link") if i % 2 else ("link", "raw"):
                if name == "link":
                    before = link.setpoint.received
                    t0 = time.monotonic_ns()
                    to_link.mav.wrench_setpoint_send(i, *ALLOCATOR_IDS, 1.0, 2.0, 3.0)
                    ok = _wait(lambda: link.setpoint.received, before)
                    stamp = link.setpoint.latest().stamp_ns if ok else 0  # type: ignore[union-attr]
                else:
                    before = raw.count
                    t0 = time.monotonic_ns()
                    to_raw.mav.wrench_setpoint_send(i, *ALLOCATOR_IDS, 1.0, 2.0, 3.0)
                    ok = _wait(lambda: raw.count, before)
                    stamp = raw.stamp_ns
                if not ok:
                    lost[name] += 1
                elif i >= WARMUP:
                    lat[name].append((stamp - t0) * 1e-3)
                time.sleep(gap_s)
    finally:
        link.shutdown()
        raw.close()
        to_link.close()
        to_raw.close()
    if any(lost.values()):
        print(f"lost: {lost}")
    return {k: np.asarray(v) for k, v in lat.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--gap-ms", type=float, default=1.0, help="pause between samples")
    args = parser.parse_args()
    lat = run(args.samples, args.gap_ms * 1e-3)
    print(f"WRENCH_SETPOINT send -> receive, {args.samples} samples each, microseconds")
    print(f"{'path':6} {'median':>8} {'p99':>8} {'max':>8}")
    for name, values in lat.items():
        med, p99, top = np.median(values), np.percentile(values, 99), values.max()
        print(f"{name:6} {med:8.1f} {p99:8.1f} {top:8.1f}")
    ratio_med = np.median(lat["link"]) / np.median(lat["raw"])
    ratio_p99 = np.percentile(lat["link"], 99) / np.percentile(lat["raw"], 99)
    print(f"link / raw: median x{ratio_med:.2f}, p99 x{ratio_p99:.2f}")


if __name__ == "__main__":
    main()
