"""Issue 22, item 4: a restart never truncates the record that survived a crash.

The real ``ftcap-hil allocator`` writes ``--command-log``, is SIGKILLed, and is started
again with the same path (as a supervisor restarting it would). Before the fix the second
start opened the path with mode "w" and the crashed run's rows were gone. Now the earlier
file is kept, byte for byte, as ``NAME.1`` (the log says so), and the new run writes a new
file at the path. The allocator runs alone on the CAN hub (as in test_hil_bad_input).
"""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from ftcap_hil.runtime.processes import wait_until
from tests.e2e.rig import Rig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

ALONE = ["can.esc_monitor=false", "daemon.setpoint_timeout_s=10.0"]


def _rows(path: Path) -> int:
    return max(0, len(path.read_text().splitlines()) - 1) if path.exists() else 0


def test_a_restart_keeps_the_crashed_runs_command_log(hil: Rig) -> None:
    first = hil.start_allocator(ALONE)
    assert wait_until(lambda: _rows(hil.command_log) >= 5, 20.0), first.output()
    first.send(signal.SIGKILL)
    first.wait(10.0)
    survived = hil.command_log.read_bytes()
    assert survived.count(b"\n") >= 6
    second = hil.start_allocator(ALONE)
    kept = hil.command_log.with_name(hil.command_log.name + ".1")
    assert kept.read_bytes() == survived
    assert f"kept as {kept}" in second.output()
    assert wait_until(lambda: _rows(hil.command_log) >= 2, 20.0), second.output()
    assert hil.command_log.read_text().startswith("stamp_ns,u_1,")
    second.send(signal.SIGTERM)
    assert second.wait(20.0) == 0, second.output()
    assert kept.read_bytes() == survived  # still there after the second run's end
    rows = len(survived.splitlines()) - 1
    print(f"\nkept {rows} rows of the killed run as {kept.name}")


def test_a_restarted_vessel_keeps_the_earlier_record(hil: Rig) -> None:
    """The same for the vessel's ``--record``: a second ``ftcap-hil sim`` with the path of
    the first keeps the first run's rows as ``NAME.1``."""
    alone = ["zenoh.enabled=false"]  # no allocator: no Zenoh router to join
    first = hil.start_sim(alone)
    assert wait_until(lambda: _rows(hil.record) >= 5, 20.0), first.output()
    first.send(signal.SIGKILL)
    first.wait(10.0)
    survived = hil.record.read_bytes()
    second = hil.start_sim(alone)
    kept = hil.record.with_name(hil.record.name + ".1")
    assert kept.read_bytes() == survived
    assert wait_until(lambda: _rows(hil.record) >= 2, 20.0), second.output()
    second.send(signal.SIGTERM)
    assert second.wait(20.0) == 0, second.output()
