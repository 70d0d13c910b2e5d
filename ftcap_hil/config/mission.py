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
    vessel_clock = false         # true: the vessel runs the scenario (a realistic truth and
                                 # its faults) held at t = 0: released at the start, flown on
                                 # its clock, nothing injected (ftcap-hil demo --scenario)
    time_scale = 1.0             # with vessel_clock: the vessel's sim seconds per wall second

The fault schedule is the truth recorded in the timeseries;
:func:`~ftcap_hil.core.faults.injection_plan` turns it into MAV_CMD_INJECT_FAILURE requests
(:attr:`Mission.injections`) at every change, and
:func:`ftcap_hil.runtime.ground_station.flight_plan` a mission into what a flight flies.
Pure: no I/O beyond reading the files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ftcap_hil.config.live_scenario import wrench_bound
from ftcap_hil.config.realistic import anchor_preset, is_realistic, parse_realistic
from ftcap_hil.config.scenario import SHIPPED
from ftcap_hil.config.scenario_tables import REPLACEABLE, scenario_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import TomlFile, apply_overrides, read_toml, shipped_names
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import Injection, injection_plan
from ftcap_hil.core.scenario import Scenario, TimeUnit
from ftcap_hil.core.status import Mode

MISSIONS = "ftcap_hil.data.hil.missions"
# The keys mission_from and gcs_settings_from read (tests/docker checks --set against them).
MISSION_KEYS = ("name", "description", "scenario", "duration", "period", "mode")
GCS_KEYS = (
    "connect_timeout_s", "odometry_timeout_s", "wrench_limit", "clear_faults_at_end",
    "vessel_clock", "time_scale",
)  # fmt: skip


@dataclass(frozen=True)
class GcsSettings:
    """The ``[gcs]`` table of a mission: start-up and mid-flight timeouts (s), the wrench
    limit [X (N), Y (N), N (N*m)] demands are shrunk to, and whether the vessel's faults are
    cleared at the end."""

    connect_timeout_s: float = 20.0
    odometry_timeout_s: float = 5.0
    wrench_limit: tuple[float, float, float] = (1000.0, 1000.0, 1000.0)  # the allocator's
    clear_faults_at_end: bool = True
    vessel_clock: bool = False  # the vessel runs the scenario on its clock (module docstring)
    time_scale: float = 1.0  # the vessel's sim seconds per wall second (vessel_clock only)


@dataclass(frozen=True)
class Mission:
    """What ``ftcap-hil gcs`` flies: the scenario's reference, fault schedule (the truth it
    injects and records) and controller, for ``duration_s``, every ``period_s`` (T_s)."""

    name: str
    description: str
    scenario: Scenario  # reference, faults (truth), controller; duration_s = the mission's
    period_s: float  # control period T_s
    mode: Mode | None  # None: fly with whatever mode the allocator is in
    gcs: GcsSettings
    source: str

    @property
    def duration_s(self) -> float:
        return self.scenario.duration_s

    @property
    def injections(self) -> list[Injection]:
        """The MAV_CMD_INJECT_FAILURE requests that reproduce the fault schedule (none when
        the vessel runs the schedule itself, ``gcs.vessel_clock``)."""
        if self.gcs.vessel_clock:
            return []
        return injection_plan(self.scenario.faults, self.duration_s)

    def with_duration(self, duration_s: float) -> Mission:
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigError(f"duration: expected a positive number of seconds, got {duration_s}")
        return replace(self, scenario=replace(self.scenario, duration_s=float(duration_s)))


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
        t.boolean("vessel_clock", d.vessel_clock),
        t.number("time_scale", d.time_scale, positive=True),
    )


def mission_from(root: Table, base: Path | None = None) -> Mission:
    """A mission from the top level of its file; the scenario it names is read (strictly)
    from ``base`` (the mission file's folder) or the shipped scenarios."""
    head = root.table("mission", required=True)
    root.allow(*REPLACEABLE)
    sc_doc = _scenario_doc(head, base)
    if is_realistic(sc_doc.data):  # its own reader: the mission's tables merged in
        merged = {**sc_doc.data, **{k: root.data[k] for k in REPLACEABLE if root.has(k)}}
        where = f"{root.file} (scenario {sc_doc.source})"
        sc = parse_realistic(anchor_preset(merged, sc_doc.base), where)
    else:
        with Table.document(sc_doc) as sc_root:
            sc = scenario_from(sc_root, root)
    if sc.time_unit is not TimeUnit.SECOND:
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


def scenario_mission(name_or_path: str | Path, overrides: list[str] | None = None) -> Mission:
    """The mission a vessel running a realistic scenario is flown with (``ftcap-hil gcs
    --scenario``): the scenario's reference, controller, period and duration, the vessel on
    its own clock (``[gcs] vessel_clock``), with ``SECTION.KEY=VALUE`` overrides."""
    path = Path(name_or_path)
    ref = str(path.resolve()) if path.is_file() else str(name_or_path)
    data = {"mission": {"scenario": ref}, "gcs": {"vessel_clock": True}}
    mission = parse_mission(apply_overrides(data, overrides or []), f"--scenario {name_or_path}")
    limit = wrench_bound(mission.scenario, mission.gcs.wrench_limit)  # the allocator's
    return replace(mission, gcs=replace(mission.gcs, wrench_limit=limit))


def load_mission(name_or_path: str | Path, overrides: list[str] | None = None) -> Mission:
    """A mission file or the name of a shipped one, with ``SECTION.KEY=VALUE`` overrides."""
    doc = read_toml(name_or_path, MISSIONS, overrides, "mission")
    return parse_mission(doc.data, doc.source, doc.base)
