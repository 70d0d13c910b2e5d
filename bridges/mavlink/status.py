"""The allocator's status on MAVLink: a status sink for the daemon's loop.

Each :meth:`MavlinkStatusSink.publish` (decimated by the daemon) sends HEARTBEAT state
(STANDBY while the setpoint is stale, ACTIVE while allocating), FTCAP_THRUST (u in N) and
ACTUATOR_OUTPUT_STATUS (u / u_max), FTCAP_ESC_STATUS with ESC_STATUS / ESC_INFO (when ESC
telemetry is monitored) and FTCAP_STATUS; announcements go out as STATUSTEXT with the
matching MAV_SEVERITY.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from bridges.mavlink.allocator import MavlinkAllocatorLink
from bridges.mavlink.codec import Severity as MavSeverity
from bridges.mavlink.codec import SystemStatus
from ftcap_hil.core.status import AllocatorStatus, Severity

_SEVERITY = {
    Severity.INFO: MavSeverity.INFO,
    Severity.WARNING: MavSeverity.WARNING,
    Severity.ERROR: MavSeverity.ERROR,
}


class MavlinkStatusSink:
    """Daemon status -> the allocator link's MAVLink messages (module docstring)."""

    def __init__(
        self,
        link: MavlinkAllocatorLink,
        esc_voltage: Callable[[], Sequence[float]] | None = None,
    ) -> None:
        self._link = link
        self._esc_voltage = esc_voltage  # V per ESC now (NaN unknown), for ESC_STATUS

    def publish(self, st: AllocatorStatus) -> None:
        """Send one status (checked when built: ``AllocatorStatus.checked``); the first call
        ends the link's MAV_STATE_BOOT."""
        state = SystemStatus.STANDBY if st.setpoint_stale else SystemStatus.ACTIVE
        self._link.set_system_status(state)
        self._link.send_thruster_commands(st.command)
        if st.esc_age_s:
            volts = () if self._esc_voltage is None else self._esc_voltage()
            self._link.send_esc_status(
                st.esc_rpm, st.esc_current_a, st.esc_age_s, st.esc_failed, volts
            )
        self._link.send_status(st)

    def announce(self, text: str, severity: Severity) -> None:
        """STATUSTEXT (chunked by the link when longer than 50 characters)."""
        self._link.send_statustext(text, _SEVERITY[severity])
