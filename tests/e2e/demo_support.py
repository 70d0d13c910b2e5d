"""Helpers for the end-to-end tests (no tests here): run ``ftcap-hil``, find and reap children."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from ftcap_hil.runtime.processes import free_ports, wait_until

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


def reap(proc: subprocess.Popen[bytes], out: Path) -> None:
    """Teardown: stop the demo (it stops its children), then SIGKILL any child left, by PID."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for pid in child_pids(out).values():
        if is_ours_and_alive(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
