"""Log a condition when it starts and when it ends, never every cycle (PX4's habit).

:class:`TransitionLog` keeps one boolean per key; :meth:`TransitionLog.update` reports a
change through ``announce(text, severity)`` and returns whether it changed. A key that was
never seen counts as off, so a condition that starts off stays silent. With
``min_interval_s``, a key that keeps flipping is announced at most once per interval: the
changes held back go to ``quiet`` (if given), and the next announcement says how many there
were. :func:`log_to` makes an ``announce`` that writes to a logger.

Every layer that announces transitions uses it: the allocator daemon and its watchdogs, the
simulated vessel, the ground station's flight, the bridges' ports.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from ftcap_hil.core.status import Severity

Announce = Callable[[str, Severity], None]

LOG_LEVEL = {
    Severity.INFO: logging.INFO,
    Severity.WARNING: logging.WARNING,
    Severity.ERROR: logging.ERROR,
}


def log_to(logger: logging.Logger) -> Announce:
    """An ``announce`` that logs the text at the severity's level."""

    def announce(text: str, severity: Severity) -> None:
        logger.log(LOG_LEVEL[severity], "%s", text)

    return announce


class TransitionLog:
    """Per-key on/off state with announcements on change (module docstring).

    ``clock`` (monotonic ns) is read only with ``min_interval_s`` > 0.
    """

    def __init__(
        self,
        announce: Announce,
        *,
        min_interval_s: float = 0.0,
        quiet: Announce | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self._announce = announce
        self._state: dict[str, bool] = {}
        self._min_interval_ns = int(min_interval_s * 1e9)
        self._quiet = quiet
        self._clock = clock
        self._said: dict[str, tuple[int, int]] = {}  # key -> (last announced ns, held back)

    def __getitem__(self, key: str) -> bool:
        return self._state.get(key, False)

    def update(
        self,
        key: str,
        on: bool,
        on_text: str,
        off_text: str | None = None,
        severity: Severity = Severity.WARNING,
        off_severity: Severity = Severity.INFO,
    ) -> bool:
        """Set ``key`` to ``on``; announce ``on_text`` (at ``severity``) when it turns on and
        ``off_text`` (at ``off_severity``; None: say nothing) when it turns off. True if it
        changed."""
        if on == self._state.get(key, False):
            return False
        self._state[key] = on
        text = on_text if on else off_text
        if text is not None:
            self._say(key, text, severity if on else off_severity)
        return True

    def _say(self, key: str, text: str, severity: Severity) -> None:
        if self._min_interval_ns <= 0:
            self._announce(text, severity)
            return
        now = self._clock()
        last = self._said.get(key)
        if last is not None and now - last[0] < self._min_interval_ns:
            self._said[key] = (last[0], last[1] + 1)
            if self._quiet is not None:
                self._quiet(text, severity)
            return
        held = 0 if last is None else last[1]
        self._said[key] = (now, 0)
        more = f" ({held} changes not logged since the last line)" if held else ""
        self._announce(text + more, severity)
