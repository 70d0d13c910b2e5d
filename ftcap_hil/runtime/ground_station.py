"""The ground-station driver: ``ftcap-hil gcs``, the end-to-end tests and the vcan tests.

A :class:`GroundStation` drives one open :class:`~ftcap_hil.ports.ground_link.GroundLink`
(the caller opens and closes it; ``bridges.mavlink.gcs.MavlinkGcsLink`` is one):

* :meth:`GroundStation.connect`: the HEARTBEATs of the vessel and the allocator, the
  allocator past MAV_STATE_BOOT (its control loop runs), the vessel's SYS_FAILURE_EN = 1 (if
  faults are to be injected), the allocator's FTC_MODE set (if asked) and read back, the
  first ODOMETRY: its receive stamp is mission time 0.
* :meth:`GroundStation.flight` -> :class:`Flight` (:meth:`Flight.run` in this thread, or
  :meth:`Flight.start` in one of its own): every ``period_s`` on absolute deadlines
  (:class:`~ftcap_hil.runtime.loop.DeadlineLoop`) the plan's :class:`WrenchLaw` -> one
  WRENCH_SETPOINT; the plan's fault changes -> MAV_CMD_INJECT_FAILURE from a worker thread
  (:mod:`~ftcap_hil.runtime.injector`: the loop never waits for an ACK); STATUSTEXTs drained
  and logged; optionally a :class:`~ftcap_hil.report.flight.FlightRecorder` row and every
  new FTCAP_STATUS kept.
* :meth:`GroundStation.wind_down`: zero wrench, the vessel's faults cleared.

Failures are :class:`GroundStationError` subclasses carrying the shared exit codes
(:class:`~ftcap_hil.core.errors.ExitCode`): :class:`NoAnswer` (3) at start-up,
:class:`LinkLost` (4) mid-flight, :class:`Refused` (5), :class:`Interrupted` (130) when a
stop was requested before the flight began. :func:`flight_plan` turns a
:class:`~ftcap_hil.config.mission.Mission` (what ``ftcap_hil.config.mission`` reads from a
mission file) into the :class:`FlightPlan` a flight flies.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from ftcap_hil.config.mission import Mission
from ftcap_hil.core.messages import FaultKind
from ftcap_hil.core.status import Mode
from ftcap_hil.ports.ground_link import GroundLink, ParamWrite, Reply
from ftcap_hil.report.flight import FlightRecorder
from ftcap_hil.runtime.gcs_flight import Flight, log
from ftcap_hil.runtime.gcs_parts import (
    FlightPlan,
    GroundStationError,
    InjectionOutcome,
    Interrupted,
    LinkLost,
    NoAnswer,
    ProgressLine,
    Refused,
    StatusLine,
    WrenchLaw,
    state_of,
)

__all__ = [
    "Connection",
    "Flight",
    "FlightPlan",
    "flight_plan",
    "GroundStation",
    "GroundStationError",
    "InjectionOutcome",
    "Interrupted",
    "LinkLost",
    "NoAnswer",
    "ProgressLine",
    "Refused",
    "StatusLine",
    "WrenchLaw",
    "state_of",
]

T = TypeVar("T")


def flight_plan(mission: Mission) -> FlightPlan:
    """Eq. (24) of the mission's scenario toward its reference, its injections and the
    ``[gcs]`` limits, every ``period_s``."""
    sc = mission.scenario
    return FlightPlan(
        WrenchLaw.track(sc.reference_at, sc.controller),
        mission.period_s,
        duration_s=mission.duration_s,
        injections=tuple(mission.injections),
        wrench_limit=mission.gcs.wrench_limit,
        odometry_timeout_s=mission.gcs.odometry_timeout_s,
        time_scale=mission.gcs.time_scale if mission.gcs.vessel_clock else 1.0,
    )


@dataclass(frozen=True)
class Connection:
    """What :meth:`GroundStation.connect` found; stamps are ``time.monotonic_ns()``."""

    t0_ns: int  # receive stamp of the first ODOMETRY: mission time 0
    heartbeats_ns: int  # both HEARTBEATs heard
    ready_ns: int  # the allocator's loop running
    failure_enable: float | None  # SYS_FAILURE_EN as the vessel reports it (None: not set)
    mode: str | None  # FTC_MODE read back (None: not read)


@dataclass
class GroundStation:
    """The ground station on ``link`` (module docstring).

    ``check`` is called while waiting and every cycle; it raises to abort (e.g. a peer
    process died). :meth:`request_exit` is safe from a signal handler or another thread.
    """

    link: GroundLink
    check: Callable[[], None] | None = None
    current: Flight | None = None
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)

    def request_exit(self) -> None:
        """Abort the start-up, or end the flight after its current cycle."""
        self._stop.set()
        if self.current is not None:
            self.current.request_exit()

    def _abort_if_asked(self) -> None:
        if self._stop.is_set():
            raise Interrupted("interrupted before the flight started")
        if self.check is not None:
            self.check()

    def _wait(self, ready: Callable[[float], T], timeout_s: float) -> T | None:
        """``ready(slice_s)`` until truthy (returned) or ``timeout_s`` passed (None)."""
        deadline = time.monotonic() + timeout_s
        while True:
            self._abort_if_asked()
            got = ready(min(0.2, max(0.0, deadline - time.monotonic())))
            if got:
                return got
            if time.monotonic() >= deadline:
                return None

    def _first_odometry(self, slice_s: float) -> int:
        end = time.monotonic() + slice_s
        while (first := self.link.odometry.latest()) is None and time.monotonic() < end:
            time.sleep(0.01)
        return 0 if first is None else first.stamp_ns

    def _vessel_epoch(self, time_scale: float, slice_s: float) -> int:
        """When (monotonic ns) the released vessel's clock was 0: the first ODOMETRY past
        t = 0, its receipt less its sim time at ``time_scale``; 0 while none came."""
        end = time.monotonic() + slice_s
        while time.monotonic() < end:
            got = self.link.odometry.latest()
            if got is not None and got.value.time_s > 0.0:
                return got.stamp_ns - int(got.value.time_s / time_scale * 1e9)
            time.sleep(0.005)
        return 0

    def _confirm(self, who: str, ids: tuple[int, int], write: Callable[[], ParamWrite]) -> float:
        """``write()`` a parameter of the ``who`` at ``ids``; the value it reports back."""
        self._abort_if_asked()
        got = write()
        if got.reported is None:
            raise NoAnswer(f"the {who} {ids} did not answer PARAM_SET {got.name} = {got.value}")
        if got.reported != got.value:
            raise Refused(
                f"the {who} {ids} refused {got.name} = {got.value} (it reports {got.reported:g})"
            )
        return got.reported

    def connect(
        self,
        timeout_s: float,
        *,
        enable_failures: bool = False,
        mode: Mode | None = None,
        read_mode: bool = True,
        param_timeout_s: float = 1.0,
        release: float | None = None,
    ) -> Connection:
        """Start-up over MAVLink (module docstring); :class:`NoAnswer`, :class:`Refused`,
        :class:`Interrupted` or whatever ``check`` raises if it cannot complete."""
        link = self.link
        for name, ids in (("vessel", link.vessel_ids), ("allocator", link.allocator_ids)):
            if not self._wait(functools.partial(link.wait_heartbeat, ids), timeout_s):
                raise NoAnswer(
                    f"no HEARTBEAT from the {name} {ids} within {timeout_s:g} s: is it "
                    "running, and on the expected UDP port?"
                )
        heartbeats_ns = time.monotonic_ns()
        if not self._wait(lambda s: link.wait_ready(link.allocator_ids, s), timeout_s):
            raise NoAnswer(
                f"the allocator {link.allocator_ids} still reports MAV_STATE_BOOT after "
                f"{timeout_s:g} s: its control loop has not started (see its log)"
            )
        ready_ns = time.monotonic_ns()
        enabled = None
        if enable_failures:
            enabled = self._confirm(
                "vessel",
                link.vessel_ids,
                lambda: link.allow_fault_injection(timeout_s=param_timeout_s),
            )
        if mode is not None:
            self._confirm(
                "allocator",
                link.allocator_ids,
                lambda: link.request_mode(mode, timeout_s=param_timeout_s),
            )
        mode_name = self._read_mode(min(timeout_s, 5.0)) if read_mode else None
        if release is not None:  # a held vessel: mission time is its clock from here
            write = functools.partial(link.release_vessel, timeout_s=param_timeout_s)
            self._confirm("vessel", link.vessel_ids, write)
            t0_ns = self._wait(functools.partial(self._vessel_epoch, release), timeout_s)
            if t0_ns is None:
                raise NoAnswer(f"the vessel sent no ODOMETRY after its release in {timeout_s:g} s")
            return Connection(t0_ns, heartbeats_ns, ready_ns, enabled, mode_name)
        t0_ns = self._wait(self._first_odometry, timeout_s)
        if t0_ns is None:
            raise NoAnswer(f"no ODOMETRY from the vessel within {timeout_s:g} s")
        return Connection(t0_ns, heartbeats_ns, ready_ns, enabled, mode_name)

    def _read_mode(self, timeout_s: float) -> str:
        self._abort_if_asked()
        mode = self.link.read_mode(timeout_s=timeout_s)
        if mode is None:
            raise NoAnswer("the allocator did not report FTC_MODE (parameter protocol)")
        return mode.value

    def flight(
        self,
        plan: FlightPlan,
        t0_ns: int | None = None,
        recorder: FlightRecorder | None = None,
        line: StatusLine | None = None,
        progress: ProgressLine | None = None,
    ) -> Flight:
        """A flight of ``plan`` from ``t0_ns`` (default: now); a stop already requested
        makes it end before its first cycle."""
        self.current = Flight(
            self.link, plan, t0_ns, recorder=recorder, line=line, check=self.check,
            progress=progress,
        )  # fmt: skip
        if self._stop.is_set():
            self.current.request_exit()
        return self.current

    def wind_down(self, clear_faults: bool) -> Reply | None:
        """Zero wrench; with ``clear_faults``, MAV_CMD_INJECT_FAILURE OK on every thruster
        (its COMMAND_ACK result, None if none came)."""
        self.link.send_wrench([0.0, 0.0, 0.0])
        if not clear_faults:
            return None
        result = self.link.inject_failure(FaultKind.OK, None)
        log.info("faults cleared on the vessel: %s", "NO_ACK" if result is None else result.name)
        return result
