"""The end-to-end rig (no tests here; the ``hil`` fixture in conftest.py builds one): CAN hub,
simulated vessel and allocator as real processes on 127.0.0.1, the test playing the ground
station (MAVLink through the product's driver, Zenoh) and a CAN tap.

Topology of one rig (every port chosen free per test, loopback only, no multicast)::

    test GCS inbox G  <-- STATUSTEXT, FTCAP_STATUS --  allocator inbox A  <-- ODOMETRY --  sim S
                      --> WRENCH_SETPOINT, PARAM -->                       (also to G)
                      --> COMMAND_LONG (faults), PARAM ------------------------------------>
    zenoh: the allocator is the router on tcp/127.0.0.1:Z; the sim and the test are clients
    CAN:   `ftcap-hil can-hub --port 0`; allocator (node 10), sim (ESC nodes 20..23)
           and the test's tap are its clients

Every process is started through a :class:`Rig` and killed by PID at its teardown.
"""

from __future__ import annotations

import contextlib
import csv
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from bridges.can_io.adapters import CanEscStatusSource
from bridges.can_io.codec import CanFrame, DataType, RawCommandMsg, TransferAssembler
from bridges.can_io.hub_bus import CanHubBus
from bridges.mavlink.config import ALLOCATOR_IDS, GCS_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.gcs import MavlinkGcsLink, wait_until
from bridges.zenoh_io.link import ZenohGcsLink, make_config
from ftcap_hil.apps.demo import free_ports
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import Odometry
from ftcap_hil.runtime.ground_station import Flight, FlightPlan, GroundStation, WrenchLaw, state_of

ALLOCATOR_NODE = 10
ESC_IDS = (20, 21, 22, 23)
START_TIMEOUT_S = 40.0  # a cold start on a loaded 2-core machine (zenoh router, mavgen cache)
RAW_MAX = 8191
U_LIMIT_N = 0.1  # thruster amplitude limit of the shipped vessel files: raw RAW_MAX


def record_raw(row: dict[str, str]) -> tuple[int, ...]:
    """The command in a sim ``--record`` row, in esc.RawCommand counts (as on the bus)."""
    return tuple(round(float(row[f"u_T{i}_N"]) * RAW_MAX / U_LIMIT_N) for i in range(1, 5))


def free_port(kind: int) -> int:
    return free_ports(kind, 1)[0]


class Proc:
    """One child process with its output in a log file; signalled and killed by PID."""

    def __init__(self, name: str, cmd: list[str], log_path: Path, cwd: Path) -> None:
        self.name = name
        self.log_path = log_path
        self._fh = open(log_path, "w")  # noqa: SIM115 - closed in kill()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.popen = subprocess.Popen(
            cmd, stdout=self._fh, stderr=subprocess.STDOUT, cwd=cwd, env=env
        )
        self.pid = self.popen.pid

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def running(self) -> bool:
        return self.popen.poll() is None

    def wait_log(self, pattern: str, timeout_s: float = START_TIMEOUT_S) -> bool:
        """True once ``pattern`` (regex) is in the log; False on timeout or early exit."""
        rx = re.compile(pattern)
        wait_until(lambda: rx.search(self.log()) or not self.running(), timeout_s)
        return rx.search(self.log()) is not None

    def send(self, sig: int) -> None:
        if self.running():
            os.kill(self.pid, sig)

    def wait(self, timeout_s: float) -> int | None:
        try:
            return self.popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def kill(self) -> None:
        """SIGKILL by PID if still running, reap, close the log. Idempotent."""
        if self.running():
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.popen.wait(10.0)
        self._fh.close()


@dataclass
class RawFrame:
    stamp_ns: int
    source: int
    raw: tuple[int, ...]


class BusTap(can.Listener):
    """The test's client of the CAN hub: every esc.RawCommand with its arrival time, and the
    ESC telemetry (``esc`` mailboxes, rpm per thruster) through the product's own source."""

    def __init__(self, channel: str, m: int = 4) -> None:
        self.frames: list[RawFrame] = []
        self._lock = threading.Lock()
        self._assembler = TransferAssembler([DataType.RAW_COMMAND])
        self.malformed = 0
        self.bus = CanHubBus(channel=channel)
        self.notifier = can.Notifier(self.bus, [self], 0.05)
        self.esc = CanEscStatusSource(self.bus, m, esc_node_ids=ESC_IDS, notifier=self.notifier)

    def on_message_received(self, msg: can.Message) -> None:
        now = time.monotonic_ns()
        frame = CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
        try:
            got = self._assembler.feed(frame, now)
        except MalformedMessage:
            self.malformed += 1
            return
        if got is not None and isinstance(got.message, RawCommandMsg):
            with self._lock:
                self.frames.append(RawFrame(now, got.source_node_id, got.message.raw))

    def commands(self, since_ns: int = 0, source: int = ALLOCATOR_NODE) -> list[RawFrame]:
        with self._lock:
            return [f for f in self.frames if f.source == source and f.stamp_ns >= since_ns]

    def latest(self) -> RawFrame | None:
        got = self.commands()
        return got[-1] if got else None

    def rpm(self) -> list[float]:
        slots = [box.latest() for box in self.esc.mailboxes]
        return [float("nan") if s is None else s.value.rpm for s in slots]

    def close(self) -> None:
        self.esc.shutdown()
        self.notifier.stop()
        self.bus.shutdown()


@dataclass
class Rig:
    """Ports, processes and the test's links of one HIL rig (see the module docstring)."""

    tmp: Path
    hub_channel: str = ""
    alloc_port: int = field(default_factory=lambda: free_port(socket.SOCK_DGRAM))
    vessel_port: int = field(default_factory=lambda: free_port(socket.SOCK_DGRAM))
    gcs_port: int = field(default_factory=lambda: free_port(socket.SOCK_DGRAM))
    zenoh_port: int = field(default_factory=lambda: free_port(socket.SOCK_STREAM))
    procs: dict[str, Proc] = field(default_factory=dict)
    closers: list[Callable[[], None]] = field(default_factory=list)

    @property
    def record(self) -> Path:
        return self.tmp / "record.csv"

    @property
    def command_log(self) -> Path:
        return self.tmp / "commands.csv"

    def _spawn(self, name: str, args: list[str]) -> Proc:
        key = name if name not in self.procs else f"{name}-{len(self.procs)}"  # kill every one
        proc = Proc(key, [sys.executable, *args], self.tmp / f"{key}.log", self.tmp)
        self.procs[key] = proc
        return proc

    def start_hub(self) -> None:
        hub = self._spawn("hub", ["-m", "ftcap_hil", "can-hub", "--port", "0"])
        assert hub.wait_log(r"can_hub listening on \S+:\d+"), hub.log()
        m = re.search(r"can_hub listening on (\S+:\d+)", hub.log())
        assert m is not None
        self.hub_channel = m.group(1)

    def start_allocator(self, sets: Sequence[str] = (), verbose: bool = False) -> Proc:
        """``ftcap-hil allocator`` on this rig's ports (+ overrides); waits until it runs."""
        base = [
            f'can.channel="{self.hub_channel}"',
            f'mavlink.connection="udpin:127.0.0.1:{self.alloc_port}"',
            f'mavlink.peers=["127.0.0.1:{self.gcs_port}"]',
            f"zenoh.overrides=['listen/endpoints:[\"tcp/127.0.0.1:{self.zenoh_port}\"]']",
        ]
        args = ["-m", "ftcap_hil", *(["-vv"] if verbose else []), "allocator"]
        args += ["--command-log", str(self.command_log)]
        for s in [*base, *sets]:
            args += ["--set", s]
        proc = self._spawn("allocator", args)
        assert proc.wait_log(r"allocator: .* Hz, \d+ thrusters"), proc.log()
        return proc

    def start_sim(self, sets: Sequence[str] = (), args: Sequence[str] = ()) -> Proc:
        """``ftcap-hil sim --record`` on this rig's ports (+ overrides); waits until it runs."""
        base = [
            f"can.channel={self.hub_channel}",
            f"mavlink.connection=udpin:127.0.0.1:{self.vessel_port}",
            f'mavlink.peers=["127.0.0.1:{self.alloc_port}", "127.0.0.1:{self.gcs_port}"]',
            f"zenoh.connect=tcp/127.0.0.1:{self.zenoh_port}",
        ]
        cmd = ["-m", "ftcap_hil", "sim", "--record", str(self.record), *args]
        for s in [*base, *sets]:
            cmd += ["--set", s]
        proc = self._spawn("sim", cmd)
        assert proc.wait_log("simulated vessel running"), proc.log()
        return proc

    def gcs(self) -> MavlinkGcsLink:
        """The test's MAVLink ground station on inbox G, sending to A and S."""
        link = MavlinkGcsLink(
            MavlinkEndpoint.inbox(self.gcs_port, GCS_IDS, (self.alloc_port, self.vessel_port)),
            allocator_ids=ALLOCATOR_IDS,
            vessel_ids=VESSEL_IDS,
        )
        self.closers.append(link.shutdown)
        return link

    def zenoh_gcs(self) -> ZenohGcsLink:
        """The test's Zenoh ground station, a client of the allocator's router."""
        link = ZenohGcsLink("ftcap1", make_config("client", port=self.zenoh_port))
        self.closers.append(link.shutdown)
        return link

    def tap(self) -> BusTap:
        tap = BusTap(self.hub_channel)
        self.closers.append(tap.close)
        return tap

    def record_rows(self) -> list[dict[str, str]]:
        with open(self.record, newline="") as fh:
            return list(csv.DictReader(fh))

    def command_log_rows(self) -> list[list[float]]:
        with open(self.command_log, newline="") as fh:
            rows = list(csv.reader(fh))
        return [[float(v) for v in r] for r in rows[1:]]

    def logs(self, tail: int = 6000) -> str:
        return "\n".join(
            f"===== {n} (pid {p.pid}) =====\n{p.log()[-tail:]}" for n, p in self.procs.items()
        )

    def teardown(self) -> None:
        """Close the test's links, then SIGKILL every child by PID (whatever the links did)."""
        try:
            for close in reversed(self.closers):
                close()
        finally:
            self.closers.clear()
            for proc in reversed(list(self.procs.values())):
                proc.kill()


def latest_odometry(gcs: MavlinkGcsLink) -> Odometry:
    """The ground station's latest ODOMETRY (the caller has waited for one)."""
    slot = gcs.odometry.latest()
    assert slot is not None, "no ODOMETRY received"
    return slot.value


def odometry_state(odom: Odometry) -> np.ndarray:
    """[north, east, psi, u, v, r] from one odometry sample (the driver's ``state_of``)."""
    return state_of(odom)


def setpoints(
    gcs: MavlinkGcsLink,
    tau: list[float] | None = None,
    hold: np.ndarray | None = None,
    period_s: float = 0.1,
) -> Flight:
    """The ground-station driver's flight on a thread of its own (leave the ``with`` to stop
    it): every ``period_s`` one WRENCH_SETPOINT, the constant wrench ``tau`` or eq. (24) with
    the paper's gains toward ``hold`` on the latest ODOMETRY. STATUSTEXTs stay in the link's
    queue for the test (:func:`texts`)."""
    law = WrenchLaw.constant(tau) if hold is None else WrenchLaw.hold(hold)
    plan = FlightPlan(law, period_s, drain_texts=False)
    return GroundStation(gcs).flight(plan).start()


def texts(gcs: MavlinkGcsLink, into: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """Append the STATUSTEXTs received since the last call to ``into`` as (receive stamp ns,
    text); return ``into``."""
    into.extend((item.stamp_ns, item.value.text) for item in gcs.drain_statustexts())
    return into
