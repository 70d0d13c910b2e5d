"""The process supervisor of the launchers (ftcap_hil.runtime.processes), on real child
processes of this interpreter: ready lines from a log file and from a pipe, stopping by PID
(the signal, then SIGKILL after the grace period), the PID file, free ports, polling."""

from __future__ import annotations

import json
import signal
import socket
import sys
import time
from pathlib import Path

import pytest

from ftcap_hil.runtime.processes import (
    Child,
    Supervisor,
    free_ports,
    start_can_hub,
    wait_until,
)

PY = sys.executable
# Prints "ready", then exits 3 on SIGTERM.
POLITE = (
    "import signal, sys, time\n"
    "signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))\n"
    "print('ready')\n"
    "time.sleep(60)\n"
)
# Prints "ready", then exits 4 at the end of its input.
READER = "import sys\nprint('ready')\nsys.stdin.read()\nsys.exit(4)\n"
# Prints "up" and ignores SIGTERM.
STUBBORN = (
    "import signal, time\n"
    "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
    "print('up')\n"
    "time.sleep(60)\n"
)


def test_a_ready_line_in_the_log_file_and_sigterm_then_the_exit_code(tmp_path: Path) -> None:
    with Child("polite", [PY, "-c", POLITE], tmp_path / "polite.log") as child:
        found = child.wait_for(r"rea(dy)", 20.0)
        assert found is not None and found.group(1) == "dy"
        assert child.running()
        assert child.stop(signal.SIGTERM, 10.0) == 3 and not child.killed
        assert child.output() == "ready\n"
    assert (tmp_path / "polite.log").read_text() == "ready\n"


def test_a_pipe_of_lines_and_end_of_input_as_the_stop() -> None:
    with Child("reader", [PY, "-c", READER], stdin_pipe=True) as child:
        assert child.next_line(20.0) == "ready"
        assert child.unread() == 0 and child.next_line(0.05) is None
        assert child.stop(None, 10.0) == 4  # EOF on its stdin
        assert child.output() == "ready\n"


def test_a_child_that_ignores_the_signal_is_killed_after_the_grace_period() -> None:
    with Child("stubborn", [PY, "-c", STUBBORN]) as child:
        assert child.next_line(20.0) == "up"
        started = time.monotonic()
        assert child.stop(signal.SIGTERM, 0.5) is None
        assert child.killed and child.returncode == -signal.SIGKILL
        assert time.monotonic() - started < 10.0


def test_a_line_that_never_comes_is_none_once_the_child_exited() -> None:
    with Child("quiet", [PY, "-c", "print('something else')"]) as child:
        assert child.wait_for("ready", 20.0) is None
        assert child.returncode == 0 and child.output() == "something else\n"


def test_the_supervisor_names_children_once_records_pids_and_stops_newest_first(
    tmp_path: Path,
) -> None:
    sup = Supervisor(tmp_path, pids_file="pids.json", grace_s=5.0)
    first = sup.start("peer", [PY, "-c", POLITE])
    second = sup.start("peer", [PY, "-c", POLITE])
    try:
        assert [c.name for c in sup.children] == ["peer", "peer-1"]
        assert json.loads((tmp_path / "pids.json").read_text()) == {
            "peer": first.pid,
            "peer-1": second.pid,
        }
        assert first.wait_for("ready", 20.0) and second.wait_for("ready", 20.0)
        assert sup.died() is None
        first.send(signal.SIGTERM)
        assert first.wait(10.0) == 3 and sup.died() is first
        sup.stop_all()
        assert second.returncode == 3
        assert sup.failures() == [
            f"peer (pid {first.pid}): exit code 3, see {tmp_path / 'peer.log'}",
            f"peer-1 (pid {second.pid}): exit code 3, see {tmp_path / 'peer-1.log'}",
        ]
    finally:
        sup.kill_all()


def test_the_can_hub_reports_its_channel_and_stops_on_sigint() -> None:
    hub, channel = start_can_hub()
    with hub:
        host, port = channel.rsplit(":", 1)
        assert host == "127.0.0.1" and int(port) > 0
        socket.create_connection((host, int(port)), timeout=5.0).close()
        hub.send(signal.SIGINT)
        assert hub.wait(10.0) == 0


def test_free_ports_are_distinct_and_bindable() -> None:
    ports = free_ports(socket.SOCK_DGRAM, 5)
    assert len(set(ports)) == 5
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", port))


def test_wait_until_returns_the_predicate_or_false_after_the_timeout() -> None:
    calls = iter([False, False, True])
    assert wait_until(lambda: next(calls), 5.0, poll_s=0.001)
    started = time.monotonic()
    assert not wait_until(lambda: False, 0.05, poll_s=0.01)
    assert time.monotonic() - started >= 0.05


def test_next_line_needs_a_pipe(tmp_path: Path) -> None:
    with Child("logged", [PY, "-c", "pass"], tmp_path / "x.log") as child:
        with pytest.raises(RuntimeError, match="not to a pipe"):
            child.next_line(0.1)
