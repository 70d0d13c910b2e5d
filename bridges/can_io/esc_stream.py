"""The ESC command stream: the latest RawCommand re-sent at the ESCs' rate, in its own thread.

Real DroneCAN ESCs expect ``esc.RawCommand`` at a steady rate and stop their motor when none
came for a while (ArduPilot's AP_Periph: 200 ms). The allocation may run slower than that
(a few Hz when idle) or jitter, so :class:`EscCommandStream` decouples the two: the loop
hands it each new allocation (``update``, which also sends it at once), and a thread sends
the latest one every ``1 / rate_hz`` on absolute deadlines (default 100 Hz, at most 400 Hz).

Lapses: what the ESCs have when the stream could not keep them fed. Two cases put them at
zero, and the stream then holds zero (never the old command): with ``restart_from_zero``
until its owner takes the lapse (``take_lapse``) and so restarts its own command from zero,
as the ESCs did; without, until the next ``update``:

* no command reached the bus for longer than ``esc_timeout_s`` (the ESCs' own command
  timeout): the bus was down, or this process stalled; the lapse lasts until a send
  succeeds again;
* no allocation came for ``hold_s`` (the loop hung while the stream ran): zero was sent
  instead of keeping a dead allocator's last command alive.

Counters: ``sent``, ``send_failures``, ``late_ticks`` (deadlines missed by more than a
period: that many frames were skipped, not bunched), ``holds_expired``, ``lapses`` (times a
lapse began, either kind).
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
DEFAULT_ESC_TIMEOUT_S = 0.2  # AP_Periph's ESC command timeout

Raw = tuple[int, ...]


def check_rate(rate_hz: float, hold_s: float, esc_timeout_s: float = DEFAULT_ESC_TIMEOUT_S) -> None:
    """Raise ValueError unless 1 <= rate_hz <= 400 Hz and both hold_s and esc_timeout_s
    exceed one period."""
    if not 1.0 <= rate_hz <= MAX_RATE_HZ:
        raise ValueError(f"can.esc_rate_hz: expected 1..{MAX_RATE_HZ:g} Hz, got {rate_hz!r}")
    if not hold_s > 1.0 / rate_hz:
        raise ValueError(f"can.esc_hold_s: expected more than one period, got {hold_s!r}")
    if not esc_timeout_s > 1.0 / rate_hz:
        raise ValueError(
            f"can.esc_command_timeout_s: expected more than one period, got {esc_timeout_s!r}"
        )


class EscCommandStream:
    """Sends the latest command every ``1 / rate_hz`` s from a daemon thread (module
    docstring).

    ``send`` returns False when the bus refused the frames (counted, the stream carries on);
    ``zero`` is the all-zero command sent before the first ``update`` and during a lapse.
    Thread-safe: ``update`` and ``take_lapse`` come from the owner's loop, ticks from the
    stream's thread.
    """

    def __init__(
        self,
        send: Callable[[Raw], bool],
        zero: Raw,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        hold_s: float = DEFAULT_HOLD_S,
        esc_timeout_s: float = DEFAULT_ESC_TIMEOUT_S,
        restart_from_zero: bool = False,
        name: str = "can-esc-stream",
    ) -> None:
        check_rate(rate_hz, hold_s, esc_timeout_s)
        self._send = send
        self._zero = zero
        self.period_ns = int(1e9 / rate_hz)
        self._hold_ns = int(hold_s * 1e9)
        self._timeout_ns = int(esc_timeout_s * 1e9)
        self._restart_from_zero = restart_from_zero
        now = time.monotonic_ns()
        self._latest: tuple[Raw, int] = (zero, now)
        self._last_ok_ns = now  # a bus dead from the start is a lapse too
        self._held = True  # the start-up zero is not a hold that ran out
        self._lapse_pending = False  # a lapse began and the owner has not taken it yet
        self._silent = False  # in a lapse of the first kind (no send succeeded lately)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.sent = 0
        self.send_failures = 0
        self.late_ticks = 0
        self.holds_expired = 0
        self.lapses = 0

    def update(self, raw: Raw, now_ns: int | None = None) -> bool:
        """Hold ``raw`` (one int14 per ESC) from now on and send it at once; with
        ``restart_from_zero``, during a lapse not yet taken, zero is held and sent instead
        (``raw`` was computed from the command the ESCs no longer have). False if the bus
        refused it."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        with self._lock:
            self._check_silence(now)
            if not (self._restart_from_zero and self._lapse_pending):
                self._latest = (raw, now)
                self._held = False
            return self._send_locked(self.command_now(now), now)

    def take_lapse(self, now_ns: int | None = None) -> bool:
        """True if the ESCs may have dropped to zero since the last call (a lapse began, or
        one is still on): the owner restarts its command from zero. Clears the lapse."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        with self._lock:
            self._check_silence(now)
            lapsed = self._lapse_pending or self._silent
            self._lapse_pending = False
            return lapsed

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
        """What a tick at ``now_ns`` sends: the latest command (zero since a lapse began),
        or zero once it is older than ``hold_s``."""
        raw, stamp = self._latest
        if now_ns - stamp <= self._hold_ns:
            return raw
        if not self._held:
            self._held = True
            self.holds_expired += 1
            self._begin_lapse(f"no new allocation for {(now_ns - stamp) / 1e9:.2f} s")
        return self._zero

    def _check_silence(self, now_ns: int) -> None:
        if not self._silent and now_ns - self._last_ok_ns > self._timeout_ns:
            self._silent = True
            gap = (now_ns - self._last_ok_ns) / 1e9
            self._begin_lapse(f"no command reached the bus for {gap:.2f} s")

    def _begin_lapse(self, why: str) -> None:
        self.lapses += 1
        self._lapse_pending = True
        self._latest = (self._zero, self._latest[1])
        log.warning("ESC stream: %s: the ESCs are at zero; holding zero", why)

    def _send_locked(self, raw: Raw, now_ns: int) -> bool:
        if not self._send(raw):
            self.send_failures += 1
            return False
        self.sent += 1
        self._last_ok_ns = time.monotonic_ns()
        self._silent = False
        return True

    def _tick(self) -> None:
        now = time.monotonic_ns()
        with self._lock:
            self._check_silence(now)
            self._send_locked(self.command_now(now), now)

    def _run(self) -> None:
        deadline = time.monotonic_ns()
        while not self._stop.is_set():
            self._tick()
            deadline += self.period_ns
            now = time.monotonic_ns()
            if now - deadline > self.period_ns:  # fell behind: skip, do not send a burst
                missed = (now - deadline) // self.period_ns
                self.late_ticks += int(missed)
                deadline += missed * self.period_ns
            if self._stop.wait(max(0.0, (deadline - now) / 1e9)):
                return
