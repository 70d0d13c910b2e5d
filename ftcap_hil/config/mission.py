"""Ground-station missions (TOML): what ``ftcap-hil gcs`` flies and which faults it injects.

A mission names a scenario (a shipped name such as ``paper-4.2-ex1`` or a path, relative to
the mission file) for the reference schedule, the fault schedule, the controller gains and
the control period; any of ``[controller]``, ``[[reference]]`` and ``[[fault]]`` given in the
mission replaces the scenario's table (same syntax as scenario files, docs/scenarios.md)::

    [mission]
    name = "paper-4.2-ex1"
    description = "..."
    scenario = "paper-4.2-ex1"
    duration = 700.0        # s, default: the scenario's duration
    # period = 0.2827       # s, control period T_s, default: the scenario's dt
    # mode = "ftcap"        # set the allocator's FTC_MODE first; default: leave it as it is

    [gcs]                   # all optional
    connect_timeout_s = 20.0     # heartbeats of vessel and allocator, first ODOMETRY
    odometry_timeout_s = 5.0     # no ODOMETRY for this long mid-flight -> abort
    wrench_limit = [1000.0, 1000.0, 1000.0]  # demands beyond are shrunk along their direction
    clear_faults_at_end = true

The fault schedule is the truth recorded in the timeseries; :func:`injection_plan` turns it
into MAV_CMD_INJECT_FAILURE requests (:class:`Injection`) at every change. Pure: no I/O
beyond reading the files.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.scenario import SHIPPED, parse_scenario
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.ground_station import GcsSettings, Mission

MISSIONS = "ftcap_hil.data.hil.missions"
MISSION_KEYS = {"name", "description", "scenario", "duration", "period", "mode"}
GCS_KEYS = {"connect_timeout_s", "odometry_timeout_s", "wrench_limit", "clear_faults_at_end"}
REPLACEABLE = ("controller", "reference", "fault")


def shipped_missions() -> list[str]:
    """Names of the missions shipped in ``ftcap_hil/data/hil/missions``."""
    return shipped_names(MISSIONS)


def _scenario_data(ref: Any, base: Path | None, where: str) -> tuple[dict[str, Any], str]:
    if not isinstance(ref, str) or not ref:
        raise ConfigError(f"{where}.mission.scenario: expected a name or a path, got {ref!r}")
    if base is not None and (base / ref).is_file():
        ref = str(base / ref)
    doc = read_toml(ref, SHIPPED, what=f"{where}.mission.scenario")
    return doc.data, doc.source


def _positive(table: dict[str, Any], key: str, where: str, default: float) -> float:
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise ConfigError(f"{where}.{key}: expected a positive number, got {v!r}")
    return float(v)


def _gcs_settings(table: Any, where: str) -> GcsSettings:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    if unknown := set(table) - GCS_KEYS:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(GCS_KEYS)})")
    d = GcsSettings()
    limit = table.get("wrench_limit", list(d.wrench_limit))
    arr = np.asarray(limit, dtype=np.float64) if isinstance(limit, list) else np.zeros(0)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
        raise ConfigError(f"{where}.wrench_limit: expected 3 positive numbers, got {limit!r}")
    clear = table.get("clear_faults_at_end", d.clear_faults_at_end)
    if not isinstance(clear, bool):
        raise ConfigError(f"{where}.clear_faults_at_end: expected true/false, got {clear!r}")
    return GcsSettings(
        _positive(table, "connect_timeout_s", where, d.connect_timeout_s),
        _positive(table, "odometry_timeout_s", where, d.odometry_timeout_s),
        (float(arr[0]), float(arr[1]), float(arr[2])),
        clear,
    )


def _mode(value: Any, where: str) -> Mode | None:
    if value is None:
        return None
    allowed = [m.value for m in Mode if m is not Mode.ORACLE]
    if value not in allowed:
        raise ConfigError(f"{where}.mission.mode: expected one of {allowed}, got {value!r}")
    return Mode(value)


def parse_mission(data: dict[str, Any], where: str, base: Path | None = None) -> Mission:
    head = data.get("mission")
    if not isinstance(head, dict):
        raise ConfigError(f"{where}.mission: missing table")
    if unknown := set(head) - MISSION_KEYS:
        raise ConfigError(
            f"{where}.mission: unknown keys {sorted(unknown)} (known: {sorted(MISSION_KEYS)})"
        )
    if unknown := set(data) - {"mission", "gcs", *REPLACEABLE}:
        raise ConfigError(f"{where}: unknown tables {sorted(unknown)}")
    sc_data, sc_where = _scenario_data(head.get("scenario"), base, where)
    for key in REPLACEABLE:
        if key in data:
            sc_data[key] = data[key]
    sc = parse_scenario(sc_data, f"{where} (scenario {sc_where})")
    if sc.time_unit != "s":
        raise ConfigError(f"{where}.mission.scenario: {sc_where!r} is not a vessel scenario")
    duration = _positive(head, "duration", f"{where}.mission", sc.duration_s)
    name = str(head.get("name", sc.name))
    return Mission(
        name=name,
        description=str(head.get("description", sc.description)),
        scenario=replace(sc, name=name, duration_s=duration),  # plots and results name it
        period_s=_positive(head, "period", f"{where}.mission", sc.dt_s),
        mode=_mode(head.get("mode"), where),
        gcs=_gcs_settings(data.get("gcs", {}), f"{where}.gcs"),
        source=where,
    )


def load_mission(name_or_path: str | Path, overrides: list[str] | None = None) -> Mission:
    """A mission file or the name of a shipped one, with ``SECTION.KEY=VALUE`` overrides."""
    doc = read_toml(name_or_path, MISSIONS, overrides, "mission")
    return parse_mission(doc.data, doc.source, doc.base)
