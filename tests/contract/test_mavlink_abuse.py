"""Abuse and fuzz of a running MavlinkAllocatorLink on loopback (bounded: well under a minute).

The sender is a process of its own (``python -m tests.support.mavlink_abuse``), as an
attacker's would be; the ground station is bare pymavlink on the link's configured peer.
Outcomes asserted: the link never dies and no handler fails; nothing from a stranger is
obeyed; every datagram is accounted for (kernel drops + what the port saw, and every one the
port saw rate-limited, oversized or parsed into counted outcomes); tables and memory stay
bounded; the ground station's parameter pings are answered (>= 99 %) through a flood.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.config import ALLOCATOR_IDS, MavlinkEndpoint
from bridges.mavlink.params import ParamSpec, ParamType
from bridges.mavlink.peers import TrafficLimits
from tests.support.mavlink_abuse import Pinger, flood, flooded, rss_bytes, start_flood, udp_drops
from tests.support.mavlink_peers import (
    RawPeer,
    free_udp_ports,
    wait_until,
)

# alone: its memory bounds are this process's resident size (tests/README.md)
pytestmark = [
    pytest.mark.timeout(120),
    pytest.mark.usefixtures("no_leaked_threads"),
    pytest.mark.alone,
]

SYS, COMP = ALLOCATOR_IDS
PARAMS = [
    ParamSpec("FTC_MODE", 2, ParamType.INT, 0, 3),
    ParamSpec("FTC_SP_TMO", 0.5, min=0.01, max=60.0),
]


@pytest.fixture
def rig() -> Iterator[tuple[MavlinkAllocatorLink, RawPeer, int]]:
    link_port, gcs_port = free_udp_ports(2)
    endpoint = MavlinkEndpoint.inbox(link_port, ALLOCATOR_IDS, (gcs_port,))
    limits = TrafficLimits(peer_timeout_s=1.0)
    with RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(1.0, 1.0, 1.0))
        with MavlinkAllocatorLink(config, endpoint, PARAMS, limits=limits) as link:
            assert gcs.wait_for("HEARTBEAT") is not None
            yield link, gcs, link_port


def _assert_accounted(link: MavlinkAllocatorLink, port: int, sent: int, kernel0: int) -> None:
    """``sent`` counts every datagram sent to the link (flood and pings)."""
    st, table = link.stats, link._port.table.stats  # noqa: SLF001
    assert wait_until(lambda: st.datagrams + udp_drops(port) - kernel0 >= sent, 10.0)
    assert st.datagrams + udp_drops(port) - kernel0 == sent
    assert st.datagrams == table.rate_limited + st.oversized + st.parsed
    assert st.frames_counted() >= st.parsed - 5  # a handful of pings' replies in flight


def test_ten_thousand_new_ports_of_fuzz_crash_nothing_and_are_all_counted(rig) -> None:
    link, gcs, port = rig
    rss0, kernel0 = rss_bytes(), udp_drops(port)
    fuzzer = start_flood(port, 2000, 5.0, "fuzz", "--new-ports")  # 10**4 source ports
    with Pinger(gcs) as pings:
        sent = flooded(fuzzer)
    assert sent == 10_000
    _assert_accounted(link, port, sent + pings.sent, kernel0)
    assert link.is_alive and link.stats.errors == 0
    assert link.params.values() == {"FTC_MODE": 2.0, "FTC_SP_TMO": 0.5}  # nothing obeyed
    assert link.setpoint.latest() is None
    assert pings.answered() >= 0.99 * pings.sent
    strangers, trusted = link._port.table.sizes()  # noqa: SLF001
    assert strangers <= link._port.table.limits.max_sources  # noqa: SLF001
    assert trusted <= 1 + link._port.table.limits.max_trusted  # noqa: SLF001
    assert link._port.table.peers == (("127.0.0.1", gcs.conn.port.getsockname()[1]),)  # noqa: SLF001
    assert rss_bytes() - rss0 < 10 * 2**20


@pytest.mark.parametrize("kind", ["heartbeat", "random"])
def test_a_ten_kilohertz_flood_from_one_source_leaves_the_pings_answered(rig, kind) -> None:
    # "heartbeat": a valid unsigned frame from the ground station's own system id, the worst
    # case without a key (it is trusted and parsed at the peer rate); "random": garbage.
    link, gcs, port = rig
    rss0, kernel0 = rss_bytes(), udp_drops(port)
    flooder = start_flood(port, 10_000, 4.0, kind)
    time.sleep(0.3)
    with Pinger(gcs) as pings:
        sent = flooded(flooder)
    _assert_accounted(link, port, sent + pings.sent, kernel0)
    answered = pings.answered()
    assert answered >= 0.99 * pings.sent, (answered, pings.sent, link.stats)
    assert link._port.table.stats.rate_limited > 0.5 * sent  # noqa: SLF001
    assert link.is_alive and link.stats.errors == 0
    assert rss_bytes() - rss0 < 10 * 2**20


def test_learnt_peers_expire_and_the_table_comes_back(rig) -> None:
    link, gcs, port = rig
    table = link._port.table  # noqa: SLF001
    from tests.support.mavlink_abuse import heartbeat

    sent = flood(port, 2000, 0.5, [heartbeat()], new_ports=True)  # 1000 "ground stations"
    assert sent == 1000
    assert wait_until(lambda: table.stats.trusted_full > 0, 5.0)
    # one identity (255/190) from 1000 ports: one reply slot (issue 22: no squatting)
    assert len(table.dynamic_peers()) == 1 and table.stats.identity_taken > 0
    assert wait_until(lambda: table.sizes()[1] == 1 and not table.dynamic_peers(), 5.0)
    assert table.stats.expired >= table.limits.max_trusted
