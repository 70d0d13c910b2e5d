"""Realistic cases with one thruster fault of a given cause (a test and bench helper): the
shipped scenario (its preset's drives, their telemetry and the data sheet the allocator is
told, off by K_T +5 %, K_Q +8 %, lag +25 %) with the fault replaced, and the same run
without drive telemetry (motion only) for comparison."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.faults import Cause, EventKind, FaultEvent, FaultSchedule
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.report.records import RunRecord


def case(
    name: str, thruster: int, cause: Cause, delta: float, onset_s: float = 60.0,
    duration_s: float = 120.0, seed: int = 0, shaft: bool = True,
) -> Scenario:  # fmt: skip
    """Scenario ``name`` with one fault (``thruster`` 0-based, ``cause`` at ``delta`` from
    ``onset_s``; HEALTHY: none); ``shaft`` False: no drive telemetry (motion only)."""
    sc = load_scenario(name)
    faults = FaultSchedule(sc.thrusters.m)
    if cause is not Cause.HEALTHY:
        stuck = cause is Cause.STUCK
        kind = EventKind.STUCK if stuck else EventKind.STEP
        ev = FaultEvent(onset_s, math.inf, thruster, None if stuck else delta, None, kind,
                        cause=cause)  # fmt: skip
        faults = FaultSchedule(sc.thrusters.m, (ev,))
    sc = dataclasses.replace(sc, faults=faults, duration_s=duration_s, seed=seed)
    if not shaft:
        sc = dataclasses.replace(
            sc, truth=dataclasses.replace(sc.truth, feedback=None), drives=None
        )
    return sc


def cs2_case(thruster: int, cause: Cause, delta: float, **kw: object) -> Scenario:
    """:func:`case` on CyberShip II station keeping."""
    return case("cybership2-station", thruster, cause, delta, **kw)  # type: ignore[arg-type]


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
