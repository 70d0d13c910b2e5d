"""Contract: MavlinkVesselLink against bare pymavlink on loopback UDP, plus the
MAV_CMD_INJECT_FAILURE -> FaultInjection mapping."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from bridges.mavlink.codec import yaw_from_quaternion
from bridges.mavlink.config import VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.vessel import (
    FAILURE_ENABLE_PARAM,
    FAILURE_UNIT_SYSTEM_MOTOR,
    MAV_CMD_INJECT_FAILURE,
    FailureType,
    MavlinkVesselLink,
    MavResult,
    decode_inject_failure,
)
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry
from tests.support.mavlink_peers import (
    DIALECT,
    RawPeer,
    free_udp_ports,
)

pytestmark = [pytest.mark.timeout(30), pytest.mark.usefixtures("no_leaked_threads")]

SYS, COMP = VESSEL_IDS
M = 4
NAN = math.nan


@pytest.mark.parametrize(
    ("ftype", "instance", "value", "expected"),
    [
        (FailureType.OK, 1, NAN, [FaultInjection(0, FaultKind.OK)]),
        (FailureType.OFF, 4, NAN, [FaultInjection(3, FaultKind.OFF)]),
        (FailureType.STUCK, 2, 35.0, [FaultInjection(1, FaultKind.STUCK, 35.0)]),
        (FailureType.WRONG, 3, -12.0, [FaultInjection(2, FaultKind.BIAS, -12.0)]),
        (FailureType.SLOW, 1, 0.25, [FaultInjection(0, FaultKind.WEAK, 0.25)]),
        (FailureType.OFF, 0, NAN, [FaultInjection(i, FaultKind.OFF) for i in range(M)]),
    ],
)
def test_inject_failure_mapping(ftype, instance, value, expected) -> None:
    decision = decode_inject_failure(FAILURE_UNIT_SYSTEM_MOTOR, ftype, instance, value, M)
    assert decision.result is MavResult.ACCEPTED
    assert len(decision.faults) == len(expected)
    for got, want in zip(decision.faults, expected, strict=True):
        assert (got.index, got.kind) == (want.index, want.kind)
        assert got.value == want.value or (math.isnan(got.value) and math.isnan(want.value))


@pytest.mark.parametrize(
    ("unit", "ftype", "instance", "value", "result"),
    [
        (100, FailureType.OFF, 1, NAN, MavResult.UNSUPPORTED),  # battery
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.GARBAGE, 1, NAN, MavResult.UNSUPPORTED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.DELAYED, 1, NAN, MavResult.UNSUPPORTED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.INTERMITTENT, 1, NAN, MavResult.UNSUPPORTED),
        (FAILURE_UNIT_SYSTEM_MOTOR, 99, 1, NAN, MavResult.UNSUPPORTED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.OFF, M + 1, NAN, MavResult.DENIED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.OFF, 1.5, NAN, MavResult.DENIED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.SLOW, 1, 1.5, MavResult.DENIED),
        (FAILURE_UNIT_SYSTEM_MOTOR, FailureType.WRONG, 1, math.inf, MavResult.DENIED),
    ],
)
def test_inject_failure_refusals(unit, ftype, instance, value, result) -> None:
    decision = decode_inject_failure(unit, ftype, instance, value, M)
    assert decision.result is result
    assert decision.faults == ()
    assert decision.reason


@pytest.fixture
def pair() -> Iterator[tuple[MavlinkVesselLink, RawPeer]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, VESSEL_IDS, (gcs_port,))
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkVesselLink(M, endpoint, heartbeat_period_s=0.2) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs


def _inject(gcs: RawPeer, ftype: int, instance: float, value: float = NAN, command: int = 0):
    since = len(gcs.received)
    cmd = command or MAV_CMD_INJECT_FAILURE
    gcs.mav.command_long_send(
        SYS, COMP, cmd, 0, FAILURE_UNIT_SYSTEM_MOTOR, ftype, instance, value, 0, 0, 0
    )
    return gcs.wait_for("COMMAND_ACK", lambda m: m.command == cmd, since=since)


def _enable(gcs: RawPeer) -> None:
    gcs.mav.param_set_send(SYS, COMP, FAILURE_ENABLE_PARAM.encode(), 1, 6)  # C-cast 1: accepted
    # answered C-cast to a C-cast set (as MAVProxy checks it; issue 22, item 6)
    assert gcs.wait_for("PARAM_VALUE", lambda m: m.param_value == 1.0)


def test_heartbeat_identifies_a_surface_vessel(pair) -> None:
    _, gcs = pair
    beat = gcs.wait_for("HEARTBEAT")
    assert (beat.get_srcSystem(), beat.get_srcComponent()) == VESSEL_IDS
    assert beat.type == DIALECT.MAV_TYPE_SURFACE_BOAT
    assert beat.system_status == DIALECT.MAV_STATE_ACTIVE


def test_odometry_goes_out_in_mavlink_frames(pair) -> None:
    link, gcs = pair
    psi = -2.4
    assert link.send_odometry(Odometry.checked([5.0, -7.0, psi], [0.8, 0.1, -0.02], 12.25))
    msg = gcs.wait_for("ODOMETRY")
    assert (msg.frame_id, msg.child_frame_id) == (
        DIALECT.MAV_FRAME_LOCAL_NED,
        DIALECT.MAV_FRAME_BODY_FRD,
    )
    assert msg.time_usec == 12_250_000
    assert yaw_from_quaternion(msg.q) == pytest.approx(psi, abs=1e-6)
    np.testing.assert_allclose([msg.x, msg.y, msg.vx, msg.vy, msg.yawspeed],
                               [5.0, -7.0, 0.8, 0.1, -0.02], atol=1e-6)  # fmt: skip
    assert math.isnan(msg.pose_covariance[0])


def test_fault_injection_is_denied_while_disabled(pair) -> None:
    link, gcs = pair
    assert link.params.get(FAILURE_ENABLE_PARAM) == 0  # off by default
    ack = _inject(gcs, FailureType.OFF, 2)
    assert ack.result == MavResult.DENIED
    assert (ack.target_system, ack.target_component) == (255, 190)
    assert gcs.wait_for("STATUSTEXT", lambda m: FAILURE_ENABLE_PARAM in m.text)
    assert link.drain_faults() == []


def test_fault_injection_enabled_by_param_reaches_the_queue(pair) -> None:
    link, gcs = pair
    _enable(gcs)
    assert _inject(gcs, FailureType.SLOW, 3, 0.4).result == MavResult.ACCEPTED
    assert _inject(gcs, FailureType.OK, 0).result == MavResult.ACCEPTED
    faults = [s.value for s in link.drain_faults()]
    assert (faults[0].index, faults[0].kind) == (2, FaultKind.WEAK)
    assert faults[0].value == pytest.approx(0.4)  # float32 on the wire
    assert [(f.index, f.kind) for f in faults[1:]] == [(i, FaultKind.OK) for i in range(M)]


def test_unsupported_failure_and_unknown_command_are_acked_unsupported(pair) -> None:
    link, gcs = pair
    _enable(gcs)
    assert _inject(gcs, FailureType.GARBAGE, 1).result == MavResult.UNSUPPORTED
    unknown = _inject(gcs, 0, 0, command=DIALECT.MAV_CMD_DO_SET_SERVO)
    assert unknown.result == MavResult.UNSUPPORTED
    assert link.drain_faults() == []


def test_full_fault_queue_is_temporarily_rejected() -> None:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, VESSEL_IDS, (gcs_port,))
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkVesselLink(M, endpoint, fault_queue_size=5) as link:
            assert gcs.wait_for("HEARTBEAT")
            _enable(gcs)
            assert _inject(gcs, FailureType.OFF, 0).result == MavResult.ACCEPTED  # 4 queued
            assert _inject(gcs, FailureType.OFF, 0).result == MavResult.TEMPORARILY_REJECTED
            assert len(link.drain_faults()) == M
