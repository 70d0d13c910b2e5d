"""The vessel's simulated ESC nodes as DroneCAN tooling sees them: the ``dronecan``
package's own node on the loopback hub lists them with ``NodeMonitor`` (GetNodeInfo) and
reads their parameters with param.GetSet, by index until the empty answer (the GUI tool's
listing) and by name (a request longer than a frame, reassembled); a set of a read-only
parameter changes nothing; a malformed request is counted and dropped.

The client's python-can driver passes ``spin``'s timeout to ``recv`` in milliseconds, so
``spin`` returns only when frames keep coming: a beat thread sends a NodeStatus every
20 ms from a node of its own while a test runs."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import dronecan
import pytest
from dronecan.app.node_monitor import NodeMonitor
from dronecan.transport import Transfer

from bridges.can_io.adapters import CanEscStatusSink
from bridges.can_io.bus import open_can_bus
from bridges.can_io.hub import CanHub
from bridges.can_io.node import GET_SET, CanNodeServer, NodeParam, get_set_response
from ftcap_hil.apps.vessel_ports import VesselPorts
from ftcap_hil.config.sim import load_config
from tests.support.polling import spin_until

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub(port=0).start() as h:
        bus = open_can_bus("canhub", h.channel)
        stop = threading.Event()

        def beat() -> None:
            status = CanEscStatusSink(bus, [99], status_period_s=0.0)
            while not stop.wait(0.02):
                status.tick()
            status.shutdown()

        thread = threading.Thread(target=beat, daemon=True)
        thread.start()
        try:
            yield h
        finally:
            stop.set()
            thread.join(2.0)
            bus.shutdown()


class Client:
    """A ``dronecan`` node (id 100) asking one question at a time."""

    def __init__(self, channel: str) -> None:
        self.node = dronecan.make_node(channel, node_id=100, interface="canhub",
                                       bustype="canhub", bitrate=1_000_000)  # fmt: skip

    def ask(self, request: Any, node_id: int, spin: Callable[[], None]) -> Any:
        got: list[Any] = []
        self.node.request(request, node_id, lambda e: got.append(e), timeout=2.0)
        assert spin_until(lambda: bool(got), 5.0, spin), "no answer"
        assert got[0] is not None, "request timed out"
        return got[0].response


def _value(v: Any) -> Any:
    tag = dronecan.get_active_union_field(v)
    return None if tag in (None, "empty") else getattr(v, tag)


def test_sim_escs_identify_themselves_and_list_their_parameters(hub: CanHub) -> None:
    cfg = load_config(
        None, [f"can.channel='{hub.channel}'", "mavlink.enabled=false", "zenoh.enabled=false"]
    )
    ths = cfg.sim.thrusters
    vessel = VesselPorts.open(cfg.ports, ths, False)
    client = Client(hub.channel)
    monitor = NodeMonitor(client.node)
    ids = [20 + i for i in range(ths.m)]
    assert vessel.esc_sink is not None

    def spin() -> None:
        assert vessel.esc_sink is not None
        vessel.esc_sink.tick()  # NodeStatus: the monitor's cue to ask GetNodeInfo
        client.node.spin(0.05)

    def known(n: int) -> bool:
        try:
            return monitor.get(n).info is not None
        except KeyError:
            return False

    try:
        assert spin_until(lambda: all(known(n) for n in ids), 20.0, spin), monitor.get_all_node_id()
        for i, n in enumerate(ids):
            assert bytes(monitor.get(n).info.name).decode() == f"org.ftcap.sim.esc{i}"
        # the GUI tool's listing: index 0, 1, ... until the empty answer
        for i, n in enumerate(ids):
            listed = {}
            for index in range(20):
                r = client.ask(GET_SET.Request(index=index), n, spin)
                name = bytes(r.name).decode()
                if not name:
                    break
                listed[name] = _value(r.value)
            assert listed == {
                "CAN_NODE": n, "ESC_INDEX": i, "ESC_BIDIR": 1,
                "THR_MAX_N": pytest.approx(ths.u_max[i]), "THR_MIN_N": pytest.approx(ths.u_min[i]),
            }  # fmt: skip
        # by name (a multi-frame request), and a set of a read-only parameter
        r = client.ask(GET_SET.Request(name="THR_MAX_N"), ids[1], spin)
        assert _value(r.value) == pytest.approx(ths.u_max[1])
        request = GET_SET.Request(name="ESC_INDEX")
        request.value.integer_value = 7
        r = client.ask(request, ids[0], spin)
        assert _value(r.value) == 0 and bytes(r.name).decode() == "ESC_INDEX"
        r = client.ask(GET_SET.Request(name="NO_SUCH_PARAM"), ids[0], spin)
        assert bytes(r.name) == b"" and _value(r.value) is None
    finally:
        monitor.close()
        client.node.close()
        vessel.shutdown()


def test_a_writable_parameter_is_set_within_its_bounds_and_bad_requests_are_dropped(
    hub: CanHub,
) -> None:
    bus = open_can_bus("canhub", hub.channel)
    gain = NodeParam("GAIN", 0.5, minimum=0.0, maximum=1.0, writable=True)
    flag = NodeParam("ENABLED", True, writable=True)
    server = CanNodeServer(bus, {30: _info(), 31: _info()}, _status, params={30: [gain, flag]})
    client = Client(hub.channel)

    def spin() -> None:
        client.node.spin(0.05)

    try:
        # in bounds; out; wrong type; not a number
        for asked, kept in ((0.8, 0.8), (1.5, 0.8), (3, 0.8), (math.nan, 0.8)):
            request = GET_SET.Request(name="GAIN")
            if isinstance(asked, int):
                request.value.integer_value = asked
            else:
                request.value.real_value = asked
            r = client.ask(request, 30, spin)
            assert _value(r.value) == pytest.approx(kept)
            assert _value(r.default_value) == pytest.approx(0.5)
        assert gain.value == pytest.approx(0.8) and server.sets_refused == 3
        # a node without parameters lists none (the empty answer, not silence)
        assert bytes(client.ask(GET_SET.Request(index=0), 31, spin).name) == b""
        request = GET_SET.Request(index=1)
        request.value.boolean_value = 0
        assert _value(client.ask(request, 30, spin).value) == 0 and flag.value is False
        # a two-frame request with its CRC broken: dropped, counted, nothing answered
        answered = server.params_answered
        frames = Transfer(transfer_id=3, source_node_id=101, dest_node_id=30,
                          payload=GET_SET.Request(name="ENABLED"), request_not_response=True,
                          service_not_message=True).to_frames()  # fmt: skip
        assert len(frames) > 1
        frames[0].bytes[0] ^= 0xFF
        raw = open_can_bus("canhub", hub.channel)
        try:
            for f in frames:
                raw.send(can.Message(arbitration_id=f.message_id, data=bytes(f.bytes),
                                     is_extended_id=True))  # fmt: skip
            # (the client would raise on these frames too: it is not spun from here on)
            assert spin_until(lambda: server.bad_requests == 1, 5.0, lambda: time.sleep(0.01))
        finally:
            raw.shutdown()
        assert server.params_answered == answered
    finally:
        client.node.close()
        server.shutdown()
        bus.shutdown()


def test_the_empty_answer_ends_a_listing() -> None:
    r = get_set_response(None)
    assert bytes(r.name) == b"" and dronecan.get_active_union_field(r.value) in (None, "empty")


def _info() -> Any:
    from bridges.can_io.node import NodeInfo

    return NodeInfo("org.ftcap.test")


def _status(_node: int) -> Any:
    from bridges.can_io.codec import Health, Mode, NodeStatusMsg

    return NodeStatusMsg(1, Health.OK, Mode.OPERATIONAL)


def test_unfinished_requests_are_bounded(hub: CanHub) -> None:
    """A flood of first frames that never finish (a fuzzer, a node rebooting mid-request)
    keeps at most 32 partial requests; the rest are counted as bad and dropped."""
    bus = open_can_bus("canhub", hub.channel)
    server = CanNodeServer(bus, {30: _info()}, _status, params={30: [NodeParam("P", 1)]})
    try:
        for k in range(40):
            request = Transfer(transfer_id=k % 32, source_node_id=40 + k, dest_node_id=30,
                               payload=GET_SET.Request(name="LONG_NAME_1"),
                               request_not_response=True, service_not_message=True)  # fmt: skip
            first = request.to_frames()[0]
            server.on_message_received(
                can.Message(
                    arbitration_id=first.message_id, data=bytes(first.bytes), is_extended_id=True
                )  # fmt: skip
            )
        assert server.bad_requests == 8 and server.params_answered == 0
    finally:
        server.shutdown()
        bus.shutdown()
