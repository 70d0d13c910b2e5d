"""The allocator's status on Zenoh: a status sink for the daemon's loop.

Each :meth:`ZenohStatusSink.publish` (decimated by the daemon) puts the last command on
``thrusters/command`` and the status on ``allocator/status`` (also the answer to
``allocator/state`` queries). Zenoh carries no text channel: announcements are logged only.
"""

from __future__ import annotations

import logging

from bridges.zenoh_io.link import ZenohAllocatorLink
from ftcap_hil.core.status import AllocatorStatus, Severity

log = logging.getLogger(__name__)


class ZenohStatusSink:
    """Daemon status -> the allocator's Zenoh publications (module docstring)."""

    def __init__(self, link: ZenohAllocatorLink) -> None:
        self._link = link

    def publish(self, st: AllocatorStatus) -> None:
        """Put the command and the status (checked when built: ``AllocatorStatus.checked``)."""
        self._link.publish_thruster_command(st.command)
        self._link.publish_status(st)

    def announce(self, text: str, severity: Severity) -> None:
        """Logged at debug level (no text channel on Zenoh)."""
        log.debug("zenoh carries no text channel (%s): %s", severity.value, text)
