"""Offline closed loop: nominal controller -> allocator core -> faulty thrusters -> true plant.

The true plant is the paper's discrete model (``integrator = "euler"``, identical to what
the allocator assumes) or RK4 with substeps (``"rk4"``), which shows what model mismatch
does to the estimates. One call runs one mode; ``run_modes`` runs several on the same
scenario (the ``none`` run is the reference for the deviation metrics). A thruster whose
output is frozen (``[[fault]] kind = "stuck"``) holds the force it produced at the onset,
as the realistic truth's thruster bank does, and is recorded as such (delta 0, f that
force: ``Truth.effective``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import replace

import numpy as np

from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.estimation.shaft import DriveReport
from ftcap_hil.core.estimation.stages import Observation
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import LinearPlant
from ftcap_hil.core.scenario import Integrator, Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.records import Recorder, RunRecord
from sim.sensors import Measurement
from sim.truth import TruthModel


def true_step(sc: Scenario, x: FloatArray, tau: FloatArray, dt: float | None = None) -> FloatArray:
    dt = sc.dt_s if dt is None else dt
    if isinstance(sc.plant, LinearPlant) or sc.integrator is Integrator.EULER:
        return sc.plant.step(x, tau, dt)
    return sc.plant.step_rk4(x, tau, dt, sc.rk4_substeps)


def exact_fault_step(
    sc: Scenario, faults: FaultSchedule, x: FloatArray, u: FloatArray, t: float,
    held: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """One step in which a fault may change mid-interval, as on a real vessel: the step is
    split at every fault change inside (t, t + dt) (vessel plant only). ``held`` (m,) N:
    the forces produced just before ``t`` (a frozen output keeps its own); returns the
    state and the forces produced at the end of the step."""
    cuts = [c for c in faults.change_times() if t < c < t + sc.dt_s]
    edges = [t, *cuts, t + sc.dt_s]
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        truth = faults.at(a).effective(held)
        held = truth.delta * u + truth.f
        x = true_step(sc, x, sc.B @ held, b - a)
    return x, held


def told_sensor_noise(sc: Scenario) -> Scenario:
    """The scenario with the estimator told the sensor's noise level, as an operator sets it
    from the data sheet: ``[estimator] measurement_std`` defaults to the ``[noise]`` std of
    the plant's dynamic state (u, v, r for a vessel)."""
    est = sc.core.estimator
    if est.measurement_std is not None or not np.any(sc.noise_std > 0):
        return sc
    dyn = sc.noise_std[3:6] if sc.noise_std.size == 6 else sc.noise_std[:1]
    est = replace(est, measurement_std=tuple(float(v) for v in dyn))
    return replace(sc, core=replace(sc.core, estimator=est))


def run_mode(
    sc: Scenario, mode: Mode, progress: bool = False, exact_faults: bool = True,
    on_core: Callable[[FtcapCore], None] | None = None,
) -> RunRecord:  # fmt: skip
    """exact_faults: a fault changes at its scheduled time, mid-step if need be, as on a real
    vessel (the paper's 12 s onset falls 0.45 T_s into a step); False applies faults per
    step (zero-order hold), which hides the sample that straddles an onset. ``on_core`` is
    handed the core before the run (a bench's instrument: the diagnosis's residual trace)."""
    sc = sc.with_mode(mode)
    drives = sc.drives if sc.truth is not None else None
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, told_sensor_noise(sc).core, sc.plant, drives)
    if on_core is not None:
        on_core(core)
    faults = FaultSchedule(sc.thrusters.m) if mode is Mode.NONE else sc.faults
    if sc.truth is not None:
        return _run_truth(sc, mode, core, faults, progress)
    rng = np.random.default_rng(sc.seed)
    noisy = bool(np.any(sc.noise_std > 0))
    rec = Recorder(sc, mode.value)
    x = sc.x0.astype(np.float64).copy()
    x_meas_prev: FloatArray | None = None
    steps: Iterable[int] = range(sc.steps)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc=f"{sc.name} [{mode.value}]", unit="step", leave=False)
    held = np.zeros(sc.thrusters.m)  # the forces produced last: what a frozen output keeps
    for k in steps:
        t = k * sc.dt_s
        x_meas = x + rng.normal(0.0, sc.noise_std) if noisy else x
        w = None if x_meas_prev is None else Observation(x_meas_prev, x_meas, sc.dt_s)
        ref = sc.reference_at(t)
        tau_d = sc.controller(x_meas, ref)
        truth = faults.at(t).effective(held)
        t0 = time.perf_counter()
        res = core.step(tau_d, w, truth)
        elapsed = time.perf_counter() - t0
        produced = truth.delta * res.u + truth.f
        tau = sc.B @ produced
        rec.add(t, x, ref, tau_d, tau, res, produced, truth, elapsed)
        x_meas_prev = x_meas
        if exact_faults and not isinstance(sc.plant, LinearPlant):
            x, held = exact_fault_step(sc, faults, x, res.u, t, held)
        else:
            x, held = true_step(sc, x, tau), produced
    return rec.finish()


def _steps(sc: Scenario, mode: Mode, progress: bool) -> Iterable[int]:
    steps: Iterable[int] = range(sc.steps)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc=f"{sc.name} [{mode.value}]", unit="step", leave=False)
    return steps


def _run_truth(
    sc: Scenario, mode: Mode, core: FtcapCore, faults: FaultSchedule, progress: bool
) -> RunRecord:
    """The closed loop on a realistic truth (sim/truth.py): the controller and the core see
    the sensor's latest delivered odometry; the truth advances over each control period
    with the command held, split at every fault change inside it (exact fault timing)."""
    model = TruthModel(sc.truth, sc.x0)
    rec = Recorder(sc, mode.value)
    every = max(1, round((sc.estimation_period_s or sc.dt_s) / sc.dt_s))
    # Before the sensor's first delivery (a delayed sensor, a dropout at 0 s) the loop holds
    # the initial state it was set up in; the estimator never takes an interval from it.
    start = model.start()
    placed = Measurement(
        0.0, 0.0, np.array(sc.x0[:3], dtype=float), np.array(sc.x0[3:], dtype=float)
    )
    latest = start[-1] if start else placed
    used: Measurement | None = None
    u_sum, u_time = np.zeros(sc.thrusters.m), 0.0
    reports: list[DriveReport] = []
    for k in _steps(sc, mode, progress):
        t = k * sc.dt_s
        x_meas = np.concatenate([latest.eta, latest.nu])
        w, u_mean = None, None
        if k % every == 0 and latest is not used:
            if used is not None and used is not placed and u_time > 0.0:
                x_prev = np.concatenate([used.eta, used.nu])
                w = Observation(x_prev, x_meas, latest.t_measured_s - used.t_measured_s)
                u_mean = u_sum / u_time  # the command's mean over the estimation interval
            used, u_sum, u_time = latest, np.zeros(sc.thrusters.m), 0.0
        ref = sc.reference_at(t)
        tau_d = sc.controller(x_meas, ref)
        truth = faults.at(t).effective(model.shaft_thrust)
        x_true = model.x
        t0 = time.perf_counter()
        res = core.step(tau_d, w, truth, u_sample=u_mean, feedback=reports, t_s=t)
        elapsed = time.perf_counter() - t0
        produced, tau, delivered, reports = _advance(model, faults, res.u, t, sc.dt_s)
        u_sum, u_time = u_sum + res.u * sc.dt_s, u_time + sc.dt_s
        latest = delivered[-1] if delivered else latest
        rec.add(t, x_true, ref, tau_d, tau, res, produced, truth, elapsed)
    return rec.finish()


def _advance(
    model: TruthModel, faults: FaultSchedule, u: FloatArray, t: float, dt: float
) -> tuple[FloatArray, FloatArray, list[Measurement], list[DriveReport]]:
    """One control period of the truth, split at the fault changes inside it; the means of
    the produced forces and of the wrench over the period, the odometry and the drive
    reports delivered (the latter stamped when delivered: all the allocator knows)."""
    cuts = [c for c in faults.change_times() if t < c < t + dt]
    edges = [t, *cuts, t + dt]
    produced, tau = np.zeros(u.shape), np.zeros(3)
    delivered: list[Measurement] = []
    reports: list[DriveReport] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        step = model.step(u, faults.at(a), b - a)
        produced += step.produced * ((b - a) / dt)
        tau += step.tau * ((b - a) / dt)
        delivered += step.measurements
        reports += [
            DriveReport(s.t_delivered_s, s.index, s.speed, s.current_a) for s in step.feedback
        ]
    return produced, tau, delivered, reports


def run_modes(
    sc: Scenario, modes: list[Mode], progress: bool = False, exact_faults: bool = True
) -> dict[str, RunRecord]:
    return {m.value: run_mode(sc, m, progress, exact_faults) for m in modes}
