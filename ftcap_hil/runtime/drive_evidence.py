"""What the ESC telemetry tells the allocator's core, one code path with the offline loop.

With the drives' data sheets (``DaemonConfig.drives``: a realistic scenario's drives, the
core's shaft diagnosis on) every ``esc.Status`` received since the last cycle becomes a
:class:`~ftcap_hil.core.estimation.shaft.DriveReport` stamped with its receipt time, and the
core judges each thruster by its shaft as ``simulate`` and the campaign do
(``FtcapCore.step(feedback=..., t_s=...)``); a silent ESC is then *telemetry lost* (that
thruster judged by the motion alone), not a dead thruster, and the daemon-only stall rule is
off. Without telemetry (no ESC port, or every ESC silent) the core runs on the motion alone,
announced once when it starts and when it ends.

Without data sheets (the paper's vessel) the ESC evidence is the watchdog's: a silent ESC
allocated as failed, a stalled shaft (:class:`~ftcap_hil.runtime.esc_watchdog.EscStallMonitor`)
as dead.

Times: the core's diagnosis runs on this process's monotonic clock, in sim seconds
(``time_scale`` x the wall clock, so that a vessel run faster than real time keeps its
drives' time constants).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from ftcap_hil.core.estimation.shaft import DriveModel, DriveReport
from ftcap_hil.core.evidence import Evidence
from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import EventQueue
from ftcap_hil.ports.transitions import TransitionLog
from ftcap_hil.runtime.esc_watchdog import EscStallMonitor
from sim.live_truth import speed_from_rpm


def diagnosis_line(
    drives: Sequence[DriveModel] | None, diagnosing: bool, reports: object, why_off: str
) -> str:
    """The start-up line on how the thrusters are judged (``why_off``: why the core has
    no diagnosis although ``drives`` are known)."""
    if drives is None:
        return (
            "thrusters judged by the motion and the ESC watchdog (no drive data sheets: "
            "--scenario with a realistic scenario gives them)"
        )
    if not diagnosing:
        return f"thrusters judged by the motion alone: {why_off}"
    if reports is None:
        return "thrusters judged by the motion alone: no ESC telemetry port ([can] esc_monitor)"
    return (
        f"thrusters judged by their drives (esc.Status rpm and current against "
        f"{len(drives)} data sheets) and the motion"
    )


class DriveEvidence:
    """The ESC telemetry as the core's evidence and drive reports (module docstring)."""

    def __init__(
        self,
        transitions: TransitionLog,
        drives: Sequence[DriveModel] | None,
        reports: EventQueue[EscStatus] | None,
        stall: EscStallMonitor,
        time_scale: float = 1.0,
    ) -> None:
        self._transitions = transitions
        self._drives = None if drives is None else tuple(drives)
        self._reports = reports
        self._stall = stall
        self.time_scale = time_scale
        self.received = 0  # drive reports handed to the core

    @property
    def diagnosing(self) -> bool:
        """Whether the drives' reports go to the core's diagnosis."""
        return self._drives is not None

    def core_time_s(self, now_ns: int) -> float:
        """``now_ns`` (monotonic) as the core's diagnosis clock (s)."""
        return now_ns * 1e-9 * self.time_scale

    def take(self, now_ns: int, ages_s: FloatArray | None, timeout_s: float) -> list[DriveReport]:
        """The reports received since the last call, oldest first; announces when the
        thrusters are judged by the motion alone (no ESC heard within ``timeout_s``)."""
        if self._drives is None:
            return []
        items = [] if self._reports is None else self._reports.drain()
        out = [
            DriveReport(
                self.core_time_s(it.stamp_ns),
                it.value.index,
                speed_from_rpm(it.value.rpm, self._drives[it.value.index].is_shaft),
                it.value.current_a,
            )
            for it in items
            if 0 <= it.value.index < len(self._drives) and math.isfinite(it.value.rpm)
        ]
        self.received += len(out)
        silent = ages_s is None or not bool(np.any(ages_s <= timeout_s))
        self._transitions.update(
            "drive_telemetry",
            silent,
            "no drive telemetry (esc.Status): thrusters judged by the motion alone",
            "drive telemetry received: thrusters judged by their drives and the motion",
            severity=Severity.WARNING,
            off_severity=Severity.INFO,
        )
        return out

    def failed(self, silent: BoolArray) -> BoolArray:
        """The watchdog's silent ESCs as the status reports them failed: none with the
        drives' diagnosis (a silent drive is telemetry lost, its hypothesis says so)."""
        return np.zeros_like(silent) if self._drives is not None else silent

    def discard(self) -> None:
        """Drop the reports received so far (a cycle without allocation: they would be
        judged against commands the core never gave)."""
        if self._reports is not None:
            self._reports.drain()

    def evidence(
        self,
        now_ns: int,
        u_prev: FloatArray,
        failed: BoolArray | None,
        ages_s: FloatArray | None,
        latest: Callable[[], Sequence[EscStatus | None]] | None,
        timeout_s: float,
    ) -> Evidence | None:
        """The ESC evidence for the core: none with drive data sheets (the diagnosis
        judges), else the watchdog's ``failed`` and the stall rule's stalled thrusters."""
        m = u_prev.size
        if self._drives is not None:
            return None
        stalled = None
        if self._stall.stall_rpm > 0 and latest is not None and ages_s is not None:
            rpm = np.array([math.nan if s is None else s.rpm for s in latest()], dtype=np.float64)
            stalled = self._stall.update(now_ns, u_prev, rpm, ages_s, timeout_s)
        return Evidence.of(m, failed, stalled)
