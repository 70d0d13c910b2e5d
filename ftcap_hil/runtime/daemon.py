"""The allocator daemon's loop: startup -> cycles on absolute deadlines -> shutdown.

One thread (the caller of ``run``) owns the core. Bridges only fill mailboxes; the loop
reads the latest values with their ages. A cycle runs at every deadline of the fixed rate
(:class:`~ftcap_hil.runtime.loop.DeadlineLoop`), and also as soon as a new setpoint arrives
(``wake_on_setpoint``: the latency from a setpoint to a thruster frame is then one cycle's
work, not up to a period; the deadlines keep their phase). Each cycle:

    queued calls, mode requests and hooks (parameters) -> setpoint (+ age) -> watchdogs
    -> estimation sample from telemetry (the sources' guard, the plausibility gate)
    -> core.step -> thruster command -> transitions
    -> status

Watchdogs: no setpoint for ``setpoint_timeout_s`` -> zero thrust; telemetry older than
``telemetry_timeout_s`` -> estimation frozen, allocation continues; an ESC silent for
``esc_timeout_s`` -> that thruster allocated as failed (the waiting/failed policy in
:mod:`ftcap_hil.runtime.esc_watchdog`), unless the drives' data sheets are known: then
every esc.Status goes to the core's shaft diagnosis (:mod:`~ftcap_hil.runtime.drive_evidence`).
The first SIGINT/SIGTERM ends the loop after its cycle, a second one forces the exit
(:mod:`ftcap_hil.runtime.signals`); either way the last command is zero. The parts, each
tested on its own: the ESC watchdog, the estimation sampler (:mod:`~.estimation`), status
assembly and announcements (:mod:`~.status_report`), the call queue (:mod:`~.calls`), the
latency record (:mod:`~.latency`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from ftcap_hil.config.daemon import DaemonConfig
from ftcap_hil.core.cycle import CoreConfig, CycleResult, FtcapCore
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.evidence import Evidence
from ftcap_hil.core.messages import EscStatus, FloatArray, Odometry, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus, Mode, Severity
from ftcap_hil.ports.mailbox import EventQueue, Mailbox
from ftcap_hil.ports.transitions import TransitionLog, log_to
from ftcap_hil.runtime.calls import PendingCalls
from ftcap_hil.runtime.drive_evidence import DriveEvidence
from ftcap_hil.runtime.esc_watchdog import BusGuard, EscStallMonitor, EscWatchdog
from ftcap_hil.runtime.estimation import EstimationSampler
from ftcap_hil.runtime.latency import LatencyStats
from ftcap_hil.runtime.loop import DeadlineLoop, fast_thread_switch
from ftcap_hil.runtime.signals import capture_signals
from ftcap_hil.runtime.status_report import (
    EscReport,
    Freshness,
    LoopCounts,
    MalformedNotice,
    announce_cycle,
    assemble_status,
)
from ftcap_hil.runtime.telemetry_guard import TelemetryGuard, TelemetryIntake, TelemetryPort

log = logging.getLogger(__name__)
_log_announce = log_to(log)
# What a status sink may raise for a status it cannot encode: the loop must go on.
_SINK_ERRORS = (ValueError, OverflowError, TypeError, OSError, RuntimeError)


class ThrusterSink(Protocol):
    """Where commands go: ``u`` (m,) in N; False if the bus refused it. ``take_lapse``:
    True if the thrusters may have dropped to zero since the last call (their command
    stream lapsed: bus down, this process stalled), so the core restarts from zero."""

    def send(self, u: FloatArray) -> bool: ...
    def send_zero(self) -> bool: ...
    def tick(self, now_ns: int | None = None) -> Any: ...
    def take_lapse(self) -> bool: ...


class StatusSink(Protocol):
    """Where the decimated status and the announcements go (a bridge's encoder)."""

    def publish(self, status: AllocatorStatus) -> None: ...
    def announce(self, text: str, severity: Severity) -> None: ...


@dataclass
class Ports:
    """The daemon's ports. Several setpoint mailboxes: the latest received wins; several
    telemetry mailboxes: the newest measurement wins. ``telemetry`` holds the ports whose
    transport authenticates the vessel, ``untrusted_telemetry`` the others, used only while
    no trusted one is fresh (:mod:`~ftcap_hil.runtime.telemetry_guard`)."""

    setpoints: list[Mailbox[WrenchSetpoint]]
    telemetry: list[Mailbox[Odometry]]
    thrusters: ThrusterSink
    status: list[StatusSink] = field(default_factory=list)
    esc_ages: Callable[[int], FloatArray] | None = None  # now_ns -> (m,) seconds
    esc_latest: Callable[[], Sequence[EscStatus | None]] | None = None  # per thruster
    modes: list[EventQueue[Mode]] = field(default_factory=list)  # mode requests (ROS 2 topic)
    untrusted_telemetry: list[Mailbox[Odometry]] = field(default_factory=list)
    bus_conflict: Callable[[int], bool] | None = None  # now_ns -> our CAN node ID in conflict
    esc_reports: EventQueue[EscStatus] | None = None  # every esc.Status, with its receipt

    def malformed(self) -> int:
        """Malformed inputs dropped so far on every setpoint and telemetry port."""
        boxes: list[Mailbox[Any]] = [*self.setpoints, *self.telemetry, *self.untrusted_telemetry]
        return sum(b.malformed for b in boxes)


def _latest(boxes: Sequence[Mailbox[Any]]) -> tuple[Any, int]:
    """The freshest value over several mailboxes and its stamp (None, -1 if none yet)."""
    best, stamp = None, -1
    for box in boxes:
        slot = box.latest()
        if slot is not None and slot.stamp_ns > stamp:
            best, stamp = slot.value, slot.stamp_ns
    return best, stamp


def _age_s(now_ns: int, stamp_ns: int) -> float:
    return math.inf if stamp_ns < 0 else (now_ns - stamp_ns) * 1e-9


class AllocatorDaemon:
    """The allocator's process loop around one :class:`FtcapCore` (module docstring).

    ``call_in_loop`` and ``request_exit`` may be called from any thread; everything else
    from the loop thread. ``before_cycle`` hooks run in the loop thread before each cycle.
    """

    def __init__(self, config: DaemonConfig, ports: Ports) -> None:
        self.config = config
        self.ports = ports
        self.period_ns = int(1e9 / config.rate_hz)
        self.core = self._make_core(config.core)
        self.loop = DeadlineLoop(self.period_ns)
        if config.wake_on_setpoint:
            for box in ports.setpoints:
                box.notify = self.loop.wake_event
        self.cycles = 0
        self.not_sent = 0  # commands the sink refused (bus errors)
        self.lapses = 0  # lapses of the thrusters' command stream (restarts from zero)
        self.transitions = TransitionLog(self._announce)
        self.esc_watchdog = EscWatchdog(self.transitions)
        self.bus_guard = BusGuard(self.transitions, ports.bus_conflict)
        self.esc_stall = EscStallMonitor(
            self.transitions, self.core.u_range, config.esc_stall_rpm, config.esc_stall_s
        )
        self.drive, c = self._drive_evidence(), config
        self.sampler = EstimationSampler(
            c.estimation_period_s, c.vessel_clock, c.odometry_limits, c.time_scale
        )
        self.telemetry = TelemetryIntake(
            TelemetryGuard(
                [TelemetryPort(b, True) for b in ports.telemetry]
                + [TelemetryPort(b, False) for b in ports.untrusted_telemetry],
                config.odometry_limits,
            ),
            self.sampler,
            self.transitions,
            config.telemetry_timeout_s,
        )
        self.calls = PendingCalls(self.loop.wake)
        self.latency = LatencyStats()
        self.malformed_notice = MalformedNotice(min_interval_s=5.0)
        self.before_cycle: list[Callable[[], None]] = []
        self.last_status: AllocatorStatus | None = None
        self._last: CycleResult | None = None
        self._last_cycle_ns: int | None = None
        self._last_status_ns = 0
        self._last_sp_stamp = -1
        self._tau_d = np.zeros(config.B.shape[0])

    def _make_core(self, core_cfg: CoreConfig) -> FtcapCore:
        cfg = self.config
        dt = cfg.time_scale / cfg.rate_hz  # the period in the vessel's (sim) seconds
        return FtcapCore(cfg.B, cfg.thrusters, dt, core_cfg, cfg.plant, cfg.drives)

    def _drive_evidence(self) -> DriveEvidence:
        """The ESC telemetry's path to the core (the drives' diagnosis if the core has one)."""
        drives = self.config.drives if self.core.shaft is not None else None
        esc = self.ports.esc_reports
        return DriveEvidence(self.transitions, drives, esc, self.esc_stall, self.config.time_scale)

    @property
    def malformed(self) -> int:
        """Inputs dropped so far: malformed on any port, or telemetry the gate found
        implausible (the count the status and the exit line report)."""
        return self.ports.malformed() + self.sampler.gate.rejected

    @property
    def overruns(self) -> int:
        """Deadlines missed so far (a cycle that ran past the next deadline counts each)."""
        return self.loop.stats.overruns

    # --- any thread ----------------------------------------------------------------------

    def call_in_loop(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the loop thread before the next cycle (parameter changes)."""
        self.calls.call_in_loop(fn)

    def request_exit(self, *_: object) -> None:
        """End the loop after the current cycle; the zero command follows."""
        self.loop.request_exit()

    # --- the loop thread -----------------------------------------------------------------

    def set_mode(self, mode: Mode) -> None:
        """Rebuild the core in another mode, keeping what is on the thrusters."""
        u_prev = self.core.u_prev
        self.config = replace(self.config, core=replace(self.config.core, mode=mode))
        self.core = self._make_core(self.config.core)
        self.core.reset_command(u_prev)
        self.drive = self._drive_evidence()

    def _take_mode_requests(self) -> None:
        """Switch to each mode asked for on ``ports.modes`` (in order) that is not in force."""
        for box in self.ports.modes:
            for item in box.drain():
                if item.value is not self.config.core.mode:
                    self.set_mode(item.value)
                    self._announce(f"mode -> {item.value.value} (requested)", Severity.INFO)

    def run(self, max_cycles: int | None = None) -> int:
        """Zero, cycles until ``request_exit`` / a stop signal / ``max_cycles``, zero.
        Returns the exit code (0); a second stop signal raises ``ForcedExit`` after the
        zero went out."""
        until = None if max_cycles is None else (lambda: self.cycles >= max_cycles)
        with fast_thread_switch(), capture_signals(self.loop.request_exit) as signals:
            try:
                self.ports.thrusters.send_zero()
                first = self.loop.clock() + self.period_ns
                self.loop.run(self._tick, until, first_deadline_ns=first)
            finally:
                with signals.shielded():
                    self.shutdown()
        return 0

    def shutdown(self) -> None:
        """Zero thrust, whatever happened. Idempotent."""
        self.ports.thrusters.send_zero()

    def _tick(self, now: int) -> None:
        self.calls.run_pending()
        self._take_mode_requests()
        for hook in self.before_cycle:
            hook()
        self.cycle(now)
        self.latency.cycle(self.loop.clock() - now)

    def cycle(self, now: int) -> CycleResult | None:
        """One cycle at ``now`` (monotonic ns); the core's result, None while the setpoint
        is stale (zero thrust)."""
        started = self.loop.clock()
        self.cycles += 1
        elapsed_s = self._elapsed_s(now)
        setpoint, sp_stamp = _latest(self.ports.setpoints)
        fresh = self._freshness(now, sp_stamp, self.telemetry.newest_stamp())
        attacked, ended = self.bus_guard.attacked(now)
        if ended:
            self.sampler.restart()  # the ESCs' commands over the conflict are unknown
        sample = self.telemetry.sample(now, fresh.telemetry_stale or attacked)
        result = None
        self._restart_after_lapse()
        if fresh.setpoint_stale:
            self.drive.discard()
            self._tau_d = np.zeros(self.core.k)
            self._send(np.zeros(self.core.m), now, started)
            self.core.reset_command()
        else:
            self._tau_d = setpoint.tau
            obs, u_mean = (None, None) if sample is None else sample
            feedback = self.drive.take(now, fresh.esc_ages_s, self.config.esc_timeout_s)
            result = self.core.step(
                setpoint.tau,
                obs,
                u_sample=u_mean,
                elapsed_s=elapsed_s,
                evidence=Evidence.none(self.core.m) if attacked else self._evidence(now, fresh),
                feedback=[] if attacked else feedback,  # a stranger's commands on the bus
                t_s=self.drive.core_time_s(now) if self.drive.diagnosing else None,
            )
            self._send(result.u, now, started)
            if sp_stamp != self._last_sp_stamp:
                self._last_sp_stamp = sp_stamp
                self.latency.reaction(self.loop.clock() - sp_stamp)
            announce_cycle(self.transitions, result)
            self._last = result
        self.ports.thrusters.tick(now)
        if now - self._last_status_ns >= self.config.status_period_s * 1e9:
            self._last_status_ns = now
            self._publish(now, fresh)
        return result

    def _evidence(self, now: int, fresh: Freshness) -> Evidence | None:
        """The ESC evidence beyond the drives' diagnosis: without one, silent and stalled."""
        ages, latest = fresh.esc_ages_s, self.ports.esc_latest
        u, timeout = self.core.u_prev, self.config.esc_timeout_s
        return self.drive.evidence(now, u, fresh.esc_failed, ages, latest, timeout)

    def _restart_after_lapse(self) -> None:
        """After a lapse the ESCs hold zero (their own timeout), not ``u_prev``: the core's
        rate-limited ramp restarts from what they actually have."""
        lapsed = self.ports.thrusters.take_lapse()  # True on every cycle of a bus outage
        if lapsed:
            self.core.reset_command()
        if self.transitions.update(
            "command_lapse",
            lapsed,
            "thruster commands lapsed (the ESCs are at zero): restarting from zero",
            "thruster commands reach the ESCs again",
        ):
            self.lapses += lapsed

    def _elapsed_s(self, now: int) -> float | None:
        """Seconds since the last cycle, clamped to ``dt_clamp`` periods (None: first)."""
        last, self._last_cycle_ns = self._last_cycle_ns, now
        if last is None:
            return None
        period = self.period_ns * 1e-9
        lo, hi = self.config.dt_clamp
        return min(max((now - last) * 1e-9, lo * period), hi * period) * self.config.time_scale

    def _freshness(self, now: int, sp_stamp: int, tel_stamp: int) -> Freshness:
        cfg = self.config
        esc_failed, ages = None, None
        if self.ports.esc_ages is not None:
            ages = self.ports.esc_ages(now)
            esc_failed = self.drive.failed(self.esc_watchdog.failed(now, ages, cfg.esc_timeout_s))
        sp_age, tel_age = _age_s(now, sp_stamp), _age_s(now, tel_stamp)
        tel_stale = tel_age > cfg.telemetry_timeout_s
        self.transitions.update(
            "telemetry_stale",
            tel_stale,
            "telemetry stale: estimation frozen",
            "telemetry recovered",
        )
        sp_stale = sp_age > cfg.setpoint_timeout_s
        self.transitions.update(
            "setpoint_stale",
            sp_stale,
            "setpoint timeout: zero thrust",
            "setpoint received: allocating",
        )
        return Freshness(sp_age, tel_age, sp_stale, tel_stale, esc_failed, ages)

    def _send(self, u: FloatArray, now: int, started: int) -> None:
        """``u`` to the thrusters; the sampler gets it stamped when it went out: ``now`` plus
        the cycle's work so far (the loop's clock read at ``started`` and after the send)."""
        if not np.isfinite(u).all():  # cannot happen (the allocator clips), never on the bus
            log.error("non-finite command %s replaced by zero", u)
            u = np.zeros_like(u)
        if not self.ports.thrusters.send(u):
            self.not_sent += 1
        # Not ``now``: estimation and the QP take a millisecond or more, and a command
        # stamped before it went out makes the interval's mean lead the motion by as much.
        self.sampler.command_sent(now + self.loop.clock() - started, u)

    def _announce(self, text: str, severity: Severity) -> None:
        _log_announce(text, severity)
        for sink in self.ports.status:
            sink.announce(text, severity)

    def _esc_report(self, now: int) -> EscReport | None:
        if self.ports.esc_latest is None or self.ports.esc_ages is None:
            return None
        return EscReport(self.ports.esc_latest(), self.ports.esc_ages(now))

    def status(self, now: int, fresh: Freshness) -> AllocatorStatus:
        """The status after the latest cycle, with this cycle's ``fresh`` inputs."""
        return assemble_status(
            mode=self.config.core.mode,
            counts=LoopCounts(self.cycles, self.overruns, self.malformed),
            fresh=fresh,
            last=self._last,
            u=self.core.u_prev,
            tau_demand=self._tau_d,
            degraded=self.transitions["degraded"],
            esc=self._esc_report(now),
        )

    def _publish(self, now: int, fresh: Freshness) -> None:
        try:
            st = self.status(now, fresh)
        except MalformedMessage as e:  # a non-finite estimate: nothing to publish, go on
            self.transitions.update("status", True, f"status not built: {e}", None, Severity.ERROR)
            return
        self.transitions.update("status", False, "")
        self.last_status = st
        for sink in self.ports.status:
            name = type(sink).__name__
            try:
                sink.publish(st)
            except _SINK_ERRORS as e:
                self.transitions.update(
                    f"status:{name}", True, f"status not published by {name}: {e}"
                )
                continue
            self.transitions.update(f"status:{name}", False, "")
        if (text := self.malformed_notice.update(now, st.malformed)) is not None:
            self._announce(text, Severity.WARNING)
