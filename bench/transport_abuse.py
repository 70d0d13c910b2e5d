"""The long versions of the CAN and Zenoh abuse tests (issue 12), with the figures it names.

* ``reassembly``: cost of one frame in ``TransferAssembler.feed`` after N never-ending
  multi-frame transfers were started (N = 1 000 and 16 000; the unbounded assembler took
  47 and 566 us), and the pending count it kept.
* ``restart``: the CAN hub stopped for ``--outage-s`` and started again, ``--restarts``
  times, with the allocator's stream at 100 Hz and the vessel listening: seconds from the
  hub's return to the vessel's next command (target: < 2 s).
* ``can-fuzz``: ``--frames`` fuzzed frames (default 10^6) into the vessel's command source
  with the allocator streaming: frames accounted for, commands out of range, max ESC age.
* ``zenoh-fuzz``: ``--payloads`` fuzzed payloads (default 10^6) in rounds of 10^5 from a
  child process into the allocator's link: accepted + malformed == sent, the router's RSS
  after each round (bounded: it must stop growing).

Usage: ``python bench/transport_abuse.py [reassembly|restart|can-fuzz|zenoh-fuzz ...]``.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bridges.can_io.adapters import CanCommandSource, CanThrusterSink  # noqa: E402
from bridges.can_io.assembler import TransferAssembler  # noqa: E402
from bridges.can_io.bus import open_can_bus  # noqa: E402
from bridges.can_io.codec import CanFrame, encode_raw_command  # noqa: E402
from bridges.can_io.force_map import ForceRawMap  # noqa: E402
from bridges.can_io.hub import CanHub  # noqa: E402
from ftcap_hil.runtime.processes import free_port  # noqa: E402
from tests.support.payloads import can_frames  # noqa: E402

FMAP = ForceRawMap.create([10.0, 10.0])


def _flooded(n: int) -> tuple[TransferAssembler, int]:
    """An assembler after ``n`` never-ending transfers started at 5 k/s; the last stamp."""
    asm, t = TransferAssembler(), 0
    for i in range(n):
        frames = encode_raw_command(
            list(range(8)), source_node_id=1 + i % 127, transfer_id=i, priority=i % 32
        )
        t = i * 200_000
        asm.feed(frames[0], t)
    return asm, t


def _cost_us(asm: TransferAssembler, frame: CanFrame, t: int, k: int = 20_000) -> float:
    t0 = time.perf_counter()
    for j in range(k):
        asm.feed(frame, t + j)
    return (time.perf_counter() - t0) / k * 1e6


def reassembly() -> None:
    """Per-frame cost after N started transfers that never end: a single-frame RawCommand
    (reassembly plus the dronecan decode) and an orphan continuation (reassembly alone)."""
    single = encode_raw_command([1, 2], source_node_id=10, transfer_id=0)[0]
    orphan = CanFrame(single.can_id, bytes(7) + bytes([0x05]))  # no SOT, nothing open
    for n in (0, 1_000, 16_000):
        asm, t = _flooded(n)
        costs = [(_cost_us(asm, single, t), _cost_us(asm, orphan, t)) for _ in range(3)]
        dec, orph = min(c[0] for c in costs), min(c[1] for c in costs)
        print(
            f"reassembly: {n:6d} started, pending kept {asm.pending:4d}: {dec:6.2f} us per "
            f"single-frame command (with decode), {orph:5.2f} us per orphan frame"
        )


def restart(restarts: int, outage_s: float) -> None:
    """Recovery time after hub restarts, both sides on ``ReconnectingBus``; the owner of the
    sink behaves as the daemon does (a cycle every 10 ms: take the lapse, send)."""
    port = free_port(socket.SOCK_STREAM)
    channel = f"127.0.0.1:{port}"
    hub = CanHub(port=port).start()
    alloc_bus, vessel_bus = open_can_bus("canhub", channel), open_can_bus("canhub", channel)
    sink, source = CanThrusterSink(alloc_bus, FMAP), CanCommandSource(vessel_bus, FMAP)
    sink.start_stream(100.0, restart_from_zero=True)
    link, thrust, lapses = [], [], 0
    try:
        for _ in range(restarts):
            sink.send([1.0, -1.0])
            hub.shutdown()
            time.sleep(outage_s)
            hub = CanHub(port=port).start()
            back = time.monotonic_ns()
            first = None
            while (
                (c := source.commands.latest()) is None or c.stamp_ns <= back or c.value.u[0] < 0.5
            ):
                if first is None and c is not None and c.stamp_ns > back:
                    first = c.stamp_ns
                lapses += sink.take_lapse()
                sink.send([1.0, -1.0])
                time.sleep(0.01)
            link.append(((first or c.stamp_ns) - back) / 1e9)
            thrust.append((c.stamp_ns - back) / 1e9)
    finally:
        for port_ in (source, sink):
            port_.shutdown()
        alloc_bus.shutdown()
        vessel_bus.shutdown()
        hub.shutdown()
    lk, t = np.array(link), np.array(thrust)
    print(
        f"restart: {restarts} hub restarts ({outage_s} s outage each): first command back "
        f"after median {np.median(lk):.3f} s, thrust (the owner's command after the lapse) "
        f"back after median {np.median(t):.3f} s, max {t.max():.3f} s (target < 2 s); "
        f"outages {getattr(alloc_bus, 'outages', '?')}/{getattr(vessel_bus, 'outages', '?')}, "
        f"cycles that saw a lapse {lapses}"
    )


def can_fuzz(n: int) -> None:
    """``n`` fuzzed frames into the vessel's source, the allocator streaming."""
    with CanHub(port=0, max_queue_bytes=64 << 20).start() as hub:
        alloc_bus, vessel_bus = (
            open_can_bus("canhub", hub.channel),
            open_can_bus("canhub", hub.channel),
        )
        stranger = open_can_bus("canhub", hub.channel, retry_period_s=None)
        sink, source = CanThrusterSink(alloc_bus, FMAP), CanCommandSource(vessel_bus, FMAP)
        sink.start_stream(100.0)
        sink.send([2.0, -2.0])
        out_of_range = 0
        t0 = time.monotonic()
        for k, (can_id, ext, data) in enumerate(can_frames(n, seed=11)):
            stranger.send(can.Message(arbitration_id=can_id, is_extended_id=ext, data=data))
            if k % 1000 == 999:
                sink.send([2.0, -2.0])
                c = source.commands.latest()
                if c is not None and np.any(np.abs(c.value.u) > 10.0):
                    out_of_range += 1
                time.sleep(max(0.0, t0 + (k + 1) / 20_000 - time.monotonic()))
        time.sleep(1.0)
        asm = source.assembler
        print(
            f"can-fuzz: {n} frames in {time.monotonic() - t0:.1f} s; vessel saw {asm.frames} "
            f"(hub dropped {hub.bytes_dropped} B): ignored {asm.ignored}, orphans "
            f"{asm.orphans}, rejected {asm.rejected}, consumed {asm.consumed}; malformed "
            f"{source.malformed}; out of range {out_of_range}; pending {asm.pending}"
        )
        for p in (source, sink):
            p.shutdown()
        for b in (stranger, alloc_bus, vessel_bus):
            b.shutdown()


PUBLISHER = textwrap.dedent(
    """
    import json, sys, time, zenoh
    sys.path.insert(0, sys.argv[3])
    from bridges.zenoh_io.link import make_config
    from tests.support.payloads import zenoh_payloads
    port, n, seed = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[4])
    base = {"v": 1, "X_N": 10.0, "Y_N": -5.0, "N_Nm": 1.0}
    with zenoh.open(make_config("client", port)) as s:
        pub = s.declare_publisher("ftcap/bench/setpoint/wrench",
                                  congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(1.0)
        for p in zenoh_payloads(base, n, seed=seed):
            pub.put(p)
        print("done", flush=True)
        time.sleep(0.5)
    """
)


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def zenoh_fuzz(n: int) -> None:
    """``n`` fuzzed setpoints in rounds of 10^5, RSS after each round."""
    from bridges.zenoh_io.link import ZenohAllocatorLink, make_config

    port = free_port(socket.SOCK_STREAM)
    with ZenohAllocatorLink(
        "bench", make_config("router", port), wrench_limit=(1e3, 1e3, 1e3)
    ) as a:
        start = _rss_mb()
        sent = 0
        for r in range(max(1, n // 100_000)):
            k = min(100_000, n - sent)
            subprocess.run(
                [sys.executable, "-c", PUBLISHER, str(port), str(k), str(ROOT), str(r)],
                check=True,
                capture_output=True,
                timeout=600,
            )
            sent += k
            deadline = time.monotonic() + 60
            while (
                a.setpoints.received + a.setpoints.malformed < sent and time.monotonic() < deadline
            ):
                time.sleep(0.05)
            seen = a.setpoints.received + a.setpoints.malformed
            print(
                f"zenoh-fuzz: round {r}: sent {sent}, accepted + malformed {seen}, decode errors "
                f"{a.decode_errors}, RSS {_rss_mb() - start:+.1f} MB from start"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", default=["reassembly", "restart", "can-fuzz", "zenoh-fuzz"])
    ap.add_argument("--restarts", type=int, default=10)
    ap.add_argument("--outage-s", type=float, default=1.0)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--payloads", type=int, default=1_000_000)
    args = ap.parse_args()
    for part in args.parts:
        if part == "reassembly":
            reassembly()
        elif part == "restart":
            restart(args.restarts, args.outage_s)
        elif part == "can-fuzz":
            can_fuzz(args.frames)
        elif part == "zenoh-fuzz":
            zenoh_fuzz(args.payloads)
        else:
            raise SystemExit(f"unknown part {part!r}")
    print(json.dumps({"done": args.parts}))


if __name__ == "__main__":
    main()
