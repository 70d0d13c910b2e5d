"""The ESC command stream: the latest RawCommand re-sent at the ESCs' rate, in its own thread.

Real DroneCAN ESCs expect ``esc.RawCommand`` at a steady rate and stop their motor when none
came for a while (ArduPilot's AP_Periph: 200 ms). The allocation may run slower than that
(a few Hz when idle) or jitter, so :class:`EscCommandStream` decouples the two: the loop
hands it each new allocation (``update``), and a thread sends the latest one every
``1 / rate_hz`` on absolute deadlines (default 100 Hz, at most 400 Hz).

It holds a command for at most ``hold_s``: if the loop stops updating (hung, or stalled
longer than that), the stream sends zero instead, so it never keeps a dead allocator's last
command alive past the ESCs' own watchdog. Counters: ``sent``, ``send_failures``,
``late_ticks`` (deadlines missed by more than a period: that many frames were skipped, not
bunched), ``holds_expired`` (times the hold ran out).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 100.0
MAX_RATE_HZ = 400.0
DEFAULT_HOLD_S = 1.0

Raw = tuple[int, ...]


def check_rate(rate_hz: float, hold_s: float) -> None:
    """Raise ValueError unless 1 <= rate_hz <= 400 Hz and hold_s exceeds one period."""
    if not 1.0 <= rate_hz <= MAX_RATE_HZ:
        raise ValueError(f"can.esc_rate_hz: expected 1..{MAX_RATE_HZ:g} Hz, got {rate_hz!r}")
    if not hold_s > 1.0 / rate_hz:
        raise ValueError(f"can.esc_hold_s: expected more than one period, got {hold_s!r}")


class EscCommandStream:
    """Sends ``send(latest)`` every ``1 / rate_hz`` s from a daemon thread (module docstring).

    ``send`` returns False when the bus refused the frames (counted, the stream carries on);
    ``zero`` is the all-zero command sent before the first ``update`` and after a hold runs
    out.
    """

    def __init__(
        self,
        send: Callable[[Raw], bool],
        zero: Raw,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        hold_s: float = DEFAULT_HOLD_S,
        name: str = "can-esc-stream",
    ) -> None:
        check_rate(rate_hz, hold_s)
        self._send = send
        self._zero = zero
        self.period_ns = int(1e9 / rate_hz)
        self._hold_ns = int(hold_s * 1e9)
        self._latest: tuple[Raw, int] = (zero, time.monotonic_ns())
        self._held = True  # the start-up zero is not a hold that ran out
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.sent = 0
        self.send_failures = 0
        self.late_ticks = 0
        self.holds_expired = 0

    def update(self, raw: Raw, now_ns: int | None = None) -> None:
        """The allocation to hold from now on (one int14 per ESC)."""
        self._latest = (raw, time.monotonic_ns() if now_ns is None else now_ns)
        self._held = False

    def start(self) -> EscCommandStream:
        """Start the thread (once); returns self."""
        self._thread.start()
        return self

    @property
    def running(self) -> bool:
        """The thread is sending."""
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Stop sending and join the thread. Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def command_now(self, now_ns: int) -> Raw:
        """What a tick at ``now_ns`` sends: the latest command, or zero once it is too old."""
        raw, stamp = self._latest
        if now_ns - stamp <= self._hold_ns:
            return raw
        if not self._held:
            self._held = True
            self.holds_expired += 1
            log.warning(
                "ESC stream: no new allocation for %.2f s: sending zero", (now_ns - stamp) / 1e9
            )
        return self._zero

    def _run(self) -> None:
        deadline = time.monotonic_ns()
        while not self._stop.is_set():
            now = time.monotonic_ns()
            if self._send(self.command_now(now)):
                self.sent += 1
            else:
                self.send_failures += 1
            deadline += self.period_ns
            now = time.monotonic_ns()
            if now - deadline > self.period_ns:  # fell behind: skip, do not send a burst
                missed = (now - deadline) // self.period_ns
                self.late_ticks += int(missed)
                deadline += missed * self.period_ns
            if self._stop.wait(max(0.0, (deadline - now) / 1e9)):
                return
