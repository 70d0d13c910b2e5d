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

Every process is started through a :class:`Rig` (its
:class:`~ftcap_hil.runtime.processes.Supervisor`) and killed by PID at its teardown.
"""

from __future__ import annotations

import csv
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from bridges.can_io.adapters import CanEscStatusSource
from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.codec import CanFrame, DataType, RawCommandMsg
from bridges.can_io.hub_bus import CanHubBus
from bridges.mavlink.config import ALLOCATOR_IDS, GCS_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.gcs import MavlinkGcsLink
from bridges.zenoh_io.link import ZenohGcsLink, make_config
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import Odometry
from ftcap_hil.runtime.ground_station import Flight, FlightPlan, GroundStation, WrenchLaw, state_of
from ftcap_hil.runtime.processes import (
    Child,
    Supervisor,
    free_port,
    ftcap_argv,
    start_can_hub,
)

ALLOCATOR_NODE = 10
ESC_IDS = (20, 21, 22, 23)
START_TIMEOUT_S = 40.0  # a cold start on a loaded 2-core machine (zenoh router, mavgen cache)
RAW_MAX = 8191
U_LIMIT_N = 0.1  # thruster amplitude limit of the shipped vessel files: raw RAW_MAX


def record_raw(row: dict[str, str]) -> tuple[int, ...]:
    """The command in a sim ``--record`` row, in esc.RawCommand counts (as on the bus)."""
    return tuple(round(float(row[f"u_T{i}_N"]) * RAW_MAX / U_LIMIT_N) for i in range(1, 5))


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
    closers: list[Callable[[], None]] = field(default_factory=list)
    supervisor: Supervisor = field(init=False)

    def __post_init__(self) -> None:
        self.supervisor = Supervisor(self.tmp)

    @property
    def procs(self) -> dict[str, Child]:
        """The rig's processes by name (a name started twice gets a suffix)."""
        return self.supervisor.by_name()

    @property
    def record(self) -> Path:
        return self.tmp / "record.csv"

    @property
    def command_log(self) -> Path:
        return self.tmp / "commands.csv"

    def _spawn(self, name: str, args: list[str]) -> Child:
        return self.supervisor.start(name, ftcap_argv(*args), cwd=self.tmp)

    def _start(self, name: str, argv: list[str]) -> Child:
        return self.supervisor.start(name, argv, cwd=self.tmp)

    def start_hub(self) -> None:
        _, self.hub_channel = start_can_hub(self._start, name="hub", timeout_s=START_TIMEOUT_S)

    def start_allocator(self, sets: Sequence[str] = (), verbose: bool = False) -> Child:
        """``ftcap-hil allocator`` on this rig's ports (+ overrides); waits until it runs."""
        base = [
            f'can.channel="{self.hub_channel}"',
            f'mavlink.connection="udpin:127.0.0.1:{self.alloc_port}"',
            f'mavlink.peers=["127.0.0.1:{self.gcs_port}"]',
            f'mavlink.telemetry_from=["127.0.0.1:{self.vessel_port}"]',  # the vessel's inbox
            f"zenoh.overrides=['listen/endpoints:[\"tcp/127.0.0.1:{self.zenoh_port}\"]']",
        ]
        args = [*(["-vv"] if verbose else []), "allocator"]
        args += ["--command-log", str(self.command_log)]
        for s in [*base, *sets]:
            args += ["--set", s]
        proc = self._spawn("allocator", args)
        assert proc.wait_for(r"allocator: .* Hz, \d+ thrusters", START_TIMEOUT_S), proc.output()
        return proc

    def start_sim(self, sets: Sequence[str] = (), args: Sequence[str] = ()) -> Child:
        """``ftcap-hil sim --record`` on this rig's ports (+ overrides); waits until it runs."""
        base = [
            f"can.channel={self.hub_channel}",
            f"mavlink.connection=udpin:127.0.0.1:{self.vessel_port}",
            f'mavlink.peers=["127.0.0.1:{self.alloc_port}", "127.0.0.1:{self.gcs_port}"]',
            f"zenoh.connect=tcp/127.0.0.1:{self.zenoh_port}",
        ]
        cmd = ["sim", "--record", str(self.record), *args]
        for s in [*base, *sets]:
            cmd += ["--set", s]
        proc = self._spawn("sim", cmd)
        assert proc.wait_for("simulated vessel running", START_TIMEOUT_S), proc.output()
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
            f"===== {n} (pid {p.pid}) =====\n{p.output()[-tail:]}" for n, p in self.procs.items()
        )

    def teardown(self) -> None:
        """Close the test's links, then SIGKILL every child by PID (whatever the links did)."""
        try:
            for close in reversed(self.closers):
                close()
        finally:
            self.closers.clear()
            self.supervisor.kill_all()


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
