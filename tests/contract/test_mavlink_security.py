"""MAVLink security on loopback: binds, key files, signing, MAVLink 1, the system allowlist.

The far end is bare pymavlink (``RawPeer``) with or without the signing key.
"""

from __future__ import annotations

import hashlib
import math
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.commands import MavResult
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.params import ParamSpec, ParamType
from bridges.mavlink.signing import load_signing_key, signing_timestamp
from bridges.mavlink.vessel import (
    FAILURE_ENABLE_PARAM,
    FAILURE_UNIT_SYSTEM_MOTOR,
    MAV_CMD_INJECT_FAILURE,
    MavlinkVesselLink,
)
from ftcap_hil.config.bridges import mavlink_endpoint_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import shipped_config
from ftcap_hil.core.errors import ConfigError
from tests.support.mavlink_peers import (
    DIALECT,
    RawPeer,
    free_udp_ports,
    send_datagram,
    wait_until,
)

pytestmark = [pytest.mark.timeout(60), pytest.mark.usefixtures("no_leaked_threads")]

SYS, COMP = ALLOCATOR_IDS
PASSPHRASE = "correct horse battery staple"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()
PARAMS = [ParamSpec("FTC_MODE", 2, ParamType.INT, 0, 3)]


def _key_file(tmp_path: Path, text: str = PASSPHRASE + "\n", mode: int = 0o600) -> Path:
    path = tmp_path / "mavlink.key"
    path.write_text(text)
    path.chmod(mode)
    return path


def _signed(peer: RawPeer, key: bytes = KEY, *, link_id: int = 0) -> RawPeer:
    peer.mav.signing.secret_key = key
    peer.mav.signing.sign_outgoing = True
    peer.mav.signing.link_id = link_id
    peer.mav.signing.timestamp = signing_timestamp(time.time())
    return peer


def _from_table(values: dict) -> MavlinkEndpoint:
    """The endpoint a file's [mavlink] table gives (the product's reader)."""
    root = Table({"mavlink": values}, "a.toml")
    return mavlink_endpoint_from(root.table("mavlink"), MavlinkEndpoint("udpin:127.0.0.1:1", 1, 1))


@pytest.mark.parametrize(
    "connection",
    ["udpin:0.0.0.0:14570", "udp:0.0.0.0:14570", "udpin:[::]:14570", "tcpin:0.0.0.0:5760"],
)
def test_a_bind_on_all_interfaces_is_refused_unless_opted_in(connection) -> None:
    with pytest.raises(LinkConfigError, match="bind_all_interfaces"):
        MavlinkEndpoint(connection, 1, 191)
    # The opt-in is accepted by the configuration (no socket is opened here: loopback only).
    assert MavlinkEndpoint(connection, 1, 191, bind_all_interfaces=True).bind_all_interfaces
    with pytest.raises(ConfigError, match=r"a\.toml: \[mavlink\].*connection: .* all interfaces"):
        _from_table({"connection": connection})


def test_key_file_must_be_private_and_hold_a_passphrase(tmp_path) -> None:
    assert load_signing_key(_key_file(tmp_path)) == KEY  # MAVProxy's "signing setup" key
    with pytest.raises(LinkConfigError, match="mode 0644"):
        load_signing_key(_key_file(tmp_path, mode=0o644))
    with pytest.raises(LinkConfigError, match="no passphrase"):
        load_signing_key(_key_file(tmp_path, text="\n"))
    with pytest.raises(LinkConfigError, match="not a regular file"):
        load_signing_key(tmp_path)
    with pytest.raises(LinkConfigError, match="cannot read"):
        load_signing_key(tmp_path / "missing.key")
    link = tmp_path / "link.key"
    link.symlink_to(_key_file(tmp_path))
    with pytest.raises(LinkConfigError, match="not a regular file"):
        load_signing_key(link)


@pytest.fixture
def signed_link(tmp_path) -> Iterator[tuple[MavlinkAllocatorLink, RawPeer, int]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint(
        f"udpin:127.0.0.1:{link_port}", SYS, COMP, (f"127.0.0.1:{gcs_port}",),
        key_file=str(_key_file(tmp_path)),
    )  # fmt: skip
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with _signed(RawPeer(f"udpin:127.0.0.1:{gcs_port}")) as gcs:
        with MavlinkAllocatorLink(config, endpoint, PARAMS, heartbeat_period_s=0.2) as link:
            beat = gcs.wait_for("HEARTBEAT")  # the peer refuses unsigned frames: this is signed
            assert beat is not None and beat._signed  # noqa: SLF001
            yield link, gcs, link_port


def test_signed_setpoints_are_obeyed_and_unsigned_ones_refused(signed_link) -> None:
    link, gcs, port = signed_link
    with RawPeer(f"udpout:127.0.0.1:{port}") as unsigned:
        unsigned.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        unsigned.mav.param_set_send(SYS, COMP, b"FTC_MODE", 0.0, 6)
        assert wait_until(lambda: link.stats.unsigned == 2)
    with _signed(RawPeer(f"udpout:127.0.0.1:{port}"), b"\x01" * 32) as wrong_key:
        wrong_key.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        assert wait_until(lambda: link.stats.bad_signature == 1)
    assert link.setpoint.latest() is None and link.params.get("FTC_MODE") == 2
    gcs.mav.wrench_setpoint_send(2, SYS, COMP, 0.25, 0.0, 0.0)
    assert wait_until(lambda: link.setpoint.latest() is not None)
    assert link.setpoint.latest().value.tau[0] == 0.25


def test_a_replayed_signed_frame_is_refused_and_forgeries_cannot_block_a_stream(
    signed_link,
) -> None:
    link, gcs, port = signed_link
    frame = DIALECT.MAVLink_wrench_setpoint_message(1, SYS, COMP, 0.1, 0.0, 0.0).pack(gcs.mav)
    send_datagram(port, frame)
    assert wait_until(lambda: link.setpoint.received == 1)
    send_datagram(port, frame)  # the same bytes again: a replay
    assert wait_until(lambda: link.stats.replay == 1)
    # A forged frame claiming the ground station's stream with a far-future timestamp: its
    # signature is wrong, so it must not move the stream's timestamp (pymavlink's own check
    # would, and then refuse every genuine frame after it as a replay).
    forged = bytearray(frame)
    forged[-12:-6] = (2**47).to_bytes(6, "little")
    send_datagram(port, bytes(forged))
    assert wait_until(lambda: link.stats.bad_signature == 1)
    gcs.mav.wrench_setpoint_send(3, SYS, COMP, 0.2, 0.0, 0.0)
    assert wait_until(lambda: link.setpoint.received == 2)


def test_mavlink1_frames_are_refused_with_or_without_a_key(signed_link) -> None:
    link, _, port = signed_link
    v1 = DIALECT.MAVLink(None, srcSystem=255, srcComponent=190)
    frame = DIALECT.MAVLink_manual_control_message(SYS, 100, 0, 0, 0, 0)
    send_datagram(port, frame.pack(v1, force_mavlink1=True))
    assert wait_until(lambda: link.stats.mavlink1 == 1)
    assert link.manual.latest() is None
    link_port, gcs_port = free_udp_ports(2)
    config = AllocatorLinkConfig(n_thrusters=2, max_wrench=(1.0, 1.0, 1.0))
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    with MavlinkAllocatorLink(config, endpoint) as plain:
        send_datagram(link_port, frame.pack(v1, force_mavlink1=True))
        assert wait_until(lambda: plain.stats.mavlink1 == 1)
        assert plain.manual.latest() is None


@pytest.fixture
def allocator() -> Iterator[tuple[MavlinkAllocatorLink, RawPeer, int]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        with MavlinkAllocatorLink(config, endpoint, PARAMS) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs, link_port


def test_only_authorized_systems_steer_set_parameters_or_command(allocator) -> None:
    link, gcs, port = allocator
    with (
        RawPeer(f"udpout:127.0.0.1:{port}", (99, 1)) as stranger,
        RawPeer(f"udpout:127.0.0.1:{port}", (SYS, 50)) as own_system,  # a companion process
    ):
        stranger.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        stranger.mav.param_set_send(SYS, COMP, b"FTC_MODE", 0.0, 6)
        assert wait_until(lambda: link.stats.unknown_system == 2)
        own_system.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        own_system.mav.manual_control_send(SYS, 500, 0, 0, 0, 0)
        own_system.mav.param_set_send(SYS, COMP, b"FTC_MODE", 0.0, 6)
        own_system.mav.param_request_list_send(SYS, COMP)
        own_system.mav.command_long_send(SYS, COMP, 512, 0, 148, 0, 0, 0, 0, 0, 0)
        assert wait_until(lambda: link.stats.unauthorized == 5)
    denied = gcs.wait_for("COMMAND_ACK", lambda m: m.command == 512)
    assert denied is not None and denied.result == MavResult.DENIED
    assert link.setpoint.latest() is None and link.manual.latest() is None
    assert link.params.get("FTC_MODE") == 2
    assert not gcs.of_type("PARAM_VALUE")  # the list request bought nothing


def test_the_allowlist_is_configurable(allocator) -> None:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint(
        f"udpin:127.0.0.1:{link_port}", SYS, COMP, (f"127.0.0.1:{gcs_port}",),
        authorized_systems=(245,),  # MAVSDK's default system id, and nobody else
    )  # fmt: skip
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with (
        MavlinkAllocatorLink(config, endpoint, PARAMS) as link,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (245, 190)) as mavsdk,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (255, 190)) as qgc,
    ):
        qgc.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        assert wait_until(lambda: link.stats.unknown_system == 1)
        mavsdk.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        assert wait_until(lambda: link.setpoint.latest() is not None)
    with pytest.raises(ConfigError, match=r"\[mavlink\] authorized_systems"):
        _from_table({"authorized_systems": [0]})


def test_mavsdk_with_its_defaults_is_served_by_default(allocator) -> None:
    """MAVSDK's own system id is 245 unless told otherwise: with the link's defaults (and
    the shipped files') its setpoints count, as a ground station's (255) do; another id
    is still refused."""
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint(
        f"udpin:127.0.0.1:{link_port}", SYS, COMP, (f"127.0.0.1:{gcs_port}",)
    )
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with (
        MavlinkAllocatorLink(config, endpoint, PARAMS) as link,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (246, 190)) as other,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (245, 190)) as mavsdk,
    ):
        other.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        assert wait_until(lambda: link.stats.unknown_system == 1)
        assert link.setpoint.latest() is None
        mavsdk.mav.wrench_setpoint_send(1, SYS, COMP, 0.5, 0.0, 0.0)
        assert wait_until(lambda: link.setpoint.latest() is not None)
    shipped = _from_table(tomllib.loads(shipped_config("allocator.toml").read_text())["mavlink"])
    assert shipped.authorized_systems == (255, 245)


def test_fault_injection_only_from_authorized_senders() -> None:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, VESSEL_IDS, (gcs_port,))
    with (
        RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs,
        MavlinkVesselLink(4, endpoint) as vessel,
        RawPeer(f"udpout:127.0.0.1:{link_port}", (VESSEL_IDS[0], 50)) as own_system,
    ):
        vessel.params.set(FAILURE_ENABLE_PARAM, 1)
        args = (FAILURE_UNIT_SYSTEM_MOTOR, 1, 1, math.nan, 0, 0, 0)
        own_system.mav.command_long_send(*VESSEL_IDS, MAV_CMD_INJECT_FAILURE, 0, *args)
        own_system.mav.param_set_send(*VESSEL_IDS, FAILURE_ENABLE_PARAM.encode(), 0.0, 6)
        ack = gcs.wait_for("COMMAND_ACK", lambda m: m.command == MAV_CMD_INJECT_FAILURE)
        assert ack is not None and ack.result == MavResult.DENIED
        assert wait_until(lambda: vessel.stats.unauthorized == 2)
        assert vessel.drain_faults() == [] and vessel.fault_injection_enabled
        gcs.mav.command_long_send(*VESSEL_IDS, MAV_CMD_INJECT_FAILURE, 0, *args)
        assert wait_until(lambda: len(vessel.faults.drain()) == 1)
