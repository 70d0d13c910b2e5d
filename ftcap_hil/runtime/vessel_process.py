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

Odometry carries the sim time in ``Odometry.time_s``. Configuration: the shipped
``ftcap_hil/data/hil/vessel.toml`` (or ``--config``) plus ``--set SECTION.KEY=VALUE``.
SIGINT/SIGTERM end the run cleanly (exit 0); a second one ends it at once (exit 130).
``--record FILE.csv`` writes one row per telemetry sample: true state, commands, produced
forces and true faults.
"""

from __future__ import annotations

import contextlib
import csv
import logging
import math
from typing import IO, Any

import numpy as np

from ftcap_hil.config.bridges import CanSettings, MavlinkSettings, PortSettings, ZenohSettings
from ftcap_hil.config.sim import VesselConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import ConfigError, PortError
from ftcap_hil.core.messages import BoolArray, EscStatus, FaultInjection, Odometry, ThrusterCommand
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import Stamped
from ftcap_hil.runtime.loop import DeadlineLoop
from ftcap_hil.runtime.signals import capture_signals
from ftcap_hil.runtime.transitions import TransitionLog, log_to
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


class VesselPorts:
    """CAN (commands in, ESC telemetry out), MAVLink and Zenoh (odometry out, faults in).

    The bridges are imported here, lazily, so that building the ``ftcap-hil`` parser does not
    import the networking stacks. ``shutdown()`` closes everything opened, in reverse.
    """

    def __init__(self, injection_enabled: bool) -> None:
        self._stack = contextlib.ExitStack()
        self._injection_enabled = injection_enabled
        self.commands: Any = None  # Mailbox[ThrusterCommand] of the CanCommandSource
        self.changes: Any = None  # its changes only (stamped at a value's first arrival)
        self.esc_sink: Any = None
        self.mavlink: Any = None
        self.zenoh: Any = None

    @classmethod
    def open(cls, settings: PortSettings, ths: ThrusterSet, injection_enabled: bool) -> VesselPorts:
        """Open every port of ``settings`` (validated by ``config.bridges``) or none."""
        ports = cls(injection_enabled)
        try:
            ports._open_can(settings.can, ths)
            if settings.mavlink is not None:
                ports._open_mavlink(settings.mavlink, ths.m)
            if settings.zenoh is not None:
                ports._open_zenoh(settings.zenoh, ths.m)
        except BaseException:
            ports.shutdown()
            raise
        return ports

    def _open_can(self, c: CanSettings, ths: ThrusterSet) -> None:
        from bridges.can_io.adapters import CanCommandSource, CanEscStatusSink
        from bridges.can_io.bus import CanBusError, open_can_bus
        from bridges.can_io.force_map import CurveForceMap, ForceRawMap
        from bridges.can_io.hub import CanHub, parse_channel

        ids = c.esc_node_ids if c.esc_node_ids is not None else [20 + i for i in range(ths.m)]
        try:
            if c.start_hub:
                host, port = parse_channel(c.channel)
                self._stack.callback(CanHub(host, port).start().shutdown)
            bus = open_can_bus(c.interface, c.channel)
            self._stack.callback(bus.shutdown)
            force_map: Any = (  # the physical curves: a wrong map in the allocator shows
                ForceRawMap.from_limits(ths.u_min, ths.u_max, c.deadband_n)
                if c.curves is None
                else CurveForceMap.create(c.curves, c.deadband_n)
            )
            source = CanCommandSource(bus, force_map, allocator_node_id=c.node_id)
            self._stack.callback(source.shutdown)
            self.esc_sink = CanEscStatusSink(bus, ids)
            self._stack.callback(self.esc_sink.shutdown)
        except (CanBusError, OSError) as e:
            raise PortError(f"can: {e}") from e
        except (ValueError, TypeError) as e:
            raise ConfigError(f"can: {e}") from e
        self.commands, self.changes = source.commands, source.changes

    def _open_mavlink(self, c: MavlinkSettings, m: int) -> None:
        from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, MavlinkVesselLink

        try:
            self.mavlink = MavlinkVesselLink(m, c.endpoint)
        except ConfigError as e:  # the endpoint cannot be opened (port taken, bad device)
            raise PortError(f"mavlink: {e}") from e
        self._stack.callback(self.mavlink.shutdown)
        self.mavlink.params.set(FAILURE_ENABLE_PARAM, int(self._injection_enabled))

    def _open_zenoh(self, c: ZenohSettings, m: int) -> None:
        from bridges.zenoh_io.link import ZenohLinkError, ZenohVesselLink, load_config
        from bridges.zenoh_io.ros2.endpoints import Ros2Settings

        conf = load_config(c.config, list(c.overrides))  # ZenohConfigError: a ConfigError
        try:
            ros2 = Ros2Settings(c.domain_id, c.namespace) if c.ros2 else None
            self.zenoh = ZenohVesselLink(c.vessel, conf, n_thrusters=m, ros2=ros2)
        except ZenohLinkError as e:
            raise PortError(f"zenoh: {e}") from e
        self._stack.callback(self.zenoh.shutdown)

    def latest_command(self) -> Stamped[ThrusterCommand] | None:
        return None if self.commands is None else self.commands.latest()

    def first_arrival_ns(self, command: Stamped[ThrusterCommand]) -> int:
        """When ``command``'s value first arrived (before the ESC stream's repeats of it):
        its own stamp unless the latest change is that value and not newer."""
        change = None if self.changes is None else self.changes.latest()
        if change is None or change.stamp_ns > command.stamp_ns:
            return command.stamp_ns
        same = np.array_equal(change.value.u, command.value.u)
        return change.stamp_ns if same else command.stamp_ns

    def drain_faults(self) -> list[tuple[str, Stamped[FaultInjection]]]:
        """Injections from every source, oldest first, as (source name, injection)."""
        out = [("mavlink", f) for f in self.mavlink.drain_faults()] if self.mavlink else []
        if self.zenoh is not None:
            out += [("zenoh", f) for f in self.zenoh.faults.drain()]
        return sorted(out, key=lambda item: item[1].stamp_ns)

    def injection_enabled(self) -> bool:
        """SYS_FAILURE_EN (live over MAVLink; the config value without MAVLink)."""
        if self.mavlink is not None:
            return bool(self.mavlink.fault_injection_enabled)
        return self._injection_enabled

    def send_odometry(self, odom: Odometry) -> None:
        if self.mavlink is not None:
            self.mavlink.send_odometry(odom)
        if self.zenoh is not None:
            self.zenoh.publish_odometry(odom)

    def send_esc(self, statuses: list[EscStatus], reporting: BoolArray, now_ns: int) -> None:
        if self.esc_sink is not None:
            self.esc_sink.send_all(statuses)
            self.esc_sink.tick(now_ns, np.flatnonzero(reporting).tolist())

    def shutdown(self) -> None:
        """Close every port opened, newest first. Idempotent."""
        self._stack.close()


MAX_CATCH_UP_STEPS = 5  # a late step integrates at most this many nominal steps


class VesselProcess:
    """startup -> steps on absolute deadlines (:class:`DeadlineLoop`) -> shutdown; the first
    SIGINT/SIGTERM ends the run after its step, a second one at once (``ForcedExit``)."""

    def __init__(
        self,
        cfg: VesselConfig,
        ports: VesselPorts,
        recorder: Recorder | None = None,
        duration_s: float | None = None,
    ) -> None:
        self.cfg = cfg
        self.sim = VesselSim(cfg.sim)
        self.ports = ports
        self.recorder = recorder
        self.duration_s = duration_s
        self.period_ns = int(1e9 / cfg.shell.rate_hz)
        self.dt_s = cfg.shell.realtime_factor / cfg.shell.rate_hz
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

    def step(self, now_ns: int) -> SimSample:
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
        if self._telemetry.due():
            odom = Odometry.checked(sample.x[:3], sample.x[3:], sample.t_s)
            self.ports.send_odometry(odom)
            if self.recorder is not None:
                self.recorder.write(sample, now_ns * 1e-9)
        if self._esc.due():
            self.ports.send_esc(self.sim.esc_statuses(), ~sample.silent, now_ns)
        return sample

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
