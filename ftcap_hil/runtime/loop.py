"""One deadline loop for every process: absolute deadlines, overruns counted, a clean exit.

A process (the allocator daemon, the simulated vessel, the ground station) hands a
``tick(now_ns)`` to :class:`DeadlineLoop` and gets::

    while not stop.should_exit:
        tick(now)                        # the loop hands the time in (ros2_control style)
        next deadline += period          # absolute: the phase never drifts
        ran past it?  -> overruns += deadlines missed, skip them (keep the phase)
        wait until the deadline, or until wake() / request_exit()

``wake()`` (from another thread, e.g. a setpoint callback; or a mailbox handed
``wake_event``) makes the loop tick at once without moving the deadlines (``wake_ticks``
says it did). A tick that started before its deadline and ended after the next one counts
every deadline it missed as an overrun.

:func:`fast_thread_switch` shortens CPython's thread switch interval while a loop runs
beside bridge threads (module docstring of the function).
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field


@dataclass
class LoopStats:
    """What a loop did: ticks on deadlines, early ticks, deadlines missed."""

    ticks: int = 0
    wake_ticks: int = 0
    overruns: int = 0


@dataclass
class DeadlineLoop:
    """Run ``tick(now_ns)`` every ``period_ns`` on absolute deadlines (module docstring).

    ``clock`` returns nanoseconds (``time.monotonic_ns``); tests hand in their own.
    """

    period_ns: int
    clock: Callable[[], int] = time.monotonic_ns
    stats: LoopStats = field(default_factory=LoopStats)
    should_exit: bool = False
    _event: threading.Event = field(default_factory=threading.Event, repr=False)

    def __post_init__(self) -> None:
        if self.period_ns <= 0:
            raise ValueError(f"period_ns: expected > 0, got {self.period_ns}")

    @property
    def wake_event(self) -> threading.Event:
        """The event that wakes the loop: hand it to a mailbox's ``notify``."""
        return self._event

    def wake(self) -> None:
        """Tick as soon as possible (thread-safe); deadlines keep their phase."""
        self._event.set()

    def request_exit(self, *_: object) -> None:
        """Leave the loop after the current tick (thread-safe, signal-handler safe)."""
        self.should_exit = True
        self._event.set()

    def run(
        self,
        tick: Callable[[int], object],
        until: Callable[[], bool] | None = None,
        first_deadline_ns: int | None = None,
    ) -> LoopStats:
        """Tick until ``request_exit`` or ``until()`` is true; the first tick is due at
        ``first_deadline_ns`` (default: now, i.e. at once)."""
        deadline = self.clock() if first_deadline_ns is None else first_deadline_ns
        while not self.should_exit and (until is None or not until()):
            timeout_s = (deadline - self.clock()) * 1e-9
            early = timeout_s > 0 and self._event.wait(timeout_s)
            if early:
                self._event.clear()
                if self.should_exit:
                    break
            now = self.clock()
            tick(now)
            if now < deadline:  # woken early: this tick does not consume a deadline
                self.stats.wake_ticks += 1
                continue
            self.stats.ticks += 1
            deadline += self.period_ns
            late = self.clock() - deadline
            if late > 0:  # ran past the next deadline: count and skip what was missed
                missed = late // self.period_ns + 1
                self.stats.overruns += int(missed)
                deadline += int(missed) * self.period_ns
        return self.stats


@contextlib.contextmanager
def fast_thread_switch(interval_s: float = 2e-4) -> Iterator[None]:
    """Run the block with CPython's thread switch interval at ``interval_s``, then restore it.

    Bridge threads (pymavlink's dispatch, zenoh's callbacks, python-can's notifier) share
    the GIL with the loop; at the default 5 ms interval a thread holding the GIL delays the
    loop's wake-up by up to 5 ms, which shows up directly in the setpoint -> frame latency.
    0.2 ms bounds that hand-off.
    """
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    try:
        yield
    finally:
        sys.setswitchinterval(previous)
