"""An ROV holding station in 6 DOF with one thruster faulty: the allocation told, not told,
or told by the thruster's own drive.

The offline loop of an underwater vehicle, as far as the product takes it today: the 6-DOF
rigid body (``core/models/vehicle6dof.py``) in a current, the nominal hold controller
(``core/models/controller6dof.py``) and the allocator (the same QP as on the surface, in 6
axes), at a fixed control period. With the vehicle file's drives, the thrusters are the
surface presets' drive physics (``sim/thrusters.py``: a T200 on a duty-cycle ESC, its lag,
speed and current) reporting through their telemetry (``sim/feedback.py``); without, ideal.

A thruster's fault starts at ``fault_s`` (:data:`FAULTS`: its cause and what is left of its
thrust). The allocator's effectiveness estimate delta_hat is, per mode:

* ``healthy``: no fault; ``cap``: 1 for all, never told (the fault-unaware baseline);
* ``oracle``: the true effectiveness from the onset (as once isolated);
* ``drives``: the drives' diagnosis (``ShaftDiagnoser``, the surface's, with the file's
  data sheet and ``diagnosis`` settings) on the telemetry: a thruster whose drive shows an
  actionable loss gets the effectiveness the drive shows, the others 1. The 6-DOF motion
  filter that would fuse the motion with it is not built yet.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.config.underwater import UnderwaterVehicle
from ftcap_hil.core.allocation.allocator import Allocator, AllocatorConfig
from ftcap_hil.core.estimation.config import wrench_scale
from ftcap_hil.core.estimation.shaft import ResidualSample, ShaftDiagnoser
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig
from ftcap_hil.core.faults import Cause, Truth
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.controller6dof import HoldController6DOF
from ftcap_hil.core.models.plants import wrap_angle
from ftcap_hil.core.models.vehicle6dof import rotation
from sim.feedback import FeedbackSensor
from sim.thrusters import ThrusterBank, ThrusterBankConfig

MODES = ("healthy", "oracle", "cap", "drives")
# kind -> (cause, the thrust left at the same command): what an ROV's thruster meets
FAULTS = {
    "dead": (Cause.DRIVE_DEAD, 0.0),  # the ESC stops driving: 0 rpm reported, idle current
    "jammed": (Cause.JAMMED, 0.0),  # a rope round the shaft: blocked, at the current limit
    "fouled": (Cause.FOULED, 0.5),  # seaweed in the duct: half the thrust, more torque
    "power-lost": (Cause.POWER_LOST, 0.0),  # the ESC silent: no thrust, no telemetry
}


@dataclass(frozen=True)
class HoldResult:
    """What a pilot sees of one hold after the fault's onset (SI, degrees for angles)."""

    mode: str
    faulty: str | None
    fault: str | None
    depth_dev_max_m: float  # largest |depth - target|
    horizontal_dev_max_m: float  # largest horizontal distance from the target
    roll_pitch_max_deg: float  # largest |roll| or |pitch|
    heading_dev_max_deg: float
    unmet_rms: float  # RMS of the wrench demanded but not produced, over the axis scales
    isolated_s: float  # drives: onset -> the faulty thruster's drive shows it (NaN: never)
    false_alarms: int  # drives: healthy thrusters shown faulty (from settle_s on)


class _Thrusters:
    """Ideal thrusters (the faulty one's share missing) or the drives' physics."""

    def __init__(self, vehicle: UnderwaterVehicle, seed: int) -> None:
        ths = vehicle.thrusters
        self.bank: ThrusterBank | None = None
        self.sensor: FeedbackSensor | None = None
        if vehicle.drives is not None:
            cfg = ThrusterBankConfig.create(
                ths.m, time_constant_s=vehicle.time_constants_s.tolist(),
                actuator=vehicle.drives.actuators, full_force_n=ths.u_max.tolist(), seed=seed,
            )  # fmt: skip
            self.bank = ThrusterBank(cfg)
            feedback = dataclasses.replace(vehicle.drives.feedback, seed=seed)
            self.sensor = FeedbackSensor(feedback, ths.m)
        self.directions = np.column_stack([t.direction() for t in ths.thrusters])

    def step(
        self, u: FloatArray, truth: Truth, dt_s: float, v_rel: FloatArray, t_end_s: float
    ) -> tuple[FloatArray, list[tuple[float, int, float, float]]]:
        """(forces (m,) N over the step, the telemetry delivered by its end)."""
        if self.bank is None:
            return truth.delta * u + truth.f, []
        assert self.sensor is not None
        out = self.bank.step(u, truth, dt_s, self.directions.T @ v_rel)
        reports = [(s.t_delivered_s, s.index, s.speed, s.current_a)
                   for s in self.sensor.step(t_end_s, out)]  # fmt: skip
        return out.produced_mean, reports


def hold(
    vehicle: UnderwaterVehicle,
    mode: str,
    faulty: int | None = None,
    fault: str = "dead",
    *,
    seconds: float = 60.0,
    fault_s: float = 30.0,
    period_s: float = 0.05,
    substeps: int = 5,
    depth_m: float = 5.0,
    current_ned: tuple[float, float, float] = (0.2, 0.0, 0.0),
    seed: int = 0,
    diagnosis: DiagnosisConfig | None = None,
    trace: list[ResidualSample] | None = None,
    settle_s: float = 20.0,
    moves: Sequence[tuple[float, Sequence[float]]] = (),
) -> HoldResult:
    """One hold at ``depth_m`` (heading north, level) in ``current_ned`` (m/s), thruster
    ``faulty`` (index) meeting ``fault`` (:data:`FAULTS`) at ``fault_s``; ``mode`` one of
    :data:`MODES`; ``seed`` the telemetry's noise; ``diagnosis`` the drives' settings (the
    vehicle file's ``[diagnosis]`` if None); ``trace`` collects the diagnosis's healthy
    residuals (the calibration's input, ``bench/calibrate_rov.py``). The drives' diagnosis
    starts at ``settle_s``, on a settled hold: started with the hold, at rest in the current,
    its speed maps learn a T200's in-flow too slowly and it raises false alarms in the
    first seconds that the allocation then acts on (docs/vessels.md). ``moves``: (time,
    target pose [n, e, d, roll, pitch, yaw] in m and rad) steps of the target, a pilot's
    repositioning (the calibration flies them; the deviations are measured from the target
    in force). The diagnosis is told each thruster's axial in-flow from the vehicle's
    velocity over ground (the navigation's; the current's share it learns)."""
    if mode not in MODES:
        raise ValueError(f"rov hold: mode is one of {MODES}, got {mode!r}")
    if mode == "healthy" and faulty is not None:
        raise ValueError("rov hold: mode 'healthy' has no faulty thruster")
    if fault not in FAULTS:
        raise ValueError(f"rov hold: fault is one of {sorted(FAULTS)}, got {fault!r}")
    ths, B, body = vehicle.thrusters, vehicle.B, vehicle.body
    m = ths.m
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    alloc = Allocator(B, ths, period_s, scale, AllocatorConfig())
    ctrl = HoldController6DOF(body)
    thrusters = _Thrusters(vehicle, seed)
    diag: ShaftDiagnoser | None = None
    cause, left = FAULTS[fault]
    healthy = Truth(np.ones(m), np.zeros(m))
    faulted = healthy
    if faulty is not None:
        delta = np.ones(m)
        delta[faulty] = left
        causes = tuple(cause if i == faulty else Cause.HEALTHY for i in range(m))
        faulted = Truth(delta, np.zeros(m), cause=causes)
    target = np.array([0.0, 0.0, depth_m, 0.0, 0.0, 0.0])
    x = np.concatenate([target, np.zeros(6)])
    current = np.array(current_ned, dtype=np.float64)
    u = np.zeros(m)
    delta_hat = np.ones(m)
    dev = {"depth": 0.0, "horizontal": 0.0, "attitude": 0.0, "heading": 0.0}
    unmet: list[FloatArray] = []
    isolated_s = math.nan
    alarmed = np.zeros(m, dtype=bool)
    h = period_s / substeps
    for k in range(round(seconds / period_s)):
        t = k * period_s
        truth = faulted if t >= fault_s else healthy
        for t_move, pose in moves:
            if abs(t - t_move) < 0.5 * period_s:
                target = np.array(pose, dtype=np.float64)
        if mode == "drives" and diag is None and t >= settle_s:
            diag = ShaftDiagnoser(vehicle.drive_models(), diagnosis or vehicle.diagnosis)
            diag.trace = trace
        if mode == "oracle":
            delta_hat = truth.delta.copy()
        elif diag is not None:
            verdict = diag.verdict(t)
            shown = verdict.actionable
            alarmed |= shown
            delta_hat = np.where(shown, verdict.delta, 1.0)
            if faulty is not None and t >= fault_s and shown[faulty] and math.isnan(isolated_s):
                isolated_s = t - fault_s
        tau_d = ctrl(x[:6], x[6:], target, period_s)
        u = alloc.allocate(tau_d, delta_hat, np.zeros(6), u).u
        if diag is not None:  # the in-flow the navigation knows: the vehicle's own velocity
            diag.command(t, u, thrusters.directions.T @ x[6:9])
        produced = np.zeros(6)
        for j in range(substeps):
            v_rel = x[6:9] - rotation(*x[3:6]).T @ current
            forces, reports = thrusters.step(u, truth, h, v_rel, t + (j + 1) * h)
            if diag is not None:
                for report in reports:
                    diag.feedback(*report)
            tau = B @ forces
            produced += tau / substeps
            x = body.step_rk4(x, tau, h, current)
        if t >= fault_s:
            unmet.append((tau_d - produced) / scale)
            dev["depth"] = max(dev["depth"], abs(x[2] - target[2]))
            dev["horizontal"] = max(dev["horizontal"], math.hypot(*(x[:2] - target[:2])))
            dev["attitude"] = max(dev["attitude"], abs(x[3]), abs(x[4]))
            dev["heading"] = max(dev["heading"], abs(float(wrap_angle(x[5] - target[5]))))
    if faulty is not None:
        alarmed[faulty] = False
    return HoldResult(
        mode=mode,
        faulty=None if faulty is None else ths.names[faulty],
        fault=None if faulty is None else fault,
        depth_dev_max_m=dev["depth"],
        horizontal_dev_max_m=dev["horizontal"],
        roll_pitch_max_deg=math.degrees(dev["attitude"]),
        heading_dev_max_deg=math.degrees(dev["heading"]),
        unmet_rms=float(np.sqrt(np.mean(np.square(unmet)))) if unmet else 0.0,
        isolated_s=isolated_s,
        false_alarms=int(alarmed.sum()) if mode == "drives" else 0,
    )
