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
from ftcap_hil.report.campaign_sweep import drive_visible_rows, headline_rows, sweep_rows

RUN_COLUMNS = (
    ("mode", "mode"),
    ("kind", "kind"),
    ("runs", "runs"),
    ("failed", "failed"),
    ("healthy h", "healthy_hours"),
    ("dev/oracle med", "dev_ratio_oracle_median"),
    ("dev/CAP med", "dev_ratio_cap_median"),
    ("dev/CAP p95", "dev_ratio_cap_p95"),
    ("dev rms med (m)", "deviation_rms_median"),
    ("false-alarm episodes /h [95 %]", "false_alarm_episodes_per_h"),
    ("removal switches /h [95 %]", "removal_switches_per_h"),
    ("healthy flagged", "healthy_flagged_frac"),
    ("healthy removed", "healthy_removed_frac"),
    ("min healthy delta-hat", "healthy_delta_hat_min"),
    ("harm runs [95 %]", "harm_share"),
)
FAULT_COLUMNS = (
    ("mode", "mode"),
    ("kind", "kind"),
    ("faults", "faults"),
    ("detectable", "detectable"),
    ("detected [95 %]", "detected_share"),
    ("det. med (s)", "detection_delay_median"),
    ("iso. med (s)", "isolation_delay_median"),
    ("iso. p95", "isolation_delay_p95"),
    ("iso. <= 5 s", "isolated_5s_share"),
    ("iso. <= 30 s", "isolated_30s_share"),
    ("never iso.", "never_isolated_share"),
    ("correct iso.", "correct_isolation_rate"),
    ("delta err med", "delta_error_median"),
    ("to 0.1 med (s)", "converge_median"),
    ("recovered", "recovered_share"),
    ("recovery med (s)", "recovery_median"),
    ("recovery p95", "recovery_p95"),
)
VISIBLE_COLUMNS = (
    ("faults", "faults"),
    ("iso. <= 2 s", "isolated_2s"),
    ("iso. <= 5 s", "isolated_5s"),
    ("never", "never"),
    ("cause named", "named"),
)
PERCENT = {
    "healthy_flagged_frac",
    "healthy_removed_frac",
    "detection_rate",
    "correct_isolation_rate",
    "detected_share",
    "isolated_5s_share",
    "isolated_30s_share",
    "never_isolated_share",
    "recovered_share",
    "harm_share",
    "isolated_2s",
    "isolated_5s",
    "isolated_30s",
    "never",
    "named",
}


def headline_block(summary: str) -> str:
    """The headline table of a summary.md, between its markers (the README carries the
    same block; a test holds the two equal)."""
    start, end = summary.index(HEADLINE_BEGIN), summary.index(HEADLINE_END)
    return summary[start : end + len(HEADLINE_END)]


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


def cell(row: Row, key: str) -> str:
    """``row[key]`` as :func:`fmt` writes it; a value with its 95 % interval (``key_lo``,
    ``key_hi``, ``key_n`` beside it) as ``value [lo, hi] (n)``: for a share, n is the
    trials; for a rate, the events."""
    text = fmt(row.get(key), key)
    if f"{key}_lo" not in row or row.get(key) is None:
        return text
    low, high = fmt(row[f"{key}_lo"], key), fmt(row[f"{key}_hi"], key)
    return f"{text} [{low}, {high}] ({row[f'{key}_n']})"


def markdown_table(rows: Sequence[Row], columns: Sequence[tuple[str, str]]) -> list[str]:
    """A Markdown table of ``rows``, one column per (header, key) of ``columns``."""
    lines = ["| " + " | ".join(h for h, _ in columns) + " |"]
    lines.append("|" + "|".join("---" for _ in columns) + "|")
    lines += ["| " + " | ".join(cell(r, k) for _, k in columns) + " |" for r in rows]
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


HARM_COLUMNS = (
    ("run", "key"),
    ("phase", "phase"),
    ("run (m)", "run_m"),
    ("CAP (m)", "cap_m"),
    ("oracle (m)", "oracle_m"),
    ("run/CAP", "ratio_cap"),
    ("run/oracle", "ratio_oracle"),
    ("dev. from fault-free max (m)", "deviation_max"),
    ("replay", "replay"),
)
HEADLINE_COLUMNS = (
    ("mode", "mode"),
    ("scenario", "scenario"),
    ("healthy h", "healthy_hours"),
    ("false-alarm episodes /h", "false_alarm_episodes_per_h"),
    ("faults", "faults"),
    ("isolated <= 5 s", "isolated_5s"),
    ("isolated <= 30 s", "isolated_30s"),
    ("never isolated", "never"),
    ("runs with harm", "harm_share"),
    ("dev/oracle med", "dev_ratio_oracle_median"),
)
HEADLINE_BEGIN, HEADLINE_END = "<!-- headline begin -->", "<!-- headline end -->"
SWEEP_COLUMNS = (
    ("mode", "mode"),
    ("scenario", "scenario"),
    ("kind", "kind"),
    ("iso. <= 5 s", "isolated_5s"),
    ("iso. <= 30 s", "isolated_30s"),
    ("never", "never"),
    ("healthy h", "healthy_hours"),
    ("false-alarm episodes /h", "false_alarm_episodes_per_h"),
    ("removal switches /h", "removal_switches_per_h"),
)


def _harm_section(harm: list[Row], params: MetricParams) -> list[str]:
    return [
        f"## Harm ({len(harm)} run phases)",
        "",
        f"A run phase where a mode's {params.harm_statistic.value} "
        f"{'tracking error' if params.harm_basis.value == 'tracking' else 'deviation'} "
        f"exceeds {params.harm_ratio:g} x the larger of CAP's and the oracle's in the same "
        "phase (no floor; a healthy case's CAP is its fault-free run). The metres of the "
        "run, CAP and the oracle, and the run's deviation from its fault-free run.",
        "",
        *(markdown_table(harm, HARM_COLUMNS) if harm else ["None."]),
        "",
    ]


def _seeds_text(rows: list[Row], tuning: list[int]) -> str:
    seeds = sorted({int(r["seed"]) for r in rows if r.get("seed") is not None})
    text = f" Evaluated on seeds {_compact(seeds)}" if seeds else ""
    if tuning:
        text += f"; thresholds tuned on seeds {_compact(sorted(tuning))} (disjoint)"
    return text + "." if text else ""


def _compact(seeds: list[int]) -> str:
    """``[1, 2, 3, 7]`` -> ``1-3, 7``."""
    parts, start = [], None
    for i, s in enumerate(seeds):
        start = s if start is None else start
        if i + 1 == len(seeds) or seeds[i + 1] != s + 1:
            parts.append(f"{start}" if start == s else f"{start}-{s}")
            start = None
    return ", ".join(parts)


def summary_markdown(rows: list[Row], params: MetricParams, info: dict[str, Any]) -> str:
    """The summary; ``info``: name, description, wall_s, workers, scheduler."""
    ok = [r for r in rows if r["status"] == "ok"]
    hours = sum(r["duration_s"] for r in ok) / 3600.0
    harm = harm_list(rows)
    faults = fault_rows(rows)
    out = [
        f"# Campaign {info.get('name', '')}",
        "",
        str(info.get("description", "")),
        "",
        f"{len(rows)} runs ({len(ok)} ok, {len(rows) - len(ok)} failed) in "
        f"{len({r['case'] for r in rows})} cases; {hours:.2f} h simulated. "
        f"This invocation: {info.get('ran', 0)} runs in {info.get('wall_s', 0.0):.1f} s on "
        f"{info.get('scheduler', 'an embedded LocalCluster')}."
        + _seeds_text(rows, info.get("tuning_seeds") or []),
        "",
        "Definitions of every column: docs/campaigns.md. Ratios: the run's deviation from its "
        "fault-free run (RMS over the run) over the oracle's / CAP's in the same case. "
        "Delays count from the fault's detectable onset; a fault never detected counts as "
        "'never' (infinite) in the percentiles. [95 %]: the exact Poisson interval of a rate "
        "(n: events) or the Wilson interval of a share (n: trials).",
        "",
        "## Headline",
        "",
        "Per estimating mode and scenario: the false-alarm episodes per healthy hour, every "
        "detectable fault's isolation (one fault per thruster and run: an intermittent "
        "fault counts once, from its first onset to its first isolation) and the runs with "
        "harm, each with its 95 % interval and sample size; the median deviation over the "
        "oracle's.",
        "",
        HEADLINE_BEGIN,
        *markdown_table(headline_rows(rows, faults), HEADLINE_COLUMNS),
        HEADLINE_END,
        "",
        "## Runs per mode and fault kind",
        "",
        *markdown_table(run_groups(rows), RUN_COLUMNS),
        "",
        "## Fault episodes per mode and fault kind",
        "",
        "Every episode on its own: each on/off spell of an intermittent fault is a row "
        "here (the headline and the map below count the fault once per run).",
        "",
        *markdown_table(fault_groups(faults), FAULT_COLUMNS),
        "",
        *_harm_section(harm, params),
        "## Where the method stops",
        "",
        "Per mode, scenario and fault kind: the detectable faults (one per thruster and "
        "run) isolated within 5 s, within 30 s and never (Wilson 95 %, n faults); per "
        "scenario the healthy hours and "
        "false-alarm episodes per hour (Poisson 95 %, n episodes).",
        "",
        *markdown_table(sweep_rows(rows, faults), SWEEP_COLUMNS),
        "",
        *_visible_section(faults),
        "## Failed runs",
        "",
        *_failed(rows),
    ]
    return "\n".join(out) + "\n"


def _visible_section(faults: list[Row]) -> list[str]:
    """The drive-visible faults per scenario and per cause (campaign_sweep)."""
    rows = drive_visible_rows(faults, "scenario")
    if not rows:
        return []
    columns = [("mode", "mode"), ("scenario", "scenario"), *VISIBLE_COLUMNS]
    return [
        "## Drive-visible faults",
        "",
        "The faults a drive's own telemetry shows (drive dead, jammed, frozen shaft, lost "
        "blade, a weak motor down by 30 % or more), one per thruster and run: isolated "
        "within 2 s, within 5 s (from when the drive could first show it: a weak motor's "
        "ramp once down by 30 %) and never, and the share isolated with the drive's verdict "
        "naming the cause (Wilson 95 %, n faults); per scenario, then per cause.",
        "",
        *markdown_table(rows, columns),
        "",
        *markdown_table(
            drive_visible_rows(faults, "cause"),
            [*columns[:1], ("cause", "cause"), *VISIBLE_COLUMNS],
        ),  # fmt: skip
        "",
    ]


PLOT_CAPTIONS = {
    "sweep_map": "Where the method stops: shares isolated within 5 s / 30 s / never",
    "isolation_by_kind": "Isolation delay per fault kind (ECDF; a curve below 1: never)",
    "dev_cap_by_scenario": "Deviation RMS over CAP's per scenario (dashed: the 1.05 harm line)",
    "distributions": "Detection and isolation delays, estimate error, deviation / oracle",
    "by_kind": "Isolation delay and deviation / CAP per fault kind",
}


def report_markdown(info: dict[str, Any], pictures: list[Path]) -> str:
    """report.md: the campaign's one page for a reviewer, linking the summary, the tables
    and embedding the plots (``pictures``: the PNGs written beside it)."""
    out = [
        f"# Campaign {info.get('name', '')}: report",
        "",
        str(info.get("description", "")),
        "",
        "- [summary.md](summary.md): every table, with 95 % intervals and sample sizes, the "
        "harm list with replay commands, the failed runs",
        "- [runs.csv](runs.csv), [faults.csv](faults.csv): one row per run / fault episode",
        "- definitions: docs/campaigns.md of ftcap-hil",
        "",
    ]
    for png in sorted(pictures, key=lambda p: list(PLOT_CAPTIONS).index(p.stem)):
        out += [f"## {PLOT_CAPTIONS[png.stem]}", "", f"![{png.stem}]({png.name})", ""]
    return "\n".join(out)


def write_report(
    rows: list[Row], params: MetricParams, out_dir: Path, info: dict[str, Any], plots: bool = True
) -> list[Path]:
    """Every output of a campaign from its rows (tables, summary.md, the plots and
    report.md linking them); returns the paths written. ``info["scenarios"]``: the
    campaign's scenario labels in its order, which the tables follow (else first seen)."""
    order = list(info.get("scenarios") or [])
    rank = {label: k for k, label in enumerate(order)}
    rows = sorted(derive(rows, params), key=lambda r: rank.get(r["scenario"], len(order)))
    written = write_tables(rows, out_dir)
    (out_dir / "summary.md").write_text(summary_markdown(rows, params, info))
    written.append(out_dir / "summary.md")
    pictures: list[Path] = []
    if plots:
        from ftcap_hil.report.campaign_plots import write_campaign_plots

        faults = fault_rows(rows)
        pictures = write_campaign_plots(rows, faults, out_dir, sweep_rows(rows, faults))
        written += pictures
    (out_dir / "report.md").write_text(report_markdown(info, pictures))
    return written + [out_dir / "report.md"]
