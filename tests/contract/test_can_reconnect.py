"""A CAN hub restart on loopback: both sides' buses re-open by themselves, the outage is
counted, and commands flow again within 2 s of the hub's return (issue 12's target) without
restarting either side: first zero (what the ESCs have after their timeout, never the old
command), then the owner's new command once it took the lapse."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import can
import pytest

from bridges.can_io.adapters import CanCommandSource, CanThrusterSink
from bridges.can_io.bus import open_can_bus
from bridges.can_io.force_map import ForceRawMap
from bridges.can_io.hub import CanHub
from bridges.can_io.reconnect import ReconnectingBus
from ftcap_hil.runtime.processes import free_port, wait_until

pytestmark = pytest.mark.timeout(120)


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    return wait_until(cond, timeout_s, 0.005)


def test_commands_flow_again_after_a_hub_restart() -> None:
    port = free_port(socket.SOCK_STREAM)
    channel = f"127.0.0.1:{port}"
    fmap = ForceRawMap.create([10.0, 10.0])
    hub = CanHub(port=port).start()
    alloc_bus = open_can_bus("canhub", channel)
    vessel_bus = open_can_bus("canhub", channel)
    assert isinstance(alloc_bus, ReconnectingBus) and isinstance(vessel_bus, ReconnectingBus)
    sink = CanThrusterSink(alloc_bus, fmap)
    source = CanCommandSource(vessel_bus, fmap)
    try:
        sink.start_stream(rate_hz=100.0, restart_from_zero=True)
        sink.send([5.0, -5.0])
        assert _wait_for(lambda: source.commands.latest() is not None, 5.0)
        hub.shutdown()
        assert _wait_for(lambda: not alloc_bus.is_up and not vessel_bus.is_up, 5.0)
        time.sleep(0.5)
        before = source.commands.latest()
        assert before is not None
        assert time.monotonic_ns() - before.stamp_ns > 400_000_000  # nothing came through
        assert sink.stale and sink.stream is not None and sink.stream.send_failures > 0

        hub = CanHub(port=port).start()
        back_at = time.monotonic_ns()
        assert _wait_for(
            lambda: (c := source.commands.latest()) is not None and c.stamp_ns > back_at, 5.0
        )
        latest = source.commands.latest()
        assert latest is not None
        recovery_s = (latest.stamp_ns - back_at) / 1e9
        assert recovery_s < 2.0, f"commands back {recovery_s:.2f} s after the hub"
        assert latest.value.u.tolist() == [0.0, 0.0]  # the lapse: zero, not [5, -5]
        assert sink.stream is not None and sink.stream.lapses == 1
        assert sink.take_lapse() and not sink.take_lapse()  # taken once the bus is back
        sink.send([1.0, -1.0])  # the owner's restart from zero
        assert _wait_for(
            lambda: (c := source.commands.latest()) is not None and c.value.u[0] > 0.5, 2.0
        )
        assert (alloc_bus.outages, alloc_bus.reconnects) == (1, 1)
        assert (vessel_bus.outages, vessel_bus.reconnects) == (1, 1)
        assert _wait_for(lambda: not sink.stale, 2.0)
    finally:
        source.shutdown()
        sink.shutdown()
        alloc_bus.shutdown()
        vessel_bus.shutdown()
        hub.shutdown()


def test_a_bus_that_cannot_be_opened_fails_at_start() -> None:
    port = free_port(socket.SOCK_STREAM)
    with pytest.raises(Exception, match="cannot open CAN bus"):
        open_can_bus("canhub", f"127.0.0.1:{port}")


def test_send_while_down_raises_and_shutdown_stops_retrying() -> None:
    port = free_port(socket.SOCK_STREAM)
    hub = CanHub(port=port).start()
    bus = open_can_bus("canhub", f"127.0.0.1:{port}", retry_period_s=0.05)
    assert isinstance(bus, ReconnectingBus)
    hub.shutdown()
    assert bus.recv(0.5) is None  # the hub's close is seen here, not raised
    assert not bus.is_up and bus.outages == 1
    with pytest.raises(can.CanOperationError, match="down"):
        bus.send(can.Message(arbitration_id=1, data=b"", is_extended_id=True))
    time.sleep(0.2)
    assert bus.recv(0.2) is None and bus.failed_attempts >= 1
    bus.shutdown()
    bus.shutdown()
    hub = CanHub(port=port).start()
    try:
        time.sleep(0.2)
        assert not bus.is_up and hub.client_count == 0  # nothing re-opened after shutdown
    finally:
        hub.shutdown()
