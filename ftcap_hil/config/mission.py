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

from dataclasses import replace
from pathlib import Path
from typing import Any

from ftcap_hil.config.realistic import is_realistic, parse_realistic
from ftcap_hil.config.scenario import SHIPPED
from ftcap_hil.config.scenario_tables import REPLACEABLE, scenario_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import TomlFile, read_toml, shipped_names
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.ground_station import GcsSettings, Mission

MISSIONS = "ftcap_hil.data.hil.missions"
# The keys mission_from and gcs_settings_from read (tests/docker checks --set against them).
MISSION_KEYS = ("name", "description", "scenario", "duration", "period", "mode")
GCS_KEYS = ("connect_timeout_s", "odometry_timeout_s", "wrench_limit", "clear_faults_at_end")


def shipped_missions() -> list[str]:
    """Names of the missions shipped in ``ftcap_hil/data/hil/missions``."""
    return shipped_names(MISSIONS)


def _scenario_doc(head: Table, base: Path | None) -> TomlFile:
    ref = head.string("scenario")
    if base is not None and (base / ref).is_file():
        ref = str(base / ref)
    try:
        return read_toml(ref, SHIPPED, what="scenario")
    except ConfigError as e:
        raise head.error("scenario", str(e)) from e


def gcs_settings_from(t: Table) -> GcsSettings:
    """``[gcs]``: every key optional (GcsSettings' defaults)."""
    d = GcsSettings()
    limit = t.vector("wrench_limit", 3, d.wrench_limit, positive=True)
    return GcsSettings(
        t.number("connect_timeout_s", d.connect_timeout_s, positive=True),
        t.number("odometry_timeout_s", d.odometry_timeout_s, positive=True),
        (float(limit[0]), float(limit[1]), float(limit[2])),
        t.boolean("clear_faults_at_end", d.clear_faults_at_end),
    )


def mission_from(root: Table, base: Path | None = None) -> Mission:
    """A mission from the top level of its file; the scenario it names is read (strictly)
    from ``base`` (the mission file's folder) or the shipped scenarios."""
    head = root.table("mission", required=True)
    root.allow(*REPLACEABLE)
    sc_doc = _scenario_doc(head, base)
    if is_realistic(sc_doc.data):  # its own reader: the mission's tables merged in
        merged = {**sc_doc.data, **{k: root.data[k] for k in REPLACEABLE if root.has(k)}}
        sc = parse_realistic(merged, f"{root.file} (scenario {sc_doc.source})")
    else:
        with Table.document(sc_doc) as sc_root:
            sc = scenario_from(sc_root, root)
    if sc.time_unit != "s":
        raise head.error("scenario", f"{sc_doc.source!r} is not a vessel scenario")
    name = head.string("name", sc.name)
    mode = head.enum("mode", Mode, exclude=[Mode.ORACLE]) if head.has("mode") else None
    head.allow("mode")
    return Mission(
        name=name,
        description=head.string("description", sc.description),
        scenario=replace(  # plots and results name it
            sc, name=name, duration_s=head.number("duration", sc.duration_s, positive=True)
        ),
        period_s=head.number("period", sc.dt_s, positive=True),
        mode=mode,
        gcs=gcs_settings_from(root.table("gcs")),
        source=root.file,
    )


def parse_mission(data: dict[str, Any], where: str, base: Path | None = None) -> Mission:
    """A mission from a parsed TOML document (``where`` names the file in messages)."""
    with Table(data, where) as root:
        return mission_from(root, base)


def load_mission(name_or_path: str | Path, overrides: list[str] | None = None) -> Mission:
    """A mission file or the name of a shipped one, with ``SECTION.KEY=VALUE`` overrides."""
    doc = read_toml(name_or_path, MISSIONS, overrides, "mission")
    return parse_mission(doc.data, doc.source, doc.base)
