"""CyberShip II station keeping with its drives modelled and reported (a test and bench
helper until the presets carry their drives): the shipped scenario with the truth's
thruster bank given propellers and servos of the vessel's sizes, 10 Hz drive telemetry,
and the allocator told a data-sheet model that is off (K_T +5 %, K_Q +8 %, lag +25 %)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.estimation.shaft import DriveModel
from ftcap_hil.core.faults import Cause, EventKind, FaultEvent, FaultSchedule
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.report.records import RunRecord
from sim.feedback import FeedbackConfig
from sim.shaft import Actuator, Propeller, Servo

# [SSF04] CyberShip II: T = 3.65e-3 n^2 (n in rev/s) on a 60 mm propeller in fresh water is
# K_T = 0.28; the bow tunnel's 1.568e-4 at K_T 0.28 is a 27.4 mm one. K_Q = 0.035 ASSUMED
# (B-series at P/D 0.8); a 12 V supply, idle currents ASSUMED.
CS2_PROPELLER = Propeller(diameter_m=0.06, k_t=0.2816, k_q=0.035, rho_kgm3=1000.0, idle_a=0.1)
CS2_BOW = Propeller(diameter_m=0.0274, k_t=0.2785, k_q=0.035, rho_kgm3=1000.0, idle_a=0.05)
CS2_ACTUATORS: tuple[Actuator, ...] = (CS2_PROPELLER, CS2_PROPELLER, Servo(), Servo(), CS2_BOW)


def data_sheet(
    actuators: tuple[Actuator, ...], full_n: np.ndarray, tc_s: np.ndarray,
    err: tuple[float, float, float] = (1.05, 1.08, 1.25),
) -> tuple[DriveModel, ...]:  # fmt: skip
    """The allocator's drive models: the truth's off by ``err`` (K_T, K_Q, time constant)."""
    out = []
    for a, full, tc in zip(actuators, full_n.tolist(), tc_s.tolist(), strict=True):
        if isinstance(a, Servo):
            out.append(DriveModel(full, tc * err[2], is_shaft=False))
            continue
        k_t = a.k_t * a.rho_kgm3 * a.diameter_m**4 * err[0]
        k_q = a.k_q * a.rho_kgm3 * a.diameter_m**5 * err[1]
        wpa = a.efficiency * a.voltage_v
        out.append(DriveModel(full, tc * err[2], True, k_t, k_q, wpa, a.idle_a))
    return tuple(out)


def cs2_case(
    thruster: int, cause: Cause, delta: float, onset_s: float = 60.0,
    duration_s: float = 120.0, seed: int = 0, shaft: bool = True,
) -> Scenario:  # fmt: skip
    """The station-keeping scenario with one fault (``thruster`` 0-based, ``cause`` at
    ``delta`` from ``onset_s``; HEALTHY: none); ``shaft`` False: no telemetry (motion only)."""
    sc = load_scenario("cybership2-station")
    full = np.maximum(np.abs(sc.thrusters.u_min), np.abs(sc.thrusters.u_max))
    bank = dataclasses.replace(sc.truth.bank, actuators=CS2_ACTUATORS, full_force_n=full, seed=seed)
    feedback = FeedbackConfig(seed=seed) if shaft else None
    truth = dataclasses.replace(sc.truth, bank=bank, feedback=feedback)
    faults = FaultSchedule(sc.thrusters.m)
    if cause is not Cause.HEALTHY:
        stuck = cause is Cause.STUCK
        kind = EventKind.STUCK if stuck else EventKind.STEP
        value = None if stuck else delta
        ev = FaultEvent(onset_s, math.inf, thruster, value, None, kind, cause=cause)
        faults = FaultSchedule(sc.thrusters.m, (ev,))
    drives = data_sheet(CS2_ACTUATORS, full, bank.time_constant_s) if shaft else None
    return dataclasses.replace(
        sc, truth=truth, faults=faults, drives=drives, duration_s=duration_s, seed=seed
    )


def flags(rec: RunRecord) -> np.ndarray:
    """(n, m) the core's fault flags of a run."""
    m = rec.scenario.thrusters.m
    return np.column_stack([rec.columns[f"faulty_{i}"] for i in range(1, m + 1)]) > 0.5


def isolation_s(rec: RunRecord, thruster: int, onset_s: float) -> float:
    """Seconds from ``onset_s`` until only ``thruster`` is flagged (inf: never)."""
    f = flags(rec)
    alone = f[:, thruster] & ~np.delete(f, thruster, axis=1).any(axis=1) & (rec.t >= onset_s)
    hits = np.flatnonzero(alone)
    return float(rec.t[hits[0]] - onset_s) if hits.size else math.inf


def deviation_max(rec: RunRecord) -> float:
    """Largest distance from the origin (station keeping at 0, 0), m."""
    return float(np.max(np.hypot(rec.columns["north"], rec.columns["east"])))
