"""CAN fuzz and floods on the real loopback hub (issue 12's targets), with live traffic.

* 10^5 fuzzed frames (our data types from random nodes, the allocator's among them, random
  tails and lengths, services, anonymous and 11-bit frames, never-ending multi-frame
  starts) from a stranger's bus while
  the allocator streams commands and the simulated ESCs report: no receiver fails, every
  frame reaches both receivers and is accounted for (ignored, orphan, rejected or consumed),
  every command the vessel accepts is within the thrusters' range, the pending transfers
  stay bounded, the frames sent as the allocator's node are seen as a node-ID conflict, and
  the genuine commands flow again once it is over.
* 15 000 never-ending multi-frame transfers at 5 k/s (the probe that gave false "ESC silent"
  alarms): the ESC telemetry keeps arriving, no ESC ages past 0.25 s (the daemon's ESC
  timeout is 0.5 s), and reassembly stays bounded.
* Every frame the allocator's sink puts on the bus for any force, NaN and inf included, is a
  valid RawCommand within +-8191 (NaN/inf refused, nothing sent).
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable

import can
import numpy as np
import pytest

from bridges.can_io.adapters import (
    CanCommandSource,
    CanEscStatusSink,
    CanEscStatusSource,
    CanThrusterSink,
)
from bridges.can_io.assembler import DEFAULT_MAX_PENDING, TransferAssembler
from bridges.can_io.bus import open_can_bus
from bridges.can_io.codec import CanFrame, RawCommandMsg, encode_raw_command
from bridges.can_io.force_map import RAW_MAX, ForceRawMap, NonFiniteCommand
from bridges.can_io.hub import CanHub
from ftcap_hil.core.messages import EscStatus, ThrusterCommand
from ftcap_hil.ports.mailbox import Mailbox
from ftcap_hil.runtime.processes import wait_until
from tests.support.payloads import can_frames

pytestmark = pytest.mark.timeout(300)

U_MAX = 10.0
FMAP = ForceRawMap.create([U_MAX, U_MAX])
N_FUZZ = 100_000


class CheckedCommands(Mailbox[ThrusterCommand]):
    """Counts accepted commands outside +-U_MAX or not finite."""

    violations = 0

    def put(self, value: ThrusterCommand, stamp_ns: int | None = None) -> None:
        u = np.asarray(value.u)
        if u.shape != (2,) or not np.all(np.isfinite(u)) or np.any(np.abs(u) > U_MAX):
            self.violations += 1
        super().put(value, stamp_ns)


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    return wait_until(cond, timeout_s, 0.01)


class Live:
    """The allocator (stream at 100 Hz) and two simulated ESCs (status at 50 Hz) on a hub."""

    def __init__(self, hub: CanHub) -> None:
        self.alloc_bus = open_can_bus("canhub", hub.channel)
        self.vessel_bus = open_can_bus("canhub", hub.channel)
        self.sink = CanThrusterSink(self.alloc_bus, FMAP)
        self.esc_source = CanEscStatusSource(self.alloc_bus, 2, esc_node_ids=[20, 21])
        self.commands = CanCommandSource(self.vessel_bus, FMAP)
        self.checked = self.commands.commands = CheckedCommands("commands")
        self.esc_sink = CanEscStatusSink(self.vessel_bus, [20, 21])
        self.max_esc_age_s = 0.0
        self.allocation = [3.0, -3.0]
        self._stop = threading.Event()
        self._esc = threading.Thread(target=self._report, daemon=True)

    def start(self) -> Live:
        self.sink.start_stream(rate_hz=100.0)
        self.sink.send([3.0, -3.0])
        self._esc.start()
        assert _wait_for(lambda: bool(np.all(self.esc_source.ages_s() < 0.1)), 5.0)
        return self

    def _report(self) -> None:
        while not self._stop.wait(0.02):
            self.esc_sink.send_all([EscStatus(i, 1000.0, 1.0, 12.0) for i in range(2)])
            self.sink.send(self.allocation)  # the allocation keeps coming at 50 Hz
            self.max_esc_age_s = max(self.max_esc_age_s, float(self.esc_source.ages_s().max()))

    def shutdown(self) -> None:
        self._stop.set()
        self._esc.join(2.0)
        for port in (self.esc_sink, self.commands, self.esc_source, self.sink):
            port.shutdown()
        self.alloc_bus.shutdown()
        self.vessel_bus.shutdown()


def _send_all(bus: can.BusABC, frames: list[tuple[int, bool, bytes]], rate_hz: float) -> None:
    t0 = time.monotonic()
    for k, (can_id, ext, data) in enumerate(frames):
        bus.send(can.Message(arbitration_id=can_id, is_extended_id=ext, data=data))
        if k % 100 == 99:  # paced in batches: sleep resolution is ~0.1 ms at best
            time.sleep(max(0.0, t0 + (k + 1) / rate_hz - time.monotonic()))


def test_fuzzed_frames_are_counted_and_harmless() -> None:
    with CanHub(port=0, max_queue_bytes=16 << 20).start() as hub:
        live = Live(hub).start()
        stranger = open_can_bus("canhub", hub.channel, retry_period_s=None)
        try:
            vessel_asm = live.commands.assembler
            alloc_asm = live.esc_source.assembler
            before = (vessel_asm.frames, alloc_asm.frames)
            frames = list(can_frames(N_FUZZ))
            live.max_esc_age_s = 0.0
            t0 = time.monotonic()
            _send_all(stranger, frames, rate_hz=20_000.0)
            sent_s = time.monotonic() - t0
            assert _wait_for(
                lambda: (
                    vessel_asm.frames - before[0] >= N_FUZZ
                    and alloc_asm.frames - before[1] >= N_FUZZ
                ),
                60.0,
            )
            assert hub.bytes_dropped == 0  # every frame reached both receivers
            assert live.max_esc_age_s < 0.25, f"an ESC went {live.max_esc_age_s:.2f} s silent"
            for asm, receiver in ((vessel_asm, live.commands), (alloc_asm, live.esc_source)):
                assert asm.ignored > 0 and asm.orphans > 0 and asm.rejected > 0
                assert asm.consumed > 0 and asm.pending <= DEFAULT_MAX_PENDING
                assert receiver.malformed >= asm.rejected and receiver.receive_errors == 0
            assert live.checked.violations == 0
            # The fuzz sent as node 10 too: a conflict, commands dropped until it is over.
            conflict = live.commands.conflict
            assert conflict is not None and conflict.conflicts >= 1
            live.allocation = [7.0, -7.0]  # the genuine allocation gets through afterwards
            assert _wait_for(
                lambda: (
                    (c := live.commands.commands.latest()) is not None
                    and np.allclose(c.value.u, [7.0, -7.0], atol=0.01)
                ),
                10.0,
            )
        finally:
            stranger.shutdown()
            live.shutdown()
    print(
        f"CAN fuzz: {N_FUZZ} frames in {sent_s:.1f} s; vessel side ignored {vessel_asm.ignored} "
        f"orphans {vessel_asm.orphans} rejected {vessel_asm.rejected} expired "
        f"{vessel_asm.expired} evicted {vessel_asm.evicted}; max ESC age "
        f"{live.max_esc_age_s * 1e3:.0f} ms"
    )


def test_never_ending_transfers_do_not_silence_the_escs() -> None:
    rng = random.Random(5)
    flood = []
    for k in range(15_000):  # first frames of 3-frame ESC statuses that never end
        node, prio, tid = rng.randrange(1, 128), rng.randrange(32), k & 0x1F
        can_id = prio << 24 | 1034 << 8 | node
        flood.append((can_id, True, rng.randbytes(7) + bytes([0x80 | tid])))
    with CanHub(port=0, max_queue_bytes=16 << 20).start() as hub:
        live = Live(hub).start()
        stranger = open_can_bus("canhub", hub.channel, retry_period_s=None)
        try:
            live.max_esc_age_s = 0.0
            t0 = time.monotonic()
            _send_all(stranger, flood, rate_hz=5_000.0)
            flood_s = time.monotonic() - t0
            asm = live.esc_source.assembler
            assert asm.pending <= DEFAULT_MAX_PENDING  # one per (node, type): 127 at most
            time.sleep(1.3)  # past the 1 s transfer timeout, with live traffic going on
            assert asm.expired > 0 and asm.pending <= 2
            assert live.max_esc_age_s < 0.25, f"an ESC went {live.max_esc_age_s:.2f} s silent"
        finally:
            stranger.shutdown()
            live.shutdown()
    print(
        f"pending flood: 15000 transfers in {flood_s:.1f} s, max ESC age "
        f"{live.max_esc_age_s * 1e3:.0f} ms, evicted {asm.evicted}, expired {asm.expired}"
    )


def test_every_frame_the_sink_sends_is_in_range() -> None:
    rng = np.random.default_rng(7)
    values = rng.choice(
        [0.0, 1e-9, 5.0, -5.0, 1e6, -1e6, 1e308, -1e308, np.nan, np.inf, -np.inf], size=(2000, 2)
    ) * rng.choice([1.0, -1.0, 0.5], size=(2000, 2))
    with CanHub(port=0).start() as hub:
        rx = open_can_bus("canhub", hub.channel, retry_period_s=None)
        with open_can_bus("canhub", hub.channel) as tx:
            sink = CanThrusterSink(tx, FMAP, zero_on_shutdown=False)
            refused = 0
            for u in values:
                try:
                    sink.send(u)
                except NonFiniteCommand:
                    refused += 1
            sink.shutdown()
        asm = TransferAssembler()
        raws = []
        while (msg := rx.recv(0.3)) is not None:
            got = asm.feed(CanFrame(msg.arbitration_id, bytes(msg.data)), 0)
            if got is not None and isinstance(got.message, RawCommandMsg):
                raws.append(got.message.raw)
        rx.shutdown()
    finite = int(np.all(np.isfinite(values), axis=1).sum())
    assert refused == len(values) - finite and len(raws) == finite
    assert all(len(r) == 2 and all(abs(v) <= RAW_MAX for v in r) for r in raws)
    assert asm.rejected == 0 and asm.orphans == 0
    assert encode_raw_command([RAW_MAX + 5], source_node_id=10, transfer_id=0)  # clips, no raise
