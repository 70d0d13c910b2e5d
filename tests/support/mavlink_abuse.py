"""Abuse inputs for the MAVLink fuzz tests and ``bench/mavlink_fuzz.py`` (no tests here).

:func:`fuzz_corpus` makes datagrams that a stranger could send: random bytes, empty
datagrams, frames with a flipped byte (CRC), truncated frames, bogus length fields,
MAVLink 1 frames, valid frames from an unknown system (setpoints, parameter writes, fault
injections, parameter list requests), frames signed with a wrong key, oversized datagrams
and datagrams of many frames. :func:`flood` sends datagrams at a rate, from one socket or a
new source port per datagram; ``python -m tests.support.mavlink_abuse PORT RATE SECONDS
KIND [--new-ports]`` runs it in a process of its own and prints the number sent.

:func:`udp_drops` reads the kernel's drop counter of a bound UDP port (``/proc/net/udp``),
so a test can account for every datagram: sent = dropped by the kernel + seen by the port.
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bridges.mavlink import dialect as mavlink_dialect

DIALECT = mavlink_dialect.load()
STRANGER = (77, 1)
KINDS = (
    "random", "empty", "bad_crc", "truncated", "bad_length", "mavlink1", "stranger_setpoint",
    "stranger_param_set", "stranger_inject", "stranger_list", "wrong_key", "oversized", "many",
)  # fmt: skip


def _mav(ids: tuple[int, int], key: bytes | None = None) -> Any:
    mav = DIALECT.MAVLink(None, srcSystem=ids[0], srcComponent=ids[1])
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = int((time.time() - 1_420_070_400) * 1e5)
    return mav


def _frames(mav: Any, target: tuple[int, int]) -> list[bytes]:
    """A few valid frames (setpoint, parameter write, fault injection, list request)."""
    sys_, comp = target
    msgs = [
        DIALECT.MAVLink_wrench_setpoint_message(0, sys_, comp, 0.2, 0.0, 0.0),
        DIALECT.MAVLink_param_set_message(sys_, comp, b"FTC_MODE", 0.0, 6),
        DIALECT.MAVLink_command_long_message(sys_, 1, 420, 0, 101, 1, 0, math.nan, 0, 0, 0),
        DIALECT.MAVLink_param_request_list_message(sys_, comp),
    ]
    return [bytes(m.pack(mav)) for m in msgs]


def one(kind: str, rng: np.random.Generator, target: tuple[int, int]) -> bytes:
    """One abuse datagram of ``kind`` (module docstring)."""
    stranger = _frames(_mav(STRANGER), target)
    base = stranger[int(rng.integers(len(stranger)))]
    if kind == "random":
        return rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
    if kind == "empty":
        return b""
    if kind == "bad_crc":
        frame = bytearray(base)
        frame[int(rng.integers(10, len(frame)))] ^= 0xFF
        return bytes(frame)
    if kind == "truncated":
        return base[: int(rng.integers(1, len(base) - 1))]
    if kind == "bad_length":
        frame = bytearray(base)
        frame[1] = int(rng.integers(0, 256))
        return bytes(frame)
    if kind == "mavlink1":
        return bytes(
            DIALECT.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(
                _mav((255, 190)), force_mavlink1=True
            )
        )
    if kind.startswith("stranger_"):
        index = ["setpoint", "param_set", "inject", "list"].index(kind.removeprefix("stranger_"))
        return stranger[index]
    if kind == "wrong_key":
        return _frames(_mav(STRANGER, b"\x42" * 32), target)[0]
    if kind == "oversized":
        return bytes(3000)
    if kind == "many":
        return b"".join(stranger * 8)
    raise ValueError(f"unknown abuse kind {kind!r}")


def fuzz_corpus(
    n: int, seed: int, target: tuple[int, int], kinds: Sequence[str] = KINDS
) -> list[bytes]:
    """``n`` abuse datagrams, kinds drawn uniformly from ``kinds``."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(kinds), n)
    return [one(kinds[int(k)], rng, target) for k in picks]


def heartbeat(ids: tuple[int, int] = (255, 190)) -> bytes:
    """A valid MAVLink 2 GCS HEARTBEAT (what an authorized but unsigned sender looks like)."""
    return bytes(DIALECT.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_mav(ids)))


def flood(
    port: int,
    rate_hz: float,
    duration_s: float,
    payloads: Sequence[bytes],
    *,
    new_ports: bool = False,
    stop: Callable[[], bool] = lambda: False,
) -> int:
    """Send ``payloads`` (cycled) to 127.0.0.1:``port`` at ``rate_hz`` for ``duration_s``;
    one socket, or a new source port per datagram. Returns the number sent."""
    dest = ("127.0.0.1", port)
    sock = None if new_ports else socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    total = int(duration_s * rate_hz)
    sent, t0 = 0, time.monotonic()
    try:
        while sent < total and not stop():
            due = min(int((time.monotonic() - t0) * rate_hz) + 1, total)
            while sent < due:
                payload = payloads[sent % len(payloads)]
                if sock is None:
                    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                        s.sendto(payload, dest)
                else:
                    sock.sendto(payload, dest)
                sent += 1
            time.sleep(0.001)
    finally:
        if sock is not None:
            sock.close()
    return sent


class Pinger:
    """A ground station (a ``RawPeer``) reads ``name`` from ``target`` every ``period_s``;
    :meth:`answered` counts the PARAM_VALUEs that came back."""

    def __init__(
        self,
        gcs: Any,
        period_s: float = 0.05,
        name: str = "FTC_SP_TMO",
        target: tuple[int, int] = (1, 191),
    ) -> None:
        self.name, self.target = name, target
        self.gcs, self.period_s = gcs, period_s
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.gcs.mav.param_request_read_send(*self.target, self.name.encode(), -1)
            self.sent += 1
            self._stop.wait(self.period_s)

    def __enter__(self) -> Pinger:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def answered(self) -> int:
        self.gcs.pump(0.5)
        return len([m for m in self.gcs.of_type("PARAM_VALUE") if m.param_id == self.name])


def udp_drops(port: int) -> int:
    """Datagrams the kernel dropped on the socket bound to 127.0.0.1:``port`` (its receive
    buffer was full), from ``/proc/net/udp``; 0 if there is no such socket."""
    want = f"0100007F:{port:04X}"
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        cols = line.split()
        if cols[1] == want:
            return int(cols[-1])
    return 0


def rss_bytes() -> int:
    """Resident set size of this process."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * 4096


def main(argv: list[str] | None = None) -> int:
    """Flood from a process of its own (see the module docstring); prints the count sent."""
    parser = argparse.ArgumentParser(prog="python -m tests.support.mavlink_abuse")
    parser.add_argument("port", type=int)
    parser.add_argument("rate_hz", type=float)
    parser.add_argument("duration_s", type=float)
    parser.add_argument("kind", choices=[*KINDS, "heartbeat", "fuzz"])
    parser.add_argument("--new-ports", action="store_true")
    parser.add_argument("--target", default="1,191")
    args = parser.parse_args(argv)
    target = tuple(int(v) for v in args.target.split(","))
    assert len(target) == 2
    if args.kind == "heartbeat":
        payloads = [heartbeat()]
    elif args.kind == "fuzz":
        payloads = fuzz_corpus(2000, 1, (target[0], target[1]))
    else:
        rng = np.random.default_rng(2)
        payloads = [one(args.kind, rng, (target[0], target[1])) for _ in range(200)]
    sent = flood(args.port, args.rate_hz, args.duration_s, payloads, new_ports=args.new_ports)
    sys.stdout.write(f"sent {sent}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
