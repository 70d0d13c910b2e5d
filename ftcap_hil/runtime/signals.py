"""One signal capture for every process (uvicorn's ``capture_signals``).

::

    with capture_signals(loop.request_exit):
        loop.run(tick)

The first SIGINT or SIGTERM calls ``on_stop`` (which only sets a flag: the loop ends its
cycle, sends its zero and closes its ports). A second one while stopping is taken as
"stop now": it raises :class:`ForcedExit` (a ``KeyboardInterrupt``, so ``finally`` blocks
and context managers still run and the thrusters still get their zero). Outside the main
thread signals cannot be installed and nothing is captured. The previous handlers are
restored on exit, whatever happened.
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
    """State of one capture: which signal asked to stop, and how many arrived."""

    def __init__(self, on_stop: Callable[[], None]) -> None:
        self._on_stop = on_stop
        self.received: list[int] = []

    @property
    def stopping(self) -> bool:
        return bool(self.received)

    @property
    def signal_name(self) -> str | None:
        """Name of the first stop signal (``"SIGTERM"``), None if none arrived."""
        return signal.Signals(self.received[0]).name if self.received else None

    def handle(self, signum: int, _frame: FrameType | None) -> None:
        self.received.append(signum)
        if len(self.received) > 1:
            raise ForcedExit(f"second {signal.Signals(signum).name}: stopping now")
        self._on_stop()


@contextlib.contextmanager
def capture_signals(
    on_stop: Callable[[], None], signals: tuple[int, ...] = STOP_SIGNALS
) -> Iterator[SignalCapture]:
    """Route ``signals`` to ``on_stop`` while the block runs (module docstring)."""
    capture = SignalCapture(on_stop)
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
