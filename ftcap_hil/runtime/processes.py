"""Child processes for the launchers: ``ftcap-hil demo``, the end-to-end and vcan rigs, the
contract tests and the benches.

* :class:`Child`: one process, its stdout and stderr in a log file, or (no log file) in a
  pipe that a thread of its own reads into lines. :meth:`Child.output` is what it printed so
  far, :meth:`Child.wait_for` waits for a line (its ready line), :meth:`Child.next_line`
  reads the pipe line by line. Stopped by its PID only (``Popen.send_signal`` never signals
  a PID it has reaped): :meth:`Child.stop` sends SIGINT or SIGTERM (or closes its stdin),
  then SIGKILL after a grace period; :meth:`Child.close` SIGKILLs what still runs and closes
  its files.
* :class:`Supervisor`: children started in order (their PIDs in ``pids.json`` if asked),
  stopped newest first.
* :func:`start_can_hub`: ``ftcap-hil can-hub`` started, its ready line read, its channel.
* :func:`free_ports`, :func:`wait_until`: free loopback ports, polling.

Nothing here opens a transport: the sockets :func:`free_ports` binds are closed before it
returns (the ports are free, not reserved).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Literal

log = logging.getLogger(__name__)

LOCALHOST = "127.0.0.1"
HUB_READY = re.compile(r"can_hub listening on (\S+:\d+)")  # ftcap-hil can-hub's ready line


def free_ports(kind: int, n: int) -> list[int]:
    """``n`` distinct ports of ``kind`` (socket.SOCK_DGRAM, SOCK_STREAM) free on 127.0.0.1
    (all held open together while picking)."""
    socks = [socket.socket(socket.AF_INET, kind) for _ in range(n)]
    try:
        for s in socks:
            s.bind((LOCALHOST, 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """One free port of ``kind`` on 127.0.0.1."""
    return free_ports(kind, 1)[0]


def wait_until(predicate: Callable[[], object], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``predicate()`` until true (True) or ``timeout_s`` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(poll_s)
    return True


def ftcap_argv(*args: str) -> list[str]:
    """The command line of ``ftcap-hil ARGS`` run by this interpreter."""
    return [sys.executable, "-m", "ftcap_hil", *args]


Stderr = Literal["log", "inherit"] | Path  # with stdout, this process's own, or a file


class Child:
    """One child process (module docstring); ``killed``: it needed SIGKILL to stop.

    ``stderr``: with stdout ("log"), this process's own ("inherit": a pipe of lines that
    must stay clean) or a file. ``stdin_pipe``: :meth:`write` and :meth:`close_stdin` talk to
    it (else its stdin is /dev/null). ``new_session``: a terminal's Ctrl-C reaches the
    launcher only. The environment is this one's with ``PYTHONUNBUFFERED=1`` and ``env``.
    """

    def __init__(
        self,
        name: str,
        argv: list[str],
        log_path: Path | None = None,
        *,
        stderr: Stderr = "log",
        stdin_pipe: bool = False,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
        new_session: bool = False,
    ) -> None:
        self.name, self.argv, self.log_path = name, argv, log_path
        self.killed = False
        self._files: list[IO[bytes]] = []
        self._lines: list[str] = []
        self._next = 0  # the first line next_line has not returned
        self._eof = False
        self._cond = threading.Condition()
        try:
            self.proc = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE if stdin_pipe else subprocess.DEVNULL,
                stdout=subprocess.PIPE if log_path is None else self._open(log_path),
                stderr=self._stderr(stderr),
                cwd=cwd,
                env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
                start_new_session=new_session,
            )
        except BaseException:
            self._close_files()
            raise
        self._reader: threading.Thread | None = None
        if log_path is None:
            self._reader = threading.Thread(target=self._read, name=f"{name}-stdout", daemon=True)
            self._reader.start()

    def _open(self, path: Path) -> IO[bytes]:
        fh = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._files.append(fh)
        return fh

    def _stderr(self, stderr: Stderr) -> Any:
        if stderr == "log":
            return subprocess.STDOUT
        return None if stderr == "inherit" else self._open(Path(stderr))

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with self.proc.stdout:
            for raw in self.proc.stdout:
                with self._cond:
                    self._lines.append(raw.decode(errors="replace").rstrip("\r\n"))
                    self._cond.notify_all()
        with self._cond:
            self._eof = True
            self._cond.notify_all()

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def running(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        """Everything it printed so far (the log file's text, or the pipe's lines: all of
        them once it has exited)."""
        if self.log_path is not None:
            try:
                return self.log_path.read_text(errors="replace")
            except FileNotFoundError:
                return ""
        if self._reader is not None and not self.running():
            self._reader.join(1.0)  # what it printed just before it exited
        with self._cond:
            return "".join(line + "\n" for line in self._lines)

    def wait_for(
        self,
        pattern: str | re.Pattern[str],
        timeout_s: float,
        *,
        check: Callable[[], None] | None = None,
        poll_s: float = 0.01,
    ) -> re.Match[str] | None:
        """The first match of ``pattern`` in :meth:`output`, waiting up to ``timeout_s``;
        None on timeout or if it exits without printing it. ``check()`` is called while
        waiting (it raises to abort)."""
        rx = re.compile(pattern) if isinstance(pattern, str) else pattern
        deadline = time.monotonic() + timeout_s
        while True:
            if check is not None:
                check()
            if (found := rx.search(self.output())) is not None:
                return found
            if not self.running() or time.monotonic() >= deadline:
                return rx.search(self.output())
            time.sleep(poll_s)

    def next_line(self, timeout_s: float) -> str | None:
        """The next line of the pipe not returned yet; None if none came within
        ``timeout_s`` or the pipe is closed (a child with a log file has no pipe)."""
        if self._reader is None:
            raise RuntimeError(f"{self.name} writes to {self.log_path}, not to a pipe")
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._next >= len(self._lines):
                left = deadline - time.monotonic()
                if self._eof or left <= 0:
                    return None
                self._cond.wait(left)
            self._next += 1
            return self._lines[self._next - 1]

    def unread(self) -> int:
        """Lines of the pipe :meth:`next_line` has not returned yet."""
        with self._cond:
            return len(self._lines) - self._next

    def write(self, line: str) -> None:
        """``line`` and a newline to its stdin (``stdin_pipe``)."""
        assert self.proc.stdin is not None, f"{self.name} was started without stdin_pipe"
        self.proc.stdin.write(line.encode() + b"\n")
        self.proc.stdin.flush()

    def close_stdin(self) -> None:
        """End of file on its stdin (``stdin_pipe``): for many programs, the request to exit."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            with contextlib.suppress(BrokenPipeError):
                self.proc.stdin.close()

    def send(self, sig: int) -> None:
        """``sig`` to its PID, if it is still running."""
        self.proc.send_signal(sig)

    def wait(self, timeout_s: float | None) -> int | None:
        """Its exit code once it exited; None if it still runs after ``timeout_s``."""
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(
        self,
        sig: int | None = signal.SIGTERM,
        grace_s: float = 10.0,
        hurried: Callable[[], bool] | None = None,
    ) -> int | None:
        """``sig`` (None: end of file on its stdin) if it still runs, up to ``grace_s`` to
        exit (none once ``hurried()``), then SIGKILL; the exit code, None if it needed
        SIGKILL."""
        if self.proc.poll() is not None:
            return self.proc.returncode
        if sig is None:
            self.close_stdin()
        else:
            self.send(sig)
        if self._ended(grace_s, hurried):
            return self.proc.returncode
        asked = "end of its input" if sig is None else signal.Signals(sig).name
        why = (
            "second stop signal"
            if hurried is not None and hurried()
            else f"ignored {asked} for {grace_s:.0f} s"
        )
        log.warning("%s (pid %d): %s: SIGKILL", self.name, self.pid, why)
        self.killed = True
        self.send(signal.SIGKILL)
        self.wait(10.0)
        return None

    def _ended(self, grace_s: float, hurried: Callable[[], bool] | None) -> bool:
        deadline = time.monotonic() + grace_s
        while not (hurried is not None and hurried()):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if self.wait(min(left, 0.1)) is not None:
                return True
        return self.proc.poll() is not None

    def close(self) -> None:
        """SIGKILL if it still runs, reap it, close its pipes and files. Idempotent."""
        self.send(signal.SIGKILL)
        self.wait(10.0)
        self.close_stdin()
        if self._reader is not None:
            self._reader.join(5.0)
        self._close_files()

    def _close_files(self) -> None:
        for fh in self._files:
            fh.close()

    def __enter__(self) -> Child:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class Supervisor:
    """Children started in order with their logs in ``log_dir`` (``NAME.log``; a name used
    twice gets a suffix), stopped newest first; every stop is by PID. With ``pids_file``,
    ``log_dir/pids_file`` always names every child's PID (written atomically). After
    :meth:`hurry` (a second stop signal) a child gets no grace period."""

    log_dir: Path
    pids_file: str | None = None
    grace_s: float = 8.0
    new_session: bool = False
    children: list[Child] = field(default_factory=list)
    hurried: bool = False

    def start(self, name: str, argv: list[str], **options: Any) -> Child:
        """Start ``argv`` as ``name`` (``options``: :class:`Child`'s)."""
        if any(c.name == name for c in self.children):
            name = f"{name}-{len(self.children)}"
        options.setdefault("new_session", self.new_session)
        child = Child(name, argv, self.log_dir / f"{name}.log", **options)
        self.children.append(child)
        log.info("started %s (pid %d): %s", name, child.pid, " ".join(argv[1:]))
        self._write_pids()
        return child

    def _write_pids(self) -> None:
        if self.pids_file is None:
            return
        tmp = self.log_dir / f"{self.pids_file}.tmp"
        tmp.write_text(json.dumps({c.name: c.pid for c in self.children}, indent=2))
        tmp.replace(self.log_dir / self.pids_file)  # atomic: a reader never sees half a file

    def by_name(self) -> dict[str, Child]:
        return {c.name: c for c in self.children}

    def died(self, exclude: Child | None = None) -> Child | None:
        """A child (other than ``exclude``) that has exited, if any."""
        return next((c for c in self.children if c is not exclude and not c.running()), None)

    def hurry(self) -> None:
        """Signal-handler safe: from now on, SIGKILL without waiting."""
        self.hurried = True

    def stop(self, child: Child, sig: int = signal.SIGTERM) -> None:
        """``sig``, ``grace_s`` to exit, SIGKILL; its files closed."""
        child.stop(sig, self.grace_s, hurried=lambda: self.hurried)
        child.close()

    def stop_all(self, sig: int = signal.SIGTERM) -> None:
        for child in reversed(self.children):
            self.stop(child, sig)

    def kill_all(self) -> None:
        """SIGKILL every child still running, newest first; their files closed."""
        for child in reversed(self.children):
            child.close()

    def failures(self) -> list[str]:
        """One line per child that needed SIGKILL or exited with a code other than 0."""
        out = []
        for c in self.children:
            code = c.returncode
            if c.killed or code != 0:
                how = "needed SIGKILL" if c.killed else f"exit code {code}"
                out.append(f"{c.name} (pid {c.pid}): {how}, see {c.log_path}")
        return out


def start_can_hub(
    start: Callable[[str, list[str]], Child] | None = None,
    *,
    name: str = "can_hub",
    port: int = 0,
    timeout_s: float = 20.0,
    check: Callable[[], None] | None = None,
) -> tuple[Child, str]:
    """``ftcap-hil can-hub --port PORT`` (0: any free port) started by ``start`` (a
    :meth:`Supervisor.start`: the supervisor stops it; default: a :class:`Child` with its
    output in a pipe, closed here if it fails), and the channel its ready line names
    (``127.0.0.1:PORT``). RuntimeError if no ready line came within ``timeout_s``;
    ``check`` as in :meth:`Child.wait_for`."""
    argv = ftcap_argv("can-hub", "--port", str(port))
    hub = start(name, argv) if start is not None else Child(name, argv, stderr="inherit")
    with contextlib.ExitStack() as on_failure:
        if start is None:
            on_failure.callback(hub.close)
        ready = hub.wait_for(HUB_READY, timeout_s, check=check, poll_s=0.02)
        if ready is None:
            where = f"see {hub.log_path}" if hub.log_path else f"it printed {hub.output()!r}"
            raise RuntimeError(f"the CAN hub did not come up within {timeout_s:g} s, {where}")
        on_failure.pop_all()
    return hub, ready.group(1)
