"""Run records, ``timeseries.csv`` and ``results.json`` (schema in docs/results.md).

Shared by the offline simulator and the ground-station script so both write the same files.
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
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.messages import FloatArray
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


def column_names(sc: Scenario) -> list[str]:
    m, k = sc.thrusters.m, sc.B.shape[0]
    state = list(sc.plant.state_labels)
    refs = ["ref_x"] if isinstance(sc.plant, LinearPlant) else ["ref_north", "ref_east", "ref_psi"]
    names = ["t", *state, *refs]
    names += [f"v_dem_{j}" for j in range(1, k + 1)] + [f"v_ach_{j}" for j in range(1, k + 1)]
    for prefix in ("u", "tau", "delta", "f", "delta_hat", "f_hat"):
        names += [f"{prefix}_{i}" for i in range(1, m + 1)]
    names += [f"bf_hat_{j}" for j in range(1, k + 1)]
    names += ["innovation", "window_len", "fallback", "probing", "solve_us"]
    return names


def flag_names(sc: Scenario) -> list[str]:
    """Per-thruster decision columns the offline recorder appends after ``column_names``:
    ``faulty_i`` (the core's fault flag, CoreConfig.fault_threshold / fault_clear) and
    ``dead_i`` (taken out of the allocation: the effectiveness the allocator used was below
    allocator.dead_threshold, ``Allocation.dead``); 0 or 1."""
    m = sc.thrusters.m
    return [f"faulty_{i}" for i in range(1, m + 1)] + [f"dead_{i}" for i in range(1, m + 1)]


class Recorder:
    """Collects one row per cycle, in the order of ``column_names`` then ``flag_names``."""

    def __init__(self, sc: Scenario, mode: str) -> None:
        self.sc = sc
        self.mode = mode
        self.names = column_names(sc) + flag_names(sc)
        self.rows: list[FloatArray] = []

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
        row = np.concatenate(
            [
                [t],
                x,
                ref,
                v_dem,
                v_ach,
                res.u,
                produced,
                truth.delta,
                truth.f,
                est.delta_hat,
                est.f_hat,
                est.bf_hat,
                [
                    est.innovation,
                    est.window_len,
                    res.allocation.status is not AllocationStatus.OK,
                    bool(np.any(res.probing)),
                    solve_s * 1e6,
                ],
                res.faulty,
                res.allocation.dead,
            ]
        )
        self.rows.append(row)

    def finish(self, **meta: Any) -> RunRecord:
        data = np.vstack(self.rows) if self.rows else np.zeros((0, len(self.names)))
        return RunRecord(
            self.sc, self.mode, {n: data[:, i] for i, n in enumerate(self.names)}, meta
        )


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
        "time_unit": sc.time_unit,
        "dt": sc.dt_s,
        "integrator": sc.integrator,
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
