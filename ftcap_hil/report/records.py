"""Run records, ``timeseries.csv`` and ``results.json`` (schema in docs/results.md).

The columns are defined once, by name (:func:`column_groups`), and filled by name
(:class:`Rows`) by both recorders, the offline simulator's :class:`Recorder` and the ground
station's ``report.flight.FlightRecorder``, so both write the same files.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.core.allocation.allocator import AllocationStatus
from ftcap_hil.core.cycle import CycleResult
from ftcap_hil.core.estimation.shaft_types import HYPOTHESIS_CODES
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.models.plants import LinearPlant, wrap_angle
from ftcap_hil.core.scenario import Scenario

CONVERGENCE_TOL = 0.05  # |delta_hat - delta| for "converged"
SCHEMA_VERSION = 1


@dataclass
class RunRecord:
    scenario: Scenario
    mode: str
    columns: dict[str, FloatArray]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> FloatArray:
        return self.columns["t"]


THRUSTER_GROUPS = ("u", "tau", "delta", "f", "delta_hat", "f_hat")
SCALARS = ("innovation", "window_len", "fallback", "probing", "solve_us")
DECISION_GROUPS = ("faulty", "dead", "delta_std", "observable", "drive")


def _numbered(prefix: str, n: int) -> list[str]:
    return [f"{prefix}_{i}" for i in range(1, n + 1)]


def column_groups(sc: Scenario) -> dict[str, list[str]]:
    """The ``timeseries.csv`` columns of a scenario by group, in file order (docs/results.md):
    ``t``; ``state`` (``x``, or ``north,east,psi,u,v,r``); ``ref``; ``v_dem_j``, ``v_ach_j``
    (j = 1..k); per thruster (i = 1..m) ``u_i``, ``tau_i``, ``delta_i``, ``f_i``,
    ``delta_hat_i``, ``f_hat_i``; ``bf_hat_j``; the scalars ``innovation``, ``window_len``,
    ``fallback``, ``probing``, ``solve_us``; per thruster ``faulty_i`` (the core's fault
    flag, CoreConfig.fault_threshold / fault_clear), ``dead_i`` (taken out of the
    allocation: the effectiveness the allocator used was below allocator.dead_threshold,
    ``Allocation.dead``), ``delta_std_i`` (standard deviation of delta_hat_i) and
    ``observable_i`` (the recent data determine delta_i), ``drive_i`` (the drives'
    diagnosis: the hypothesis's code, ``HYPOTHESIS_CODES``; NaN without one); flags are 0
    or 1."""
    m, k = sc.thrusters.m, sc.B.shape[0]
    linear = isinstance(sc.plant, LinearPlant)
    groups = {
        "t": ["t"],
        "state": list(sc.plant.state_labels),
        "ref": ["ref_x"] if linear else ["ref_north", "ref_east", "ref_psi"],
        "v_dem": _numbered("v_dem", k),
        "v_ach": _numbered("v_ach", k),
    }
    groups |= {g: _numbered(g, m) for g in THRUSTER_GROUPS}
    groups |= {"bf_hat": _numbered("bf_hat", k)}
    groups |= {c: [c] for c in SCALARS}
    groups |= {g: _numbered(g, m) for g in DECISION_GROUPS}
    return groups


def column_names(sc: Scenario) -> list[str]:
    """Every ``timeseries.csv`` column of a scenario, in file order (:func:`column_groups`)."""
    return [name for names in column_groups(sc).values() for name in names]


class Rows:
    """A record's rows, each filled by group name (:func:`column_groups`): a group not
    given is NaN (not measured)."""

    def __init__(self, sc: Scenario) -> None:
        self.names = column_names(sc)
        self._slices: dict[str, slice] = {}
        at = 0
        for group, names in column_groups(sc).items():
            self._slices[group] = slice(at, at + len(names))
            at += len(names)
        self.rows: list[FloatArray] = []

    def add(self, **groups: object) -> None:
        """Append a row; each value is a scalar (a one-column group) or a vector of its
        group's width. KeyError for an unknown group, ValueError for a wrong width."""
        row = np.full(len(self.names), np.nan)
        for group, value in groups.items():
            where = self._slices[group]
            arr = np.asarray(value, dtype=np.float64)
            width = where.stop - where.start
            if arr.shape != (width,) and not (arr.ndim == 0 and width == 1):
                raise ValueError(f"{group}: expected {width} values, got shape {arr.shape}")
            row[where] = arr
        self.rows.append(row)

    def columns(self) -> dict[str, FloatArray]:
        """The rows as columns by name."""
        data = np.vstack(self.rows) if self.rows else np.zeros((0, len(self.names)))
        return {n: data[:, i] for i, n in enumerate(self.names)}


class Recorder:
    """The offline simulator's record: one row per cycle, every column filled but
    ``delta_std`` and ``observable`` where the estimator gives none (NaN)."""

    def __init__(self, sc: Scenario, mode: str) -> None:
        self.sc = sc
        self.mode = mode
        self._rows = Rows(sc)
        self.names = self._rows.names

    def add(
        self,
        t: float,
        x: FloatArray,
        ref: FloatArray,
        v_dem: FloatArray,
        v_ach: FloatArray,
        res: CycleResult,
        produced: FloatArray,
        truth: Truth,
        solve_s: float,
    ) -> None:
        est = res.estimate
        self._rows.add(
            t=t,
            state=x,
            ref=ref,
            v_dem=v_dem,
            v_ach=v_ach,
            u=res.u,
            tau=produced,
            delta=truth.delta,
            f=truth.f,
            delta_hat=est.delta_hat,
            f_hat=est.f_hat,
            bf_hat=est.bf_hat,
            innovation=est.innovation,
            window_len=est.window_len,
            fallback=res.allocation.status is not AllocationStatus.OK,
            probing=bool(np.any(res.probing)),
            solve_us=solve_s * 1e6,
            faulty=res.faulty,
            dead=res.allocation.dead,
            **_uncertainty(res),
        )

    def finish(self, **meta: Any) -> RunRecord:
        return RunRecord(self.sc, self.mode, self._rows.columns(), meta)


def _uncertainty(res: CycleResult) -> dict[str, FloatArray | BoolArray]:
    """delta_std and observable when the estimator gives them (the Kalman stage)."""
    out: dict[str, FloatArray | BoolArray] = {}
    if res.estimate.delta_std is not None:
        out["delta_std"] = res.estimate.delta_std
    if res.decision is not None:
        out["observable"] = res.decision.observable
    if res.shaft is not None:
        out["drive"] = np.array([HYPOTHESIS_CODES[h] for h in res.shaft.hypothesis], float)
    return out


def write_csv(rec: RunRecord, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(rec.columns)
    data = np.column_stack([rec.columns[n] for n in names])
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for row in data:
            w.writerow([f"{v:.9g}" for v in row])


def _stack(rec: RunRecord, prefix: str, n: int) -> FloatArray:
    return np.column_stack([rec.columns[f"{prefix}_{i}"] for i in range(1, n + 1)])


def tracking_error(rec: RunRecord) -> FloatArray:
    """Position error (m) for the vessel, |x - r| for the linear plant."""
    c = rec.columns
    if "ref_x" in c:
        return np.abs(c["x"] - c["ref_x"])
    return np.hypot(c["north"] - c["ref_north"], c["east"] - c["ref_east"])


def heading_error(rec: RunRecord) -> FloatArray | None:
    c = rec.columns
    return None if "psi" not in c else np.abs(wrap_angle(c["psi"] - c["ref_psi"]))


def deviation(rec: RunRecord, ref: RunRecord) -> FloatArray:
    a, b = rec.columns, ref.columns
    n = min(len(rec.t), len(ref.t))
    if "x" in a:
        return np.abs(a["x"][:n] - b["x"][:n])
    return np.hypot(a["north"][:n] - b["north"][:n], a["east"][:n] - b["east"][:n])


def _rms(x: FloatArray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def _settle(err: FloatArray, t: FloatArray, tol: float, start: float) -> float | None:
    """Time after ``start`` from which err stays below tol until the end of the slice."""
    bad = np.flatnonzero(err >= tol)
    if bad.size == 0:
        return 0.0
    if bad[-1] == err.size - 1:
        return None
    return float(t[bad[-1] + 1] - start)


def phase_metrics(
    rec: RunRecord, none: RunRecord | None, start: float, end: float
) -> dict[str, Any]:
    sc = rec.scenario
    t = rec.t
    sel = (t >= start) & (t < end)
    m, k = sc.thrusters.m, sc.B.shape[0]
    err = tracking_error(rec)[sel]
    track_tol = 0.02 if "x" in rec.columns else 0.1
    out: dict[str, Any] = {
        "start": start,
        "end": end,
        "tracking_rms": _rms(err),
        "tracking_max": float(np.max(err, initial=0.0)),
        "settle_time": _settle(err, t[sel], track_tol, start),
        "settle_tol": track_tol,
    }
    head = heading_error(rec)
    if head is not None:
        out["heading_rms"] = _rms(head[sel])
        out["heading_max"] = float(np.max(head[sel], initial=0.0))
    if none is not None:
        dev = deviation(rec, none)
        dsel = sel[: dev.size]
        out["deviation_rms"] = _rms(dev[dsel])
        out["deviation_max"] = float(np.max(dev[dsel], initial=0.0))
    alloc = _stack(rec, "v_dem", k)[sel] - _stack(rec, "v_ach", k)[sel]
    out["allocation_error_rms"] = _rms(np.linalg.norm(alloc, axis=1))
    dh, d = _stack(rec, "delta_hat", m)[sel], _stack(rec, "delta", m)[sel]
    out["delta_convergence_time"] = [
        _settle(np.abs(dh[:, i] - d[:, i]), t[sel], CONVERGENCE_TOL + 1e-12, start)
        for i in range(m)
    ]
    out["delta_error_final"] = np.abs(dh[-1] - d[-1]).tolist() if dh.size else []
    return out


def results(records: dict[str, RunRecord]) -> dict[str, Any]:
    """results.json content: per mode, per fault phase (see docs/results.md)."""
    none = records.get("none")
    any_rec = next(iter(records.values()))
    sc = any_rec.scenario
    out: dict[str, Any] = {
        "schema": SCHEMA_VERSION,
        "scenario": sc.name,
        "time_unit": sc.time_unit.value,
        "dt": sc.dt_s,
        "integrator": sc.integrator.value,
        "phases": sc.phases(),
        "modes": {},
    }
    for name, rec in records.items():
        state = np.column_stack([rec.columns[s] for s in sc.plant.state_labels])
        solve = rec.columns["solve_us"]
        out["modes"][name] = {
            "bounded": bool(np.all(np.isfinite(state)) and np.max(np.abs(state[:, :2])) < 1e3),
            "fallback_cycles": int(np.sum(rec.columns["fallback"])),
            "cycle_us_median": float(np.median(solve)) if solve.size else math.nan,
            "cycle_us_p99": float(np.percentile(solve, 99)) if solve.size else math.nan,
            "phases": [phase_metrics(rec, none, a, b) for a, b in sc.phases()],
            **rec.meta,
        }
    return out


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float (a metric that never happened, an empty run's
    median) as None, so the file is strict JSON (RFC 8259 has no NaN or Infinity):
    ``null`` in results.json means "never" or "not measured" (docs/results.md)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_ready(v) for v in obj]
    return obj


def write_results(records: dict[str, RunRecord], out_dir: Path) -> dict[str, Any]:
    """Write each record's timeseries.csv and results.json (strict JSON: :func:`json_ready`);
    returns the results as computed (NaN where a metric never happened)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, rec in records.items():
        write_csv(rec, out_dir / name / "timeseries.csv")
    res = results(records)
    text = json.dumps(json_ready(res), indent=2, allow_nan=False)
    (out_dir / "results.json").write_text(text)
    return res
