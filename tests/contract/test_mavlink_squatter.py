"""Issue 22, item 2: ground-station slots cannot be squatted (MavlinkAllocatorLink, loopback).

Eight sockets claiming system 255 used to fill all eight reply-peer slots, and a ground
station that came later (the README's ``mavproxy.py --master=udpout:127.0.0.1:14570``)
got no datagram at all. The squatters and the late ground station here are bare pymavlink
(the library MAVProxy is built on), each on a socket of its own, the squatters beating at
5 Hz for the whole test.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.config import ALLOCATOR_IDS, MavlinkEndpoint
from tests.support.mavlink_peers import DIALECT, RawPeer, free_udp_ports, wait_until

pytestmark = [pytest.mark.timeout(60), pytest.mark.usefixtures("no_leaked_threads")]

MAVPROXY_IDS = (255, 230)  # MAVProxy's default source system and component


class Squatters:
    """``identities`` sockets, each beating HEARTBEAT at 5 Hz until closed."""

    def __init__(self, port: int, identities: list[tuple[int, int]]) -> None:
        self.peers = [RawPeer(f"udpout:127.0.0.1:{port}", ids) for ids in identities]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            for p in self.peers:
                p.mav.heartbeat_send(DIALECT.MAV_TYPE_GCS, DIALECT.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for p in self.peers:
            p.close()


def _beats_received(gcs: RawPeer, seconds: float) -> int:
    """The allocator's HEARTBEATs ``gcs`` receives in ``seconds`` while it beats at 1 Hz."""
    since = len(gcs.received)
    for _ in range(int(seconds)):
        gcs.mav.heartbeat_send(DIALECT.MAV_TYPE_GCS, DIALECT.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        gcs.pump(1.0)
    return sum(
        1 for m in gcs.of_type("HEARTBEAT", since) if (m.get_srcSystem(), m.get_srcComponent())
        == ALLOCATOR_IDS
    )  # fmt: skip


@pytest.fixture
def link() -> Iterator[tuple[MavlinkAllocatorLink, int]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
    with MavlinkAllocatorLink(config, endpoint, heartbeat_period_s=0.2) as lk:
        yield lk, link_port


def test_eight_squatting_sockets_leave_a_late_ground_station_served(link) -> None:
    lk, port = link
    table = lk._port.table  # noqa: SLF001
    squat = Squatters(port, [(255, 190)] * 8)
    try:
        assert wait_until(lambda: table.sizes()[1] == 1 + 8, 5.0)  # the squatters trusted
        with RawPeer(f"udpout:127.0.0.1:{port}", MAVPROXY_IDS) as gcs:
            got = _beats_received(gcs, 5.0)
    finally:
        squat.close()
    # 5 s of beats every 0.2 s: 25; at least 15 (the first second is spent getting a slot,
    # the dispatch thread shares 2 loaded cores with the squatters' thread)
    assert got >= 15, (got, table.stats)
    assert table.stats.identity_taken >= 7
    assert len(table.dynamic_peers()) == 2  # one squatter slot, one ground station


def test_the_first_ground_station_keeps_its_slot_against_eight_identities(link) -> None:
    lk, port = link
    table = lk._port.table  # noqa: SLF001
    with RawPeer(f"udpout:127.0.0.1:{port}", MAVPROXY_IDS) as first:
        assert _beats_received(first, 2.0) >= 5
        # eight other identities, and one more socket claiming the first one's identity
        squat = Squatters(port, [(255, c) for c in range(1, 9)] + [MAVPROXY_IDS])
        try:
            assert wait_until(lambda: table.stats.peers_full > 0, 5.0)
            got = _beats_received(first, 5.0)
        finally:
            squat.close()
    assert got >= 15, (got, table.stats)
    assert table.stats.identity_taken > 0
    assert len(table.dynamic_peers()) == table.limits.max_dynamic_peers
