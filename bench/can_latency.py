"""CAN loopback latency: the ``canhub`` transport against python-can's in-process ``virtual``.

Measured in one run, interleaved sample by sample so every path sees the same machine load:

* ``frame``: ``bus.send(msg)`` -> ``other_bus.recv()`` returns, one 8-byte extended frame;
* ``setpoint->frames``: ``CanThrusterSink.send(u)`` for 8 thrusters (DroneCAN encode, 3
  frames) -> the last frame received by a second bus;
* ``setpoint->mailbox``: the same, until ``CanCommandSource`` (Notifier thread, reassembly,
  decode, force map) stamps its Mailbox;
* ``echo RTT`` (canhub only): a frame to a child process that echoes it back.

Each path has a bus of its own: a ``virtual`` channel, or a hub running as its own process
(``ftcap-hil can-hub --port 0``) as in deployment; both clients of a path live in
this process. Times include the send call.
Usage: ``python bench/can_latency.py [--samples 2000] [--thrusters 8] [--gap-ms 1]``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from bridges.can_io.adapters import CanCommandSource, CanThrusterSink
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import decode_frames, encode_raw_command
from bridges.can_io.force_map import ForceRawMap
from ftcap_hil.ports.mailbox import Mailbox
from ftcap_hil.runtime.processes import Child, start_can_hub

WARMUP = 100

ECHO = textwrap.dedent(
    """
    import sys, can
    only = [{"can_id": 2, "can_mask": 0x1FFFFFFF, "extended": True}]
    with can.Bus(interface="canhub", channel=sys.argv[1], can_filters=only) as bus:
        print("ready", flush=True)
        while (m := bus.recv(5.0)) is not None:
            bus.send(can.Message(arbitration_id=m.arbitration_id + 1, data=m.data))
    """
)


def signalling_mailbox(name: str) -> Mailbox[Any]:
    """A Mailbox whose ``notify`` event wakes the benchmark; the stamp is taken in put()."""
    return Mailbox(name, notify=threading.Event())


class Path:
    """One measured path: ``run()`` returns a latency in ns."""

    def __init__(self, name: str, run: Callable[[], int]) -> None:
        self.name = name
        self.run = run
        self.ns: list[int] = []


def frame_path(tx: can.BusABC, rx: can.BusABC, can_id: int) -> Callable[[], int]:
    msg = can.Message(arbitration_id=can_id, data=b"\x01\x02\x03\x04\x05\x06\x07\x08")

    def run() -> int:
        t0 = time.perf_counter_ns()
        tx.send(msg)
        got = rx.recv(1.0)
        t1 = time.perf_counter_ns()
        assert got is not None, "frame lost"
        return t1 - t0

    return run


def setpoint_frames_path(sink: CanThrusterSink, rx: can.BusABC) -> Callable[[], int]:
    rng = np.random.default_rng(1)
    frames_per_transfer = len(
        encode_raw_command([0] * sink.force_map.m, source_node_id=1, transfer_id=0)
    )

    def run() -> int:
        u = rng.uniform(-1.0, 1.0, sink.force_map.m) * sink.force_map.u_max_abs
        t0 = time.perf_counter_ns()
        sink.send(u)
        for _ in range(frames_per_transfer):
            assert rx.recv(1.0) is not None, "frame lost"
        return time.perf_counter_ns() - t0

    return run


def setpoint_mailbox_path(sink: CanThrusterSink, source: CanCommandSource) -> Callable[[], int]:
    box = signalling_mailbox("bench")
    arrived = box.notify
    assert arrived is not None
    source.commands = box
    rng = np.random.default_rng(2)

    def run() -> int:
        arrived.clear()
        u = rng.uniform(-1.0, 1.0, sink.force_map.m) * sink.force_map.u_max_abs
        t0 = time.monotonic_ns()
        sent = sink.send(u)
        if not arrived.wait(1.0):
            raise RuntimeError(f"{source.bus.channel_info}: command lost (sent={sent})")
        slot = box.latest()
        assert slot is not None
        return slot.stamp_ns - t0

    return run


def codec_us(m: int) -> tuple[float, float]:
    raw = list(range(-m, 0))
    n = 2000
    t0 = time.perf_counter()
    for k in range(n):
        frames = encode_raw_command(raw, source_node_id=10, transfer_id=k)
    t1 = time.perf_counter()
    for _ in range(n):
        decode_frames(frames)
    t2 = time.perf_counter()
    return (t1 - t0) / n * 1e6, (t2 - t1) / n * 1e6


def stats_us(ns: list[int]) -> tuple[float, float, float]:
    arr = np.asarray(ns[WARMUP:], dtype=np.float64) / 1e3
    return float(np.median(arr)), float(np.percentile(arr, 99)), float(arr.max())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--thrusters", type=int, default=8)
    parser.add_argument("--gap-ms", type=float, default=1.0, help="pause between rounds")
    args = parser.parse_args()

    fmap = ForceRawMap.create([100.0] * args.thrusters)
    # One bus (virtual channel or hub process) per path, so no path wakes another's reader.
    hubs = [start_can_hub() for _ in range(4)]
    channels = [channel for _, channel in hubs]
    echo = Child("echo", [sys.executable, "-c", ECHO, channels[3]], stderr="inherit")
    buses: list[can.BusABC] = []
    ports: list[CanThrusterSink | CanCommandSource] = []

    def bus(interface: str, chan: str) -> can.BusABC:
        buses.append(open_can_bus(interface, chan))
        return buses[-1]

    try:
        assert echo.next_line(20.0) == "ready"
        paths = []
        for iface, chans in (("virtual", ["v0", "v1", "v2"]), ("canhub", channels)):
            tx, rx = bus(iface, chans[0]), bus(iface, chans[0])
            paths.append(Path(f"frame {iface}", frame_path(tx, rx, 1)))
            sink0 = CanThrusterSink(bus(iface, chans[1]), fmap, zero_on_shutdown=False)
            rx = bus(iface, chans[1])
            paths.append(Path(f"setpoint->frames {iface}", setpoint_frames_path(sink0, rx)))
            sink = CanThrusterSink(bus(iface, chans[2]), fmap, zero_on_shutdown=False)
            source = CanCommandSource(bus(iface, chans[2]), fmap)
            paths.append(Path(f"setpoint->mailbox {iface}", setpoint_mailbox_path(sink, source)))
            ports += [sink0, sink, source]
        echo_bus = bus("canhub", channels[3])
        paths.append(Path("echo RTT canhub (other process)", frame_path(echo_bus, echo_bus, 2)))

        for _ in range(args.samples + WARMUP):
            for path in paths:
                path.ns.append(path.run())
                time.sleep(args.gap_ms / 1e3)
        report(paths, args.thrusters)
        bad = [p.malformed for p in ports if isinstance(p, CanCommandSource)]
        print(f"malformed transfers seen by the mailbox paths: {bad}")
    finally:
        for port in ports:
            port.shutdown()
        for b in buses:
            b.shutdown()
        for proc in [echo] + [hub for hub, _ in hubs]:
            proc.stop(signal.SIGTERM, 10.0)
            proc.close()
    enc, dec = codec_us(args.thrusters)
    print(f"\ncodec only, {args.thrusters} thrusters: encode {enc:.1f} us, decode {dec:.1f} us")
    return 0


def report(paths: list[Path], m: int) -> None:
    print(f"{len(paths[0].ns) - WARMUP} samples, {m} thrusters; microseconds")
    print(f"{'path':38s} {'median':>8s} {'p99':>8s} {'max':>8s} {'x virtual (median/p99)':>24s}")
    base = {p.name.rsplit(" ", 1)[0]: stats_us(p.ns) for p in paths if p.name.endswith("virtual")}
    for p in paths:
        med, p99, mx = stats_us(p.ns)
        ref = base.get(p.name.rsplit(" ", 1)[0])
        ratio = (
            f"{med / ref[0]:.1f} / {p99 / ref[1]:.1f}" if ref and "virtual" not in p.name else ""
        )
        print(f"{p.name:38s} {med:8.1f} {p99:8.1f} {mx:8.1f} {ratio:>24s}")


if __name__ == "__main__":
    sys.exit(main())
