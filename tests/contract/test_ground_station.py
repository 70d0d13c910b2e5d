"""Contract: the ground-station driver (ftcap_hil.runtime.ground_station) against the product's
own allocator and vessel MAVLink links, in-process on loopback UDP: start-up, a flight with
an injection, the loop's records, the errors and their exit codes, the wind-down."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.codec import SystemStatus
from bridges.mavlink.config import ALLOCATOR_IDS, GCS_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.gcs import MavlinkGcsLink
from bridges.mavlink.params import ParamSpec, ParamType
from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, MavlinkVesselLink
from ftcap_hil.core.errors import ExitCode
from ftcap_hil.core.faults import Injection
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.runtime.ground_station import (
    FlightPlan,
    GroundStation,
    Interrupted,
    LinkLost,
    NoAnswer,
    Refused,
    WrenchLaw,
)
from tests.support.mavlink_peers import free_udp_ports, wait_until

pytestmark = [pytest.mark.timeout(60), pytest.mark.usefixtures("no_leaked_threads")]

POSE = ([0.5, -0.2, 0.1], [0.05, 0.0, 0.0])  # eta (m, m, rad), nu (m/s, m/s, rad/s)


class Peers:
    """The allocator's and the vessel's links; the vessel streams ODOMETRY until stopped."""

    def __init__(self, allocator: MavlinkAllocatorLink, vessel: MavlinkVesselLink) -> None:
        self.allocator, self.vessel = allocator, vessel
        self.streaming = threading.Event()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._stream, daemon=True)
        self._thread.start()

    def _stream(self) -> None:
        while not self._done.wait(0.05):
            if self.streaming.is_set():
                self.vessel.send_odometry(Odometry.checked(*POSE, 1.0))

    def close(self) -> None:
        self._done.set()
        self._thread.join(2.0)


@pytest.fixture
def rig() -> Iterator[tuple[GroundStation, Peers]]:
    gcs_port, allocator_port, vessel_port = free_udp_ports(3)
    gcs_ep = MavlinkEndpoint.inbox(gcs_port, GCS_IDS, (allocator_port, vessel_port))
    alloc_ep = MavlinkEndpoint.inbox(allocator_port, ALLOCATOR_IDS, (gcs_port,))
    vessel_ep = MavlinkEndpoint.inbox(vessel_port, VESSEL_IDS, (allocator_port, gcs_port))
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(10.0, 10.0, 10.0))
    mode = ParamSpec("FTC_MODE", 2, ParamType.INT, 0, 2)  # 3 (ftcap-literal) is refused
    with (
        MavlinkGcsLink(gcs_ep, heartbeat_period_s=0.2) as gcs,
        MavlinkAllocatorLink(config, alloc_ep, [mode], heartbeat_period_s=0.2) as allocator,
        MavlinkVesselLink(4, vessel_ep, heartbeat_period_s=0.2) as vessel,
    ):
        peers = Peers(allocator, vessel)
        try:
            yield GroundStation(gcs), peers
        finally:
            peers.close()


def _ready(peers: Peers) -> None:
    peers.allocator.set_system_status(SystemStatus.STANDBY)
    peers.streaming.set()


def test_connect_enables_failures_sets_the_mode_and_starts_at_the_first_odometry(rig) -> None:
    station, peers = rig
    _ready(peers)
    conn = station.connect(5.0, enable_failures=True, mode=Mode.CAP)
    assert conn.failure_enable == 1.0 and conn.mode == "cap"
    assert peers.vessel.params.values() == {FAILURE_ENABLE_PARAM: 1.0}
    assert peers.allocator.params.get("FTC_MODE") == 1
    first = station.link.odometry.latest()
    # mission time 0: the latest ODOMETRY once the start-up is done (the vessel streams on)
    assert first is not None and conn.heartbeats_ns <= conn.ready_ns
    assert conn.t0_ns <= first.stamp_ns


def test_connect_errors_carry_their_exit_codes(rig) -> None:
    station, peers = rig
    peers.streaming.set()  # but the allocator still says BOOT
    with pytest.raises(NoAnswer, match="MAV_STATE_BOOT") as boot:
        station.connect(1.0)
    assert boot.value.exit_code == ExitCode.NO_ANSWER == 3
    peers.allocator.set_system_status(SystemStatus.STANDBY)
    with pytest.raises(Refused, match="FTC_MODE = 3") as refused:
        station.connect(2.0, mode=Mode.FTCAP_LITERAL)
    assert refused.value.exit_code == ExitCode.REFUSED == 5
    station.request_exit()
    with pytest.raises(Interrupted) as stopped:
        station.connect(2.0)
    assert stopped.value.exit_code == ExitCode.INTERRUPTED == 130


def test_a_flight_sends_eq24_injects_and_keeps_what_it_heard(rig) -> None:
    station, peers = rig
    _ready(peers)
    conn = station.connect(5.0, enable_failures=True)
    peers.allocator.send_statustext("thruster 2 fault detected")
    status = AllocatorStatus(delta_hat=(1.0, 0.5, 1.0, 1.0), f_hat=(0.0,) * 4)
    peers.allocator.send_status(status)
    plan = FlightPlan(
        WrenchLaw.hold([0.0, 0.0, 0.0]),
        0.1,
        duration_s=1.0,
        injections=(Injection(0.3, 1, FaultKind.WEAK, 0.5),),
        odometry_timeout_s=1.0,
        keep_statuses=True,
    )
    flight = station.flight(plan, conn.t0_ns)
    flight.run()
    assert 9 <= flight.cycles + flight.overruns <= 11, (flight.cycles, flight.overruns)
    assert flight.sent == flight.cycles and flight.send_failures == 0
    sent = peers.allocator.setpoint.latest()
    want = [-0.26313548, 0.11761354, -0.04725]  # eq. (24), kp 0.75, k_eta 0.63, at POSE
    assert sent is not None
    np.testing.assert_allclose(sent.value.tau, want, rtol=1e-5)  # float32 on the wire
    assert flight.max_position_error_m == pytest.approx(math.hypot(0.5, 0.2), rel=1e-5)
    assert [(o.injection.thruster, o.result) for o in flight.outcomes] == [(1, "ACCEPTED")]
    assert 0.3 <= flight.outcomes[0].sent_at_s < 1.0
    assert [s.value for s in peers.vessel.drain_faults()] == [
        FaultInjection(1, FaultKind.WEAK, 0.5)
    ]
    assert "thruster 2 fault detected" in [t.value.text for t in flight.texts]
    assert [s.value.delta_hat for s in flight.statuses] == [status.delta_hat]


def test_a_silent_vessel_ends_the_flight_with_link_lost(rig) -> None:
    station, peers = rig
    _ready(peers)
    conn = station.connect(5.0)
    peers.streaming.clear()
    law = WrenchLaw.hold([0.0, 0.0, 0.0])
    plan = FlightPlan(law, 0.05, duration_s=10.0, odometry_timeout_s=0.3)
    flight = station.flight(plan, conn.t0_ns)
    with pytest.raises(LinkLost, match="no ODOMETRY") as lost:
        flight.run()
    assert lost.value.exit_code == ExitCode.LINK_LOST == 4
    assert flight.cycles < 20  # 10 s planned: it stopped at the silence


def test_a_background_flight_streams_a_constant_wrench_and_winds_down(rig) -> None:
    station, peers = rig
    # no ODOMETRY and no start-up: a constant wrench needs neither
    with station.flight(FlightPlan(WrenchLaw.constant([0.1, 0.0, 0.02]), 0.05)).start() as loop:
        assert wait_until(lambda: loop.sent >= 5, 5.0)
        got = peers.allocator.setpoint.latest()
        assert got is not None
        np.testing.assert_allclose(got.value.tau, [0.1, 0.0, 0.02], rtol=1e-6)
    sent = loop.sent
    assert station.link.set_param(VESSEL_IDS, FAILURE_ENABLE_PARAM, 1) == 1.0
    assert station.wind_down(clear_faults=True) is not None
    assert wait_until(lambda: not peers.allocator.setpoint.latest().value.tau.any(), 2.0)
    cleared = [(s.value.index, s.value.kind) for s in peers.vessel.drain_faults()]
    assert cleared == [(i, FaultKind.OK) for i in range(4)]  # MAVLink instance 0: every one
    assert loop.sent == sent  # stopped when the with block ended
