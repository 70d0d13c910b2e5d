"""Drivers of the SocketCAN HIL tests; run where vcan0 is up (see vcanrun.py), write artifacts.

    python inner_hil.py hil OUT_DIR [options]    allocator + simulated vessel on one CAN bus
    python inner_hil.py idle OUT_DIR [options]   the allocator alone on the bus

``hil``: ``candump -L CHANNEL`` first (OUT/capture.log), then ``ftcap-hil sim`` (--record
OUT/record.csv, log OUT/sim.log) and ``ftcap-hil allocator`` (--command-log OUT/commands.csv,
log OUT/allocator.log), both on ``socketcan``/CHANNEL with Zenoh off and MAVLink on free
loopback UDP ports. This script is the ground station, through the product's driver
(ftcap_hil.runtime.ground_station, as ``ftcap-hil gcs``): it sets the vessel's
SYS_FAILURE_EN = 1, flies eq. (24) on ODOMETRY every T_s (hold the origin, then a step of
the reference), injects one fault with MAV_CMD_INJECT_FAILURE mid-run, and saves every
FTCAP_STATUS it sees (OUT/status.json). At the end: SIGTERM to the allocator and its
exit code, then the sim and candump are stopped. OUT/summary.json says what happened
(times on both clocks: ``monotonic`` for the sim's record, ``wall`` for candump's stamps).

``idle``: the allocator alone (no sim, esc_monitor=false, no MAVLink, no Zenoh) at
``--rate-hz`` for ``--seconds``; with ``--down-at``/``--down-s`` this script brings CHANNEL
down mid-run and up again (needs root: the VM runs as root), restarting candump (which exits
when its interface goes down): OUT/capture-1.log, OUT/capture-2.log.

``--bus canhub`` runs the same on the loopback CAN hub (no SocketCAN), with an in-process
logger writing the capture in candump's format: for developing the driver on a host without
vcan, not used by the tests.

Exit status: 0 if every step went through (the host-side test judges the artifacts),
1 otherwise; summary.json is written either way, with ``errors``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from ftcap_hil.core.errors import FtcapError
from ftcap_hil.runtime.processes import Child, free_ports, ftcap_argv

SYNC_ID = 0x7FF  # 11-bit frame cansend puts on the bus to see candump listening (not DroneCAN)
T_S = 0.2827  # the paper's sample time: the ground station's period (3.54 Hz)
DEFAULT_CHANNEL = "vcan0"

# The guest runs Python ~18x slower than a host: these sim/daemon settings keep its one vCPU
# out of overload while the control loop stays the paper's (T_s, window, limits). The
# watchdogs get a few periods of slack so that a scheduling hiccup of the guest is not a fault.
SIM_SETTINGS = [
    "sim.rate_hz=10.0",
    "sim.telemetry_rate_hz=10.0",
    "sim.esc_status_rate_hz=5.0",
    "sim.command_timeout_s=2.0",
]
ALLOCATOR_SETTINGS = [
    "daemon.setpoint_timeout_s=2.0",
    "daemon.telemetry_timeout_s=2.0",
    "daemon.esc_timeout_s=2.0",
    # One RawCommand per cycle (no 100 Hz ESC stream): the capture is checked command by
    # command against the command log, and the guest's one vCPU has no time to spare.
    "can.esc_rate_hz=0",
]


class StepError(RuntimeError):
    """A step of the run failed; the message says which and why."""


def wait_for(what: str, predicate: Callable[[], Any], timeout_s: float, alive: list[Child]) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        for child in alive:
            if not child.running():
                raise StepError(
                    f"{child.name} exited ({child.proc.returncode}) while waiting for {what}"
                )
        if time.monotonic() > deadline:
            raise StepError(f"no {what} after {timeout_s:g} s")
        time.sleep(0.1)


def sets(items: list[str]) -> list[str]:
    return [a for item in items for a in ("--set", item)]


# --- the CAN capture ---------------------------------------------------------------------


class Capture:
    """``candump -L`` on a SocketCAN interface, or an in-process logger on the CAN hub."""

    def __init__(self, bus: str, channel: str, path: Path) -> None:
        self.bus, self.channel, self.path = bus, channel, path
        self.child: Child | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if bus == "socketcan":
            # stderr apart: candump says "read: Network is down" when the interface goes
            argv = ["candump", "-L", channel]
            self.child = Child("candump", argv, path, stderr=path.with_suffix(".err"))
        else:
            self._thread = threading.Thread(target=self._hub_logger, daemon=True)
            self._thread.start()

    def _hub_logger(self) -> None:
        from bridges.can_io.bus import open_can_bus

        with open_can_bus("canhub", self.channel) as bus, open(self.path, "w") as fh:
            while not self._stop.is_set():
                msg = bus.recv(timeout=0.1)
                if msg is not None:
                    width = 8 if msg.is_extended_id else 3
                    can_id = f"{msg.arbitration_id:0{width}X}"
                    data = bytes(msg.data).hex().upper()
                    fh.write(f"({time.time():.6f}) canhub {can_id}#{data}\n")
                    fh.flush()

    def wait_listening(self, timeout_s: float) -> None:
        """Send an 11-bit sync frame until it shows up in the capture."""
        if self.child is None:
            time.sleep(1.0)  # the hub logger: no cansend; the hub starts before any sender
            return
        needle = f" {self.channel} {SYNC_ID:03X}#"

        def seen() -> bool:
            subprocess.run(
                ["cansend", self.channel, f"{SYNC_ID:03X}#53594E43"], check=False, timeout=30
            )
            time.sleep(0.3)
            return needle in self.child.output() if self.child else False

        wait_for("sync frame in the capture", seen, 120.0, [self.child])

    def stop(self) -> int | None:
        if self.child is not None:
            if self.child.running():
                time.sleep(0.5)  # the last frames reach the file
            return self.child.stop(signal.SIGINT, 10.0)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        return 0

    def close(self) -> None:
        if self.child is not None:
            self.child.close()
        self._stop.set()


def bus_settings(bus: str, channel: str) -> list[str]:
    return [f'can.interface="{bus}"', f'can.channel="{channel}"']


# --- hil ---------------------------------------------------------------------------------


def _alive(children: list[Child]) -> Callable[[], None]:
    """The driver's ``check``: a child that exited ends the start-up or the flight."""

    def check() -> None:
        for child in children:
            if not child.running():
                raise StepError(f"{child.name} exited ({child.proc.returncode})")

    return check


def _flight_plan(opts: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """The driver's plan (eq. (24) toward the origin, then the step; one injection) and its
    summary entry."""
    import numpy as np

    from ftcap_hil.core.faults import Injection
    from ftcap_hil.core.messages import FaultKind
    from ftcap_hil.runtime.ground_station import FlightPlan, WrenchLaw

    step_to = np.array([float(v) for v in opts.step_to])
    inject = opts.fault_kind != "NONE"
    kind = FaultKind[opts.fault_kind] if inject else FaultKind.OK
    plan = FlightPlan(
        WrenchLaw.track(lambda t: step_to if t >= opts.step_at else np.zeros(3)),
        T_S,
        duration_s=opts.run_s,
        injections=(Injection(opts.fault_at, opts.fault_thruster, kind, opts.fault_value),)
        if inject
        else (),
        odometry_timeout_s=10.0,
        keep_statuses=True,
        inject_timeout_s=2.0,
        inject_attempts=5,
    )
    fault = {
        "at_s": opts.fault_at,
        "thruster": opts.fault_thruster,
        "kind": kind.name,
        "value": None if math.isnan(opts.fault_value) else opts.fault_value,
    }
    summary = {
        "period_s": T_S,
        "run_s": opts.run_s,
        "reference": [[0.0, [0.0, 0.0, 0.0]], [opts.step_at, step_to.tolist()]],
        "sim_set": opts.sim_set,
        "fault": fault if inject else None,
    }
    return plan, summary


def _status_row(st: Any, t0_s: float) -> dict[str, Any]:
    s = st.value
    return {
        "t_s": st.stamp_ns * 1e-9 - t0_s,
        "monotonic_s": st.stamp_ns * 1e-9,
        "delta_hat": list(s.delta_hat),
        "f_hat": list(s.f_hat),
        "tau_demand": list(s.tau_demand),
        "tau_unallocated": list(s.unallocated),
        "fault_detected": s.fault_detected,
        "faulty": list(s.faulty),
    }


def fly(opts: argparse.Namespace, gcs: Any, children: list[Child], summary: dict[str, Any]) -> Any:
    """Start-up and flight through the product's ground-station driver; the flight."""
    from ftcap_hil.runtime.ground_station import GroundStation

    station = GroundStation(gcs, check=_alive(children))
    # Its heartbeat says BOOT until the allocator's loop has run a cycle: under TCG the
    # core's set-up takes seconds after the link is up (connect waits for it).
    conn = station.connect(
        opts.start_timeout_s, enable_failures=True, read_mode=False, param_timeout_s=3.0
    )
    summary["heartbeats_monotonic"] = conn.heartbeats_ns * 1e-9
    summary["allocator_ready_monotonic"] = conn.ready_ns * 1e-9
    summary["sys_failure_en"] = conn.failure_enable
    t0 = conn.t0_ns * 1e-9
    summary["t0_monotonic"] = t0
    summary["t0_wall"] = time.time() - (time.monotonic() - t0)
    plan, summary["plan"] = _flight_plan(opts)
    flight = station.flight(plan, conn.t0_ns)
    flight.run()
    summary["gcs"] = {
        "cycles": flight.cycles,
        "overruns": flight.overruns,
        "wrench_send_failures": flight.send_failures,
        "statuses": len(flight.statuses),
        "statustexts": [
            {
                "t_s": item.stamp_ns * 1e-9 - t0,
                "from": [item.value.system, item.value.component],
                "text": item.value.text,
            }
            for item in flight.texts
        ],
    }
    out = flight.outcomes[0] if flight.outcomes else None
    summary["injection"] = {
        "result": None if out is None else out.result,
        "sent_monotonic": math.nan if out is None else t0 + out.sent_at_s,
        "sent_wall": math.nan if out is None else out.sent_wall_s,
        "sent_t_s": math.nan if out is None else out.sent_at_s,
    }
    return flight


def start_peers(
    opts: argparse.Namespace, can: list[str], ports: tuple[int, int, int], children: list[Child]
) -> tuple[Child, Child]:
    """The sim and the allocator on the bus and on loopback MAVLink (gcs, vessel, allocator
    UDP ports), appended to ``children`` as they start."""
    out: Path = opts.out
    gcs_port, vessel_port, alloc_port = ports
    sim = Child(
        "sim",
        ftcap_argv("sim", "--record", str(out / "record.csv"), *sets([
            *can, "zenoh.enabled=false", *SIM_SETTINGS, *opts.sim_set,
            f'mavlink.connection="udpin:127.0.0.1:{vessel_port}"',
            f'mavlink.peers=["127.0.0.1:{alloc_port}", "127.0.0.1:{gcs_port}"]',
        ])),
        out / "sim.log",
    )  # fmt: skip
    children.append(sim)
    alloc = Child(
        "allocator",
        ftcap_argv("allocator", "--command-log", str(out / "commands.csv"), *sets([
            *can, "zenoh.enabled=false", *ALLOCATOR_SETTINGS,
            f'mavlink.connection="udpin:127.0.0.1:{alloc_port}"',
            f'mavlink.peers=["127.0.0.1:{gcs_port}"]',
            # ODOMETRY is believed only from the vessel's inbox (docs/security.md)
            f'mavlink.telemetry_from=["127.0.0.1:{vessel_port}"]',
        ])),
        out / "allocator.log",
    )  # fmt: skip
    children.append(alloc)
    return sim, alloc


def run_hil(opts: argparse.Namespace, summary: dict[str, Any]) -> None:
    from bridges.mavlink.config import GCS_IDS, MavlinkEndpoint
    from bridges.mavlink.gcs import MavlinkGcsLink

    out: Path = opts.out
    gcs_port, vessel_port, alloc_port = free_ports(socket.SOCK_DGRAM, 3)
    children: list[Child] = []
    capture: Capture | None = None
    hub = None
    flight = None
    try:
        channel = opts.channel
        if opts.bus == "canhub":
            from bridges.can_io.hub import CanHub

            hub = CanHub(port=0).start()
            channel = hub.channel
        capture = Capture(opts.bus, channel, out / "capture.log")
        capture.wait_listening(opts.start_timeout_s)
        summary["capture_started_wall"] = time.time()
        can = bus_settings(opts.bus, channel)
        sim, alloc = start_peers(opts, can, (gcs_port, vessel_port, alloc_port), children)
        endpoint = MavlinkEndpoint.inbox(gcs_port, GCS_IDS, (alloc_port, vessel_port))
        with MavlinkGcsLink(endpoint) as gcs:
            flight = fly(opts, gcs, children, summary)
            # The end: SIGTERM to the allocator while the sim still runs, its exit code. No
            # wind-down: the allocator's own zero on SIGTERM is what the tests judge, and the
            # injected fault stays on the vessel (its record is the truth they compare with).
            summary["sigterm_wall"] = time.time()
            summary["sigterm_monotonic"] = time.monotonic()
            summary["allocator_exit"] = alloc.stop(signal.SIGTERM, opts.stop_timeout_s)
            summary["allocator_exited_wall"] = time.time()
        summary["sim_exit"] = sim.stop(signal.SIGTERM, opts.stop_timeout_s)
        summary["capture_exit"] = capture.stop()
        result = summary["injection"]["result"]
        if flight.plan.injections and result != "ACCEPTED":
            raise StepError(f"fault injection: {result}")
    finally:
        statuses = [] if flight is None else flight.statuses
        t0 = summary.get("t0_monotonic", 0.0)
        (out / "status.json").write_text(json.dumps([_status_row(st, t0) for st in statuses]))
        for child in children:
            child.close()
        if capture is not None:
            capture.stop()
            capture.close()
        if hub is not None:
            hub.shutdown()


# --- idle --------------------------------------------------------------------------------


def ip_link(channel: str, *args: str) -> dict[str, Any]:
    done = subprocess.run(
        ["ip", "link", "set", "dev", channel, *args],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    return {
        "args": list(args),
        "rc": done.returncode,
        "stderr": done.stderr.strip(),
        "monotonic": time.monotonic(),
        "wall": time.time(),
    }


def run_idle(opts: argparse.Namespace, summary: dict[str, Any]) -> None:
    out: Path = opts.out
    summary.update(rate_hz=opts.rate_hz, seconds=opts.seconds)
    captures: list[Capture] = []
    alloc: Child | None = None
    hub = None
    try:
        channel = opts.channel
        if opts.bus == "canhub":
            from bridges.can_io.hub import CanHub

            hub = CanHub(port=0).start()
            channel = hub.channel
        captures.append(Capture(opts.bus, channel, out / "capture-1.log"))
        captures[0].wait_listening(opts.start_timeout_s)
        alloc = Child(
            "allocator",
            ftcap_argv("allocator", "--duration", f"{opts.seconds:g}",
                "--command-log", str(out / "commands.csv"), *sets([
                    *bus_settings(opts.bus, channel), "can.esc_monitor=false",
                    "mavlink.enabled=false", "zenoh.enabled=false",
                    f"daemon.rate_hz={opts.rate_hz:g}",
                ])),
            out / "allocator.log",
        )  # fmt: skip
        wait_for(
            "the allocator's start-up line",
            lambda: "allocator: " in alloc.output() and " Hz, " in alloc.output(),
            opts.start_timeout_s,
            [alloc],
        )
        started = time.monotonic()
        summary["loop_started_monotonic"] = started
        if opts.down_at is not None and opts.bus == "socketcan":
            time.sleep(max(0.0, started + opts.down_at - time.monotonic()))
            summary["down"] = ip_link(channel, "down")
            time.sleep(opts.down_s)
            summary["up"] = ip_link(channel, "up")
            captures[0].stop()
            captures.append(Capture(opts.bus, channel, out / "capture-2.log"))
        rc = None
        try:
            rc = alloc.proc.wait(opts.seconds + opts.stop_timeout_s)
        except subprocess.TimeoutExpired:
            summary.setdefault("errors", []).append("the allocator outlived its --duration")
            rc = alloc.stop(signal.SIGTERM, opts.stop_timeout_s)
        summary["allocator_exit"] = rc
        summary["allocator_exited_monotonic"] = time.monotonic()
        summary["capture_exit"] = captures[-1].stop()
    finally:
        if alloc is not None:
            alloc.close()
        for capture in captures:
            capture.stop()
            capture.close()
        if hub is not None:
            hub.shutdown()


# --- command line ------------------------------------------------------------------------


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("what", choices=["hil", "idle"])
    p.add_argument("out", type=Path)
    p.add_argument("--bus", choices=["socketcan", "canhub"], default="socketcan")
    p.add_argument("--channel", default=DEFAULT_CHANNEL)
    p.add_argument("--start-timeout-s", type=float, default=180.0)
    p.add_argument("--stop-timeout-s", type=float, default=60.0)
    # hil
    p.add_argument("--run-s", type=float, default=70.0, help="flight time after first ODOMETRY")
    p.add_argument("--step-at", type=float, default=8.0, help="reference step time (s)")
    p.add_argument("--step-to", type=float, nargs=3, default=[1.0, 0.0, 0.0])
    p.add_argument("--fault-at", type=float, default=30.0)
    p.add_argument("--fault-thruster", type=int, default=0, help="0-based")
    p.add_argument("--fault-kind", default="OFF", help="a FaultKind name, or NONE")
    p.add_argument("--fault-value", type=float, default=math.nan)
    p.add_argument(
        "--sim-set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="sim --set"
    )
    # idle
    p.add_argument("--rate-hz", type=float, default=20.0)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--down-at", type=float, default=None)
    p.add_argument("--down-s", type=float, default=5.0)
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    """One run, or several in a row separated by ``--then`` (one VM boot for all of them):
    each writes its own summary.json; the exit status is the worst."""
    runs: list[list[str]] = [[]]
    for arg in argv:
        if arg == "--then":
            runs.append([])
        else:
            runs[-1].append(arg)
    return max(run_one(args) for args in runs)


def run_one(argv: list[str]) -> int:
    opts = parse(argv)
    opts.out.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s"
    )
    started = time.monotonic()
    summary: dict[str, Any] = {"kind": opts.what, "bus": opts.bus, "channel": opts.channel}
    run = run_hil if opts.what == "hil" else run_idle
    try:
        run(opts, summary)  # fills summary as it goes; cleans up after itself
    except (StepError, FtcapError) as e:  # the driver's: no answer, refused, link lost
        summary.setdefault("errors", []).append(str(e))
    except Exception as e:  # the summary must say what broke, whatever it was
        import traceback

        summary.setdefault("errors", []).append(f"driver crashed: {e!r}")
        traceback.print_exc()
    summary["driver_s"] = time.monotonic() - started
    summary["pid"] = os.getpid()
    write_json(opts.out / "summary.json", summary)
    for error in summary.get("errors", []):
        print(f"inner_hil: {error}", file=sys.stderr)
    print(f"inner_hil: {opts.what} done in {summary['driver_s']:.1f} s")
    return 1 if summary.get("errors") else 0


def write_json(path: Path, data: Any) -> None:
    def default(o: Any) -> Any:
        return None if isinstance(o, float) and math.isnan(o) else str(o)

    text = json.dumps(data, indent=1, default=default, allow_nan=True)
    fh: IO[str]
    with open(path, "w") as fh:
        fh.write(text)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
