"""Benchmarks of the allocator daemon as a process, on loopback.

    python bench/hil_latency.py latency [--samples 500] [--rate-hz 500]
    python bench/hil_latency.py rate [--seconds 60] [--rate-hz 500]

``latency``: time from a setpoint leaving this process (MAVLink WRENCH_SETPOINT, or a Zenoh
put on ftcap/<vessel>/setpoint/wrench) to the first esc.RawCommand frame carrying its
allocation arriving back here from the CAN hub. Baselines in the same run: a bare pymavlink
UDP send -> receive, and a CAN hub frame send -> receive (the transports alone).

``rate``: the daemon at --rate-hz for --seconds with setpoints streaming at 50 Hz; reports the
cycles and overruns the daemon counted (its exit log line).
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import tempfile
import threading
import time
from pathlib import Path

import can
import numpy as np

from bridges.can_io.codec import CanFrame, RawCommandMsg, decode_frames
from bridges.can_io.hub_bus import CanHubBus
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import WrenchSetpoint
from ftcap_hil.runtime.processes import Child, free_port, ftcap_argv, start_can_hub

EXTRA_SETS: list[str] = os.environ.get("FTCAP_BENCH_SET", "").split()  # more allocator --set


class RawCommandTap(can.Listener):
    """Every RawCommand seen on the bus with its arrival time."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, tuple[int, ...]]] = []
        self.lock = threading.Lock()
        self.arrived = threading.Event()

    def on_message_received(self, msg: can.Message) -> None:
        now = time.monotonic_ns()
        try:
            got = decode_frames([CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)])
        except MalformedMessage:
            return
        if isinstance(got.message, RawCommandMsg):
            with self.lock:
                self.frames.append((now, got.message.raw))
            self.arrived.set()

    def first_after(
        self, t0: int, differs_from: tuple[int, ...] | None
    ) -> tuple[int, tuple[int, ...]] | None:
        with self.lock:
            for t, raw in self.frames:
                if t >= t0 and raw != differs_from:
                    return t, raw
        return None


def start_allocator(
    hub_channel: str, rate_hz: float, mav_port: int, gcs_port: int, zenoh_port: int, log_path: str
) -> Child:
    sets = [
        f'can.channel="{hub_channel}"',
        "can.esc_monitor=false",
        f'mavlink.connection="udpin:127.0.0.1:{mav_port}"',
        f'mavlink.peers=["127.0.0.1:{gcs_port}"]',
        f"zenoh.overrides=['listen/endpoints:[\"tcp/127.0.0.1:{zenoh_port}\"]']",
        f"daemon.rate_hz={rate_hz}",
        "daemon.setpoint_timeout_s=5.0",
    ]
    cmd = ftcap_argv("allocator")
    for s in sets:
        cmd += ["--set", s]
    return Child("allocator", cmd, Path(log_path))


class HubProcess:
    """The CAN hub in its own process, so its thread does not compete for our GIL."""

    def __enter__(self) -> HubProcess:
        self.proc, self.channel = start_can_hub()
        return self

    def __exit__(self, *exc: object) -> None:
        stop(self.proc)


def connect_zenoh(make, timeout_s: float = 20.0):  # type: ignore[no-untyped-def]
    """The daemon's router needs a few seconds to start: retry the client session."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return make()
        except RuntimeError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def stop(proc: Child) -> None:
    """SIGTERM, 10 s to exit, SIGKILL."""
    proc.stop(signal.SIGTERM, 10.0)
    proc.close()


def measure(send, tap: RawCommandTap, samples: int, amplitude: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    out = []
    last: tuple[int, ...] | None = None
    rng = np.random.default_rng(1)
    for i in range(samples):
        tau = np.array([amplitude if i % 2 else -amplitude, 0.0, 0.0])
        t0 = time.monotonic_ns()
        send(tau)
        deadline = time.monotonic() + 0.5
        hit = None
        while time.monotonic() < deadline:
            hit = tap.first_after(t0, last)
            if hit is not None:
                break
            tap.arrived.wait(0.05)
            tap.arrived.clear()
        if hit is not None:
            out.append((hit[0] - t0) * 1e-3)
            last = hit[1]
        time.sleep(0.01 + 0.01 * rng.random())
    return np.array(out)


def baseline_mavlink(samples: int) -> np.ndarray:
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    port = free_port()
    rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=2)
    tx = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=3)
    out = []
    for _ in range(samples):
        t0 = time.monotonic_ns()
        tx.mav.heartbeat_send(6, 8, 0, 0, 0)
        msg = rx.recv_match(blocking=True, timeout=1.0)
        if msg is not None:
            out.append((time.monotonic_ns() - t0) * 1e-3)
    rx.close()
    tx.close()
    return np.array(out)


def baseline_can(channel: str, samples: int) -> np.ndarray:
    a, b = CanHubBus(channel=channel), CanHubBus(channel=channel)
    out = []
    try:
        for i in range(samples):
            t0 = time.monotonic_ns()
            a.send(can.Message(arbitration_id=0x1000 + i % 16, data=bytes(8), is_extended_id=True))
            if b.recv(1.0) is not None:
                out.append((time.monotonic_ns() - t0) * 1e-3)
    finally:
        a.shutdown()
        b.shutdown()
    return np.array(out)


def stats(name: str, us: np.ndarray, base: float | None = None) -> str:
    if us.size == 0:
        return f"  {name:42s} no samples"
    med, p99 = np.median(us), np.percentile(us, 99)
    ratio = f"  x{med / base:.2f} of transport floor" if base else ""
    return f"  {name:42s} n={us.size:4d} median {med:7.0f} us  p99 {p99:7.0f} us{ratio}"


def run_latency(args: argparse.Namespace) -> None:
    from bridges.mavlink.config import MavlinkEndpoint
    from bridges.mavlink.gcs import MavlinkGcsLink
    from bridges.zenoh_io.link import ZenohGcsLink, make_config

    mav_port, gcs_port, z_port = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    with tempfile.TemporaryDirectory(prefix="ftcap-bench-") as logs, HubProcess() as hub:
        log_path = str(Path(logs) / "allocator.log")  # private, never a fixed name
        proc = start_allocator(hub.channel, args.rate_hz, mav_port, gcs_port, z_port, log_path)
        tap = RawCommandTap()
        bus = CanHubBus(channel=hub.channel)
        notifier = can.Notifier(bus, [tap])
        gcs = MavlinkGcsLink(MavlinkEndpoint.inbox(gcs_port, (255, 190), (mav_port,)))
        zen = connect_zenoh(lambda: ZenohGcsLink("ftcap1", make_config("client", port=z_port)))
        try:
            time.sleep(2.0)  # zenoh subscriber matching
            amp = 0.002
            mav = measure(lambda tau: gcs.send_wrench(tau), tap, args.samples, amp)
            zmu = measure(
                lambda tau: zen.publish_setpoint(WrenchSetpoint.checked(tau)),
                tap,
                args.samples,
                amp,
            )
        finally:
            zen.shutdown()
            gcs.shutdown()
            notifier.stop()
            bus.shutdown()
            stop(proc)
        b_mav = baseline_mavlink(args.samples)
        b_can = baseline_can(hub.channel, args.samples)
    floor = float(np.median(b_mav) + np.median(b_can))
    print(f"setpoint -> RawCommand frame, daemon at {args.rate_hz} Hz (wake on setpoint)")
    print(stats("MAVLink WRENCH_SETPOINT -> CAN", mav, floor))
    print(stats("Zenoh setpoint/wrench -> CAN", zmu, floor))
    print(stats("baseline: bare pymavlink UDP send->recv", b_mav))
    print(stats("baseline: CAN hub frame send->recv", b_can))


def run_rate(args: argparse.Namespace) -> None:
    from bridges.mavlink.config import MavlinkEndpoint
    from bridges.mavlink.gcs import MavlinkGcsLink

    mav_port, gcs_port, z_port = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    with tempfile.TemporaryDirectory(prefix="ftcap-bench-") as logs, HubProcess() as hub:
        log_path = str(Path(logs) / "allocator.log")
        proc = start_allocator(hub.channel, args.rate_hz, mav_port, gcs_port, z_port, log_path)
        gcs = MavlinkGcsLink(MavlinkEndpoint.inbox(gcs_port, (255, 190), (mav_port,)))
        try:
            t_end = time.monotonic() + args.seconds + 2.0
            k = 0
            while time.monotonic() < t_end:
                gcs.send_wrench([0.05 * np.sin(0.5 * k * 0.02), 0.02, 0.0])
                k += 1
                time.sleep(0.02)
        finally:
            gcs.shutdown()
            stop(proc)
        text = Path(log_path).read_text()
    m = re.search(r"stopped after (\d+) cycles, (\d+) overruns", text)
    if not m:
        print(text[-2000:])
        raise SystemExit("no summary line in the allocator log")
    cycles, overruns = int(m.group(1)), int(m.group(2))
    print(
        f"daemon at {args.rate_hz} Hz for ~{args.seconds + 2:.0f} s with 50 Hz setpoints: "
        f"{cycles} cycles, {overruns} overruns ({100.0 * overruns / max(cycles, 1):.3f} %)"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="what", required=True)
    lat = sub.add_parser("latency")
    lat.add_argument("--samples", type=int, default=300)
    lat.add_argument("--rate-hz", type=float, default=500.0)
    rate = sub.add_parser("rate")
    rate.add_argument("--seconds", type=float, default=60.0)
    rate.add_argument("--rate-hz", type=float, default=500.0)
    args = ap.parse_args()
    (run_latency if args.what == "latency" else run_rate)(args)


if __name__ == "__main__":
    main()
