"""What standard clients expect of the components, against bare pymavlink on loopback:
parameter encoding and float32 limits, COMMAND_ACK for every command, AUTOPILOT_VERSION,
ESC_STATUS / ESC_INFO, the vessel's position messages, fault-injection defaults."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import numpy as np
import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.allocator_params import allocator_param_specs
from bridges.mavlink.commands import MavResult
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.geodesy import GeodeticOrigin
from bridges.mavlink.params import ParamServer, ParamSpec, ParamType, decode_set_value
from bridges.mavlink.vessel import (
    FAILURE_UNIT_SYSTEM_MOTOR,
    FailureType,
    MavlinkVesselLink,
    decode_inject_failure,
)
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.messages import FaultKind, Odometry
from tests.support.mavlink_peers import (
    DIALECT,
    RawPeer,
    free_udp_ports,
    param_number,
    wait_until,
)

pytestmark = [pytest.mark.timeout(60), pytest.mark.usefixtures("no_leaked_threads")]


def _bits(i: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", i))[0])


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


@pytest.fixture
def allocator() -> Iterator[tuple[MavlinkAllocatorLink, RawPeer]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    specs = allocator_param_specs(CoreConfig(), 0.5, 1.0, 0.5, 20.0, 0.1)
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkAllocatorLink(config, endpoint, specs) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs


def test_ftc_dead_thr_099_is_accepted_though_float32_rounds_it_up(allocator) -> None:
    link, gcs = allocator
    assert _f32(0.99) > 0.99  # why the old float64 comparison refused it
    gcs.mav.param_set_send(*ALLOCATOR_IDS, b"FTC_DEAD_THR", 0.99, DIALECT.MAV_PARAM_TYPE_REAL32)
    echo = gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "FTC_DEAD_THR")
    assert link.params.get("FTC_DEAD_THR") == 0.99  # snapped to the limit, not 0.99000001
    assert echo.param_value == pytest.approx(0.99, abs=1e-7)
    gcs.mav.param_set_send(*ALLOCATOR_IDS, b"FTC_DEAD_THR", 0.991, DIALECT.MAV_PARAM_TYPE_REAL32)
    assert gcs.wait_for("STATUSTEXT", lambda m: m.text.startswith("FTC_DEAD_THR not set"))
    assert link.params.get("FTC_DEAD_THR") == 0.99


def test_integer_sets_work_bytewise_and_c_cast(allocator) -> None:
    link, gcs = allocator
    int32 = DIALECT.MAV_PARAM_TYPE_INT32
    gcs.mav.param_set_send(*ALLOCATOR_IDS, b"FTC_MODE", _bits(1), int32)  # QGC / MAVSDK
    echo = gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "FTC_MODE")
    assert link.params.get("FTC_MODE") == 1 and param_number(echo) == 1
    gcs.mav.param_set_send(*ALLOCATOR_IDS, b"FTC_MODE", 3.0, int32)  # MAVProxy's C-cast
    assert wait_until(lambda: link.params.get("FTC_MODE") == 3)


@pytest.mark.parametrize("value", [0, 1, 3, 10_000, 2**24, -5])
def test_bytewise_and_c_cast_readings_never_overlap(value) -> None:
    spec = ParamSpec("P", 0, ParamType.INT, -(2**24), 2**24)
    assert decode_set_value(spec, _bits(value)) == value
    assert decode_set_value(spec, float(value)) == value
    real = ParamSpec("R", 0.0)
    assert decode_set_value(real, 2.5) == 2.5


def test_every_command_to_the_allocator_is_acknowledged(allocator) -> None:
    link, gcs = allocator
    for command in (DIALECT.MAV_CMD_DO_SET_MODE, DIALECT.MAV_CMD_COMPONENT_ARM_DISARM, 31_000):
        gcs.mav.command_long_send(*ALLOCATOR_IDS, command, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = gcs.wait_for("COMMAND_ACK", lambda m, c=command: m.command == c)
        assert ack is not None and ack.result == MavResult.UNSUPPORTED
    gcs.mav.command_int_send(*ALLOCATOR_IDS, 0, DIALECT.MAV_CMD_DO_REPOSITION, 0, 0, *[0] * 7)
    assert gcs.wait_for("COMMAND_ACK", lambda m: m.command == DIALECT.MAV_CMD_DO_REPOSITION)
    gcs.mav.command_long_send(*ALLOCATOR_IDS, 512, 0, 148, 0, 0, 0, 0, 0, 0)
    ack = gcs.wait_for("COMMAND_ACK", lambda m: m.command == 512)
    version = gcs.wait_for("AUTOPILOT_VERSION")
    assert ack.result == MavResult.ACCEPTED and version is not None
    caps = version.capabilities
    assert caps & DIALECT.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert caps & DIALECT.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert not caps & DIALECT.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    acks = len(gcs.of_type("COMMAND_ACK"))
    gcs.mav.command_long_send(ALLOCATOR_IDS[0], 0, 31_000, 0, *[0] * 7)  # a broadcast
    gcs.pump(0.3)
    assert len(gcs.of_type("COMMAND_ACK")) == acks  # not ours to refuse: no ACK storm
    assert wait_until(lambda: link.commands.acked == 5)


def test_esc_telemetry_goes_out_as_esc_status_and_esc_info(allocator) -> None:
    link, gcs = allocator
    rpm = [1200.4, -800.0, math.nan, 0.0]
    current = [0.5, 0.4, math.nan, 0.05]
    volts = [12.0, 11.5, math.nan, 12.0]
    assert link.send_esc_status(rpm, current, [0.01, 0.02, math.inf, 0.1], [0, 0, 1, 0], volts)
    status = gcs.wait_for("ESC_STATUS")
    info = gcs.wait_for("ESC_INFO")
    assert status.index == 0 and status.rpm == [1200, -800, 0, 0]
    np.testing.assert_equal(status.current, [_f32(0.5), _f32(0.4), math.nan, _f32(0.05)])
    np.testing.assert_equal(status.voltage, [12.0, 11.5, math.nan, 12.0])  # issue 22: was NaN
    # ESC_CONNECTION_TYPE_CAN is 4 (common.xml; 5 is DShot)
    assert (info.count, info.connection_type, info.info) == (4, 4, 0b1011)
    assert info.failure_flags == [0, 0, 64, 0] and info.temperature == [32767] * 4
    link.send_esc_status(rpm, current, [0.01] * 4, [0] * 4)
    gcs.pump(0.2)
    assert len(gcs.of_type("ESC_STATUS")) == 2 and len(gcs.of_type("ESC_INFO")) == 1  # 1 Hz


@pytest.fixture
def vessel() -> Iterator[tuple[MavlinkVesselLink, RawPeer]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, VESSEL_IDS, (gcs_port,))
    origin = GeodeticOrigin(63.4305, 10.3951, 2.0)  # Trondheim harbour
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkVesselLink(4, endpoint, geodetic_origin=origin) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs


def test_the_vessel_is_drawn_from_standard_position_messages(vessel) -> None:
    link, gcs = vessel
    psi = math.radians(-90.0)  # heading west
    assert link.send_odometry(Odometry.checked([111.2, -50.0, psi], [2.0, 0.5, 0.1], 1.0))
    glob = gcs.wait_for("GLOBAL_POSITION_INT")
    att = gcs.wait_for("ATTITUDE")
    local = gcs.wait_for("LOCAL_POSITION_NED")
    assert glob.lat == pytest.approx((63.4305 + 111.2 / 111_320.0 * 0.9982) * 1e7, abs=300)
    assert glob.lon == pytest.approx((10.3951 - 50.0 / (111_320.0 * 0.4477)) * 1e7, abs=300)
    assert (glob.alt, glob.hdg) == (2000, 27000)
    # body (2.0 ahead, 0.5 to starboard) heading west: 0.5 m/s north, 2 m/s west
    assert (glob.vx, glob.vy) == (50, -200)
    assert att.yaw == pytest.approx(psi, abs=1e-6) and att.yawspeed == pytest.approx(0.1)
    np.testing.assert_allclose(
        [local.x, local.y, local.vx, local.vy], [111.2, -50, 0.5, -2], atol=1e-4
    )


def test_geodesy_flat_earth_matches_known_distances() -> None:
    origin = GeodeticOrigin(0.0, 0.0)
    lat, lon = origin.to_geodetic(110_574.0, 111_320.0)  # one degree each at the equator
    assert (lat, lon) == (pytest.approx(1.0, abs=1e-4), pytest.approx(1.0, abs=1e-4))
    assert GeodeticOrigin.from_value(None) is None
    assert GeodeticOrigin.from_value([10, 20]) == GeodeticOrigin(10.0, 20.0, 0.0)
    for bad in ([95.0, 0.0], [0.0], [math.nan, 0.0], "63,10"):
        with pytest.raises(LinkConfigError, match="geodetic_origin"):
            GeodeticOrigin.from_value(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [0.0, math.nan])
@pytest.mark.parametrize(
    "failure", [FailureType.STUCK, FailureType.WRONG, FailureType.SLOW], ids=lambda f: f.name
)
def test_param4_zero_or_nan_means_the_default(failure, value) -> None:
    # MAVProxy's "long INJECT_FAILURE 101 4 1" sends param4 = 0: a 0 N bias would be a no-op
    # and STUCK at 0 N the same as OFF, so 0 is the simulator's default, as NaN is.
    decision = decode_inject_failure(FAILURE_UNIT_SYSTEM_MOTOR, failure, 1, value, 4)
    assert decision.result is MavResult.ACCEPTED
    assert math.isnan(decision.faults[0].value)
    assert (
        decision.faults[0].kind
        is {
            FailureType.STUCK: FaultKind.STUCK,
            FailureType.WRONG: FaultKind.BIAS,
            FailureType.SLOW: FaultKind.WEAK,
        }[failure]
    )


def test_a_given_param4_is_kept() -> None:
    decision = decode_inject_failure(FAILURE_UNIT_SYSTEM_MOTOR, FailureType.WRONG, 2, -0.05, 4)
    assert decision.faults[0].value == -0.05


def test_param_server_snaps_only_within_float32_rounding() -> None:
    server = ParamServer([ParamSpec("X", 0.5, min=0.01, max=0.99)])
    assert server.set("X", _f32(0.99)).value == 0.99
    assert server.set("X", _f32(0.01)).value == 0.01
    assert not server.set("X", 0.9901).accepted
