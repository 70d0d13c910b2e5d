"""A live (HIL) flight of a realistic scenario against the offline run of the same scenario
and seed: the same metrics from both, on the vessel's clock (docs/hil.md).

The live side comes from two files of the flight: the vessel's ``--record`` (its true state
on sim time) and the ground station's ``timeseries.csv`` (the allocator's fault flags
``faulty_i`` as FTCAP_STATUS carried them, on mission time, which is the vessel's clock
when the mission has ``[gcs] vessel_clock``). Per case:

* ``deviation_rms_m``: RMS over the run of the distance between the vessel's true position
  and the offline fault-free run's (mode ``none``) at the same sim time;
* ``detection_s``: from the first fault onset to the first flag on any thruster;
* ``isolation_s``: from that onset to the first time every faulty thruster is flagged and
  no healthy one is;
* ``false_alarms``: flags raised (0 -> 1) on a thruster healthy at that time.

None means never.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.report.records import RunRecord


@dataclass(frozen=True)
class CaseMetrics:
    """The metrics of one run of a case (module docstring)."""

    deviation_rms_m: float
    detection_s: float | None
    isolation_s: float | None
    false_alarms: int


def read_columns(path: Path, names: list[str]) -> dict[str, FloatArray]:
    """Columns ``names`` of a CSV file with a header row, as floats."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {n: np.array([float(r[n]) for r in rows], dtype=np.float64) for n in names}


def onset(faults: FaultSchedule) -> tuple[float, BoolArray] | None:
    """The first fault change after 0 and the thrusters faulty from it (None: no fault)."""
    for t in faults.change_times():
        if t > 0.0:
            faulty = ~healthy(faults, t)
            if faulty.any():
                return t, faulty
    return None


def healthy(faults: FaultSchedule, t: float) -> BoolArray:
    """(m,) thrusters with no fault at ``t`` (delta 1, no bias, not stuck)."""
    truth = faults.at(t)
    out: BoolArray = (truth.delta >= 1.0) & (truth.f == 0.0) & ~truth.stuck
    return out


def flag_metrics(
    faults: FaultSchedule, t: FloatArray, flags: BoolArray
) -> tuple[float | None, float | None, int]:
    """(detection, isolation, false alarms) of fault flags ``flags`` (n, m) at times ``t``."""
    raised = flags & ~np.vstack([flags[:1], flags[:-1]])  # the first row raises nothing
    ok = np.array([healthy(faults, float(ti)) for ti in t])
    false_alarms = int(np.sum(raised & ok))
    first = onset(faults)
    if first is None:
        return None, None, false_alarms
    t0, faulty = first
    after = t >= t0
    detected = np.flatnonzero(after & flags.any(axis=1))
    isolated = np.flatnonzero(
        after & np.all(flags[:, faulty], axis=1) & ~np.any(flags[:, ~faulty], axis=1)
    )
    det = float(t[detected[0]] - t0) if detected.size else None
    iso = float(t[isolated[0]] - t0) if isolated.size else None
    return det, iso, false_alarms


def deviation_rms(t: FloatArray, north: FloatArray, east: FloatArray, none: RunRecord) -> float:
    """RMS distance (m) of a track from the fault-free run's, over their common times."""
    ref_t = none.t
    sel = (ref_t >= t[0]) & (ref_t <= t[-1])
    n = np.interp(ref_t[sel], t, north) - none.columns["north"][sel]
    e = np.interp(ref_t[sel], t, east) - none.columns["east"][sel]
    return float(np.sqrt(np.mean(n**2 + e**2))) if n.size else math.nan


def _flags(cols: dict[str, FloatArray], m: int) -> BoolArray:
    stack = np.column_stack([cols[f"faulty_{i}"] for i in range(1, m + 1)])
    out: BoolArray = np.nan_to_num(stack) > 0.5
    return out


def offline_metrics(rec: RunRecord, none: RunRecord) -> CaseMetrics:
    """The metrics of an offline run (its own true track and flags)."""
    c, m = rec.columns, rec.scenario.thrusters.m
    det, iso, fa = flag_metrics(rec.scenario.faults, rec.t, _flags(c, m))
    return CaseMetrics(deviation_rms(rec.t, c["north"], c["east"], none), det, iso, fa)


def live_metrics(
    faults: FaultSchedule, vessel_csv: Path, gcs_csv: Path, none: RunRecord
) -> CaseMetrics:
    """The metrics of a live flight: the vessel's ``--record`` and the ground station's
    ``timeseries.csv`` (module docstring)."""
    track = read_columns(vessel_csv, ["time_s", "north_m", "east_m"])
    names = ["t", *[f"faulty_{i}" for i in range(1, faults.m + 1)]]
    gcs = read_columns(gcs_csv, names)
    det, iso, fa = flag_metrics(faults, gcs["t"], _flags(gcs, faults.m))
    dev = deviation_rms(track["time_s"], track["north_m"], track["east_m"], none)
    return CaseMetrics(dev, det, iso, fa)


def _s(x: float | None) -> str:
    return "never" if x is None else f"{x:.1f} s"


def comparison_lines(live: CaseMetrics, offline: CaseMetrics, period_s: float) -> list[str]:
    """Live against offline, each metric with its target (issue 21): deviation within 10 %
    or 5 mm, detection within one estimation period + 0.5 s, the same isolation, no false
    alarm live that offline does not have."""
    dev_ok = abs(live.deviation_rms_m - offline.deviation_rms_m) <= max(
        0.1 * offline.deviation_rms_m, 0.005
    )
    det_ok = (live.detection_s is None) == (offline.detection_s is None) and (
        live.detection_s is None
        or offline.detection_s is None
        or abs(live.detection_s - offline.detection_s) <= period_s + 0.5
    )
    iso_ok = (live.isolation_s is None) == (offline.isolation_s is None)
    fa_ok = live.false_alarms <= offline.false_alarms
    mark = {True: "ok", False: "DIFFERS"}
    return [
        f"  deviation RMS  live {live.deviation_rms_m * 1e3:.1f} mm, offline "
        f"{offline.deviation_rms_m * 1e3:.1f} mm: {mark[dev_ok]}",
        f"  detection      live {_s(live.detection_s)}, offline {_s(offline.detection_s)}:"
        f" {mark[det_ok]}",
        f"  isolation      live {_s(live.isolation_s)}, offline {_s(offline.isolation_s)}:"
        f" {mark[iso_ok]}",
        f"  false alarms   live {live.false_alarms}, offline {offline.false_alarms}: {mark[fa_ok]}",
        "VERDICT: live as offline"
        if dev_ok and det_ok and iso_ok and fa_ok
        else "VERDICT: live differs from offline (see above)",
    ]
