"""Zenoh links on real loopback sessions: an allocator router, clients, one in a subprocess.

A subscriber declared less than about a second before a publish can miss it, so every test
first waits for the publisher to match, then republishes until the sample shows up.
"""

from __future__ import annotations

import dataclasses
import json
import math
import queue
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import zenoh

from bridges.zenoh_io.config import ZenohConfigError
from bridges.zenoh_io.link import (
    ZenohAllocatorLink,
    ZenohGcsLink,
    ZenohLinkError,
    ZenohVesselLink,
    make_config,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import (
    FaultInjection,
    FaultKind,
    ThrusterCommand,
    WrenchSetpoint,
)
from ftcap_hil.core.status import AllocatorStatus, Mode

pytestmark = pytest.mark.timeout(120)

VESSEL = "testship"
TIMEOUT_S = 10.0

# The simulated vessel's side, in its own process: reports on stdout, one JSON object a line.
VESSEL_PROCESS = """
import json, sys, threading, time
from bridges.zenoh_io.link import ZenohVesselLink, make_config
from ftcap_hil.core.messages import Odometry

def say(**event):
    print(json.dumps(event), flush=True)

stop = threading.Event()
threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
with ZenohVesselLink(sys.argv[1], make_config("client", int(sys.argv[2])), n_thrusters=4) as link:
    say(event="ready", matched=link.subscribers_matched(timeout_s=10.0))
    k = 0
    while not stop.wait(0.05):
        link.publish_odometry(Odometry.checked([1.0, 2.0, 0.5], [0.1, 0.0, 0.0], k * 0.05))
        k += 1
        for item in link.faults.drain():
            f = item.value
            say(event="fault", index=f.index, kind=f.kind.value, value=f.value)
    say(event="bye", received=link.faults.received, malformed=link.faults.malformed)
"""


def wait_until(
    condition: Callable[[], bool],
    timeout_s: float = TIMEOUT_S,
    retry: Callable[[], object] | None = None,
) -> bool:
    """Poll ``condition``; call ``retry`` (e.g. publish again) every 100 ms meanwhile."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if retry is not None:
            retry()
        if condition():
            return True
        time.sleep(0.1)
    return condition()


def status_with_cycle(cycle: int) -> AllocatorStatus:
    return AllocatorStatus(
        mode=Mode.FTCAP,
        cycle=cycle,
        overruns=0,
        degraded=False,
        delta_hat=(1.0, 1.0, 0.5, 1.0),
        f_hat=(0.0,) * 4,
        bf_hat=(0.0,) * 3,
        u=(10.0, 20.0, 30.0, 40.0),
        unallocated=(0.0,) * 3,
        saturated=(False, False, True, False),
        setpoint_age_s=0.01,
        telemetry_stale=True,
    )


@pytest.fixture
def port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def allocator(port: int) -> Iterator[ZenohAllocatorLink]:
    with ZenohAllocatorLink(VESSEL, make_config("router", port)) as link:
        yield link


@pytest.fixture
def gcs(allocator: ZenohAllocatorLink, port: int) -> Iterator[ZenohGcsLink]:
    with ZenohGcsLink(VESSEL, make_config("client", port)) as link:
        yield link


class VesselProcess:
    def __init__(self, port: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", VESSEL_PROCESS, VESSEL, str(port)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.events: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.events.put(json.loads(line))

    def next_event(self, name: str, timeout_s: float = TIMEOUT_S) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            event = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
            if event["event"] == name:
                return event

    def stop(self) -> int:
        assert self.proc.stdin is not None
        if not self.proc.stdin.closed:
            self.proc.stdin.close()
        try:
            return self.proc.wait(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


@pytest.fixture
def vessel_process(allocator: ZenohAllocatorLink, port: int) -> Iterator[VesselProcess]:
    vessel = VesselProcess(port)
    try:
        assert vessel.next_event("ready", timeout_s=30.0)["matched"] is True
        yield vessel
    finally:
        vessel.stop()


def test_setpoint_reaches_allocator_mailbox(
    allocator: ZenohAllocatorLink, gcs: ZenohGcsLink
) -> None:
    assert gcs.subscribers_matched(gcs.keys.setpoint_wrench, TIMEOUT_S)
    before_ns = time.monotonic_ns()
    setpoint = WrenchSetpoint.checked([1500.0, -20.0, 300.0])
    assert wait_until(
        lambda: allocator.setpoints.received > 0, retry=lambda: gcs.publish_setpoint(setpoint)
    )
    slot = allocator.setpoints.latest()
    assert slot is not None
    np.testing.assert_array_equal(slot.value.tau, [1500.0, -20.0, 300.0])
    assert slot.stamp_ns >= before_ns
    assert allocator.setpoints.malformed == 0


def test_odometry_from_vessel_process_reaches_allocator_and_gcs(
    allocator: ZenohAllocatorLink, gcs: ZenohGcsLink, vessel_process: VesselProcess
) -> None:
    assert wait_until(lambda: allocator.odometry.received > 0 and gcs.odometry.received > 0)
    for box in (allocator.odometry, gcs.odometry):
        slot = box.latest()
        assert slot is not None
        np.testing.assert_array_equal(slot.value.eta, [1.0, 2.0, 0.5])
        np.testing.assert_array_equal(slot.value.nu, [0.1, 0.0, 0.0])
        assert slot.value.time_s >= 0.0


def test_fault_injection_reaches_vessel_process(
    gcs: ZenohGcsLink, vessel_process: VesselProcess
) -> None:
    assert gcs.subscribers_matched(gcs.keys.fault_inject, TIMEOUT_S)
    first = FaultInjection(2, FaultKind.WEAK, 0.25)
    assert wait_until(
        lambda: not vessel_process.events.empty(), retry=lambda: gcs.inject_fault(first)
    )
    event = vessel_process.next_event("fault")
    assert (event["index"], event["kind"], event["value"]) == (2, "weak", 0.25)
    # a thruster the vessel does not have (n_thrusters=4) is dropped and counted, in order
    assert gcs.inject_fault(FaultInjection(9, FaultKind.OFF))
    assert gcs.inject_fault(FaultInjection(1, FaultKind.BIAS, -15.0))
    while (event := vessel_process.next_event("fault"))["kind"] == "weak":
        pass  # repeats of the first injection
    assert (event["index"], event["kind"], event["value"]) == (1, "bias", -15.0)
    assert vessel_process.stop() == 0
    assert vessel_process.next_event("bye")["malformed"] == 1


def test_thruster_commands_and_status_reach_clients(
    allocator: ZenohAllocatorLink, gcs: ZenohGcsLink, port: int
) -> None:
    with ZenohVesselLink(
        VESSEL, make_config("client", port), n_thrusters=4, monitor_commands=True
    ) as vessel:
        assert allocator.subscribers_matched(timeout_s=TIMEOUT_S)
        command = ThrusterCommand.checked([10.0, -20.0, 0.0, 5.5])
        assert wait_until(
            lambda: vessel.commands.received > 0,
            retry=lambda: allocator.publish_thruster_command(command),
        )
        slot = vessel.commands.latest()
        assert slot is not None
        np.testing.assert_array_equal(slot.value.u, [10.0, -20.0, 0.0, 5.5])

    status = status_with_cycle(41)
    assert wait_until(
        lambda: gcs.status.received > 0, retry=lambda: allocator.publish_status(status)
    )
    got = gcs.status.latest()
    assert got is not None
    assert (got.value.cycle, got.value.saturated) == (41, (False, False, True, False))
    assert got.value.telemetry_age_s == math.inf and got.value.telemetry_stale
    assert allocator.publish_errors == 0


def test_queryable_answers_with_the_latest_snapshot(
    allocator: ZenohAllocatorLink, gcs: ZenohGcsLink, port: int
) -> None:
    errors: list[bytes] = []
    with zenoh.open(make_config("client", port)) as session:

        def ask() -> None:
            for reply in session.get(allocator.keys.state, timeout=1.0):
                if reply.err is not None:
                    errors.append(reply.err.payload.to_bytes())

        assert wait_until(lambda: bool(errors), retry=ask)
    assert errors[0] == b"no allocator status yet"
    assert gcs.query_state(timeout_s=1.0) is None
    allocator.set_status_snapshot(status_with_cycle(7))

    def state_cycle() -> int | None:
        state = gcs.query_state(timeout_s=1.0)
        return None if state is None else state.cycle

    assert wait_until(lambda: state_cycle() == 7)
    assert allocator.publish_status(status_with_cycle(8))
    state = gcs.query_state(timeout_s=1.0)
    assert state is not None
    assert state.cycle == 8
    np.testing.assert_array_equal(state.delta_hat, [1.0, 1.0, 0.5, 1.0])
    assert allocator.queries_answered >= 2


def test_malformed_payloads_are_counted_and_dropped(
    allocator: ZenohAllocatorLink, port: int
) -> None:
    bad = [
        b"garbage",
        b'{"v":1,"X_N":NaN,"Y_N":0,"N_Nm":0}',
        b'{"v":1,"X_N":1,"Y_N":0}',
        b'{"v":2,"X_N":1,"Y_N":0,"N_Nm":0}',
        b"\xff" * 10,
    ]
    with zenoh.open(make_config("client", port)) as session:
        publisher = session.declare_publisher(allocator.keys.setpoint_wrench)
        assert wait_until(lambda: publisher.matching_status.matching)  # type: ignore[attr-defined]
        valid_puts: list[None] = []

        def put_valid() -> None:
            publisher.put(b'{"v":1,"X_N":1.0,"Y_N":0.0,"N_Nm":0.0}')
            valid_puts.append(None)

        assert wait_until(lambda: allocator.setpoints.received > 0, retry=put_valid)
        for payload in bad:
            publisher.put(payload)
        publisher.delete()  # a DELETE sample is no setpoint, and not malformed either
        publisher.put(b'{"v":1,"X_N":2.0,"Y_N":0.0,"N_Nm":0.0}')  # in order after the bad ones

        def latest_surge() -> float:
            slot = allocator.setpoints.latest()
            return math.nan if slot is None else float(slot.value.tau[0])

        assert wait_until(lambda: latest_surge() == 2.0)
    assert allocator.setpoints.malformed == len(bad)
    assert allocator.setpoints.received <= len(valid_puts) + 1  # no bad one was accepted


def test_bad_status_is_refused_without_raising(allocator: ZenohAllocatorLink) -> None:
    with pytest.raises(MalformedMessage, match="u: expected 0 or 4"):  # checked when built
        AllocatorStatus.checked(delta_hat=(1.0,) * 4, u=(1.0,))
    # What JSON cannot carry: an unknown delta_std (NaN), a NaN no check caught.
    unknown_std = dataclasses.replace(status_with_cycle(1), delta_std=(0.0, math.nan, 0.0, 0.0))
    assert allocator.publish_status(unknown_std) is False
    nan_status = dataclasses.replace(status_with_cycle(1), delta_hat=(1.0, math.nan, 1.0, 1.0))
    assert allocator.publish_status(nan_status) is False
    assert allocator.publish_errors == 2


def test_shutdown_is_idempotent_and_stops_publishing(port: int) -> None:
    link = ZenohAllocatorLink(VESSEL, make_config("router", port))
    link.shutdown()
    link.shutdown()
    assert link.closed
    assert link.publish_thruster_command(ThrusterCommand.checked([1.0])) is False


def test_link_refuses_unsafe_config_before_opening(port: int) -> None:
    unsafe = make_config("router", port)
    unsafe.insert_json5("scouting/multicast/enabled", "true")
    with pytest.raises(ZenohConfigError, match="scouting/multicast/enabled"):
        ZenohAllocatorLink(VESSEL, unsafe)


def test_client_without_router_fails_at_start_up(port: int) -> None:
    with pytest.raises(ZenohLinkError, match="ZenohGcsLink"):
        ZenohGcsLink(VESSEL, make_config("client", port))


def test_process_that_forgets_shutdown_still_exits(port: int) -> None:
    # zenoh-python joins its callback threads at exit: an open link must not hang the process
    code = (
        "import sys\n"
        "from bridges.zenoh_io.link import ZenohAllocatorLink, ZenohGcsLink, make_config\n"
        "port = int(sys.argv[1])\n"
        "allocator = ZenohAllocatorLink('testship', make_config('router', port))\n"
        "gcs = ZenohGcsLink('testship', make_config('client', port))\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(port)], timeout=60)
    assert done.returncode == 0
