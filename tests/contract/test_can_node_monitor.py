"""DroneCAN node services against the ``dronecan`` package's own ``NodeMonitor`` (a third-
party node on the loopback hub, through its python-can driver), and node-ID conflicts.

The allocator's node (10) and two simulated ESC nodes (20, 21) send NodeStatus and answer
GetNodeInfo through ``CanNodeServer``; the monitor must list all three with their names,
unique IDs and health, and see the allocator's health follow ``health_for`` of its status.
The monitor's python-can driver passes ``spin``'s timeout to ``recv`` in milliseconds, so
frames must keep coming while it spins: the ESC stream and a NodeStatus thread provide them.
A stranger sending as node 10 is detected by the allocator's server (its own ID on the bus)
and by the vessel's command source (two interleaved sequences), and the vessel drops the
commands while the conflict is on.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import can
import dronecan
import numpy as np
import pytest
from dronecan.app.node_monitor import NodeMonitor

from bridges.can_io.adapters import (
    CanCommandSource,
    CanEscStatusSink,
    CanEscStatusSource,
    CanThrusterSink,
)
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import Health, Mode, NodeStatusMsg, encode, encode_raw_command
from bridges.can_io.force_map import ForceRawMap
from bridges.can_io.hub import CanHub
from bridges.can_io.node import CanNodeServer, NodeInfo, health_for, mode_for, unique_id_for
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.ports.mailbox import Mailbox
from tests.support.polling import spin_until

pytestmark = pytest.mark.timeout(120)

FMAP = ForceRawMap.create([10.0, 10.0])
ALLOCATOR = NodeInfo("org.ftcap.allocator", 0, 1, 0xABCDEF, unique_id_for("allocator", 10))


class Recording(Mailbox[tuple[int, ...]]):
    """A mailbox that also keeps every value put."""

    def __init__(self) -> None:
        super().__init__("recorded")
        self.values: list[tuple[int, ...]] = []

    def put(self, value: tuple[int, ...], stamp_ns: int | None = None) -> None:
        self.values.append(value)
        super().put(value, stamp_ns)


def _esc_info(i: int) -> NodeInfo:
    return NodeInfo(f"org.ftcap.sim.esc{i}", 0, 1, 0, unique_id_for("esc", 20 + i))


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub(port=0).start() as h:
        yield h


def test_dronecan_node_monitor_lists_allocator_and_escs(hub: CanHub) -> None:
    alloc_bus = open_can_bus("canhub", hub.channel)
    vessel_bus = open_can_bus("canhub", hub.channel)
    sink = CanThrusterSink(alloc_bus, FMAP, status_period_s=0.2)
    esc_source = CanEscStatusSource(alloc_bus, 2)
    alloc_server = CanNodeServer(
        alloc_bus, {10: ALLOCATOR}, sink.current_status, notifier=esc_source.notifier
    )
    escs = CanEscStatusSink(vessel_bus, [20, 21], status_period_s=0.2)
    commands = CanCommandSource(vessel_bus, FMAP)
    esc_server = CanNodeServer(
        vessel_bus, {20: _esc_info(0), 21: _esc_info(1)}, escs.current_status,
        notifier=commands.notifier,
    )  # fmt: skip
    node = dronecan.make_node(hub.channel, node_id=100, interface="canhub", bustype="canhub",
                              bitrate=1_000_000)  # fmt: skip
    monitor = NodeMonitor(node)
    stop = threading.Event()

    def heartbeat() -> None:
        while not stop.wait(0.05):
            sink.tick()
            escs.tick()

    beat = threading.Thread(target=heartbeat, daemon=True)
    beat.start()
    sink.start_stream(rate_hz=50.0)

    def spin() -> None:
        node.spin(0.05)

    def info(n: int) -> object:
        try:
            return monitor.get(n).info
        except KeyError:
            return None

    try:
        found = spin_until(lambda: all(info(n) for n in (10, 20, 21)), 20, spin)
        assert found, f"monitor sees {monitor.get_all_node_id()}"
        info = monitor.get(10).info
        assert bytes(info.name).decode() == "org.ftcap.allocator"
        assert bytes(info.hardware_version.unique_id) == unique_id_for("allocator", 10)
        assert info.software_version.vcs_commit == 0xABCDEF
        for i, n in enumerate((20, 21)):
            assert bytes(monitor.get(n).info.name).decode() == f"org.ftcap.sim.esc{i}"
            assert monitor.get(n).status.health == Health.OK
        assert monitor.get(10).status.health == Health.OK
        assert alloc_server.requests_answered >= 1 and esc_server.requests_answered >= 2

        flagged = AllocatorStatus(cycle=5, delta_hat=(1.0, 0.2), faulty=(False, True))
        sink.set_status(health_for(flagged), mode_for(flagged))
        assert spin_until(lambda: monitor.get(10).status.health == Health.WARNING, 5, spin)
        degraded = AllocatorStatus(cycle=6, delta_hat=(1.0, 1.0), degraded=True)
        sink.set_status(health_for(degraded), mode_for(degraded))
        assert spin_until(lambda: monitor.get(10).status.health == Health.ERROR, 5, spin)
        assert alloc_server.conflicts == 0 and esc_server.conflicts == 0  # none of this is one
        assert commands.conflict is not None and commands.conflict.conflicts == 0
    finally:
        stop.set()
        beat.join(2.0)
        monitor.close()
        node.close()
        for port in (esc_server, alloc_server, commands, escs, esc_source, sink):
            port.shutdown()
        alloc_bus.shutdown()
        vessel_bus.shutdown()


def test_health_and_mode_mapping() -> None:
    ok = AllocatorStatus(cycle=1, delta_hat=(1.0, 1.0), faulty=(False, False))
    assert (health_for(ok), mode_for(ok)) == (Health.OK, Mode.OPERATIONAL)
    assert mode_for(AllocatorStatus()) == Mode.INITIALIZATION
    cases = {
        Health.WARNING: [
            {"faulty": (True, False)}, {"probing": (False, True)}, {"setpoint_stale": True},
            {"telemetry_stale": True}, {"estimation_frozen": True},
        ],
        Health.ERROR: [
            {"degraded": True}, {"esc_failed": (False, True)}, {"faulty": (True, True)},
        ],
    }  # fmt: skip
    for health, changes in cases.items():
        for change in changes:
            status = AllocatorStatus(cycle=1, delta_hat=(1.0, 1.0), **change)  # type: ignore[arg-type]
            assert health_for(status) == health, change


def test_a_second_node_on_the_allocators_id_is_detected_on_both_sides(hub: CanHub) -> None:
    alloc_bus = open_can_bus("canhub", hub.channel)
    vessel_bus = open_can_bus("canhub", hub.channel)
    stranger = open_can_bus("canhub", hub.channel, retry_period_s=None)
    sink = CanThrusterSink(alloc_bus, FMAP)
    server = CanNodeServer(alloc_bus, {10: ALLOCATOR}, sink.current_status)
    commands = CanCommandSource(vessel_bus, FMAP)
    recorded = commands.raw_commands = Recording()
    try:
        sink.start_stream(rate_hz=100.0)
        sink.send([1.0, 1.0])
        time.sleep(0.3)
        assert commands.conflict is not None and not commands.conflict.in_conflict()
        accepted = commands.raw_commands.received
        assert accepted > 10
        for k in range(30):  # 10 Hz of spoofed full-ahead commands, its own transfer IDs
            for f in encode_raw_command([8191, 8191], source_node_id=10, transfer_id=k):
                stranger.send(can.Message(arbitration_id=f.can_id, data=f.data))
            time.sleep(0.1)
        assert server.in_conflict(10) and server.conflicts == 1 and server.conflict_frames == 30
        assert commands.conflict.in_conflict() and commands.conflict.conflicts == 1
        assert commands.dropped_in_conflict > 0
        spoofed = [v for v in recorded.values if v == (8191, 8191)]
        assert len(spoofed) <= 1  # a first frame whose transfer ID fits (2 in 32), then zero
        for f in encode(NodeStatusMsg(1), source_node_id=10, transfer_id=0):
            stranger.send(can.Message(arbitration_id=f.can_id, data=f.data))
        time.sleep(3.5)  # no more evidence: both conflicts end
        assert not server.in_conflict(10)
        assert not commands.conflict.in_conflict()
        sink.send([2.0, -2.0])  # the genuine allocator is obeyed again
        time.sleep(0.3)
        latest = commands.commands.latest()
        assert latest is not None and np.allclose(latest.value.u, [2.0, -2.0], atol=0.01)
    finally:
        for port in (server, commands, sink):
            port.shutdown()
        for bus in (stranger, alloc_bus, vessel_bus):
            bus.shutdown()
