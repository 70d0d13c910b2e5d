"""Helpers for the end-to-end tests (no tests here): run ``ftcap-hil``, find and reap children."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import sys
from collections.abc import Callable
from pathlib import Path

from ftcap_hil.runtime.processes import Child, free_ports, wait_until

OUR_PROCESSES = ("ftcap_hil", "ftcap-hil")


def ftcap_hil(*args: str) -> list[str]:
    script = Path(sys.executable).with_name("ftcap-hil")
    return [str(script), *args] if script.exists() else [sys.executable, "-m", "ftcap_hil", *args]


def free_udp_ports(n: int) -> list[int]:
    """``n`` distinct UDP ports free on 127.0.0.1 right now."""
    return free_ports(socket.SOCK_DGRAM, n)


def is_ours_and_alive(pid: int) -> bool:
    """True if ``pid`` runs and is one of our processes (a recycled PID is not ours)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    zombie = stat.rsplit(")", 1)[1].split()[0] == "Z"
    return not zombie and any(name in cmdline for name in OUR_PROCESSES)


def child_pids(out: Path) -> dict[str, int]:
    path = out / "logs" / "pids.json"
    return json.loads(path.read_text()) if path.exists() else {}


def wait_for(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.1) -> bool:
    return wait_until(predicate, timeout_s, poll_s)


def start(name: str, argv: list[str], out: Path) -> Child:
    """``argv`` with its stdout in ``out``/NAME.stdout and its stderr in NAME.stderr."""
    out.mkdir(parents=True, exist_ok=True)
    return Child(name, argv, out / f"{name}.stdout", stderr=out / f"{name}.stderr")


def stderr_of(proc: Child) -> str:
    """What ``proc`` (started by :func:`start`) wrote to its stderr so far."""
    assert proc.log_path is not None
    return proc.log_path.with_suffix(".stderr").read_text(errors="replace")


def reap(proc: Child, out: Path) -> None:
    """Teardown: stop the demo (SIGTERM: it stops its children, 30 s), then SIGKILL any child
    left, by PID."""
    proc.stop(signal.SIGTERM, 30.0)
    proc.close()
    for pid in child_pids(out).values():
        if is_ours_and_alive(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
