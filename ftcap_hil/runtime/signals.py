"""One signal capture for every process (uvicorn's ``capture_signals``).

::

    with capture_signals(loop.request_exit) as signals:
        try:
            loop.run(tick)
        finally:
            with signals.shielded():
                send_zero()

The first SIGINT or SIGTERM calls ``on_stop`` (which only sets a flag: the loop ends its
cycle, sends its zero and closes its ports). A second one while stopping is taken as
"stop now": it raises :class:`ForcedExit` (a ``KeyboardInterrupt``, so ``finally`` blocks
and context managers still run and the thrusters still get their zero), once; later
signals are only counted. A process that must not be cut short anywhere (a supervisor
between starting a child and recording its PID) hands ``on_force`` instead and is called
rather than interrupted. Inside :meth:`SignalCapture.shielded` (a final zero command going
out) no signal raises. Outside the main thread signals cannot be installed and nothing is
captured. The previous handlers are restored on exit, whatever happened.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class ForcedExit(KeyboardInterrupt):
    """A second stop signal arrived while the process was already stopping."""


class SignalCapture:
    """State of one capture: which signals arrived, whether the stop was forced."""

    def __init__(
        self, on_stop: Callable[[], None], on_force: Callable[[], None] | None = None
    ) -> None:
        self._on_stop = on_stop
        self._on_force = on_force
        self._shield_depth = 0
        self.received: list[int] = []
        self.forced = False

    @property
    def stopping(self) -> bool:
        """A stop signal arrived."""
        return bool(self.received)

    @property
    def signal_name(self) -> str | None:
        """Name of the first stop signal (``"SIGTERM"``), None if none arrived."""
        return signal.Signals(self.received[0]).name if self.received else None

    @contextlib.contextmanager
    def shielded(self) -> Iterator[None]:
        """No signal raises while the block runs (it still counts and still stops)."""
        self._shield_depth += 1
        try:
            yield
        finally:
            self._shield_depth -= 1

    def handle(self, signum: int, _frame: FrameType | None) -> None:
        """The installed handler (module docstring)."""
        self.received.append(signum)
        if len(self.received) == 1:
            self._on_stop()
            return
        if self.forced or self._shield_depth:
            return
        self.forced = True
        if self._on_force is not None:
            self._on_force()
            return
        raise ForcedExit(f"second {signal.Signals(signum).name}: stopping now")


@contextlib.contextmanager
def capture_signals(
    on_stop: Callable[[], None],
    signals: tuple[int, ...] = STOP_SIGNALS,
    on_force: Callable[[], None] | None = None,
) -> Iterator[SignalCapture]:
    """Route ``signals`` to ``on_stop`` while the block runs (module docstring)."""
    capture = SignalCapture(on_stop, on_force)
    if threading.current_thread() is not threading.main_thread():
        yield capture
        return
    saved: dict[int, Any] = {}
    try:
        for sig in signals:
            saved[sig] = signal.signal(sig, capture.handle)
        yield capture
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
