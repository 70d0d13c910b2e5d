"""Where the bridges meet the loop: latest-value mailboxes and bounded event queues.

Library callbacks (pymavlink's dispatch thread, zenoh's callbacks, python-can's notifier)
never run allocator code: they validate, then ``put`` into a :class:`Mailbox` (latest value
wins: setpoints, telemetry) or an :class:`EventQueue` (every item counts: fault injections).
Both stamp on arrival with ``time.monotonic_ns()`` unless the caller hands a stamp in; the
loop thread reads them with their ages. Counters let the status report drops per port.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass
class Stamped(Generic[T]):
    """A value and its arrival stamp (``time.monotonic_ns()`` unless handed in)."""

    value: T
    stamp_ns: int


@dataclass
class Mailbox(Generic[T]):
    """Latest-value slot written by library callbacks, read by the loop thread.

    Callbacks never run allocator code: they validate, then ``put``. The loop reads the
    latest value (:meth:`latest`, not consumed) and its age (:meth:`age_s`). Counters let the
    status report drops per port.
    """

    name: str
    _slot: Stamped[T] | None = None
    received: int = 0
    malformed: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    notify: threading.Event | None = None  # set on every put: wakes the loop early
    # every value put also goes here (a loop that needs each sample, not only the latest)
    history: EventQueue[T] | None = None

    def put(self, value: T, stamp_ns: int | None = None) -> None:
        """Replace the latest value (stamped now unless ``stamp_ns`` is given); sets
        ``notify``; appends to ``history``."""
        stamped = Stamped(value, time.monotonic_ns() if stamp_ns is None else stamp_ns)
        with self._lock:
            self._slot = stamped
            self.received += 1
        if self.history is not None:
            self.history.put(value, stamped.stamp_ns)
        if self.notify is not None:
            self.notify.set()

    def count_malformed(self) -> None:
        """Count one input that was dropped as malformed before reaching the slot."""
        with self._lock:
            self.malformed += 1

    def latest(self) -> Stamped[T] | None:
        """The latest value with its stamp, or None if nothing arrived yet (not consumed)."""
        with self._lock:
            return self._slot

    def age_s(self, now_ns: int | None = None) -> float:
        """Seconds since the latest value arrived; +inf if none ever did."""
        slot = self.latest()
        if slot is None:
            return math.inf
        now = time.monotonic_ns() if now_ns is None else now_ns
        return (now - slot.stamp_ns) * 1e-9


class EventQueue(Generic[T]):
    """Bounded FIFO of stamped events, written by callbacks and drained by the loop thread.

    Unlike a :class:`Mailbox` nothing is overwritten: on overflow the oldest item is dropped
    and counted in ``overflowed``. :meth:`room` lets a producer refuse a batch that would
    not fit (the MAVLink injection path answers TEMPORARILY_REJECTED then).
    """

    def __init__(self, name: str, maxlen: int = 64) -> None:
        self.name = name
        self.maxlen = maxlen
        self.received = 0
        self.malformed = 0
        self.overflowed = 0
        self._queue: collections.deque[Stamped[T]] = collections.deque(maxlen=maxlen)
        self._lock = threading.Lock()

    def put(self, value: T, stamp_ns: int | None = None) -> None:
        """Append one event (stamped now unless ``stamp_ns`` is given); a full queue drops
        its oldest item and counts it in ``overflowed``."""
        stamped = Stamped(value, time.monotonic_ns() if stamp_ns is None else stamp_ns)
        with self._lock:
            if len(self._queue) == self.maxlen:
                self.overflowed += 1
            self._queue.append(stamped)
            self.received += 1

    def count_malformed(self) -> None:
        """Count one input that was dropped as malformed before reaching the queue."""
        with self._lock:
            self.malformed += 1

    def room(self) -> int:
        """How many items fit before the oldest would be dropped."""
        with self._lock:
            return self.maxlen - len(self._queue)

    def drain(self) -> list[Stamped[T]]:
        """Every item received since the last drain, oldest first."""
        with self._lock:
            items = list(self._queue)
            self._queue.clear()
        return items
