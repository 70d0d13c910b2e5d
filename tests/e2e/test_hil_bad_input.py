"""Malformed, non-finite and absurd setpoints over MAVLink and Zenoh against the running
allocator: dropped, counted, never on the bus. The allocator runs alone on the CAN hub (no
sim: no telemetry, so no estimation sample moves the dither and a constant setpoint gives a
constant command; ``can.esc_monitor=false`` so that no ESC is declared silent).
"""

from __future__ import annotations

import json
import math
import re
import signal
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zenoh
from pymavlink import mavutil

from bridges.mavlink import dialect as mavlink_dialect
from bridges.zenoh_io.link import make_config
from ftcap_hil.runtime.processes import wait_until
from tests.e2e.rig import ALLOCATOR_NODE, RAW_MAX, RawFrame, Rig, setpoints

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

ALONE = ["can.esc_monitor=false", "daemon.setpoint_timeout_s=10.0"]
SETPOINT_KEY = "ftcap/ftcap1/setpoint/wrench"
STATUS_KEY = "ftcap/ftcap1/allocator/status"
GOOD = [0.1, 0.05, 0.0]
BAD_MAVLINK = [  # WRENCH_SETPOINT (surge, sway, yaw): non-finite, or beyond mavlink.wrench_limit
    (math.nan, 0.0, 0.0),
    (0.0, math.inf, 0.0),
    (0.0, 0.0, -math.inf),
    (1e6, 0.0, 0.0),  # the shipped sanity bound is 1000 N
]
BAD_ZENOH = [
    b"garbage \xff\xfe",
    b'{"v":1,"X_N":NaN,"Y_N":0.0,"N_Nm":0.0}',
    b'{"v":1,"X_N":1e999,"Y_N":0.0,"N_Nm":0.0}',  # parses to inf
    b'{"v":2,"X_N":0.1,"Y_N":0.0,"N_Nm":0.0}',  # unknown version
    b'{"v":1,"X_N":0.1,"Y_N":0.0}',  # a field missing
]


class RawMavlink:
    """A plain pymavlink sender with the ftcap dialect: it packs what the product's own
    MavlinkGcsLink refuses to send (NaN, inf)."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, source_component=190
        )
        self.mav = mavlink_dialect.load().MAVLink(self.conn, srcSystem=255, srcComponent=190)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def zenoh_session(hil: Rig) -> Iterator[Any]:
    """Yields a factory: a raw zenoh client of the rig's router (after the allocator runs)."""
    sessions: list[Any] = []

    def open_session() -> Any:
        sessions.append(zenoh.open(make_config("client", port=hil.zenoh_port)))
        return sessions[-1]

    yield open_session
    for s in sessions:
        s.close()


def _signs(frame: RawFrame) -> tuple[int, ...]:
    return tuple(int(v) for v in np.sign(frame.raw))


def _in_range(frames: list[RawFrame]) -> bool:
    return all(
        len(f.raw) == 4 and all(isinstance(v, int) and -RAW_MAX <= v <= RAW_MAX for v in f.raw)
        for f in frames
    )


def test_malformed_setpoints_are_dropped_and_never_reach_the_bus(
    hil: Rig, zenoh_session: Any
) -> None:
    gcs = hil.gcs()
    alloc = hil.start_allocator(ALONE, verbose=True)  # DEBUG: every MAVLink drop is logged
    tap = hil.tap()
    mav = RawMavlink(hil.alloc_port)
    hil.closers.append(mav.close)
    pub = zenoh_session().declare_publisher(SETPOINT_KEY)
    assert wait_until(lambda: pub.matching_status.matching, 20.0), alloc.output()
    with setpoints(gcs, tau=GOOD):
        assert wait_until(lambda: len(tap.commands()) > 5, 10.0), alloc.output()
        time.sleep(1.0)
    before = tap.latest()
    assert before is not None and min(map(abs, before.raw)) > 0, before
    t_bad = time.monotonic_ns()
    for surge, sway, yaw in BAD_MAVLINK:
        mav.mav.wrench_setpoint_send(0, 1, 191, surge, sway, yaw)
        time.sleep(0.1)
    mav.mav.manual_control_send(1, 5000, 0, 0, 0, 0)  # x outside +-1000
    for payload in BAD_ZENOH:
        pub.put(payload)
        time.sleep(0.1)
    drops = {
        "allocator: dropped WRENCH_SETPOINT": len(BAD_MAVLINK),
        "allocator: dropped MANUAL_CONTROL": 1,
        "setpoint/wrench: dropped malformed sample": len(BAD_ZENOH),
    }
    assert wait_until(
        lambda: all(alloc.output().count(text) == n for text, n in drops.items()), 10.0
    ), {text: alloc.output().count(text) for text in drops}
    # the daemon kept cycling (3.5 Hz deadlines) on the last good setpoint, unchanged (waited
    # for, not slept for: a loaded CI machine once gave 4 frames where 5 were expected)
    assert wait_until(lambda: len(tap.commands(t_bad)) >= 5, 5.0), tap.commands(t_bad)
    during = tap.commands(t_bad)
    assert {f.raw for f in during} == {before.raw}, [f.raw for f in during]
    # and still listens on both transports: a good setpoint on each moves the thrusters
    t_good = time.monotonic_ns()
    with setpoints(gcs, tau=[-0.1, 0.0, 0.0]):
        ok = wait_until(lambda: any(_signs(f) == (-1, -1, 1, 1) for f in tap.commands(t_good)), 5)
        assert ok, [f.raw for f in tap.commands(t_good)]
    t_good = time.monotonic_ns()
    while not any(_signs(f) == (-1, 1, -1, 1) for f in tap.commands(t_good)):
        assert time.monotonic_ns() - t_good < 5e9, [f.raw for f in tap.commands(t_good)]
        pub.put(b'{"v":1,"X_N":0.0,"Y_N":-0.1,"N_Nm":0.0}')
        time.sleep(0.1)
    assert wait_until(lambda: "setpoint/wrench: valid samples again" in alloc.output(), 5.0)
    frames = tap.commands(source=ALLOCATOR_NODE)
    assert _in_range(frames) and tap.malformed == 0, frames
    print(f"\n{len(during)} commands while bad setpoints arrived, all {before.raw}")


def test_the_malformed_count_is_reported(hil: Rig, zenoh_session: Any) -> None:
    gcs = hil.gcs()
    alloc = hil.start_allocator(ALONE)
    mav = RawMavlink(hil.alloc_port)
    hil.closers.append(mav.close)
    session = zenoh_session()
    statuses: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_status(sample: Any) -> None:
        with lock:
            statuses.append(json.loads(sample.payload.to_bytes()))

    session.declare_subscriber(STATUS_KEY, on_status)
    pub = session.declare_publisher(SETPOINT_KEY)
    assert wait_until(lambda: pub.matching_status.matching, 20.0), alloc.output()
    with setpoints(gcs, tau=GOOD):
        for surge, sway, yaw in BAD_MAVLINK:
            mav.mav.wrench_setpoint_send(0, 1, 191, surge, sway, yaw)
        for payload in BAD_ZENOH:
            pub.put(payload)
        time.sleep(1.5)
    alloc.send(signal.SIGTERM)
    assert alloc.wait(15.0) == 0, alloc.output()
    sent = len(BAD_MAVLINK) + len(BAD_ZENOH)
    with lock:
        latest = statuses[-1] if statuses else {}
    counts = [v for k, v in latest.items() if "malformed" in k and isinstance(v, int)]
    summary = re.search(r"stopped after .*?(\d+) malformed", alloc.output())
    if summary:
        counts.append(int(summary.group(1)))
    assert any(c >= sent for c in counts), (latest, alloc.output()[-500:])


@pytest.mark.parametrize("huge", ["1e39", "1e308"])
def test_an_absurd_finite_zenoh_setpoint_does_not_stop_the_allocator(
    hil: Rig, zenoh_session: Any, huge: str
) -> None:
    gcs = hil.gcs()
    alloc = hil.start_allocator(ALONE)
    tap = hil.tap()
    pub = zenoh_session().declare_publisher(SETPOINT_KEY)
    assert wait_until(lambda: pub.matching_status.matching, 20.0), alloc.output()
    with setpoints(gcs, tau=GOOD):
        time.sleep(1.0)
    pub.put(f'{{"v":1,"X_N":{huge},"Y_N":0.0,"N_Nm":0.0}}'.encode())
    time.sleep(1.5)
    assert alloc.running(), alloc.output()[-3000:]
    t_good = time.monotonic_ns()
    with setpoints(gcs, tau=[-0.1, 0.0, 0.0]):
        ok = wait_until(lambda: any(_signs(f) == (-1, -1, 1, 1) for f in tap.commands(t_good)), 5)
    assert ok and _in_range(tap.commands()), alloc.output()[-3000:]
