"""Contract: MavlinkAllocatorLink against bare pymavlink on loopback UDP."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import numpy as np
import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.codec import StatusFlag, SystemStatus, quaternion_from_yaw, status_from_message
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.params import ParamSpec, ParamType
from ftcap_hil.core.messages import ThrusterCommand
from ftcap_hil.core.status import AllocatorStatus
from tests.support.mavlink_peers import (
    DIALECT,
    RawPeer,
    free_udp_ports,
    param_number,
    send_datagram,
    wait_until,
)

pytestmark = [pytest.mark.timeout(30), pytest.mark.usefixtures("no_leaked_threads")]

MAX_WRENCH = (100.0, 50.0, 200.0)
SYS, COMP = ALLOCATOR_IDS


def _params() -> list[ParamSpec]:
    def even(v: float) -> str | None:
        return None if int(v) % 2 == 0 else "must be even"

    return [
        ParamSpec("ALLOC_W_U", 1.0, min=0.0, max=10.0),
        ParamSpec("ALLOC_HORIZON", 4, ParamType.INT, 0, 100, settable_while_running=False),
        ParamSpec("ALLOC_EVEN", 2, ParamType.INT, 0, 10, validate=even),
    ]


@pytest.fixture
def pair() -> Iterator[tuple[MavlinkAllocatorLink, RawPeer, int]]:
    link_port, gcs_port, vessel_port = free_udp_ports(3)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,), relay=(vessel_port,))
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=MAX_WRENCH)
    # The GCS end binds and waits: it can only answer once the link has sent to it.
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkAllocatorLink(config, endpoint, _params(), heartbeat_period_s=0.2) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs, link_port


def _vessel_peer(link: MavlinkAllocatorLink, link_port: int) -> RawPeer:
    """The vessel, sending from its inbox (the link's one telemetry address)."""
    (inbox,) = link.telemetry_from
    peer = RawPeer(f"udpout:127.0.0.1:{link_port}", VESSEL_IDS)
    peer.conn.port.bind(inbox)
    return peer


def test_heartbeat_identifies_allocator_and_follows_status(pair) -> None:
    link, gcs, _ = pair
    beat = gcs.wait_for("HEARTBEAT")
    assert (beat.get_srcSystem(), beat.get_srcComponent()) == ALLOCATOR_IDS
    assert beat.type == DIALECT.MAV_TYPE_ONBOARD_CONTROLLER
    assert beat.system_status == SystemStatus.BOOT  # until the daemon's first cycle says
    link.set_system_status(SystemStatus.ACTIVE)
    assert gcs.wait_for("HEARTBEAT", lambda m: m.system_status == SystemStatus.ACTIVE)


def test_a_status_change_is_announced_at_once_not_a_heartbeat_period_later() -> None:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=MAX_WRENCH)
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkAllocatorLink(config, endpoint, heartbeat_period_s=60.0) as link:
            first = gcs.wait_for("HEARTBEAT")  # sent as the link starts
            assert first is not None and first.system_status == SystemStatus.BOOT
            link.set_system_status(SystemStatus.BOOT)  # no change: nothing extra is sent
            link.set_system_status(SystemStatus.STANDBY)
            since = len(gcs.received)
            beat = gcs.wait_for("HEARTBEAT", timeout_s=2.0, since=since)
            assert beat is not None and beat.system_status == SystemStatus.STANDBY
            assert len(gcs.of_type("HEARTBEAT")) == 2  # the periodic one is a minute away


def test_wrench_setpoint_arrives_in_mailbox(pair) -> None:
    link, gcs, _ = pair
    gcs.mav.wrench_setpoint_send(1, SYS, COMP, 12.5, -3.0, 40.0)
    assert wait_until(lambda: link.setpoint.latest() is not None)
    np.testing.assert_allclose(link.setpoint.latest().value.tau, [12.5, -3.0, 40.0])
    assert link.setpoint.age_s() < 5.0
    gcs.mav.wrench_setpoint_send(2, 0, 0, 1.0, 2.0, 3.0)  # broadcast is accepted too
    assert wait_until(lambda: link.setpoint.received == 2)


def test_wrench_setpoint_for_someone_else_is_ignored(pair) -> None:
    link, gcs, _ = pair
    gcs.mav.wrench_setpoint_send(1, SYS, COMP + 1, 1.0, 1.0, 1.0)
    gcs.mav.wrench_setpoint_send(1, SYS + 1, COMP, 1.0, 1.0, 1.0)
    assert wait_until(lambda: link.stats.ignored >= 2)
    assert link.setpoint.latest() is None


@pytest.mark.parametrize(
    "tau",
    [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, 10.0 * MAX_WRENCH[2] + 1.0)],
    ids=["nan", "inf", "beyond-limit"],
)
def test_invalid_wrench_is_counted_and_dropped(pair, tau) -> None:
    link, gcs, _ = pair
    gcs.mav.wrench_setpoint_send(1, SYS, COMP, *tau)
    assert wait_until(lambda: link.setpoint.malformed == 1)
    assert link.setpoint.latest() is None
    gcs.mav.wrench_setpoint_send(2, SYS, COMP, 1.0, 2.0, 3.0)  # the link still serves
    assert wait_until(lambda: link.setpoint.latest() is not None)


def test_garbage_bytes_are_counted_and_dropped(pair) -> None:
    link, gcs, link_port = pair
    rng = np.random.default_rng(7)
    for _ in range(20):
        send_datagram(link_port, rng.integers(0, 256, 60, dtype=np.uint8).tobytes())
    # A valid frame with a flipped payload byte fails its CRC.
    frame = bytearray(DIALECT.MAVLink_wrench_setpoint_message(1, SYS, COMP, 1, 2, 3).pack(gcs.mav))
    frame[12] ^= 0xFF
    send_datagram(link_port, bytes(frame))
    gcs.mav.wrench_setpoint_send(2, SYS, COMP, 4.0, 5.0, 6.0)
    assert wait_until(lambda: link.setpoint.latest() is not None)
    np.testing.assert_allclose(link.setpoint.latest().value.tau, [4.0, 5.0, 6.0])
    assert link.setpoint.received == 1
    assert link.stats.bad_data >= 1
    assert link.is_alive


def test_manual_control_is_scaled_by_max_wrench(pair) -> None:
    link, gcs, _ = pair
    gcs.mav.manual_control_send(SYS, 500, -1000, 0, 250, 0)
    assert wait_until(lambda: link.manual.latest() is not None)
    np.testing.assert_allclose(link.manual.latest().value.tau, [50.0, -50.0, 50.0])
    assert link.setpoint.latest() is None  # manual input has its own mailbox


def test_manual_control_invalid_axis_is_zero_and_out_of_range_is_dropped(pair) -> None:
    link, gcs, _ = pair
    gcs.mav.manual_control_send(SYS, 32767, 1000, 0, 32767, 0)
    assert wait_until(lambda: link.manual.latest() is not None)
    np.testing.assert_allclose(link.manual.latest().value.tau, [0.0, 50.0, 0.0])
    gcs.mav.manual_control_send(SYS, 1001, 0, 0, 0, 0)
    gcs.mav.manual_control_send(SYS + 1, 100, 0, 0, 0, 0)  # another system's joystick
    assert wait_until(lambda: link.manual.malformed == 1 and link.stats.ignored >= 1)
    assert link.manual.received == 1


def test_odometry_from_the_vessel_gives_eta_and_nu(pair) -> None:
    link, _, link_port = pair
    psi = 2.9  # near +pi: atan2 branch matters
    with _vessel_peer(link, link_port) as vessel:
        vessel.mav.odometry_send(
            3_500_000, DIALECT.MAV_FRAME_LOCAL_NED, DIALECT.MAV_FRAME_BODY_FRD,
            10.0, -4.0, 0.0, quaternion_from_yaw(psi), 1.5, -0.2, 0.0, 0.0, 0.0, 0.05,
            [math.nan] * 21, [math.nan] * 21,
        )  # fmt: skip
        assert wait_until(lambda: link.odometry.latest() is not None)
    odom = link.odometry.latest().value
    np.testing.assert_allclose(odom.eta, [10.0, -4.0, psi], atol=1e-6)
    np.testing.assert_allclose(odom.nu, [1.5, -0.2, 0.05], atol=1e-6)
    assert odom.time_s == pytest.approx(3.5)


def test_odometry_in_wrong_frame_or_bad_quaternion_or_wrong_source_is_dropped(pair) -> None:
    link, _, link_port = pair
    nan21 = [math.nan] * 21
    ned, frd = DIALECT.MAV_FRAME_LOCAL_NED, DIALECT.MAV_FRAME_BODY_FRD
    with (
        _vessel_peer(link, link_port) as vessel,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (7, 1)) as other,
    ):
        args = (0.0, 0.0, 0.0, [1, 0, 0, 0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        vessel.mav.odometry_send(1, DIALECT.MAV_FRAME_LOCAL_ENU, frd, *args, nan21, nan21)
        vessel.mav.odometry_send(1, ned, ned, *args, nan21, nan21)
        bad_q = (0.0, 0.0, 0.0, [0.5, 0, 0, 0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        vessel.mav.odometry_send(1, ned, frd, *bad_q, nan21, nan21)
        other.mav.odometry_send(1, ned, frd, *args, nan21, nan21)  # system 7: refused at once
        assert wait_until(lambda: link.odometry.malformed == 3 and link.stats.unknown_system >= 1)
    assert link.odometry.latest() is None


def test_odometry_claiming_the_vessel_ids_from_another_port_is_refused(pair) -> None:
    """Issue 22, item 1: a forger that claims system 1 component 1 from any UDP port but the
    vessel's inbox is not the vessel; its ODOMETRY never reaches the mailbox."""
    link, _, link_port = pair
    nan21 = [math.nan] * 21
    ned, frd = DIALECT.MAV_FRAME_LOCAL_NED, DIALECT.MAV_FRAME_BODY_FRD
    args = (5.0, 0.0, 0.0, [1, 0, 0, 0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    with RawPeer(f"udpout:127.0.0.1:{link_port}", VESSEL_IDS) as forger:
        for k in range(50):
            forger.mav.odometry_send(k, ned, frd, *args, nan21, nan21)
        assert wait_until(lambda: link.stats.wrong_source == 50)
    assert link.odometry.latest() is None and link.odometry.received == 0
    with _vessel_peer(link, link_port) as vessel:  # the vessel itself still gets through
        vessel.mav.odometry_send(1, ned, frd, *args, nan21, nan21)
        assert wait_until(lambda: link.odometry.received == 1)


def _param_values(gcs: RawPeer, since: int) -> dict[str, tuple[float, int, int, int]]:
    return {
        m.param_id: (m.param_value, m.param_type, m.param_index, m.param_count)
        for m in gcs.of_type("PARAM_VALUE", since)
    }


def test_param_request_list_answers_every_param_integers_bytewise(pair) -> None:
    _, gcs, _ = pair
    gcs.mav.param_request_list_send(SYS, COMP)
    assert gcs.wait_for("PARAM_VALUE", lambda m: m.param_index == 2)
    as_float = lambda i: struct.unpack("<f", struct.pack("<i", i))[0]  # noqa: E731
    assert _param_values(gcs, 0) == {
        "ALLOC_W_U": (1.0, DIALECT.MAV_PARAM_TYPE_REAL32, 0, 3),
        "ALLOC_HORIZON": (as_float(4), DIALECT.MAV_PARAM_TYPE_INT32, 1, 3),
        "ALLOC_EVEN": (as_float(2), DIALECT.MAV_PARAM_TYPE_INT32, 2, 3),
    }


def test_param_request_read_by_name_and_by_index(pair) -> None:
    _, gcs, _ = pair
    since = len(gcs.received)
    gcs.mav.param_request_read_send(SYS, COMP, b"ALLOC_HORIZON", -1)
    assert gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "ALLOC_HORIZON", since=since)
    gcs.mav.param_request_read_send(SYS, COMP, b"", 0)
    assert gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "ALLOC_W_U", since=since)
    gcs.mav.param_request_read_send(SYS, COMP, b"NO_SUCH", -1)
    gcs.pump(0.3)
    assert len(gcs.of_type("PARAM_VALUE", since)) == 2  # unknown names get no answer


def test_param_set_accepted_is_echoed_and_visible_to_the_loop(pair) -> None:
    link, gcs, _ = pair
    generation = link.params.generation
    gcs.mav.param_set_send(SYS, COMP, b"ALLOC_W_U", 2.5, DIALECT.MAV_PARAM_TYPE_REAL32)
    echo = gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "ALLOC_W_U")
    assert echo.param_value == 2.5
    assert link.params.get("ALLOC_W_U") == 2.5
    assert link.params.generation == generation + 1


@pytest.mark.parametrize(
    ("name", "value", "running", "reason"),
    [
        ("ALLOC_W_U", 11.0, False, "outside"),
        ("ALLOC_W_U", math.nan, False, "not finite"),
        ("ALLOC_HORIZON", 2.5, False, "not an integer"),
        ("ALLOC_HORIZON", 8, True, "not settable while running"),
        ("ALLOC_EVEN", 3, False, "must be even"),
    ],
)
def test_param_set_refused_echoes_unchanged_value_and_says_why(
    pair, name, value, running, reason
) -> None:
    link, gcs, _ = pair
    link.params.set_running(running)
    before = link.params.get(name)
    ptype = DIALECT.MAV_PARAM_TYPE_REAL32
    gcs.mav.param_set_send(SYS, COMP, name.encode(), value, ptype)
    echo = gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == name)
    text = gcs.wait_for("STATUSTEXT", lambda m: m.text.startswith(name))
    error = gcs.wait_for("PARAM_ERROR", lambda m: m.param_id == name)
    assert param_number(echo) == before  # sent typed REAL32: answered byte-wise
    assert link.params.get(name) == before
    assert error is not None and (error.target_system, error.target_component) == (255, 190)
    expected = "READ_ONLY" if running else "VALUE_OUT_OF_RANGE"
    assert error.error == getattr(DIALECT, f"MAV_PARAM_ERROR_{expected}")
    assert reason in text.text
    assert text.severity == DIALECT.MAV_SEVERITY_WARNING


def test_thruster_commands_go_out_normalised_and_in_newtons() -> None:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    config = AllocatorLinkConfig(4, MAX_WRENCH, u_max=(2.0, 4.0, 1.0, 4.0))
    with (
        RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs,
        MavlinkAllocatorLink(config, endpoint) as link,
    ):
        assert link.send_thruster_commands(ThrusterCommand.checked([1.0, -2.0, 0.0, 4.5]))
        out = gcs.wait_for("ACTUATOR_OUTPUT_STATUS")
        thrust = gcs.wait_for("FTCAP_THRUST")
    assert out.active == 0b1111
    assert out.actuator[:5] == [0.5, -0.5, 0.0, 1.0, 0.0]  # u / u_max, clipped to [-1, 1]
    assert thrust.n_thrusters == 4
    assert thrust.u[:5] == [1.0, -2.0, 0.0, 4.5, 0.0]
    with pytest.raises(LinkConfigError, match="u_max"):
        AllocatorLinkConfig(4, MAX_WRENCH, u_max=(1.0, 1.0))


def test_thruster_commands_and_status_go_out(pair) -> None:
    link, gcs, _ = pair
    assert link.send_thruster_commands(ThrusterCommand.checked([1.0, -2.0, 0.0, 4.5]))
    assert gcs.wait_for("FTCAP_THRUST").u[:4] == [1.0, -2.0, 0.0, 4.5]
    gcs.pump(0.1)
    assert not gcs.of_type("ACTUATOR_OUTPUT_STATUS")  # u_max not configured: not sent
    status = AllocatorStatus(
        tau_demand=(10.0, 0.0, 5.0),
        unallocated=(0.0, 0.0, 1.5),
        delta_hat=(1.0, 0.0, 0.5, 1.0),
        f_hat=(0.0, 0.0, 0.0, 3.0),
        faulty=(False, True, True, False),
        saturated=(False, False, False, True),
        probing=(False, True, False, False),
        delta_std=(0.0, 0.25, 0.125, math.nan),
    )
    assert link.send_status(status)
    msg = gcs.wait_for("FTCAP_STATUS")
    assert msg.flags == StatusFlag.FAULT_DETECTED | StatusFlag.UNALLOCATED | StatusFlag.SATURATED
    decoded = status_from_message(msg)
    np.testing.assert_allclose(decoded.delta_hat, status.delta_hat)
    np.testing.assert_allclose(decoded.f_hat, status.f_hat)
    np.testing.assert_allclose(decoded.unallocated, status.unallocated)
    np.testing.assert_equal(decoded.delta_std, status.delta_std)  # NaN (unknown) survives
    assert (decoded.faulty, decoded.saturated, decoded.probing) == (
        status.faulty,
        status.saturated,
        status.probing,
    )
    with pytest.raises(ValueError, match="shape"):
        link.send_thruster_commands(ThrusterCommand.checked([1.0, 2.0]))


def test_long_statustext_is_sent_in_chunks(pair) -> None:
    link, gcs, _ = pair
    text = "thruster 3 lost: " + "x" * 90  # 107 characters -> 3 chunks
    assert link.send_statustext(text)
    assert gcs.wait_for("STATUSTEXT", lambda m: m.chunk_seq == 2)
    chunks = [m for m in gcs.of_type("STATUSTEXT") if m.id != 0]
    assert len({m.id for m in chunks}) == 1
    assert "".join(m.text for m in sorted(chunks, key=lambda m: m.chunk_seq)) == text


def test_shutdown_is_idempotent_and_sends_nothing_after() -> None:
    (port,) = free_udp_ports(1)
    config = AllocatorLinkConfig(n_thrusters=2, max_wrench=MAX_WRENCH)
    link = MavlinkAllocatorLink(config, MavlinkEndpoint.inbox(port, ALLOCATOR_IDS))
    with link:
        assert link.is_alive
    link.shutdown()
    assert not link.is_alive
    assert link.send_statustext("late") is False


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"n_thrusters": 17, "max_wrench": MAX_WRENCH}, "n_thrusters"),
        ({"n_thrusters": 4, "max_wrench": (1.0, 0.0, 1.0)}, "max_wrench"),
        ({"n_thrusters": 4, "max_wrench": MAX_WRENCH, "wrench_limit": (1, 1)}, "wrench_limit"),
    ],
)
def test_bad_config_names_the_key(kwargs, key) -> None:
    with pytest.raises(LinkConfigError, match=key):
        AllocatorLinkConfig(**kwargs)


def test_bad_param_table_names_the_param() -> None:
    (port,) = free_udp_ports(1)
    config = AllocatorLinkConfig(n_thrusters=2, max_wrench=MAX_WRENCH)
    endpoint = MavlinkEndpoint.inbox(port, ALLOCATOR_IDS)
    with pytest.raises(LinkConfigError, match="ALLOC_GAIN"):
        MavlinkAllocatorLink(config, endpoint, [ParamSpec("ALLOC_GAIN", 5.0, max=1.0)])


def test_esc_status_reaches_the_ground_station() -> None:
    """FTCAP_ESC_STATUS: per-thruster ESC telemetry as the allocator saw it on CAN."""
    import math
    import socket

    from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
    from bridges.mavlink.config import MavlinkEndpoint
    from bridges.mavlink.gcs import MavlinkGcsLink
    from ftcap_hil.runtime.processes import wait_until

    def free() -> int:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            return int(s.getsockname()[1])

    a_port, g_port = free(), free()
    alloc = MavlinkAllocatorLink(
        AllocatorLinkConfig(4, (0.3, 0.3, 0.06)),
        MavlinkEndpoint.inbox(a_port, (1, 191), (g_port,)),
    )
    gcs = MavlinkGcsLink(MavlinkEndpoint.inbox(g_port, (255, 190), (a_port,)))
    try:

        def sent_and_seen() -> bool:
            alloc.send_esc_status(
                [1200.0, -800.0, math.nan, 0.0],
                [0.5, 0.4, math.nan, 0.05],
                [0.01, 0.02, math.inf, 0.1],
                [False, False, True, False],
            )
            return gcs.esc_status.latest() is not None

        assert wait_until(sent_and_seen, timeout_s=5.0, poll_s=0.1), "no FTCAP_ESC_STATUS"
        slot = gcs.esc_status.latest()
        assert slot is not None
        rep = slot.value
        assert rep.failed == (False, False, True, False)
        assert rep.rpm[:2] == (1200.0, -800.0) and math.isnan(rep.rpm[2])
        assert math.isinf(rep.age_s[2]) and rep.current_a[0] == 0.5
    finally:
        gcs.shutdown()
        alloc.shutdown()
