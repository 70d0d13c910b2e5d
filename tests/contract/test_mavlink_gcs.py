"""Contract: MavlinkGcsLink against bare pymavlink, and the three links in the documented
topology (each binds one inbox, sends to its peers' inboxes) on loopback UDP."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.codec import Severity, SystemStatus, quaternion_from_yaw
from bridges.mavlink.config import ALLOCATOR_IDS, GCS_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.gcs import MavlinkGcsLink
from bridges.mavlink.params import ParamSpec
from bridges.mavlink.vessel import (
    FAILURE_ENABLE_PARAM,
    FAILURE_UNIT_SYSTEM_MOTOR,
    MAV_CMD_INJECT_FAILURE,
    MavlinkVesselLink,
    MavResult,
)
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry, ThrusterCommand
from ftcap_hil.core.status import AllocatorStatus
from tests.support.mavlink_peers import (
    DIALECT,
    RawPeer,
    free_udp_ports,
    wait_until,
)

pytestmark = [pytest.mark.timeout(30), pytest.mark.usefixtures("no_leaked_threads")]


@pytest.fixture
def gcs_and_vessel_peer() -> Iterator[tuple[MavlinkGcsLink, RawPeer]]:
    gcs_port, vessel_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(gcs_port, GCS_IDS, (vessel_port,))
    with RawPeer(f"udpin:127.0.0.1:{vessel_port}", VESSEL_IDS) as vessel:
        with MavlinkGcsLink(endpoint, heartbeat_period_s=0.2) as gcs:
            assert vessel.wait_for("HEARTBEAT") is not None  # the GCS spoke first
            yield gcs, vessel


def test_gcs_sends_inject_failure_as_mavlink_defines_it(gcs_and_vessel_peer) -> None:
    gcs, vessel = gcs_and_vessel_peer
    result: list[MavResult | None] = []

    caller = threading.Thread(
        target=lambda: result.append(gcs.inject_failure(FaultKind.WEAK, 2, 0.5, timeout_s=2.0))
    )
    caller.start()
    cmd = vessel.wait_for("COMMAND_LONG")
    assert (cmd.target_system, cmd.target_component, cmd.command) == (
        *VESSEL_IDS,
        MAV_CMD_INJECT_FAILURE,
    )
    assert (cmd.param1, cmd.param2, cmd.param3, cmd.param4) == (
        FAILURE_UNIT_SYSTEM_MOTOR,
        DIALECT.FAILURE_TYPE_SLOW,
        3.0,  # 0-based thruster 2 is MAVLink instance 3
        0.5,
    )
    vessel.mav.command_ack_send(MAV_CMD_INJECT_FAILURE, MavResult.ACCEPTED, 0, 0, *GCS_IDS)
    caller.join(5.0)
    assert result == [MavResult.ACCEPTED]


def test_gcs_inject_failure_times_out_without_ack(gcs_and_vessel_peer) -> None:
    gcs, vessel = gcs_and_vessel_peer
    assert gcs.inject_failure(FaultKind.OFF, None, timeout_s=0.1, attempts=2) is None
    assert vessel.wait_for("COMMAND_LONG", lambda m: m.confirmation == 1)
    sent = vessel.of_type("COMMAND_LONG")
    assert [m.confirmation for m in sent] == [0, 1]  # a retry bumps confirmation
    assert sent[0].param3 == 0.0  # None = all thrusters = instance 0


def test_gcs_receives_vessel_odometry_and_statustext(gcs_and_vessel_peer) -> None:
    gcs, vessel = gcs_and_vessel_peer
    vessel.mav.odometry_send(
        2_000_000, DIALECT.MAV_FRAME_LOCAL_NED, DIALECT.MAV_FRAME_BODY_FRD,
        1.0, 2.0, 0.0, quaternion_from_yaw(0.7), 0.3, 0.0, 0.0, 0.0, 0.0, 0.1,
        [math.nan] * 21, [math.nan] * 21,
    )  # fmt: skip
    vessel.mav.statustext_send(DIALECT.MAV_SEVERITY_ERROR, b"thruster 2 overheating")
    assert wait_until(lambda: gcs.odometry.latest() is not None)
    np.testing.assert_allclose(gcs.odometry.latest().value.eta, [1.0, 2.0, 0.7], atol=1e-6)
    assert wait_until(lambda: not gcs.statustexts.empty())
    text = gcs.drain_statustexts()[0].value
    assert (text.system, text.component, text.severity) == (*VESSEL_IDS, Severity.ERROR)
    assert text.text == "thruster 2 overheating"


@pytest.fixture
def topology() -> Iterator[tuple[MavlinkGcsLink, MavlinkAllocatorLink, MavlinkVesselLink]]:
    gcs_port, allocator_port, vessel_port = free_udp_ports(3)
    gcs_ep = MavlinkEndpoint.inbox(gcs_port, GCS_IDS, (allocator_port, vessel_port))
    alloc_ep = MavlinkEndpoint.inbox(
        allocator_port, ALLOCATOR_IDS, (gcs_port,), relay=(vessel_port,)
    )  # the vessel's inbox: the one address ODOMETRY is accepted from
    vessel_ep = MavlinkEndpoint.inbox(vessel_port, VESSEL_IDS, (allocator_port, gcs_port))
    config = AllocatorLinkConfig(n_thrusters=3, max_wrench=(100.0, 50.0, 80.0))
    params = [ParamSpec("ALLOC_W_U", 1.0, min=0.0, max=10.0)]
    with (
        MavlinkGcsLink(gcs_ep) as gcs,
        MavlinkAllocatorLink(config, alloc_ep, params) as allocator,
        MavlinkVesselLink(3, vessel_ep) as vessel,
    ):
        assert gcs.wait_heartbeat(ALLOCATOR_IDS) and gcs.wait_heartbeat(VESSEL_IDS)
        yield gcs, allocator, vessel


def test_topology_gcs_waits_for_the_allocator_to_leave_boot(topology) -> None:
    gcs, allocator, vessel = topology
    assert gcs.wait_ready(VESSEL_IDS, 1.0)  # the vessel heartbeats ACTIVE from the start
    assert not gcs.wait_ready(ALLOCATOR_IDS, 1.5)  # a heartbeat, but BOOT: not ready
    assert gcs.heartbeat(ALLOCATOR_IDS).value.system_status == SystemStatus.BOOT
    allocator.set_system_status(SystemStatus.STANDBY)
    assert gcs.wait_ready(ALLOCATOR_IDS, 1.0)


def test_topology_setpoints_telemetry_and_status_flow(topology) -> None:
    gcs, allocator, vessel = topology
    assert gcs.send_wrench([30.0, -5.0, 12.0])
    assert gcs.send_manual(1000, 0, -500)
    assert vessel.send_odometry(Odometry.checked([3.0, 4.0, 0.2], [1.0, 0.0, 0.0], 1.0))
    assert wait_until(
        lambda: all(
            box.latest() is not None
            for box in (allocator.setpoint, allocator.manual, allocator.odometry, gcs.odometry)
        )
    )
    np.testing.assert_allclose(allocator.setpoint.latest().value.tau, [30.0, -5.0, 12.0])
    np.testing.assert_allclose(allocator.manual.latest().value.tau, [100.0, 0.0, -40.0])
    np.testing.assert_allclose(allocator.odometry.latest().value.eta, [3.0, 4.0, 0.2], atol=1e-6)
    allocator.send_thruster_commands(ThrusterCommand.checked([1.0, 2.0, 3.0]))
    allocator.send_status(
        AllocatorStatus(
            tau_demand=(30.0, -5.0, 12.0), unallocated=(0.0,) * 3, delta_hat=(1.0, 0.2, 1.0),
            f_hat=(0.0,) * 3, faulty=(False, True, False),
        )
    )  # fmt: skip
    assert wait_until(
        lambda: (
            gcs.thruster_commands.latest() is not None and gcs.allocator_status.latest() is not None
        )
    )
    np.testing.assert_allclose(gcs.thruster_commands.latest().value.u, [1.0, 2.0, 3.0])
    got = gcs.allocator_status.latest().value
    np.testing.assert_allclose(got.delta_hat, [1.0, 0.2, 1.0])
    assert got.faulty == (False, True, False) and got.fault_detected
    # The vessel's own telemetry never shows up as allocator status and vice versa.
    assert gcs.thruster_commands.malformed == gcs.allocator_status.malformed == 0


def test_topology_fault_injection_and_params(topology) -> None:
    gcs, allocator, vessel = topology
    assert gcs.inject_failure(FaultKind.OFF, 1) is MavResult.DENIED
    assert gcs.set_param(VESSEL_IDS, FAILURE_ENABLE_PARAM, 1) == 1.0
    assert gcs.inject_failure(FaultKind.BIAS, 0, -20.0) is MavResult.ACCEPTED
    assert [s.value for s in vessel.drain_faults()] == [FaultInjection(0, FaultKind.BIAS, -20.0)]
    assert gcs.fetch_params(ALLOCATOR_IDS) == {"ALLOC_W_U": 1.0}
    assert gcs.set_param(ALLOCATOR_IDS, "ALLOC_W_U", 3.0) == 3.0
    assert gcs.set_param(ALLOCATOR_IDS, "ALLOC_W_U", 30.0) == 3.0  # refused: unchanged
    assert allocator.params.get("ALLOC_W_U") == 3.0
    assert vessel.params.values() == {
        FAILURE_ENABLE_PARAM: 1.0
    }  # the allocator's PARAM_SETs left it alone
