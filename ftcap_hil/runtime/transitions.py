"""Log a condition when it starts and when it ends, never every cycle (PX4's habit).

:class:`TransitionLog` keeps one boolean per key; :meth:`TransitionLog.update` reports a
change through ``announce(text, severity)`` and returns whether it changed. A key that was
never seen counts as off, so a condition that starts off stays silent. :func:`log_to`
makes an ``announce`` that writes to a logger.
"""

from __future__ import annotations

import logging
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
    """Per-key on/off state with announcements on change (module docstring)."""

    def __init__(self, announce: Announce) -> None:
        self._announce = announce
        self._state: dict[str, bool] = {}

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
        if on:
            self._announce(on_text, severity)
        elif off_text is not None:
            self._announce(off_text, off_severity)
        return True
