"""The real ``ftcap-hil allocator`` process against what killed it (issue 12): 10**4 new
source ports sending ground-station heartbeats, then 10**4 more of fuzz, then a 10 kHz
flood from one socket. The allocator runs alone on the CAN hub (as in test_hil_bad_input).

Asserted: the process survives all three, answers the ground station's parameter pings
(>= 99 %), keeps its parameters, its resident memory ends within 10 MB of where it started
after its peer table expired, and on SIGTERM it stops cleanly with no overrun.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.e2e.rig import Rig, wait_until
from tests.support.mavlink_abuse import Pinger
from tests.support.mavlink_peers import RawPeer

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]

ALONE = ["can.esc_monitor=false", "daemon.setpoint_timeout_s=10.0"]


def _rss_kib(pid: int) -> int:
    m = re.search(r"VmRSS:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text())
    assert m is not None
    return int(m.group(1))


def _flood(gcs: RawPeer, port: int, rate: float, seconds: float, kind: str, *extra: str) -> int:
    """Flood from a process of its own while the ground station keeps reading (its socket
    buffer would otherwise overflow and lose answers that did come)."""
    cmd = [sys.executable, "-m", "tests.support.mavlink_abuse", str(port), str(rate)]
    proc = subprocess.Popen([*cmd, str(seconds), kind, *extra], stdout=subprocess.PIPE, text=True)
    while proc.poll() is None:
        gcs.pump(0.1)
    out, _ = proc.communicate()
    assert proc.returncode == 0
    return int(out.split()[-1])


def test_the_allocator_process_survives_new_ports_fuzz_and_floods(hil: Rig) -> None:
    gcs = RawPeer(f"udpin:127.0.0.1:{hil.gcs_port}")
    hil.closers.append(gcs.close)
    alloc = hil.start_allocator(ALONE)
    assert gcs.wait_for("HEARTBEAT", timeout_s=20.0) is not None
    pid = alloc.pid
    gcs.pump(2.0)
    rss0 = _rss_kib(pid)
    floods = [
        (1000, 10.0, "heartbeat", "--new-ports"),  # 10**4 "ground stations", 2x the rate that
        (2000, 5.0, "fuzz", "--new-ports"),  # killed it; then fuzz from 10**4 more ports
        (10_000, 3.0, "random"),  # and one socket at 10 kHz
    ]
    for rate, seconds, kind, *extra in floods:
        with Pinger(gcs, target=(1, 191)) as pings:
            sent = _flood(gcs, hil.alloc_port, rate, seconds, kind, *extra)
        assert alloc.running(), f"died under {kind}\n{alloc.log()}"
        answered = pings.answered()
        assert answered >= 0.99 * pings.sent, (kind, answered, pings.sent)
        assert sent == int(rate * seconds)
        gcs.received.clear()
    gcs.mav.param_request_read_send(1, 191, b"FTC_MODE", -1)
    mode = gcs.wait_for("PARAM_VALUE", lambda m: m.param_id == "FTC_MODE")
    assert mode is not None and mode.param_value == 2.802596928649634e-45  # 2 (byte-wise)
    time.sleep(11.0)  # learnt peers expire after 10 s
    assert _rss_kib(pid) - rss0 < 10 * 1024, (rss0, _rss_kib(pid))
    alloc.send(signal.SIGTERM)
    assert alloc.wait(20.0) == 0, alloc.log()
    assert wait_until(lambda: "allocator: stopped after" in alloc.log(), 5.0)
    assert re.search(r"stopped after \d+ cycles, 0 overruns", alloc.log()), alloc.log()[-2000:]
