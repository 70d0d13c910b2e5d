"""Zenoh loopback latency: publish -> Mailbox through the ftcap links, against raw zenoh.

Measures, in one run and interleaved sample by sample so both see the same machine load:

* ``setpoint link``: ``ZenohGcsLink.publish_setpoint`` (client) -> router ->
  ``ZenohAllocatorLink.setpoints`` stamp (encode + transport + decode + Mailbox.put);
* ``setpoint raw``: the same bytes from a bare zenoh client publisher to a bare subscriber
  callback on a second router session that only reads the clock (the baseline: the same
  client -> router topology, on its own port, without codec or Mailbox);
* ``setpoint raw+codec``: the baseline plus ``encode_wrench_setpoint`` before the put and
  ``decode_wrench_setpoint`` in the callback (isolates the codec from the link machinery);
* ``command link`` / ``command raw``: the other direction, router -> client, for
  ``ZenohAllocatorLink.publish_thruster_command`` -> ``ZenohVesselLink.commands``;
* the codec alone (encode + decode, no transport), and a fixed ``struct`` setpoint for
  comparison with a binary encoding.

Every sample starts after the same idle gap (1 / rate) and the paths run in shuffled order, so
cold caches after the gap hit all paths alike. All sessions live in this process (sharing one
GIL); each path is one TCP loopback hop between a client session and a router session.
Usage: ``python bench/zenoh_latency.py [--samples 2000] [--rate-hz 200] [--port 0]``.
"""

from __future__ import annotations

import argparse
import math
import random
import socket
import struct
import threading
import time
import timeit
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from bridges.zenoh_io.codec import (
    decode_thruster_command,
    decode_wrench_setpoint,
    encode_thruster_command,
    encode_wrench_setpoint,
)
from bridges.zenoh_io.link import (
    ZenohAllocatorLink,
    ZenohGcsLink,
    ZenohVesselLink,
    make_config,
)
from ftcap_hil.core.messages import ThrusterCommand, WrenchSetpoint
from ftcap_hil.ports.mailbox import Mailbox
from ftcap_hil.runtime.processes import free_port

VESSEL = "bench"
WARMUP = 100


def signalling_mailbox(name: str) -> Mailbox[Any]:
    """A Mailbox whose ``notify`` event wakes the benchmark; the stamp is taken in put()."""
    return Mailbox(name, notify=threading.Event())


class RawProbe:
    """Bare zenoh publisher and subscriber on a side key: no link, optionally the codec."""

    def __init__(
        self,
        pub_session: zenoh.Session,
        sub_session: zenoh.Session,
        key: str,
        decode: Callable[[bytes], object] | None = None,
    ) -> None:
        self.arrived = threading.Event()
        self.stamp_ns = 0
        self._decode = decode
        self._sub = sub_session.declare_subscriber(key, self._on_sample)
        self.publisher = pub_session.declare_publisher(
            key, priority=zenoh.Priority.REAL_TIME, express=True
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()  # the link's callback reads the bytes too
        if self._decode is not None:
            self._decode(payload)
        self.stamp_ns = time.monotonic_ns()
        self.arrived.set()

    def stamp(self) -> int:
        return self.stamp_ns


def one_sample(
    send: Callable[[], object], arrived: threading.Event, stamp: Callable[[], int]
) -> float:
    """Microseconds from just before ``send`` to the receiver's stamp (NaN if lost)."""
    arrived.clear()
    t0 = time.monotonic_ns()
    send()
    if not arrived.wait(1.0):
        return math.nan
    return (stamp() - t0) * 1e-3


def summary(name: str, samples_us: list[float]) -> tuple[str, float]:
    """A table row (median, p90, p99, max in us, samples, lost) and the median."""
    kept = [s for s in samples_us[WARMUP:] if not math.isnan(s)]
    lost = len(samples_us) - WARMUP - len(kept)
    if not kept:
        return f"{name:<18} no samples ({lost} lost)", math.nan
    q = np.percentile(kept, [50, 90, 99])
    row = (
        f"{name:<18} {q[0]:9.1f} {q[1]:9.1f} {q[2]:9.1f} {max(kept):9.1f} {len(kept):7d} {lost:5d}"
    )
    return row, float(q[0])


def after_gap_us(fn: Callable[[], object], gap_s: float, n: int = 300) -> float:
    """Median cost of one call made after sleeping ``gap_s`` (caches cold, as in a paced loop)."""
    costs = []
    for _ in range(n):
        time.sleep(gap_s)
        t0 = time.perf_counter_ns()
        fn()
        costs.append((time.perf_counter_ns() - t0) * 1e-3)
    return float(np.median(costs))


def codec_cost_us(gap_s: float) -> list[str]:
    sp = WrenchSetpoint.checked([1200.0, -35.5, 310.25])
    cmd = ThrusterCommand.checked(np.linspace(-100.0, 100.0, 6))
    sp_bytes, cmd_bytes = encode_wrench_setpoint(sp), encode_thruster_command(cmd)
    fixed = struct.Struct("<B3d")

    def struct_round_trip() -> None:
        _, *tau = fixed.unpack(fixed.pack(1, *sp.tau.tolist()))
        WrenchSetpoint.checked(tau)

    cases = {
        "setpoint json": lambda: decode_wrench_setpoint(encode_wrench_setpoint(sp)),
        "command json m=6": lambda: decode_thruster_command(encode_thruster_command(cmd), 6),
        "setpoint struct": struct_round_trip,
    }
    lines = [
        f"payload sizes: setpoint {len(sp_bytes)} B, command m=6 {len(cmd_bytes)} B",
        f"{'encode+decode (us)':<18} {'warm':>9} {'after gap':>9}",
    ]
    for name, fn in cases.items():
        warm = min(timeit.repeat(fn, number=2000, repeat=5)) / 2000 * 1e6
        lines.append(f"{name:<18} {warm:9.2f} {after_gap_us(fn, gap_s):9.1f}")
    return lines


TCP = socket.SOCK_STREAM


def run(samples: int, rate_hz: float, port: int, raw_port: int) -> list[str]:
    setpoints: Mailbox[WrenchSetpoint] = signalling_mailbox("setpoint")
    commands: Mailbox[ThrusterCommand] = signalling_mailbox("thruster_command")
    assert setpoints.notify is not None and commands.notify is not None
    sp = WrenchSetpoint.checked([1200.0, -35.5, 310.25])
    cmd = ThrusterCommand.checked(np.linspace(-100.0, 100.0, 6))
    sp_bytes, cmd_bytes = encode_wrench_setpoint(sp), encode_thruster_command(cmd)
    with (
        ZenohAllocatorLink(VESSEL, make_config("router", port), setpoints=setpoints) as alloc,
        ZenohGcsLink(VESSEL, make_config("client", port)) as gcs,
        ZenohVesselLink(
            VESSEL, make_config("client", port), monitor_commands=True, commands=commands
        ),
        zenoh.open(make_config("router", raw_port)) as raw_router,
        zenoh.open(make_config("client", raw_port)) as raw_client,
    ):
        up = RawProbe(raw_client, raw_router, "bench/up")
        up_codec = RawProbe(raw_client, raw_router, "bench/up_codec", decode_wrench_setpoint)
        down = RawProbe(raw_router, raw_client, "bench/down")
        # name -> (send, arrival event, receiver stamp)
        paths: dict[str, tuple[Callable[[], object], threading.Event, Callable[[], int]]] = {
            "setpoint link": (
                lambda: gcs.publish_setpoint(sp),
                setpoints.notify,
                _stamp(setpoints),
            ),
            "setpoint raw": (lambda: up.publisher.put(sp_bytes), up.arrived, up.stamp),
            "setpoint raw+codec": (
                lambda: up_codec.publisher.put(encode_wrench_setpoint(sp)),
                up_codec.arrived,
                up_codec.stamp,
            ),
            "command link": (
                lambda: alloc.publish_thruster_command(cmd),
                commands.notify,
                _stamp(commands),
            ),
            "command raw": (lambda: down.publisher.put(cmd_bytes), down.arrived, down.stamp),
        }
        time.sleep(1.0)  # subscriptions declared less than ~1 s ago can miss samples
        results: dict[str, list[float]] = {name: [] for name in paths}
        order, rng = list(paths), random.Random(0)
        for _ in range(samples):
            rng.shuffle(order)  # no path always goes first after the idle gap
            for name in order:
                time.sleep(1.0 / rate_hz)  # every sample starts from the same idle gap
                results[name].append(one_sample(*paths[name]))
    header = (
        f"{'path (us)':<18} {'median':>9} {'p90':>9} {'p99':>9} {'max':>9} {'n':>7} {'lost':>5}"
    )
    rows = {name: summary(name, v) for name, v in results.items()}
    lines = [header] + [row for row, _ in rows.values()]
    med = {name: median for name, (_, median) in rows.items()}
    lines.append(
        "median overhead over raw: "
        f"setpoint link {med['setpoint link'] - med['setpoint raw']:+.1f} us "
        f"(codec alone {med['setpoint raw+codec'] - med['setpoint raw']:+.1f} us), "
        f"command link {med['command link'] - med['command raw']:+.1f} us"
    )
    return lines


def _stamp(box: Mailbox[Any]) -> Callable[[], int]:
    def latest_stamp() -> int:
        slot = box.latest()
        return 0 if slot is None else slot.stamp_ns

    return latest_stamp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--rate-hz", type=float, default=200.0)
    parser.add_argument("--port", type=int, default=0, help="router port (0: pick a free one)")
    args = parser.parse_args()
    if args.samples <= WARMUP:
        parser.error(f"--samples must exceed the {WARMUP} warm-up samples")
    lines = (
        codec_cost_us(1.0 / args.rate_hz)
        + [""]
        + run(
            args.samples,
            args.rate_hz,
            args.port or free_port(socket.SOCK_STREAM),
            free_port(socket.SOCK_STREAM),
        )
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
