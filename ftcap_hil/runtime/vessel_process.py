"""Run the simulated vessel: plant, ESCs on CAN, odometry out, fault injection in.

Each step, on absolute wall-clock deadlines at ``sim.rate_hz``::

    latest esc.RawCommand (CAN, with its age) -> fault injections (MAVLink
    MAV_CMD_INJECT_FAILURE, Zenoh fault/inject) -> integrate one nominal step
    (realtime_factor / rate_hz of sim time) per period since the last step -> ODOMETRY
    (MAVLink) + telemetry/odometry (Zenoh) at telemetry_rate_hz -> esc.Status per ESC
    (unless silent) at esc_status_rate_hz + ESC NodeStatus at 1 Hz

A step that runs late integrates the time that really passed, in whole nominal steps (up to
``MAX_CATCH_UP_STEPS``; a longer stall loses the excess, counted in ``lost_s``): the plant
keeps real time as a boat does when its computer is busy, sim time stays on the grid of
nominal steps, and each command is weighted by the time it really acted, as the allocator
weights it (docs/decisions.md).

With a realistic scenario (``--scenario``, ``config.sim.VesselConfig.truth``) the step
integrates the scenario's truth (:class:`~sim.live_truth.TruthVesselSim`: environment,
thruster bank, drives) with its fault schedule on sim time; odometry is what its sensor
delivers (its own rate, noise, delay) and esc.Status what its drives report, as delivered.
With ``sim.hold`` the vessel stays at its initial state and sim time 0, publishing that
state, until released (MAVLink parameter SIM_HOLD = 0: the ground station's start), so that
sim time and the scenario's schedule start with the mission.

Odometry carries the sim time in ``Odometry.time_s``. Configuration: the shipped
``ftcap_hil/data/hil/vessel.toml`` (or ``--config``) plus ``--set SECTION.KEY=VALUE``.
SIGINT/SIGTERM end the run cleanly (exit 0); a second one ends it at once (exit 130).
``--record FILE.csv`` writes one row per telemetry sample: true state, commands, produced
forces and true faults.
"""

from __future__ import annotations

import csv
import logging
import math
from typing import IO, Protocol

import numpy as np

from ftcap_hil.config.sim import VesselConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.messages import BoolArray, EscStatus, FaultInjection, Odometry, ThrusterCommand
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import Stamped
from ftcap_hil.ports.transitions import TransitionLog, log_to
from ftcap_hil.runtime.loop import DeadlineLoop
from ftcap_hil.runtime.signals import capture_signals
from sim.live_truth import TruthVesselSim
from sim.vessel import (
    Decimator,
    SimSample,
    VesselSim,
    record_header,
    record_row,
)

log = logging.getLogger(__name__)


class Recorder:
    """``--record`` CSV: one row per telemetry sample, columns ``record_header``."""

    def __init__(self, fh: IO[str], thrusters: ThrusterSet) -> None:
        self._fh = fh
        self._writer = csv.writer(fh)
        self._writer.writerow(record_header(thrusters.names))

    def write(self, sample: SimSample, monotonic_s: float) -> None:
        self._writer.writerow(record_row(sample, monotonic_s))
        self._fh.flush()


class VesselIO(Protocol):
    """What the vessel's loop is handed: CAN (commands in, ESC telemetry out), MAVLink and
    Zenoh (odometry out, fault injections in). ``ftcap_hil.apps.vessel_ports`` opens them."""

    def latest_command(self) -> Stamped[ThrusterCommand] | None:
        """The latest thruster command and its receipt stamp (None: none yet)."""
        ...

    def first_arrival_ns(self, command: Stamped[ThrusterCommand]) -> int:
        """When ``command``'s value first arrived (before the ESC stream's repeats of it)."""
        ...

    def drain_faults(self) -> list[tuple[str, Stamped[FaultInjection]]]:
        """Injections from every source, oldest first, as (source name, injection); the
        ``"mavlink"`` source has checked SYS_FAILURE_EN itself."""
        ...

    def injection_enabled(self) -> bool:
        """SYS_FAILURE_EN: whether the other sources' injections are carried out."""
        ...

    def held(self) -> bool:
        """SIM_HOLD: whether the vessel is asked to wait at t = 0 (``sim.hold``)."""
        ...

    def send_odometry(self, odom: Odometry) -> None: ...
    def send_esc(self, statuses: list[EscStatus], reporting: BoolArray, now_ns: int) -> None: ...


MAX_CATCH_UP_STEPS = 5  # a late step integrates at most this many nominal steps


class VesselProcess:
    """startup -> steps on absolute deadlines (:class:`DeadlineLoop`) -> shutdown; the first
    SIGINT/SIGTERM ends the run after its step, a second one at once (``ForcedExit``)."""

    def __init__(
        self,
        cfg: VesselConfig,
        ports: VesselIO,
        recorder: Recorder | None = None,
        duration_s: float | None = None,
    ) -> None:
        self.cfg = cfg
        self.dt_s = cfg.shell.realtime_factor / cfg.shell.rate_hz
        self.sim = VesselSim(cfg.sim)
        if cfg.truth is not None:
            self.sim = TruthVesselSim(cfg.sim, cfg.truth, self.dt_s)
        self.ports = ports
        self.recorder = recorder
        self.duration_s = duration_s
        self.period_ns = int(1e9 / cfg.shell.rate_hz)
        self._holding = cfg.shell.hold
        self.loop = DeadlineLoop(self.period_ns)
        self.steps = 0
        self.lost_s = 0.0  # sim time not integrated: stalls longer than MAX_CATCH_UP_STEPS
        self._last_step_ns: int | None = None
        self._telemetry = Decimator(cfg.shell.rate_hz, cfg.shell.telemetry_rate_hz)
        self._esc = Decimator(cfg.shell.rate_hz, cfg.shell.esc_status_rate_hz)
        self._command_stamp = -1
        self._transitions = TransitionLog(log_to(log))
        m = self.sim.m
        self._true_fault = (np.ones(m), np.zeros(m))  # (delta, f) last logged

    def request_exit(self, *_: object) -> None:
        """End the run after the current step (any thread, signal-handler safe)."""
        self.loop.request_exit()

    def run(self) -> int:
        """Step until stopped or ``duration_s`` of sim time; the exit code (0)."""
        try:
            with capture_signals(self.loop.request_exit):
                self.loop.run(self.step, until=self._done)
        finally:
            log.info(
                "stopped at sim time %.2f s after %d steps (%d overruns, %.2f s lost to stalls)",
                self.sim.t_s, self.steps, self.loop.stats.overruns, self.lost_s,
            )  # fmt: skip
        return 0

    def _done(self) -> bool:
        return self.duration_s is not None and self.sim.t_s >= self.duration_s - 1e-9

    def step(self, now_ns: int) -> SimSample | None:
        """One step at ``now_ns`` (module docstring); None while held at t = 0."""
        if self._held():
            if self._telemetry.due():
                x0 = self.cfg.sim.x0
                self.ports.send_odometry(Odometry.checked(x0[:3], x0[3:], 0.0))
            return None
        slot = self.ports.latest_command()
        if slot is not None and slot.stamp_ns != self._command_stamp:
            self._command_stamp = slot.stamp_ns
            first = self.ports.first_arrival_ns(slot)
            self.sim.set_command(slot.value.u, slot.stamp_ns * 1e-9, first * 1e-9)
        for source, fault in self.ports.drain_faults():
            self._inject(source, fault)
        sample = self.sim.step(self._elapsed_s(now_ns), now_ns * 1e-9)
        self.steps += 1
        self._log_transitions(sample)
        odometry = self.sim.odometry(sample, self._telemetry.due())
        for odom in odometry:
            self.ports.send_odometry(odom)
        if odometry and self.recorder is not None:
            self.recorder.write(sample, now_ns * 1e-9)
        statuses = self.sim.esc_reports(self._esc.due())
        if statuses is not None:
            self.ports.send_esc(statuses, self.sim.reporting(), now_ns)
        return sample

    def _held(self) -> bool:
        """Whether the vessel still waits at t = 0 (``sim.hold`` until the ports say it is
        released); logged once when it starts."""
        if self._holding and not self.ports.held():
            self._holding = False
            self._last_step_ns = None  # the first step after the hold is one nominal step
            log.info("released: sim time starts")
        return self._holding

    def _elapsed_s(self, now_ns: int) -> float:
        """Sim seconds for this step (module docstring): as many nominal steps as periods
        passed since the last step, so that sim time stays on the grid of nominal steps (an
        offline run at the same step reproduces it); one on the first step."""
        last, self._last_step_ns = self._last_step_ns, now_ns
        if last is None:
            return self.dt_s
        periods = max(1, round((now_ns - last) / self.period_ns))
        if periods > MAX_CATCH_UP_STEPS:
            self.lost_s += (periods - MAX_CATCH_UP_STEPS) * self.dt_s
            periods = MAX_CATCH_UP_STEPS
        return periods * self.dt_s

    def _inject(self, source: str, fault: Stamped[FaultInjection]) -> None:
        f = fault.value
        names = self.cfg.sim.thrusters.names
        what = f"thruster {names[f.index] if 0 <= f.index < self.sim.m else f.index} {f.kind.name}"
        what += "" if math.isnan(f.value) else f" {f.value:g}"
        if source != "mavlink" and not self.ports.injection_enabled():
            log.warning("%s fault injection refused (SYS_FAILURE_EN is 0): %s", source, what)
            return
        try:
            self.sim.inject(f)
        except ValueError as e:
            log.warning("%s fault injection refused: %s", source, e)
            return
        log.info("fault injected via %s: %s", source, what)

    def _log_transitions(self, s: SimSample) -> None:
        self._transitions.update(
            "command",
            bool(s.command_fresh),
            "thruster commands received",
            f"no thruster command for {s.command_age_s:.2f} s: thrusters at zero",
            severity=Severity.INFO,
            off_severity=Severity.WARNING,
        )
        names = self.cfg.sim.thrusters.names
        delta, f = self._true_fault
        for i in np.flatnonzero((s.delta != delta) | (s.f != f)):
            log.warning(
                "t = %.2f s: thruster %s true fault delta %.2f -> %.2f, f %.4f -> %.4f N",
                s.t_s, names[i], delta[i], s.delta[i], f[i], s.f[i],
            )  # fmt: skip
        self._true_fault = (s.delta, s.f)
        for name, silent in zip(names, s.silent, strict=True):
            self._transitions.update(
                f"silent:{name}",
                bool(silent),
                f"t = {s.t_s:.2f} s: ESC {name} silent",
                f"t = {s.t_s:.2f} s: ESC {name} reporting again",
                off_severity=Severity.WARNING,
            )
