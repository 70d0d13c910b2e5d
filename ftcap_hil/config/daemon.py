"""Daemon configuration (TOML). Precedence: command-line ``--set KEY=VALUE`` > file > defaults.

Sections: ``[daemon]`` (loop, watchdogs, mode), ``[vessel]`` and ``[plant]``, ``[estimator]``,
``[allocator]``, ``[excitation]`` (core tunables: the same tables as in scenario files; the
former name ``[allocation]`` is refused with the new one), and one table per bridge:
``[mavlink]``, ``[zenoh]``, ``[can]`` (``config.bridges``). Every table and key is checked.
A key left out takes the default of :class:`DaemonConfig` (or :class:`OdometryLimits`),
written there only; the shipped file is ``ftcap_hil/data/hil/allocator.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

from ftcap_hil.config.bridges import PortSettings, allocator_ports_from
from ftcap_hil.config.live_scenario import fit_node_ids, wrench_bound
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.config.scenario_tables import core_config_from
from ftcap_hil.config.table_dataclass import defaults_of
from ftcap_hil.config.tables import Table
from ftcap_hil.config.thruster_curves import limited_to_curves
from ftcap_hil.config.toml import HIL_DATA, read_toml
from ftcap_hil.config.vessel import surface_vessel_from
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.shaft_types import DriveModel
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import SurfaceVessel
from ftcap_hil.core.models.vessel3dof import PlantModel
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode


class OdometryLimits(NamedTuple):
    """What the vessel can do: telemetry beyond it is implausible
    (:class:`~ftcap_hil.runtime.estimation.PlausibilityGate`).

    Defaults are loose for any surface vessel (30 kn, 5 m/s^2: far beyond what thrust gives a
    hull, so only forged or broken telemetry trips them); the margins cover the sensor's noise
    and a GNSS re-fix of a couple of metres between two samples.
    """

    max_speed_m_s: float = 15.0
    max_yaw_rate_rad_s: float = 2.0
    max_accel_m_s2: float = 5.0
    position_margin_m: float = 2.0
    velocity_margin_m_s: float = 0.5


T_S = 0.2827  # s: the paper's sample time (section 4.2)


@dataclass(frozen=True)
class DaemonConfig:
    """The daemon's settings: the vessel (thrusters, B (k, m), plant), the core's tunables,
    the loop rate (Hz), the estimation period and the watchdog timeouts (s). The defaults
    here are the only ones: ``[daemon]`` keys left out of a file take them."""

    thrusters: ThrusterSet
    B: FloatArray
    plant: SurfaceVessel | PlantModel
    core: CoreConfig
    rate_hz: float = 1.0 / T_S
    estimation_period_s: float = T_S  # one estimator sample per T_s of telemetry
    setpoint_timeout_s: float = 1.0  # no setpoint for this long -> zero thrust
    telemetry_timeout_s: float = 1.0  # telemetry older than this -> estimation frozen
    esc_timeout_s: float = 0.5  # an ESC silent for this long -> thruster treated as failed
    status_period_s: float = 0.1  # status publication period (decimation)
    wake_on_setpoint: bool = True  # run a cycle as soon as a setpoint arrives
    # time command averages over telemetry intervals by VesselClock (else by receipt stamps)
    vessel_clock: bool = True
    dt_clamp: tuple[float, float] = (0.2, 5.0)  # dt for rate limits, in periods (PX4 clamps)
    # what the vessel can do: odometry beyond it is dropped before the estimator
    odometry_limits: OdometryLimits = field(default_factory=OdometryLimits)
    # ESC telemetry as evidence: no rpm (below this) under command for esc_stall_s -> the
    # thruster is allocated as dead until it turns again (0: off)
    esc_stall_rpm: float = 50.0
    esc_stall_s: float = 1.0
    # the drives' data sheets (a realistic --scenario's): the core's shaft diagnosis judges
    # each thruster by its esc.Status rpm and current (None: no diagnosis, the stall rule)
    drives: tuple[DriveModel, ...] | None = None
    # sim seconds per wall second of the vessel this allocator serves (sim.realtime_factor):
    # the core's periods and its drives' clock run that much faster than the wall clock
    time_scale: float = 1.0


@dataclass(frozen=True)
class LoadedConfig:
    """The allocator's file: the daemon's settings, the ports to open, the merged TOML and
    the file's name (for messages)."""

    daemon: DaemonConfig
    raw: dict[str, Any]  # the merged TOML
    source: str
    ports: PortSettings


def daemon_config_from(root: Table) -> DaemonConfig:
    """``[daemon]`` (loop, watchdogs, mode), ``[vessel]``, ``[plant]`` and the core tables."""
    d = root.table("daemon")
    plant, ths, B = surface_vessel_from(root, "the daemon")
    mode = d.enum("mode", Mode, defaults_of(CoreConfig)["mode"])
    if mode is Mode.ORACLE:
        raise d.error("mode", "'oracle' needs the true faults, which a daemon cannot know")
    base = defaults_of(DaemonConfig)

    def positive(key: str) -> float:
        return d.number(key, base[key], positive=True)

    return DaemonConfig(
        thrusters=ths,
        B=B,
        plant=plant,
        core=core_config_from(root, mode, B.shape[0]),
        rate_hz=positive("rate_hz"),
        estimation_period_s=positive("estimation_period_s"),
        setpoint_timeout_s=positive("setpoint_timeout_s"),
        telemetry_timeout_s=positive("telemetry_timeout_s"),
        esc_timeout_s=positive("esc_timeout_s"),
        status_period_s=positive("status_period_s"),
        wake_on_setpoint=d.boolean("wake_on_setpoint", base["wake_on_setpoint"]),
        vessel_clock=d.boolean("vessel_clock", base["vessel_clock"]),
        odometry_limits=_odometry_limits(d),
        esc_stall_rpm=d.number("esc_stall_rpm", base["esc_stall_rpm"], lo=0.0),
        esc_stall_s=positive("esc_stall_s"),
        time_scale=positive("time_scale"),
    )


def _odometry_limits(d: Table) -> OdometryLimits:
    """``[daemon] odometry_*``: what the vessel can do (:class:`OdometryLimits`)."""
    base = OdometryLimits()
    return OdometryLimits(
        *(d.number(f"odometry_{name}", getattr(base, name), positive=True) for name in base._fields)
    )


HOLD_PERIODS = 2.5  # the ESC stream's hold, at least, in the daemon's deadline periods


def told_by_scenario(daemon: DaemonConfig, sc: Scenario, given: dict[str, Any]) -> DaemonConfig:
    """The daemon told what the offline simulator tells its core of a realistic scenario
    (``config.realistic``: geometry and limits with the stated mismatch, the allocator's
    plant, the estimator with the sensor's data-sheet noise, the thrusters' lag and the
    sea-state model, the drives' data sheets), in the file's mode; the loop at the
    scenario's period and estimation period (times ``time_scale``) unless ``[daemon]``
    (``given``) sets them."""
    if sc.truth is None:
        raise ConfigError(
            f"--scenario {sc.name}: not a realistic scenario ([plant] kind = 'preset'): the "
            "allocator takes the vessel of its own file"
        )
    k = daemon.time_scale
    period = sc.estimation_period_s or sc.dt_s
    return replace(
        daemon,
        thrusters=sc.thrusters,
        B=sc.B,
        plant=sc.plant,
        core=replace(sc.core, mode=daemon.core.mode),
        rate_hz=given.get("rate_hz", k / sc.dt_s),
        estimation_period_s=given.get("estimation_period_s", period),
        drives=sc.drives,
    )


def _sized_to(ports: PortSettings, sc: Scenario) -> PortSettings:
    """The setpoint bounds of the file's vessel widened to the scenario's vessel
    (:func:`~ftcap_hil.config.live_scenario.wrench_bound`; no bound stays none)."""
    mav, zen = ports.mavlink, ports.zenoh
    if mav is not None and mav.wrench_limit is not None:
        mav = replace(mav, wrench_limit=wrench_bound(sc, mav.wrench_limit))
    if zen is not None and zen.wrench_limit is not None:
        zen = replace(zen, wrench_limit=wrench_bound(sc, zen.wrench_limit))
    return replace(ports, mavlink=mav, zenoh=zen)


def load_daemon_config(
    path: str | Path | None, overrides: list[str] | None = None, scenario: str | None = None
) -> LoadedConfig:
    """A TOML file (or the shipped ``allocator.toml`` when path is None) plus overrides;
    every table and key checked (an unknown one is a ConfigError naming file, table, key).
    ``scenario``: a realistic scenario (file or shipped name) the daemon is told about in
    place of the file's vessel (:func:`told_by_scenario`)."""
    doc = read_toml(path if path is not None else "allocator", HIL_DATA, overrides, "config")
    sc = None if scenario is None else load_scenario(scenario)
    with Table.document(doc) as root:
        daemon = daemon_config_from(root)
        if sc is not None:
            daemon = told_by_scenario(daemon, sc, dict(doc.data.get("daemon", {})))
            fit_node_ids(doc.data, daemon.thrusters.m, doc.source)
        ports = allocator_ports_from(root, daemon.thrusters.m)
        if sc is not None:
            ports = _sized_to(ports, sc)
    # A hold shorter than the loop's deadline period would zero the thrusters between
    # every two cycles: it lasts at least HOLD_PERIODS of them.
    hold = max(ports.can.esc_hold_s, HOLD_PERIODS / daemon.rate_hz)
    ports = replace(ports, can=replace(ports.can, esc_hold_s=hold))
    # The allocator knows its thrusters' curves: it never asks for more than they can give.
    daemon = replace(daemon, thrusters=limited_to_curves(daemon.thrusters, ports.can.curves))
    return LoadedConfig(daemon, doc.data, doc.source, ports)
