"""bridges.mavlink.link: endpoint config, frame conversions, and the port on loopback."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bridges.mavlink.codec import quaternion_from_yaw, yaw_from_quaternion
from bridges.mavlink.config import (
    ALLOCATOR_IDS,
    ALLOCATOR_PORT,
    GCS_PORT,
    VESSEL_PORT,
    MavlinkEndpoint,
    default_allocator_endpoint,
    default_gcs_endpoint,
    default_vessel_endpoint,
)
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.link import MavlinkPort, Route
from ftcap_hil.core.errors import MalformedMessage
from tests.support.mavlink_peers import RawPeer, free_udp_ports

pytestmark = [pytest.mark.timeout(30)]


def test_default_topology_is_loopback_with_distinct_inboxes() -> None:
    gcs, allocator, vessel = (
        default_gcs_endpoint(),
        default_allocator_endpoint(),
        default_vessel_endpoint(),
    )
    assert gcs.connection == f"udpin:127.0.0.1:{GCS_PORT}"
    assert allocator.connection == f"udpin:127.0.0.1:{ALLOCATOR_PORT}"
    assert vessel.connection == f"udpin:127.0.0.1:{VESSEL_PORT}"
    assert len({GCS_PORT, ALLOCATOR_PORT, VESSEL_PORT}) == 3
    assert set(vessel.peers) == {f"127.0.0.1:{ALLOCATOR_PORT}", f"127.0.0.1:{GCS_PORT}"}
    assert allocator.peers == (f"127.0.0.1:{GCS_PORT}",)
    assert (allocator.system_id, allocator.component_id) == ALLOCATOR_IDS


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"system_id": 0}, r"^system_id: expected an integer in 1\.\.255, got 0"),
        ({"component_id": "191"}, r"^component_id: expected an integer in 1\.\.255, got '191'"),
        ({"peers": ("localhost",)}, r"^peers: expected 'host:port', got 'localhost'"),
        ({"connection": "udpout:127.0.0.1:1"}, r"^peers: only a 'udpin:'"),
        ({"connection": ""}, r"^connection: expected a pymavlink string"),
    ],
)
def test_bad_endpoint_names_the_field(values, message) -> None:
    """The endpoint's own checks (the [mavlink] table's: tests/unit/test_config_files.py)."""
    with pytest.raises(LinkConfigError, match=message):
        dataclasses.replace(default_allocator_endpoint(), **values)


@pytest.mark.parametrize("psi", np.linspace(-math.pi + 1e-6, math.pi - 1e-6, 13))
def test_yaw_quaternion_round_trip(psi) -> None:
    assert yaw_from_quaternion(quaternion_from_yaw(psi)) == pytest.approx(psi, abs=1e-12)


def test_yaw_ignores_roll_and_pitch() -> None:
    # q = yaw(0.5) * roll(0.1): heading is still 0.5 (ZYX Euler angles).
    cy, sy, cr, sr = math.cos(0.25), math.sin(0.25), math.cos(0.05), math.sin(0.05)
    q = [cy * cr, cy * sr, sy * sr, sy * cr]
    assert yaw_from_quaternion(q) == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize("q", [[0, 0, 0, 0], [2, 0, 0, 0], [math.nan, 0, 0, 1]])
def test_non_unit_quaternion_is_malformed(q) -> None:
    with pytest.raises(MalformedMessage):
        yaw_from_quaternion(q)


@pytest.mark.usefixtures("no_leaked_threads")
def test_port_sends_before_it_has_received_and_survives_handler_bugs() -> None:
    port_no, peer_no = free_udp_ports(2)
    calls: list[str] = []

    def buggy(msg: object, now_ns: int) -> None:
        calls.append("called")
        raise RuntimeError("bug in a handler")

    endpoint = MavlinkEndpoint.inbox(port_no, ALLOCATOR_IDS, (peer_no,))
    with RawPeer(f"udpin:127.0.0.1:{peer_no}") as peer:
        with MavlinkPort(
            endpoint, role="test", mav_type="MAV_TYPE_GENERIC", routes={"PING": Route(buggy)}
        ) as port:
            assert peer.wait_for("HEARTBEAT") is not None  # nobody sent to it first
            peer.mav.ping_send(1, 0, 0, 0)
            peer.mav.ping_send(2, 0, 0, 0)
            assert peer.wait_for("HEARTBEAT", lambda m: port.stats.errors == 2, timeout_s=3)
            assert port.is_alive
    assert calls == ["called", "called"]
