"""The allocator's CAN port as ``allocator_ports.build_ports`` opens it from the shipped
file on a loopback hub: the ESC command stream runs at ``esc_rate_hz`` between allocations,
forces go through the configured thruster curves, GetNodeInfo is answered with
``node_name``, and the node's NodeStatus health follows the allocator's status."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator

import can
import numpy as np
import pytest

from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import CanFrame, DataType, Health, NodeStatusMsg, RawCommandMsg
from bridges.can_io.hub import CanHub
from ftcap_hil.apps.allocator_ports import build_ports
from ftcap_hil.config.daemon import LoadedConfig, load_daemon_config
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.runtime.daemon import Ports
from ftcap_hil.runtime.processes import wait_until

pytestmark = pytest.mark.timeout(120)

NODE = 10
TESTER = 99
GET_NODE_INFO = 1  # uavcan.protocol.GetNodeInfo service type ID


class Tap(can.Listener):
    """Every RawCommand and NodeStatus from the allocator's node, and every frame sent to
    the tester's node ID (service responses), with arrival times."""

    def __init__(self, bus: can.BusABC) -> None:
        self.raw: list[tuple[int, tuple[int, ...]]] = []
        self.status: list[NodeStatusMsg] = []
        self.to_tester: list[bytes] = []
        self._lock = threading.Lock()
        self._assembler = TransferAssembler([DataType.RAW_COMMAND, DataType.NODE_STATUS])
        self.notifier = can.Notifier(bus, [self], 0.05)

    def on_message_received(self, msg: can.Message) -> None:
        can_id, data = msg.arbitration_id, bytes(msg.data)
        if can_id & 0x80 and (can_id >> 8) & 0x7F == TESTER:
            with self._lock:
                self.to_tester.append(data)
            return
        try:
            got = self._assembler.feed(CanFrame(can_id, data), time.monotonic_ns())
        except MalformedMessage:
            return
        if got is None or got.source_node_id != NODE:
            return
        with self._lock:
            if isinstance(got.message, RawCommandMsg):
                self.raw.append((time.monotonic_ns(), got.message.raw))
            elif isinstance(got.message, NodeStatusMsg):
                self.status.append(got.message)

    def raw_since(self, t_ns: int, until_ns: float = math.inf) -> list[tuple[int, ...]]:
        """The RawCommands received from ``t_ns`` (and before ``until_ns``)."""
        with self._lock:
            return [r for t, r in self.raw if t_ns <= t < until_ns]


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    return wait_until(cond, timeout_s, 0.01)


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub(port=0).start() as h:
        yield h


def _open(
    hub: CanHub, stack: contextlib.ExitStack, *sets: str
) -> tuple[tuple[LoadedConfig, Ports], Tap]:
    cfg = load_daemon_config(
        None,
        [f"can.channel='{hub.channel}'", "mavlink.enabled=false", "zenoh.enabled=false", *sets],
    )
    tap_bus = stack.enter_context(open_can_bus("canhub", hub.channel, retry_period_s=None))
    tap = Tap(tap_bus)
    stack.callback(tap.notifier.stop)
    ports, _ = build_ports(cfg, stack, None)
    return (cfg, ports), tap


def test_the_stream_runs_between_allocations_through_the_curves(hub: CanHub) -> None:
    with contextlib.ExitStack() as stack:
        (cfg, ports), tap = _open(
            hub, stack, "can.thruster_curve='t200-12v'", "can.curve_thrust_max_n=0.1"
        )
        assert cfg.ports.can.curves is not None
        u = np.array([0.05, -0.05, 0.02, 0.0])
        t0 = time.monotonic_ns()
        assert ports.thrusters.send(u)
        time.sleep(1.0)  # no allocation for 1 s: the stream alone keeps the ESCs fed
        want = (5277, -6117, 2959, 0)  # the T200 curve scaled to 0.1 N, 8191 = full raw
        # Frames received in the first 0.9 s were sent within the stream's 1 s hold (sent
        # before received), whenever the loaded machine let this thread read them; after
        # the hold the stream sends zero, as it must (one loaded run caught 2 of those).
        got = tap.raw_since(t0, t0 + 0.9e9)
        frames = got[got.index(want) :]  # a tick may send the start-up zero before it
        # 100 Hz: ~90 in 0.9 s; half of that leaves room for a loaded 2-core machine.
        assert len(frames) >= 45, f"{len(frames)} RawCommands in 0.9 s at 100 Hz"
        assert frames.count(want) == len(frames) and len(got) - len(frames) <= 1
        assert want[0] > 4096 and want[1] < -4096  # the T200 shape: 50 % thrust above half raw


def test_get_node_info_and_the_node_health(hub: CanHub) -> None:
    with contextlib.ExitStack() as stack:
        (_, ports), tap = _open(hub, stack, "can.node_name='org.example.boat'")
        asker = stack.enter_context(open_can_bus("canhub", hub.channel, retry_period_s=None))
        time.sleep(0.3)  # the server's notifier is listening
        request_id = (31 << 24) | (GET_NODE_INFO << 16) | 0x8000 | (NODE << 8) | 0x80 | TESTER
        asker.send(can.Message(arbitration_id=request_id, data=bytes([0xC0 | 5])))
        assert _wait_for(lambda: any(d[-1] & 0x40 for d in tap.to_tester), 5.0), tap.to_tester
        payload = b"".join(d[:-1] for d in tap.to_tester)
        assert b"org.example.boat" in payload
        ports.thrusters.tick()
        assert _wait_for(lambda: bool(tap.status), 2.0)
        assert all(s.health == Health.OK for s in tap.status), tap.status
        flagged = AllocatorStatus(cycle=5, delta_hat=(1.0, 0.2, 1.0, 1.0),
                                  faulty=(False, True, False, False))  # fmt: skip
        for sink in ports.status:
            sink.publish(flagged)

        # NodeStatus goes out from the daemon's tick, once a second: the next says WARNING.
        def warned() -> bool:
            ports.thrusters.tick()
            return any(s.health == Health.WARNING for s in tap.status)

        assert _wait_for(warned, 5.0), tap.status


@pytest.mark.parametrize(
    ("allocator_curve", "ratio"),
    [("t200-12v", (0.97, 1.03)), ("t200-12v-linear", (0.55, 0.75))],
)
def test_the_vessel_decodes_with_its_own_physical_curve(
    hub: CanHub, allocator_curve: str, ratio: tuple[float, float]
) -> None:
    """Same curve on both sides: the force arrives (within the int14 and table
    resolution); the deliberately wrong linear curve in the allocator: at half thrust the
    T200 gives 12.23 / 18.2 = 0.67 of the force asked for."""
    from ftcap_hil.apps.vessel_ports import VesselPorts
    from ftcap_hil.config.sim import load_config

    scale = "can.curve_thrust_max_n=0.1"
    vessel_cfg = load_config(
        None,
        [f"can.channel='{hub.channel}'", "mavlink.enabled=false", "zenoh.enabled=false",
         "can.thruster_curve='t200-12v'", scale],
    )  # fmt: skip
    vessel = VesselPorts.open(vessel_cfg.ports, vessel_cfg.sim.thrusters, False)
    try:
        with contextlib.ExitStack() as stack:
            (_, ports), _ = _open(hub, stack, f"can.thruster_curve='{allocator_curve}'", scale)
            u = np.array([0.05, 0.05, 0.05, 0.05])  # half of full ahead
            assert ports.thrusters.send(u)

            # The stream's start-up zeros may come first: wait for the command itself.
            def arrived() -> bool:
                got = vessel.latest_command()
                return got is not None and bool(np.any(got.value.u != 0.0))

            assert _wait_for(arrived, 5.0), vessel.latest_command()
            got = vessel.latest_command()
            assert got is not None
            lo, hi = ratio
            assert np.all(got.value.u >= lo * u) and np.all(got.value.u <= hi * u), got.value.u
    finally:
        vessel.shutdown()


def test_esc_rate_zero_sends_one_command_per_send(hub: CanHub) -> None:
    with contextlib.ExitStack() as stack:
        (_, ports), tap = _open(hub, stack, "can.esc_rate_hz=0")
        t0 = time.monotonic_ns()
        for k in range(3):
            assert ports.thrusters.send(np.full(4, 0.01 * (k + 1)))
        assert _wait_for(lambda: len(tap.raw_since(t0)) >= 3, 5.0)
        time.sleep(0.5)  # nothing follows: no stream
        assert len(tap.raw_since(t0)) == 3 and not ports.thrusters.take_lapse()
