"""A python-can bus that survives its backend going away: ``ReconnectingBus``.

Wraps any bus made by a factory (a ``CanHubBus``, a socketcan bus): when the backend fails
(the hub restarted, the interface went down, the adapter was unplugged), the wrapper closes
it, announces the outage once (a warning), and re-opens it in the background of the next
``send``/``recv`` calls, at most once every ``retry_period_s``. While the bus is down,
``send`` raises ``CanOperationError`` (the adapters count it and mark their port stale) and
``recv`` behaves like a silent bus, so python-can's ``Notifier`` keeps running. When the
factory succeeds again the return is announced (an info line with the outage's length) and
frames flow again: nobody has to restart the process.

Counters: ``outages`` (times the backend was lost), ``reconnects`` (times it came back),
``failed_attempts`` (re-opens that failed), ``down_since_s`` (monotonic start of the current
outage, None while up). Frames sent while down are not queued: a thruster command is only
worth its latest value, and the ESC stream sends a fresh one at its own rate.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import can

log = logging.getLogger(__name__)

BusFactory = Callable[[], can.BusABC]
DEFAULT_RETRY_PERIOD_S = 0.25


class ReconnectingBus(can.BusABC):
    """A bus from ``factory`` that is re-opened by itself after it fails (module docstring).

    ``factory`` opens the backend and raises (``can.CanError`` or ``OSError``) if it cannot;
    the first call is made here, so a bus that cannot be opened at start-up still fails at
    once. ``name`` is used in the log lines.
    """

    def __init__(
        self,
        factory: BusFactory,
        *,
        name: str = "CAN bus",
        retry_period_s: float = DEFAULT_RETRY_PERIOD_S,
        **kwargs: Any,
    ) -> None:
        if not retry_period_s > 0.0:
            raise ValueError(f"retry_period_s: expected a period > 0 s, got {retry_period_s!r}")
        self._factory = factory
        self._name = name
        self._retry_ns = int(retry_period_s * 1e9)
        self._lock = threading.Lock()  # guards _inner swaps; never held while blocked in I/O
        self._reopen_lock = threading.Lock()
        self._inner: can.BusABC | None = factory()
        self._next_try_ns = 0
        self.outages = 0
        self.reconnects = 0
        self.failed_attempts = 0
        self.down_since_s: float | None = None
        self.channel_info = f"reconnecting {getattr(self._inner, 'channel_info', name)}"
        super().__init__(channel=getattr(self._inner, "channel", name), **kwargs)

    @property
    def is_up(self) -> bool:
        """The backend is open (the last operation on it did not fail)."""
        return self._inner is not None

    @property
    def inner(self) -> can.BusABC | None:
        """The backend bus now (None while down)."""
        return self._inner

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send through the backend; ``CanOperationError`` while it is down or if it fails."""
        inner = self._current()
        if inner is None:
            raise can.CanOperationError(f"{self._name}: down since {self._down_for_s():.1f} s")
        try:
            inner.send(msg, timeout)
        except (can.CanError, OSError) as e:
            self._lost(inner, e)
            raise can.CanOperationError(f"{self._name}: send failed: {e}") from e

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        inner = self._current()
        if inner is None:
            wait_s = self._retry_ns / 1e9 if timeout is None else min(timeout, self._retry_ns / 1e9)
            time.sleep(max(0.0, wait_s))
            return None, False
        try:
            msg = inner.recv(timeout)
        except (can.CanError, OSError) as e:
            if self._is_shutdown:
                raise can.CanOperationError(f"{self._name}: bus was shut down") from e
            self._lost(inner, e)
            return None, False
        if msg is None and inner.state is can.BusState.ERROR:  # a backend gone quiet
            self._lost(inner, "the backend reports an error state")
        return msg, True  # the backend applied its own filters

    def _current(self) -> can.BusABC | None:
        """The backend, re-opened first if it is down and a retry is due."""
        inner = self._inner
        if inner is not None or self._is_shutdown:
            return inner
        if time.monotonic_ns() < self._next_try_ns or not self._reopen_lock.acquire(False):
            return None
        try:
            return self._reopen()
        finally:
            self._reopen_lock.release()

    def _reopen(self) -> can.BusABC | None:
        self._next_try_ns = time.monotonic_ns() + self._retry_ns
        try:
            inner = self._factory()
        except (can.CanError, OSError, ValueError) as e:
            self.failed_attempts += 1
            log.debug("%s: re-open failed: %s", self._name, e)
            return None
        with self._lock:
            if self._is_shutdown:
                inner.shutdown()
                return None
            self._inner = inner
        self.reconnects += 1
        log.info("%s: back after %.2f s (outage %d)", self._name, self._down_for_s(), self.outages)
        self.down_since_s = None
        return inner

    def _lost(self, inner: can.BusABC, why: BaseException | str) -> None:
        with self._lock:
            if self._inner is not inner:
                return  # another thread already saw this backend fail
            self._inner = None
        self.outages += 1
        self.down_since_s = time.monotonic()
        self._next_try_ns = time.monotonic_ns() + self._retry_ns
        log.warning("%s: lost (%s); re-opening every %.2f s", self._name, why, self._retry_ns / 1e9)
        _quiet_shutdown(inner)

    def _down_for_s(self) -> float:
        since = self.down_since_s
        return 0.0 if since is None else time.monotonic() - since

    def flush_tx_buffer(self) -> None:
        """Flush the backend's transmit buffer, if it is up."""
        inner = self._inner
        if inner is not None:
            inner.flush_tx_buffer()

    def shutdown(self) -> None:
        """Close the backend and stop re-opening it. Idempotent."""
        if self._is_shutdown:
            return
        super().shutdown()
        with self._lock:
            inner, self._inner = self._inner, None
        if inner is not None:
            _quiet_shutdown(inner)


def _quiet_shutdown(bus: can.BusABC) -> None:
    try:
        bus.shutdown()
    except (can.CanError, OSError) as e:
        log.debug("closing a failed CAN backend: %s", e)
