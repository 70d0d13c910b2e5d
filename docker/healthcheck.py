"""Health checks of the ftcap-hil compose services; installed as /opt/ftcap/healthcheck.py.

    python /opt/ftcap/healthcheck.py listening tcp 127.0.0.1:29536
        healthy once a TCP socket listens on that address in this network namespace. Read
        from /proc/net/tcp, so the check makes no connection (the CAN hub logs none).
    python /opt/ftcap/healthcheck.py allocator --zenoh-config FILE|NAME [--vessel NAME]
        healthy when the allocator answers its Zenoh state query (ftcap/<vessel>/allocator/state)
        twice and its cycle count advanced in between: the daemon loop is running and
        reachable over Zenoh, not merely alive. FILE is a client JSON5 file; NAME a shipped
        config (``gcs``: a client of tcp/127.0.0.1:7447).

Exit 0 = healthy, 1 = unhealthy (Docker's convention); one line on stdout says why, and
``docker inspect`` shows it. The test suite runs the same commands against local processes
(tests/docker/test_compose.py), so a check that drifts from the product fails there.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import socket
import struct
import sys
import time
from pathlib import Path

LISTEN = "0A"  # TCP_LISTEN in /proc/net/tcp's "st" column


def _proc_address(host: str, port: int) -> str:
    """``127.0.0.1``, 29536 -> ``0100007F:7320``, as the kernel prints a local address."""
    packed = socket.inet_aton(host)
    return f"{struct.unpack('=I', packed)[0]:08X}:{port:04X}"


def listening_tcp(address: str, table: Path = Path("/proc/net/tcp")) -> tuple[bool, str]:
    host, _, port_text = address.rpartition(":")
    ipaddress.IPv4Address(host)  # ValueError for anything else
    wanted = {_proc_address(host, int(port_text)), _proc_address("0.0.0.0", int(port_text))}
    for line in table.read_text().splitlines()[1:]:
        fields = line.split()
        if len(fields) > 3 and fields[1] in wanted and fields[3] == LISTEN:
            return True, f"tcp {address}: listening"
    return False, f"tcp {address}: nothing listens"


def allocator_cycling(config: str, vessel: str, gap_s: float = 0.6) -> tuple[bool, str]:
    # The product's own Zenoh adapter: the check speaks exactly what a ground station speaks.
    from bridges.zenoh_io.config import shipped_config_path
    from bridges.zenoh_io.link import ZenohGcsLink, ZenohLinkError, load_config

    path = Path(config)
    if not path.exists():  # as the allocator's zenoh.config: a file, else a shipped name
        path = shipped_config_path(config.removesuffix(".json5"))
    # Fail fast if the router is down (the clients' files wait 10 s for it at start-up). The
    # compose network's router is plain tcp (never published), as the allocator's
    # zenoh.allow_unauthenticated says: this probe only reads the status.
    conf = load_config(path, ["connect/timeout_ms:2000"], allow_unauthenticated=True)
    try:
        link = ZenohGcsLink(vessel, conf)
    except ZenohLinkError as e:
        return False, f"allocator: no zenoh session: {e}"
    with link:
        first = link.query_state(timeout_s=2.0)
        if first is None:
            return False, f"allocator: no answer on ftcap/{vessel}/allocator/state"
        time.sleep(gap_s)
        second = link.query_state(timeout_s=2.0)
    if second is None:
        return False, "allocator: answered once, then no more"
    if second.cycle <= first.cycle:
        return False, f"allocator: stuck at cycle {second.cycle}"
    mode = "unknown" if second.mode is None else second.mode.value
    return True, (
        f"allocator: mode {mode}, cycle {first.cycle} -> {second.cycle}, "
        f"{second.overruns} overruns, degraded {second.degraded}, stale setpoint "
        f"{second.setpoint_stale} telemetry {second.telemetry_stale}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="check", required=True)
    p = sub.add_parser("listening", help="a local listening socket")
    p.add_argument("protocol", choices=["tcp"])
    p.add_argument("address", help="IPv4:PORT")
    p = sub.add_parser("allocator", help="the allocator's Zenoh state query")
    p.add_argument("--zenoh-config", required=True, help="client JSON5 file or shipped name")
    p.add_argument("--vessel", default="ftcap1", help="vessel name in the key expressions")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    try:
        if args.check == "listening":
            ok, why = listening_tcp(args.address)
        else:
            ok, why = allocator_cycling(args.zenoh_config, args.vessel)
    except (OSError, ValueError) as e:  # ZenohConfigError is a ValueError
        ok, why = False, f"{args.check}: {e}"
    print(("healthy: " if ok else "unhealthy: ") + why)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
