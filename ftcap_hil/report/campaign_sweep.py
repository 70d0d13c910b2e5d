"""Where the method stops: per mode, scenario (a preset in one condition of a sweep) and
fault kind, the share of detectable faults (one per thruster and run: the spells of an
intermittent fault count once) isolated within 5 s, within 30 s and never, with
their Wilson 95 % intervals; and per mode and scenario the healthy hours and the
false-alarm episodes per hour with their Poisson interval.

A sweep is written in a campaign as one ``[[scenario]]`` entry per condition (for example
the supply vessel in Beaufort 2 to 6, each with its ``[environment]`` levels and its own
label): the map's rows are those labels, in the campaign's order. Definitions:
docs/campaigns.md.
"""

from __future__ import annotations

import math
import statistics
from collections import defaultdict
from typing import Any

from ftcap_hil.report.intervals import poisson_rate, put_interval, wilson_share

Row = dict[str, Any]
WITHIN_S = (5.0, 30.0)


def _delay(f: Row, key: str = "isolation_delay_s") -> float:
    d = f.get(key)
    return math.inf if d is None else float(d)


def faults_per_run(faults: list[Row]) -> list[Row]:
    """The faults a user counts: one per thruster and run. The spells of an intermittent
    fault (one row each) become one fault from the first spell's onset, isolated when any
    spell first was (its delay counted from that first onset), detectable if any spell
    was; ``spells`` says how many it had. Rows without a run ``key`` stand alone."""
    groups: dict[Any, list[Row]] = defaultdict(list)
    for n, f in enumerate(faults):
        key = f.get("key")
        groups[n if key is None else (key, f.get("thruster"))].append(f)
    out = []
    for g in groups.values():
        if len(g) == 1:
            out.append({**g[0], "spells": 1})
            continue
        first = min(g, key=lambda f: float(f["onset_s"]))
        t0 = float(first["onset_s"])
        isolated = min(float(f["onset_s"]) + _delay(f) for f in g)
        delay = None if math.isinf(isolated) else isolated - t0
        out.append({
            **first, "spells": len(g), "detectable": any(f["detectable"] for f in g),
            "isolation_delay_s": delay,
            # an intermittent fault's cause shows from its first onset (dead, power lost)
            "visible_delay_s": delay if first.get("drive_visible") else None,
        })  # fmt: skip
    return out


def sweep_rows(rows: list[Row], faults: list[Row]) -> list[Row]:
    """One row per (mode, scenario, fault kind) with detectable faults (per run:
    :func:`faults_per_run`), and per (mode, scenario) one ``healthy`` row: see the module
    docstring. Shares are fractions; each value ``x`` has ``x_lo``, ``x_hi`` and ``x_n``
    beside it."""
    order = list(dict.fromkeys(r["scenario"] for r in rows))
    groups: dict[tuple[str, str, str], list[Row]] = defaultdict(list)
    for f in faults_per_run(faults):
        if f["mode"] != "none" and f["detectable"]:
            groups[(f["variant"], f["scenario"], f["kind"])].append(f)
    out: list[Row] = []
    for (variant, scenario, kind), g in sorted(
        groups.items(), key=lambda kv: (kv[0][0], order.index(kv[0][1]), kv[0][2])
    ):
        row: Row = {"mode": variant, "scenario": scenario, "kind": kind, "faults": len(g)}
        _shares(row, [_delay(f) for f in g])
        out.append(row)
    return out + _healthy_rows(rows, order)


VISIBLE_WITHIN_S = (2.0, 5.0)  # the targets: CyberShip II within 2 s, the supply vessel 5 s


def drive_visible_rows(faults: list[Row], by: str) -> list[Row]:
    """The faults a drive's telemetry shows by itself (``drive_visible``; per run:
    :func:`faults_per_run`), per mode and ``by`` (``scenario`` or ``cause``): isolated
    within 2 s, 5 s (from when the drive could first show it: ``visible_delay_s``), never,
    and the share whose isolation the drive's verdict named right
    (``cause_named``) among all of them; estimating modes only."""
    groups: dict[tuple[str, str], list[Row]] = defaultdict(list)
    order: dict[str, int] = {}
    for f in faults_per_run(faults):
        order.setdefault(str(f[by]), len(order))
        if f["mode"] not in ("none", "cap", "oracle") and f.get("drive_visible"):
            groups[(f["variant"], str(f[by]))].append(f)
    out = []
    for (variant, key), g in sorted(groups.items(), key=lambda kv: (kv[0][0], order[kv[0][1]])):
        row: Row = {"mode": variant, by: key, "faults": len(g)}
        _shares(row, [_delay(f, "visible_delay_s") for f in g], VISIBLE_WITHIN_S)
        put_interval(row, "named", wilson_share(sum(bool(f.get("cause_named")) for f in g), len(g)))
        out.append(row)
    return out


def _shares(row: Row, delays: list[float], within: tuple[float, ...] = WITHIN_S) -> None:
    """The isolated-within and never shares of ``delays`` (inf: never) into ``row``."""
    n = len(delays)
    for limit in within:
        put_interval(row, f"isolated_{limit:g}s", wilson_share(sum(d <= limit for d in delays), n))
    put_interval(row, "never", wilson_share(sum(math.isinf(d) for d in delays), n))


def headline_rows(rows: list[Row], faults: list[Row]) -> list[Row]:
    """Per estimating mode and scenario, one line a reader takes away: the healthy hours
    and false-alarm episodes per hour, every detectable fault's isolation (within 5 s,
    30 s, never; per run, an intermittent fault once: :func:`faults_per_run`), the runs
    with harm and the median deviation over the oracle's; each rate and share with its
    95 % interval and sample size. ``rows`` with ``derive``'s columns (harm,
    dev_ratio_oracle)."""
    order = list(dict.fromkeys(r["scenario"] for r in rows))
    healthy = {(h["mode"], h["scenario"]): h for h in _healthy_rows(rows, order)}
    faults = faults_per_run(faults)
    out = []
    for (variant, scenario), h in healthy.items():
        row: Row = {k: v for k, v in h.items() if k != "kind"}
        det = [f for f in faults if (f["variant"], f["scenario"]) == (variant, scenario)
               and f["detectable"]]  # fmt: skip
        row["faults"] = len(det)
        _shares(row, [_delay(f) for f in det])
        runs = [r for r in rows if (r["variant"], r["scenario"]) == (variant, scenario)
                and r["status"] == "ok"]  # fmt: skip
        judged = [r for r in runs if r.get("harm") is not None]
        put_interval(
            row, "harm_share", wilson_share(sum(bool(r["harm"]) for r in judged), len(judged))
        )
        ratios = [r["dev_ratio_oracle"] for r in runs if r.get("dev_ratio_oracle") is not None]
        row["dev_ratio_oracle_median"] = statistics.median(ratios) if ratios else None
        out.append(row)
    return out


def _healthy_rows(rows: list[Row], order: list[str]) -> list[Row]:
    hours: dict[tuple[str, str], list[Row]] = defaultdict(list)
    for r in rows:
        if r["mode"] not in ("none", "cap", "oracle") and r["status"] == "ok":
            hours[(r["variant"], r["scenario"])].append(r)
    out = []
    for (variant, scenario), g in sorted(
        hours.items(), key=lambda kv: (kv[0][0], order.index(kv[0][1]))
    ):
        h = sum(r["healthy_hours"] for r in g)
        row: Row = {"mode": variant, "scenario": scenario, "kind": "healthy", "healthy_hours": h}
        episodes = sum(r.get("false_alarm_episodes", 0) for r in g)
        put_interval(row, "false_alarm_episodes_per_h", poisson_rate(episodes, h))
        switches = sum(r.get("removal_switches", 0) for r in g)
        put_interval(row, "removal_switches_per_h", poisson_rate(switches, h))
        out.append(row)
    return out
