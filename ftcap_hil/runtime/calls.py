"""Work handed to the loop thread from other threads (parameter changes from a bridge).

The core is called from one thread only, so a bridge thread never changes it: it queues a
call with :meth:`PendingCalls.call_in_loop` (which also wakes the loop), and the loop runs
every queued call, in order, before its next cycle (:meth:`PendingCalls.run_pending`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable


class PendingCalls:
    """A thread-safe FIFO of calls for the loop thread (module docstring)."""

    def __init__(self, wake: Callable[[], None]) -> None:
        self._wake = wake
        self._lock = threading.Lock()
        self._pending: list[Callable[[], None]] = []

    def call_in_loop(self, fn: Callable[[], None]) -> None:
        """Any thread: run ``fn`` in the loop thread before the next cycle."""
        with self._lock:
            self._pending.append(fn)
        self._wake()

    def run_pending(self) -> int:
        """Loop thread: run what was queued so far, oldest first; how many ran. A call
        queued while these run waits for the next time."""
        with self._lock:
            pending, self._pending = self._pending, []
        for fn in pending:
            fn()
        return len(pending)
