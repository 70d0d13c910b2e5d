"""The realistic truth in the vessel process's shell: :class:`TruthVesselSim`.

The process shell (``ftcap_hil.runtime.vessel_process``) steps a :class:`~sim.vessel.VesselSim`
on its deadlines; this subclass keeps everything the shell relies on (commands applied from
their receipt, the watchdog, the step split at command arrivals and scheduled fault changes,
live injections, silent ESC windows) and steps the offline simulator's
:class:`~sim.truth.TruthModel` instead of the paper's plant: environment, thruster bank with
drives, lag, dead band and the 14-bit command, the odometry sensor and the drives'
telemetry. What it publishes::

    odometry   the sensor's deliveries, Odometry.time_s = the measurement's sim time
    esc.Status the drives' reports as delivered (sim/feedback.py): rpm = 60 x shaft speed,
               a servo's deflection as esc_rpm() encodes it; current and voltage as measured

Live injections act on the truth as causes (``Truth.cause``, sim/thrusters.py)::

    OK    -> healthy           OFF  -> drive-dead (0 rpm, idle current, still reporting)
    STUCK -> the output frozen at the injection (a given value is refused: the bank holds
             its own state)
    WEAK  -> weak-motor at delta = value (NaN: default_weak_delta)
    BIAS  -> a force outside the actuator, cause unchanged

A step longer than ``max_step_s`` (a late shell step catching up) is integrated in pieces
no longer than that, so the sensor and the drives sample on their own grid as offline.
Pure: no clock, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.faults import Cause, Truth
from ftcap_hil.core.messages import (
    BoolArray,
    EscStatus,
    FaultInjection,
    FaultKind,
    FloatArray,
    Odometry,
)
from ftcap_hil.core.models.plants import wrap_angle
from sim.feedback import FeedbackSample
from sim.sensors import Measurement
from sim.truth import TruthConfig, TruthModel
from sim.vessel import SimSample, VesselSim, VesselSimConfig

# esc.Status carries rpm as an integer: a servo's deflection (a fraction of full, in
# [-1, 1]) goes on the wire as this many "rpm" per full deflection.
SERVO_RPM_FULL = 10000.0


def esc_rpm(speed: float, is_shaft: bool) -> float:
    """The ``esc.Status`` rpm of a drive report: 60 x rev/s, or a servo's deflection."""
    return speed * (60.0 if is_shaft else SERVO_RPM_FULL)


def speed_from_rpm(rpm: float, is_shaft: bool) -> float:
    """The inverse of :func:`esc_rpm`: rev/s for a shaft, the deflection for a servo."""
    return rpm / (60.0 if is_shaft else SERVO_RPM_FULL)


_CAUSE_OF = {
    FaultKind.OK: Cause.HEALTHY,
    FaultKind.OFF: Cause.DRIVE_DEAD,
    FaultKind.STUCK: Cause.STUCK,
    FaultKind.WEAK: Cause.WEAK_MOTOR,
}


class TruthVesselSim(VesselSim):
    """The vessel process's simulation on a realistic truth (module docstring). ``config``
    gives the thrusters (names, limits), the true effectiveness ``B`` (``truth.B``), the
    fault schedule, silent windows, the watchdog and the injection defaults; its ``plant``
    is not used."""

    def __init__(self, config: VesselSimConfig, truth: TruthConfig, max_step_s: float) -> None:
        if not np.array_equal(config.B, truth.B):
            raise ValueError("TruthVesselSim: config.B must be the truth's B")
        super().__init__(config)
        if not (math.isfinite(max_step_s) and max_step_s > 0.0):
            raise ValueError(f"max_step_s: expected a finite positive step, got {max_step_s}")
        self.max_step_s = max_step_s
        self.model = TruthModel(truth, config.x0)
        self._x = self._published_state()
        self._cause_override: list[Cause | None] = [None] * self.m
        self._measured: list[Measurement] = list(self.model.start())
        self._feedback: list[FeedbackSample] = []
        self._reports = np.ones(self.m, dtype=bool)

    def _published_state(self) -> FloatArray:
        x = self.model.x
        x[2] = float(wrap_angle(x[2]))
        return x

    # --- faults ---

    def inject(self, fault: FaultInjection) -> None:
        """A live injection as a cause (module docstring); ValueError if refused."""
        i, value = fault.index, fault.value
        if fault.kind is FaultKind.STUCK and not math.isnan(value):
            raise ValueError(
                "fault injection: the realistic truth holds a stuck output at its own value "
                f"(STUCK takes no value, got {value:g})"
            )
        super().inject(fault)  # checks index and value, sets delta / f
        if fault.kind is FaultKind.BIAS:
            return
        if fault.kind is FaultKind.STUCK:
            self._delta_override[i], self._f_override[i] = 1.0, 0.0  # the bank holds it
        self._cause_override[i] = _CAUSE_OF[fault.kind]

    def _truth_at(self, t_s: float) -> Truth:
        """The schedule's truth at ``t_s`` (with its causes and stuck flags) overridden by
        the injections."""
        if self.config.schedule is not None:
            base = self.config.schedule.at(t_s)
        else:
            base = Truth(np.ones(self.m), np.zeros(self.m))
        causes = list(base.causes())
        for i, c in enumerate(self._cause_override):
            causes[i] = causes[i] if c is None else c
        stuck = np.array([c is Cause.STUCK for c in causes], dtype=bool)
        delta = np.where(np.isnan(self._delta_override), base.delta, self._delta_override)
        f = np.where(np.isnan(self._f_override), base.f, self._f_override)
        return Truth(delta, f, stuck, tuple(causes))

    # --- dynamics ---

    def _integrate(self, truth: Truth, u: FloatArray, h_s: float) -> FloatArray:
        """Step the truth model over ``h_s`` in pieces of at most ``max_step_s``."""
        n = max(1, math.ceil(h_s / self.max_step_s - 1e-9))
        produced = np.zeros(self.m)
        for _ in range(n):
            step = self.model.step(u, truth, h_s / n)
            produced += step.produced / n
            self._measured += step.measurements
            self._feedback += step.feedback
            self._reports = step.bank.reports
        self._x = self._published_state()
        return produced

    def _recorded(self, truth: Truth) -> Truth:
        """A stuck thruster as the command sees it: delta 0 and the force it holds."""
        return truth.effective(self.model.shaft_thrust)

    # --- outputs ---

    def odometry(self, sample: SimSample, due: bool) -> list[Odometry]:
        """What the sensor delivered since the last call (``due`` is not used: the sensor
        has its own rate), each stamped with its measurement's sim time."""
        out = [Odometry.checked(m.eta, m.nu, m.t_measured_s) for m in self._measured]
        self._measured = []
        return out

    def esc_reports(self, due: bool) -> list[EscStatus] | None:
        """The drives' reports delivered since the last call (None: none), those of an ESC
        made silent left out (``due`` is not used: the drives have their own rate)."""
        got, self._feedback = self._feedback, []
        silent = self.silent()
        out = [
            EscStatus(s.index, esc_rpm(s.speed, s.is_shaft), s.current_a, s.voltage_v)
            for s in got
            if not silent[s.index]
        ]
        return out or None

    def reporting(self) -> BoolArray:
        """(m,) drives whose telemetry is on now (their cause reports, no silent window)."""
        out: BoolArray = self._reports & ~self.silent()
        return out
