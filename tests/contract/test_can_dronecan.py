"""DroneCAN adapters on a real loopback CAN hub, the vessel side in a separate process.

The allocator side (``CanThrusterSink`` + ``CanEscStatusSource``) runs in the test process;
the vessel side (``CanCommandSource`` + ``CanEscStatusSink``) runs in a child process started
from this file (``python test_can_dronecan.py CHANNEL U_MAX...``), which prints each command
it decoded as a JSON line and answers with one ``esc.Status`` per ESC (rpm = raw command).
A third plain python-can client captures the frames for checks with the dronecan decoder.
"""

from __future__ import annotations

import json
import math
import select
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import numpy as np
import pytest

from bridges.can_io.adapters import (
    CanCommandSource,
    CanEscStatusSink,
    CanEscStatusSource,
    CanThrusterSink,
)
from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import (
    CanFrame,
    DataType,
    EscStatusMsg,
    Health,
    Mode,
    NodeStatusMsg,
    RawCommandMsg,
    encode,
    encode_raw_command,
)
from bridges.can_io.force_map import ForceRawMap, NonFiniteCommand
from bridges.can_io.hub import CanHub
from bridges.can_io.ports import receipt_ns
from ftcap_hil.core.messages import EscStatus
from ftcap_hil.runtime.processes import Child, wait_until

pytestmark = pytest.mark.timeout(120)

ESC_NODE_BASE = 20


def _wait_for(cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    return wait_until(cond, timeout_s, 0.002)


def _to_frame(msg: can.Message) -> CanFrame:
    return CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)


def _capture(bus: can.BusABC, quiet_s: float = 0.3) -> list[CanFrame]:
    frames = []
    while (msg := bus.recv(quiet_s)) is not None:
        frames.append(_to_frame(msg))
    return frames


def _decode_all(frames: list[CanFrame]) -> list[Any]:
    asm = TransferAssembler()
    return [r for f in frames if (r := asm.feed(f, 0)) is not None]


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub(port=0).start() as h:
        yield h


@pytest.fixture
def bus_factory(hub: CanHub) -> Iterator[Callable[[], can.BusABC]]:
    buses: list[can.BusABC] = []

    def _open() -> can.BusABC:
        buses.append(open_can_bus("canhub", hub.channel))
        return buses[-1]

    yield _open
    for bus in buses:
        bus.shutdown()


class VesselProcess(Child):
    """The child process playing the ESCs; the lines it prints are read as dicts."""

    def __init__(self, channel: str, u_max: list[float]) -> None:
        args = [sys.executable, __file__, channel, *map(str, u_max)]
        super().__init__("esc-vessel", args, stderr="inherit", stdin_pipe=True)
        assert self.next(20.0) == {"ready": True}

    def next(self, timeout_s: float = 10.0) -> dict[str, Any]:
        line = self.next_line(timeout_s)
        assert line is not None, f"no line from the ESC process within {timeout_s:g} s"
        got: dict[str, Any] = json.loads(line)
        return got

    def next_command(self, timeout_s: float = 10.0) -> dict[str, Any]:
        while "u" not in (line := self.next(timeout_s)):
            pass
        return line


@pytest.mark.parametrize("m", [4, 6, 8])
def test_command_round_trip_and_esc_telemetry_across_processes(
    hub: CanHub, bus_factory: Callable[[], can.BusABC], m: int
) -> None:
    u_max = [50.0 + 10.0 * i for i in range(m)]
    fmap = ForceRawMap.create(u_max)
    capture = bus_factory()
    vessel = VesselProcess(hub.channel, u_max)
    try:
        bus = bus_factory()
        esc_ids = [ESC_NODE_BASE + i for i in range(m)]
        with (
            CanThrusterSink(bus, fmap) as sink,
            CanEscStatusSource(bus, m, esc_node_ids=esc_ids) as source,
        ):
            u = np.linspace(-1.0, 1.0, m) * fmap.u_max_abs * 0.9 + 0.123
            assert sink.send(u)
            got = vessel.next_command()
            assert np.all(np.abs(np.array(got["u"]) - u) <= fmap.quantum_n() / 2 + 1e-9)
            assert got["raw"] == fmap.to_raw(u).tolist() == list(sink.last_raw or ())
            assert _wait_for(lambda: all(b.latest() is not None for b in source.mailboxes))
            for i, box in enumerate(source.mailboxes):
                slot = box.latest()
                assert slot is not None
                assert slot.value == EscStatus(i, float(got["raw"][i]), 0.25 * i, 48.0, i)
            assert np.all(source.ages_s() < 10.0) and source.malformed == 0
            assert _wait_for(lambda: source.node_status(ESC_NODE_BASE) is not None)
        # leaving the block: zero command, then NodeStatus OFFLINE
        last = [vessel.next(), vessel.next()]
        assert {"allocator_mode": "OFFLINE"} in last
        assert [line["raw"] for line in last if "raw" in line] == [[0] * m]
    finally:
        code = vessel.stop(None)  # EOF on its stdin tells it to shut down
        vessel.close()
        assert code == 0

    frames = _capture(capture)
    commands = [f for f in frames if (f.can_id >> 8) & 0xFFFF == DataType.RAW_COMMAND]
    assert len(commands) == 2 * (1 if m <= 4 else 2 if m <= 6 else 3)
    decoded = [r.message for r in _decode_all(commands)]
    assert decoded == [RawCommandMsg(tuple(got["raw"])), RawCommandMsg((0,) * m)]


def test_nan_rejected_and_nothing_sent(bus_factory: Callable[[], can.BusABC]) -> None:
    capture = bus_factory()
    with CanThrusterSink(bus_factory(), ForceRawMap.create([10.0] * 6)) as sink:
        with pytest.raises(NonFiniteCommand):
            sink.send([1.0, 2.0, math.nan, 0.0, 0.0, 0.0])
        assert sink.transfers_sent == 0 and sink.last_raw is None
        assert capture.recv(0.3) is None


def test_malformed_frames_counted_and_dropped(bus_factory: Callable[[], can.BusABC]) -> None:
    injector = bus_factory()
    fmap = ForceRawMap.create([10.0] * 6)

    def put(frames: list[CanFrame]) -> None:
        for f in frames:
            injector.send(can.Message(arbitration_id=f.can_id, data=f.data, is_extended_id=True))

    def status(index: int, node: int) -> list[CanFrame]:
        return encode(EscStatusMsg(index, 100, 1.0), source_node_id=node, transfer_id=0)

    with (
        CanCommandSource(bus_factory(), fmap) as cmd,
        CanEscStatusSource(bus_factory(), 2, esc_node_ids=[20, 21]) as esc,
    ):
        good = encode_raw_command([1, 2, 3, 4, 5, 6], source_node_id=10, transfer_id=3)
        bad_crc = [CanFrame(good[0].can_id, bytes([good[0].data[0] ^ 1]) + good[0].data[1:])]
        put(bad_crc + good[1:])  # 1: CRC mismatch
        put(encode_raw_command([1, 2, 3], source_node_id=10, transfer_id=2))  # 2: wrong m
        put([CanFrame(good[0].can_id, b"\x01\x02\x03\xc5")])  # 3: bad length
        put(encode_raw_command([9] * 6, source_node_id=11, transfer_id=0))  # other node: ignored
        put(status(5, 20) + status(1, 20) + [CanFrame(status(0, 20)[0].can_id, b"\xc0")])
        put(good)
        put(status(1, 21))
        assert _wait_for(lambda: cmd.commands.received == 1 and esc.mailboxes[1].received == 1)
        assert cmd.malformed == 3 and cmd.commands.malformed == 3
        assert esc.malformed == 3  # index 5 >= m, index 1 from node 20, empty payload
        latest = cmd.commands.latest()
        assert latest is not None
        np.testing.assert_allclose(latest.value.u, fmap.to_force([1, 2, 3, 4, 5, 6]))
        assert esc.mailboxes[0].received == 0


def test_node_status_schedule_and_health(bus_factory: Callable[[], can.BusABC]) -> None:
    capture = bus_factory()
    sink = CanThrusterSink(bus_factory(), ForceRawMap.create([1.0]), node_id=33)
    sink.set_status(Health.WARNING)
    t0 = time.monotonic_ns()
    sent = [sink.tick(t0), sink.tick(t0 + 500_000_000), sink.tick(t0 + 1_000_000_000)]
    assert sent == [True, False, True]
    sink.shutdown()
    sink.shutdown()
    assert not sink.send_zero()  # shut down: nothing more goes out
    got = _decode_all(_capture(capture))
    assert [r.source_node_id for r in got] == [33] * 4
    kinds = [type(r.message).__name__ for r in got]
    assert kinds == ["NodeStatusMsg", "NodeStatusMsg", "RawCommandMsg", "NodeStatusMsg"]
    assert got[0].message == NodeStatusMsg(0, Health.WARNING, Mode.OPERATIONAL)
    assert got[3].message.mode == Mode.OFFLINE
    assert [r.transfer_id for r in got] == [0, 1, 0, 2]


def test_transfer_ids_wrap_on_the_bus(bus_factory: Callable[[], can.BusABC]) -> None:
    capture = bus_factory()
    fmap = ForceRawMap.create([1.0] * 8)
    with CanThrusterSink(bus_factory(), fmap, zero_on_shutdown=False) as sink:
        for k in range(40):
            assert sink.send(np.full(8, k / 100.0))
    got = _decode_all(_capture(capture))
    assert [r.transfer_id for r in got] == [k % 32 for k in range(40)]
    assert [r.message.raw[0] for r in got] == [round(k / 100.0 * 8191) for k in range(40)]


def test_esc_status_sink_round_trip(bus_factory: Callable[[], can.BusABC]) -> None:
    with (
        CanEscStatusSink(bus_factory(), [40, 41, 42]) as sink,
        CanEscStatusSource(bus_factory(), 3) as source,
    ):
        assert sink.send(EscStatus(2, -1234.4, 7.3, math.nan, 9), temperature_k=300.0)
        assert sink.tick(indices=[0, 2]) and not sink.tick()
        assert _wait_for(lambda: source.mailboxes[2].received == 1)
        assert _wait_for(lambda: source.node_status(42) is not None)
        slot = source.mailboxes[2].latest()
        assert slot is not None
        got = slot.value
        assert (got.index, got.rpm, got.error_count) == (2, -1234.0, 9)
        assert abs(got.current_a - 7.3) < 7.3 * 2**-10 and math.isnan(got.voltage_v)
        assert source.node_status(41) is None  # ESC 1 was left out of the NodeStatus tick
        with pytest.raises(ValueError, match="index"):
            sink.send(EscStatus(3, 0.0, 0.0))
        with pytest.raises(ValueError, match="rpm"):
            sink.send(EscStatus(0, math.nan, 0.0))


def test_send_failure_marks_port_stale_without_raising(hub: CanHub) -> None:
    bus = open_can_bus("canhub", hub.channel)
    with CanThrusterSink(bus, ForceRawMap.create([1.0]), owns_bus=True) as sink:
        assert sink.send([0.5]) and not sink.stale
        hub.shutdown()
        assert _wait_for(lambda: not sink.send([0.5]))
        assert sink.stale and sink.send_errors >= 1
    assert bus._is_shutdown  # owns_bus: the sink shut it down


def test_virtual_bus_for_in_process_tests() -> None:
    fmap = ForceRawMap.create([100.0] * 5, deadband_n=1.0)
    with open_can_bus("virtual", "ftcap-test") as a, open_can_bus("virtual", "ftcap-test") as b:
        with CanThrusterSink(a, fmap) as sink, CanCommandSource(b, fmap) as source:
            assert sink.send([0.5, -50.0, 100.0, -100.0, 25.0])
            assert _wait_for(lambda: source.commands.received == 1)
            slot = source.raw_commands.latest()
            assert slot is not None and slot.value == (0, -4096, 8191, -8191, 2048)


def test_shared_notifier_and_idempotent_shutdown(bus_factory: Callable[[], can.BusABC]) -> None:
    bus = bus_factory()
    notifier = can.Notifier(bus, [], timeout=0.1)
    try:
        fmap = ForceRawMap.create([1.0])
        source = CanCommandSource(bus, fmap, notifier=notifier, allocator_node_id=None)
        esc = CanEscStatusSource(bus, 1, notifier=notifier)
        assert len(notifier.listeners) == 2
        source.shutdown()
        source.shutdown()
        assert notifier.listeners == [esc]
        esc.shutdown()
        assert not notifier.listeners and not notifier.stopped
    finally:
        notifier.stop()


# --- the vessel child process -------------------------------------------------------------


def _vessel_main(channel: str, u_max: list[float]) -> int:
    fmap = ForceRawMap.create(u_max)
    esc_ids = [ESC_NODE_BASE + i for i in range(fmap.m)]

    def emit(obj: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    with open_can_bus("canhub", channel) as bus, CanCommandSource(bus, fmap) as commands:
        with CanEscStatusSink(bus, esc_ids) as escs:
            emit({"ready": True})
            seen_cmd = seen_status = 0
            while not select.select([sys.stdin], [], [], 0.001)[0]:  # until stdin EOF
                escs.tick()
                if commands.allocator_status.received != seen_status:
                    seen_status = commands.allocator_status.received
                    node = commands.allocator_status.latest()
                    if node is not None and node.value.mode != Mode.OPERATIONAL:
                        emit({"allocator_mode": node.value.mode.name})
                if commands.commands.received == seen_cmd:
                    continue
                seen_cmd = commands.commands.received
                cmd, raw = commands.commands.latest(), commands.raw_commands.latest()
                assert cmd is not None and raw is not None
                emit({"u": cmd.value.u.tolist(), "raw": list(raw.value)})
                for i, r in enumerate(raw.value):
                    escs.send(EscStatus(i, float(r), 0.25 * i, 48.0, i))
    return 0


if __name__ == "__main__":
    sys.exit(_vessel_main(sys.argv[1], [float(v) for v in sys.argv[2:]]))


def test_receipt_stamp_from_the_interface_timestamp() -> None:
    now_ns, wall = 5_000_000_000, 1_700_000_000.0
    # kernel stamp 78 ms before now (float wall seconds: sub-microsecond rounding)
    assert abs(receipt_ns(wall - 0.078, now_ns, wall) - (now_ns - 78_000_000)) < 1_000
    assert receipt_ns(wall, now_ns, wall) == now_ns
    assert receipt_ns(0.0, now_ns, wall) == now_ns  # no timestamp
    assert receipt_ns(wall + 0.5, now_ns, wall) == now_ns  # from the future: not trusted
    assert receipt_ns(wall - 5.0, now_ns, wall) == now_ns  # too old: not trusted


def test_a_command_is_stamped_when_its_frame_arrived_not_when_it_was_handled() -> None:
    # The Notifier thread may run long after the interface received the frame (the GIL, a
    # busy vCPU): the command's stamp is the interface's receipt time.
    fmap = ForceRawMap.create([10.0] * 4)
    with open_can_bus("virtual", "ftcap-receipt") as bus, CanCommandSource(bus, fmap) as cmd:
        (frame,) = encode_raw_command([1, 2, 3, 4], source_node_id=10, transfer_id=0)
        before = time.monotonic_ns()
        cmd.on_message_received(
            can.Message(
                timestamp=time.time() - 0.2,
                arbitration_id=frame.can_id,
                data=frame.data,
                is_extended_id=True,
            )
        )
        latest = cmd.commands.latest()
        assert latest is not None
        lag_s = (before - latest.stamp_ns) * 1e-9
        assert 0.19 < lag_s < 0.25, lag_s
