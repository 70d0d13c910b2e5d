"""Capture files with python-can's own writers and players (issue 13's interop list).

The allocator's sink talks on a loopback hub; a python-can ``Notifier`` writes what it
hears with ``can.Logger`` to a candump ``.log`` (``CanutilsLogWriter``, whose lines end in
`` R``) and a Vector ``.asc`` (``ASCWriter``). Then:

* ``tests/vcan/decode_capture.py`` (the independent ``dronecan`` decoder) reads the ``.log``;
* ``can.LogReader`` plays each file back into our ``TransferAssembler``;
* ``can.MessageSync`` replays the ``.asc`` in real time onto the hub, where the vessel's
  ``CanCommandSource`` decodes it as if the allocator were live.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import can
import pytest

from bridges.can_io.adapters import CanCommandSource, CanThrusterSink
from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import CanFrame, NodeStatusMsg, RawCommandMsg
from bridges.can_io.force_map import ForceRawMap
from bridges.can_io.hub import CanHub

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "vcan"))
import decode_capture  # noqa: E402

pytestmark = pytest.mark.timeout(120)

FMAP = ForceRawMap.create([10.0, 10.0, 10.0])
COMMANDS = [[1.0, -2.0, 3.0], [4.0, 5.0, -6.0], [0.5, 0.0, -0.5]]


def _record(tmp_path: Path) -> tuple[Path, Path, list[tuple[int, ...]]]:
    log_path, asc_path = tmp_path / "capture.log", tmp_path / "capture.asc"
    with CanHub(port=0).start() as hub:
        rx = open_can_bus("canhub", hub.channel)
        writers = [can.Logger(str(log_path)), can.Logger(str(asc_path))]
        notifier = can.Notifier(rx, list(writers), timeout=0.05)
        with open_can_bus("canhub", hub.channel) as tx:
            sink = CanThrusterSink(tx, FMAP, zero_on_shutdown=False)
            sent = []
            for u in COMMANDS:
                sink.send(u)
                sent.append(tuple(int(v) for v in FMAP.to_raw(u)))
                sink.tick()
                time.sleep(0.05)
            sink.shutdown()
        time.sleep(0.3)
        notifier.stop()
        for w in writers:
            w.stop()
        rx.shutdown()
    return log_path, asc_path, sent


def _replay(path: Path) -> list[object]:
    asm = TransferAssembler()
    out = []
    for msg in can.LogReader(str(path)):
        frame = CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
        if (got := asm.feed(frame, int(msg.timestamp * 1e9))) is not None:
            out.append(got.message)
    return out


def test_python_can_capture_files_decode_and_replay(tmp_path: Path) -> None:
    log_path, asc_path, sent = _record(tmp_path)
    text = log_path.read_text()
    assert text.splitlines()[0].endswith(" R")  # python-can's candump flavour

    decoded = decode_capture.decode(decode_capture.parse_candump(text))
    assert not decoded.errors and decoded.incomplete == 0
    raws = [tuple(t.payload.cmd) for t in decoded.of_type(decode_capture.RAW_COMMAND, 10)]
    assert raws == sent
    assert len(decoded.of_type(decode_capture.NODE_STATUS, 10)) == 1

    for path in (log_path, asc_path):
        messages = _replay(path)
        assert [m.raw for m in messages if isinstance(m, RawCommandMsg)] == sent, path.name
        assert sum(isinstance(m, NodeStatusMsg) for m in messages) == 1


def test_a_replayed_capture_drives_the_vessel_side(tmp_path: Path) -> None:
    _, asc_path, sent = _record(tmp_path)
    with CanHub(port=0).start() as hub:
        with (
            open_can_bus("canhub", hub.channel) as vessel_bus,
            open_can_bus("canhub", hub.channel) as player,
        ):
            source = CanCommandSource(vessel_bus, FMAP)
            got: list[tuple[int, ...]] = []
            for msg in can.MessageSync(can.LogReader(str(asc_path))):  # original timing
                player.send(msg)
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and source.raw_commands.received < len(sent):
                time.sleep(0.01)
            latest = source.raw_commands.latest()
            assert latest is not None and source.raw_commands.received == len(sent)
            got.append(latest.value)
            assert got == [sent[-1]] and source.malformed == 0
            source.shutdown()
