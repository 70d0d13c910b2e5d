"""A campaign's results: ratios and harm across the runs of a case, aggregates, tables.

Input: the rows of ``runs.jsonl`` (one per run, ``runtime.campaign``). ``derive`` adds what
needs several runs of one case (the deviation as a ratio to the oracle's and to CAP's, and
harm); ``run_groups`` / ``fault_groups`` aggregate per mode (variant) and fault kind;
``write_tables`` writes runs.csv, faults.csv (and Parquet when pyarrow is installed) and
``summary_markdown`` the Markdown summary. Definitions: docs/campaigns.md.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import HarmBasis, MetricParams
from ftcap_hil.report.intervals import poisson_rate, put_interval, wilson_share

REFERENCE_MODES = ("none", "cap")
Row = dict[str, Any]


def latest(rows: Iterable[Row]) -> list[Row]:
    """The last row of every key (a re-run replaces a failed one), in first-seen order."""
    out: dict[str, Row] = {}
    for row in rows:
        out.pop(row["key"], None)
        out[row["key"]] = row
    return list(out.values())


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not b > 1e-12:
        return None
    return a / b


def _phase_ref(run: Row | None, j: int, stat: str) -> float | None:
    """A reference run's statistic ``stat`` in phase ``j`` (None: no such run or value)."""
    return None if run is None else run["phases"][j][stat]


def _harm(
    row: Row, cap: Row | None, oracle: Row | None, p: MetricParams
) -> tuple[bool | None, list[int], list[Row]]:
    """Phases (indices) where the run's tracking error (``harm_basis``: or its deviation
    from the fault-free run) exceeds ``harm_ratio`` x the larger of CAP's and the oracle's
    in that phase, no floor; and per phase the metres and the ratios to each. A healthy
    case's CAP is its fault-free run (``derive`` hands it in; for the deviation, 0 m)."""
    stat = f"{p.harm_basis.value}_{p.harm_statistic.value}"
    if cap is None and not row["healthy"]:
        return None, [], []
    phases, detail = [], []
    for j, ph in enumerate(row["phases"]):
        c = 0.0 if cap is None else _phase_ref(cap, j, stat)
        o = _phase_ref(oracle, j, stat)
        if ph[stat] is None or c is None:
            return None, [], []
        best = max(c, o) if o is not None else c
        detail.append(
            {"run_m": ph[stat], "cap_m": c, "oracle_m": o,
             "ratio_cap": _ratio(ph[stat], c), "ratio_oracle": _ratio(ph[stat], o)}
        )  # fmt: skip
        if ph[stat] > p.harm_ratio * best:
            phases.append(j)
    return bool(phases), phases, detail


def derive(rows: Iterable[Row], params: MetricParams) -> list[Row]:
    """Rows with ``dev_ratio_oracle``, ``dev_ratio_cap``, ``harm``, ``harm_phases`` and
    ``harm_detail`` (per phase: the metres and the ratios to CAP and the oracle)."""
    rows = latest(rows)
    by_case: dict[str, dict[str, Row]] = defaultdict(dict)
    for row in rows:
        if row["status"] == "ok":
            by_case[row["case"]][row["variant"]] = row
    out = []
    for row in rows:
        row = dict(row)
        if row["status"] == "ok" and row["mode"] != "none":
            refs = by_case[row["case"]]
            cap, oracle = refs.get("cap"), refs.get("oracle")
            if cap is None and row["healthy"] and params.harm_basis is HarmBasis.TRACKING:
                cap = refs.get("none")  # without faults CAP is the fault-free run
            row["dev_ratio_oracle"] = _ratio(
                row["deviation_rms"], (oracle or {}).get("deviation_rms")
            )
            row["dev_ratio_cap"] = _ratio(row["deviation_rms"], (cap or {}).get("deviation_rms"))
            if row["mode"] not in REFERENCE_MODES:
                row["harm"], row["harm_phases"], row["harm_detail"] = _harm(
                    row, cap, oracle, params
                )
        out.append(row)
    return out


def fault_rows(rows: Iterable[Row]) -> list[Row]:
    """One row per fault episode of every successful run, with its run's identity."""
    head = ("key", "case", "scenario", "seed", "variant", "mode")
    return [
        {**{k: row[k] for k in head}, "run_kind": row["kind"], **f}
        for row in rows
        if row["status"] == "ok"
        for f in row.get("faults", [])
    ]


_MISS = 1e300  # stands for "never" inside the percentile (inf - inf would give NaN)


def _q(values: list[float], q: float) -> float | None:
    """Percentile (linear); one that interpolates towards a miss (inf) is inf."""
    if not values:
        return None
    v = float(np.percentile(np.minimum(np.asarray(values, dtype=np.float64), _MISS), q))
    return math.inf if v >= _MISS * 1e-10 else v


def _delays(rows: list[Row], key: str, keep: Callable[[Row], bool]) -> list[float]:
    """Values of ``key`` for the rows kept; a delay that never came counts as infinite."""
    return [math.inf if r[key] is None else r[key] for r in rows if keep(r)]


ISOLATION_WITHIN_S = (5.0, 30.0)  # the shares isolated within these delays (and never)


def _rate(rows: list[Row], key: str) -> float | None:
    vals = [r[key] for r in rows if r[key] is not None]
    return sum(map(bool, vals)) / len(vals) if vals else None


def _groups(rows: list[Row], kind: str) -> dict[tuple[str, str], list[Row]]:
    out: dict[tuple[str, str], list[Row]] = defaultdict(list)
    for row in rows:
        if row["mode"] != "none":
            out[(row["variant"], row[kind])].append(row)
            out[(row["variant"], "all")].append(row)
    return dict(sorted(out.items()))


def run_groups(rows: list[Row]) -> list[Row]:
    """Per (mode, run kind) and (mode, all): run-level statistics."""
    out = []
    for (variant, kind), group in _groups(rows, "kind").items():
        ok = [r for r in group if r["status"] == "ok"]
        hours = sum(r["healthy_hours"] for r in ok)
        healthy_s = sum(r["healthy_thruster_s"] for r in ok)

        def vals(key: str, rows: list[Row] = ok) -> list[float]:
            return [r[key] for r in rows if r.get(key) is not None]

        out.append(
            {
                "mode": variant,
                "kind": kind,
                "runs": len(group),
                "failed": len(group) - len(ok),
                "sim_hours": sum(r["duration_s"] for r in ok) / 3600.0,
                "dev_ratio_oracle_median": _q(vals("dev_ratio_oracle"), 50),
                "dev_ratio_oracle_p95": _q(vals("dev_ratio_oracle"), 95),
                "dev_ratio_cap_median": _q(vals("dev_ratio_cap"), 50),
                "dev_ratio_cap_p95": _q(vals("dev_ratio_cap"), 95),
                "deviation_rms_median": _q(vals("deviation_rms"), 50),
                "unallocated_rms_median": _q(vals("unallocated_rms"), 50),
                "false_alarm_rate_per_h": sum(r["false_alarms"] for r in ok) / hours
                if hours
                else None,
                "healthy_flagged_frac": sum(r["healthy_flagged_s"] for r in ok) / healthy_s
                if healthy_s
                else None,
                "healthy_removed_frac": sum(r["healthy_removed_s"] for r in ok) / healthy_s
                if healthy_s
                else None,
                "healthy_delta_hat_min": min(vals("healthy_delta_hat_min"), default=None),
                "harm_runs": sum(1 for r in ok if r.get("harm")),
            }
        )
        row = out[-1]
        row["healthy_hours"] = hours
        events = sum(r.get("false_alarm_episodes", 0) for r in ok)
        put_interval(row, "false_alarm_episodes_per_h", poisson_rate(events, hours))
        switches = sum(r.get("removal_switches", 0) for r in ok)
        put_interval(row, "removal_switches_per_h", poisson_rate(switches, hours))
        judged = [r for r in ok if r.get("harm") is not None]
        put_interval(
            row, "harm_share", wilson_share(sum(bool(r["harm"]) for r in judged), len(judged))
        )
    return out


def fault_groups(faults: list[Row]) -> list[Row]:
    """Per (mode, fault kind) and (mode, all): fault-level statistics (misses as inf)."""
    out = []
    for (variant, kind), g in _groups(faults, "kind").items():
        det = [r for r in g if r["detectable"]]
        hits = sum(r["detection_delay_s"] is not None for r in det)
        row: Row = {
            "mode": variant,
            "kind": kind,
            "faults": len(g),
            "detectable": len(det),
            "detection_rate": hits / len(det) if det else None,
            "correct_isolation_rate": _rate(det, "correct_isolation"),
        }
        series = {
            "detection_delay": _delays(g, "detection_delay_s", lambda r: r["detectable"]),
            "isolation_delay": _delays(g, "isolation_delay_s", lambda r: r["detectable"]),
            "isolation_delay_used": _delays(
                g, "isolation_delay_s", lambda r: r["detectable"] and bool(r["used"])
            ),
            "removal_delay": _delays(g, "removal_delay_s", lambda r: r["detectable"]),
            "delta_error": _delays(g, "delta_error", lambda r: True),
            "converge": _delays(g, "converge_s", lambda r: True),
            "recovery": _delays(g, "recovery_s", lambda r: r["ended"]),
        }
        for name, values in series.items():
            row[f"{name}_median"], row[f"{name}_p95"] = _q(values, 50), _q(values, 95)
        put_interval(row, "detected_share", wilson_share(hits, len(det)))
        iso = series["isolation_delay"]
        for limit in ISOLATION_WITHIN_S:
            within = sum(d <= limit for d in iso)
            put_interval(row, f"isolated_{limit:g}s_share", wilson_share(within, len(iso)))
        put_interval(
            row, "never_isolated_share", wilson_share(sum(math.isinf(d) for d in iso), len(iso))
        )
        ended = [r for r in g if r["ended"]]
        back = sum(r["recovery_s"] is not None for r in ended)
        put_interval(row, "recovered_share", wilson_share(back, len(ended)))
        out.append(row)
    return out


def harm_list(rows: list[Row]) -> list[Row]:
    """Every (run, phase) with harm: the run, the phase and both deviations."""
    out = []
    for row in rows:
        for j in row.get("harm_phases") or []:
            ph, d = row["phases"][j], row["harm_detail"][j]
            out.append(
                {
                    "key": row["key"],
                    "phase": f"[{ph['start_s']:g}, {ph['end_s']:g}) s",
                    "run_m": d["run_m"],
                    "cap_m": d["cap_m"],
                    "oracle_m": d["oracle_m"],
                    "ratio_cap": d["ratio_cap"],
                    "ratio_oracle": d["ratio_oracle"],
                    "deviation_max": ph["deviation_max"],
                    "replay": row["replay"],
                }
            )
    return out


def _scalars(row: Row) -> Row:
    out = {k: v for k, v in row.items() if not isinstance(v, list | dict)}
    if "harm_phases" in row:
        out["harm_phases"] = " ".join(map(str, row["harm_phases"] or []))
    return out


def _write_csv(rows: list[Row], path: Path) -> None:
    names = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, names, restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if v is None else v for k, v in r.items()})


def write_tables(rows: list[Row], out_dir: Path) -> list[Path]:
    """runs.csv and faults.csv; runs.parquet and faults.parquet when pyarrow is there."""
    tables = {"runs": [_scalars(r) for r in rows], "faults": fault_rows(rows)}
    written = []
    for name, data in tables.items():
        _write_csv(data, out_dir / f"{name}.csv")
        written.append(out_dir / f"{name}.csv")
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    for name, data in tables.items():
        if data:
            pq.write_table(pa.Table.from_pylist(data), out_dir / f"{name}.parquet")
            written.append(out_dir / f"{name}.parquet")
    return written
