"""The allocator app's wiring, in-process: ``apps.allocator.wire`` on python-can's ``virtual``
bus (a real python-can bus, no hub process) and MAVLink on loopback UDP with free ports,
Zenoh disabled.

The test is the ground station (``MavlinkGcsLink``), the ESCs (``CanEscStatusSink`` on the
same virtual channel) and a bus tap decoding every ``esc.RawCommand`` with the product's
codec. The daemon runs ``run()`` in a thread; every check waits on an event (a frame, a
status, a parameter echo) with a generous timeout, never on a tight wall-clock bound.
"""

from __future__ import annotations

import contextlib
import csv
import math
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import pytest

from bridges.can_io.adapters import CanEscStatusSink
from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.codec import CanFrame, DataType, RawCommandMsg
from bridges.mavlink.config import ALLOCATOR_IDS, GCS_IDS, MavlinkEndpoint
from bridges.mavlink.gcs import MavlinkGcsLink
from ftcap_hil.apps.allocator import wire
from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.messages import EscStatus
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.daemon import AllocatorDaemon
from ftcap_hil.runtime.processes import free_ports, wait_until

pytestmark = pytest.mark.timeout(60)

ALLOCATOR_NODE = 10  # allocator.toml can.node_id
ESC_IDS = [20, 21, 22, 23]
RAW_PER_N = 8191 / 0.1  # esc.RawCommand full scale at the shipped 0.1 N thruster limit
# Pure surge on the paper layout: u = (0.04, 0.04, -0.04, -0.04) N (X = 4 * 0.04 / sqrt 2).
TAU = (4 * 0.04 / math.sqrt(2), 0.0, 0.0)
ESC_RPM = (100.0, 200.0, 300.0, 400.0)
TIMEOUT_S = 15.0  # for each awaited event; they come within a second on an idle machine


class Tap(can.Listener):
    """Every esc.RawCommand from the allocator on the virtual channel, in order."""

    def __init__(self, channel: str) -> None:
        self.raws: list[tuple[int, tuple[int, ...]]] = []
        self._lock = threading.Lock()
        self._assembler = TransferAssembler([DataType.RAW_COMMAND])
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.notifier = can.Notifier(self.bus, [self], 0.05)

    def on_message_received(self, msg: can.Message) -> None:
        frame = CanFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
        got = self._assembler.feed(frame, time.monotonic_ns())
        if got is not None and isinstance(got.message, RawCommandMsg):
            with self._lock:
                self.raws.append((got.source_node_id, got.message.raw))

    def commands(self) -> list[tuple[int, ...]]:
        """The raw commands of the allocator's node, oldest first."""
        with self._lock:
            return [raw for node, raw in self.raws if node == ALLOCATOR_NODE]

    def others(self) -> int:
        """RawCommands from any other node (there is none on this bus)."""
        with self._lock:
            return sum(node != ALLOCATOR_NODE for node, _ in self.raws)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


class Repeater:
    """Calls ``action`` every ``period_s`` in a thread until closed (setpoints, ESC status)."""

    def __init__(self, action: Callable[[], object], period_s: float) -> None:
        self._action = action
        self._period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._action()
            self._stop.wait(self._period_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


@dataclass
class App:
    daemon: AllocatorDaemon
    gcs: MavlinkGcsLink
    tap: Tap
    command_log: Path
    ports: contextlib.ExitStack  # the app's own stack: its ports close with it
    runner: threading.Thread
    errors: list[BaseException] = field(default_factory=list)

    def stop(self) -> None:
        """request_exit, wait for ``run`` to end, close the app's ports (idempotent)."""
        self.daemon.request_exit()
        self.runner.join(10.0)
        self.ports.close()

    def command_log_rows(self) -> list[list[float]]:
        with open(self.command_log, newline="") as fh:
            return [[float(v) for v in row] for row in list(csv.reader(fh))[1:]]


@pytest.fixture
def app(tmp_path: Path) -> Iterator[App]:
    gcs_port, alloc_port = free_ports(socket.SOCK_DGRAM, 2)
    channel = f"ftcap-app-{uuid.uuid4().hex}"  # virtual channels are per name, per process
    cfg = load_daemon_config(
        None,
        [
            'daemon.mode="cap"',  # no estimation, no dither: the command is the plain allocation
            "daemon.rate_hz=20.0",
            'can.interface="virtual"',
            f'can.channel="{channel}"',
            f'mavlink.connection="udpin:127.0.0.1:{alloc_port}"',
            f'mavlink.peers=["127.0.0.1:{gcs_port}"]',
            "zenoh.enabled=false",
        ],
    )
    with contextlib.ExitStack() as stack:
        tap = Tap(channel)  # listening before the allocator's first zero
        stack.callback(tap.close)
        esc_bus = can.Bus(interface="virtual", channel=channel)
        stack.callback(esc_bus.shutdown)
        escs = CanEscStatusSink(esc_bus, ESC_IDS)
        stack.callback(escs.shutdown)
        gcs = stack.enter_context(
            MavlinkGcsLink(MavlinkEndpoint.inbox(gcs_port, GCS_IDS, (alloc_port,)))
        )
        ports = stack.enter_context(contextlib.ExitStack())
        daemon = wire(cfg, ports, tmp_path / "commands.csv")
        errors: list[BaseException] = []

        def run() -> None:
            try:
                daemon.run()
            except BaseException as e:  # reported by the test, not lost in the thread
                errors.append(e)

        runner = threading.Thread(target=run, name="allocator-loop")
        feed = [EscStatus(i, rpm, 0.5) for i, rpm in enumerate(ESC_RPM)]
        stack.callback(Repeater(lambda: escs.send_all(feed), 0.05).close)
        a = App(daemon, gcs, tap, tmp_path / "commands.csv", ports, runner, errors)
        stack.callback(a.stop)
        runner.start()
        yield a


def expected_raw() -> tuple[int, ...]:
    ths = paper_four_thrusters()
    u = np.linalg.pinv(effectiveness(ths)) @ np.array(TAU)  # minimum-norm, inside the limits
    np.testing.assert_allclose(u, [0.04, 0.04, -0.04, -0.04], atol=1e-12)
    return tuple(int(round(v * RAW_PER_N)) for v in u)  # (3276, 3276, -3276, -3276)


def _near(raw: tuple[int, ...], want: tuple[int, ...]) -> bool:
    return len(raw) == len(want) and all(abs(a - b) <= 1 for a, b in zip(raw, want, strict=True))


def test_setpoint_to_raw_command_parameters_and_zero_on_stop(app: App) -> None:
    gcs, tap = app.gcs, app.tap
    assert gcs.wait_ready(ALLOCATOR_IDS, TIMEOUT_S), "no HEARTBEAT past BOOT from the allocator"
    assert wait_until(lambda: bool(tap.commands()), TIMEOUT_S)
    assert tap.commands()[0] == (0, 0, 0, 0)  # zero first, before any setpoint
    want = expected_raw()
    setpoints = Repeater(lambda: gcs.send_wrench(TAU), 0.05)
    try:
        assert wait_until(lambda: _near(tap.commands()[-1], want), TIMEOUT_S), tap.commands()[-5:]
        # the ESC telemetry from the bus is in the allocator's status on MAVLink
        assert wait_until(
            lambda: (e := gcs.esc_status.latest()) is not None and e.value.rpm == ESC_RPM,
            TIMEOUT_S,
        ), gcs.esc_status.latest()
        esc = gcs.esc_status.latest()
        assert esc is not None and esc.value.failed == (False,) * 4
        # PARAM_SET: echoed by the parameter server, applied by the daemon in its loop
        assert gcs.set_param(ALLOCATOR_IDS, "FTC_SP_TMO", 0.4) == pytest.approx(0.4)
        assert wait_until(lambda: app.daemon.config.setpoint_timeout_s == pytest.approx(0.4), 10.0)
        assert gcs.set_param(ALLOCATOR_IDS, "FTC_MODE", 0) == 0  # none
        # FTCAP_STATUS carries no mode: read the status the daemon assembled for its sinks
        assert wait_until(
            lambda: (s := app.daemon.last_status) is not None and s.mode is Mode.NONE, TIMEOUT_S
        ), app.daemon.last_status
        assert app.daemon.config.core.mode is Mode.NONE
        assert _near(tap.commands()[-1], want)  # a mode change keeps the command
        thrusting = len(tap.commands())
        app.stop()  # while setpoints keep coming
    finally:
        setpoints.close()
    assert not app.runner.is_alive() and app.errors == []
    assert tap.others() == 0
    assert wait_until(lambda: tap.commands()[-1] == (0, 0, 0, 0), 5.0), tap.commands()[-3:]
    frames = tap.commands()
    assert _near(frames[thrusting - 1], want)  # it was thrusting when asked to stop
    first_zero = next(i for i in range(thrusting, len(frames)) if frames[i] == (0, 0, 0, 0))
    assert all(f == (0, 0, 0, 0) for f in frames[first_zero:]), frames[thrusting:]
    rows = app.command_log_rows()
    assert rows[-1][1:] == [0.0] * 4  # the daemon's own last command, logged
    assert any(_near(tuple(round(v * RAW_PER_N) for v in r[1:]), want) for r in rows[-50:])
