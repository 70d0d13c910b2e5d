"""A campaign's report in DIR: summary.md, runs.csv, faults.csv (Parquet if pyarrow), plots.

``write_report(rows, params, out_dir, info)`` takes every row of ``runs.jsonl`` and writes
all of them again from scratch, so a resumed campaign's report covers all its runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ftcap_hil.config.campaign import MetricParams
from ftcap_hil.report.campaign_summary import (
    Row,
    derive,
    fault_groups,
    fault_rows,
    harm_list,
    run_groups,
    write_tables,
)

RUN_COLUMNS = (
    ("mode", "mode"),
    ("kind", "kind"),
    ("runs", "runs"),
    ("failed", "failed"),
    ("dev/oracle med", "dev_ratio_oracle_median"),
    ("dev/oracle p95", "dev_ratio_oracle_p95"),
    ("dev/CAP med", "dev_ratio_cap_median"),
    ("dev/CAP p95", "dev_ratio_cap_p95"),
    ("dev rms med (m)", "deviation_rms_median"),
    ("unalloc. rms med", "unallocated_rms_median"),
    ("false alarms /h", "false_alarm_rate_per_h"),
    ("healthy flagged", "healthy_flagged_frac"),
    ("healthy removed", "healthy_removed_frac"),
    ("min healthy delta-hat", "healthy_delta_hat_min"),
    ("harm runs", "harm_runs"),
)
FAULT_COLUMNS = (
    ("mode", "mode"),
    ("kind", "kind"),
    ("faults", "faults"),
    ("detectable", "detectable"),
    ("detected", "detection_rate"),
    ("det. med (s)", "detection_delay_median"),
    ("det. p95", "detection_delay_p95"),
    ("iso. med (s)", "isolation_delay_median"),
    ("iso. p95", "isolation_delay_p95"),
    ("iso. used med", "isolation_delay_used_median"),
    ("iso. used p95", "isolation_delay_used_p95"),
    ("correct iso.", "correct_isolation_rate"),
    ("removal med", "removal_delay_median"),
    ("delta err med", "delta_error_median"),
    ("delta err p95", "delta_error_p95"),
    ("to 0.1 med (s)", "converge_median"),
    ("to 0.1 p95", "converge_p95"),
    ("recovery med (s)", "recovery_median"),
    ("recovery p95", "recovery_p95"),
)
PERCENT = {
    "healthy_flagged_frac",
    "healthy_removed_frac",
    "detection_rate",
    "correct_isolation_rate",
}


def fmt(value: Any, key: str = "") -> str:
    """A table cell: '-' for none, 'never' for an infinite delay, 3 significant digits."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return "never"
        return f"{100 * value:.3g} %" if key in PERCENT else f"{value:.3g}"
    return str(value)


def markdown_table(rows: Sequence[Row], columns: Sequence[tuple[str, str]]) -> list[str]:
    lines = ["| " + " | ".join(h for h, _ in columns) + " |"]
    lines.append("|" + "|".join("---" for _ in columns) + "|")
    lines += ["| " + " | ".join(fmt(r.get(k), k) for _, k in columns) + " |" for r in rows]
    return lines


def _failed(rows: list[Row]) -> list[str]:
    bad = [r for r in rows if r["status"] != "ok"]
    if not bad:
        return ["None."]
    lines = ["| run | error | replay |", "|---|---|---|"]
    for r in bad:
        last = (r.get("error") or "").strip().splitlines()[-1:] or [""]
        lines.append(f"| {r['key']} | {last[0].replace('|', '/')} | `{r['replay']}` |")
    return lines


def summary_markdown(rows: list[Row], params: MetricParams, info: dict[str, Any]) -> str:
    """The summary; ``info``: name, description, wall_s, workers, scheduler."""
    ok = [r for r in rows if r["status"] == "ok"]
    hours = sum(r["duration_s"] for r in ok) / 3600.0
    harm = harm_list(rows)
    out = [
        f"# Campaign {info.get('name', '')}",
        "",
        str(info.get("description", "")),
        "",
        f"{len(rows)} runs ({len(ok)} ok, {len(rows) - len(ok)} failed) in "
        f"{len({r['case'] for r in rows})} cases; {hours:.2f} h simulated. "
        f"This invocation: {info.get('ran', 0)} runs in {info.get('wall_s', 0.0):.1f} s on "
        f"{info.get('scheduler', 'an embedded LocalCluster')}.",
        "",
        "Definitions of every column: docs/campaigns.md. Ratios: the run's deviation from its "
        "fault-free run (RMS over the run) over the oracle's / CAP's in the same case. "
        "Delays count from the fault's detectable onset; a fault never detected counts as "
        "'never' (infinite) in the percentiles.",
        "",
        "## Runs per mode and fault kind",
        "",
        *markdown_table(run_groups(rows), RUN_COLUMNS),
        "",
        "## Faults per mode and fault kind",
        "",
        *markdown_table(fault_groups(fault_rows(rows)), FAULT_COLUMNS),
        "",
        f"## Harm ({len(harm)} run phases)",
        "",
        f"A run phase where a mode's {params.harm_statistic.value} deviation exceeds "
        f"max({params.harm_ratio:g} x CAP's, {params.harm_length_fraction:g} x the vessel's "
        "length).",
        "",
        *(
            markdown_table(
                harm,
                [
                    ("run", "key"),
                    ("phase", "phase"),
                    ("dev max (m)", "deviation_max"),
                    ("dev rms (m)", "deviation_rms"),
                    ("replay", "replay"),
                ],
            )
            if harm
            else ["None."]
        ),
        "",
        "## Failed runs",
        "",
        *_failed(rows),
    ]
    return "\n".join(out) + "\n"


def write_report(
    rows: list[Row], params: MetricParams, out_dir: Path, info: dict[str, Any], plots: bool = True
) -> list[Path]:
    """Every output of a campaign from its rows; returns the paths written."""
    rows = derive(rows, params)
    written = write_tables(rows, out_dir)
    (out_dir / "summary.md").write_text(summary_markdown(rows, params, info))
    written.append(out_dir / "summary.md")
    if plots:
        from ftcap_hil.report.campaign_plots import write_campaign_plots

        written += write_campaign_plots(rows, fault_rows(rows), out_dir)
    return written
