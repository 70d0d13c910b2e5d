"""Daemon configuration (TOML). Precedence: command-line ``--set KEY=VALUE`` > file > defaults.

Sections: ``[daemon]`` (loop, watchdogs, mode), ``[vessel]`` and ``[plant]``, ``[estimator]``,
``[allocator]``, ``[excitation]`` (core tunables: the same tables as in scenario files; the
former name ``[allocation]`` is refused with the new one), and one table per bridge:
``[mavlink]``, ``[zenoh]``, ``[can]`` (``config.bridges``). Every table and key is checked.
The shipped defaults are ``ftcap_hil/data/hil/allocator.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ftcap_hil.config.bridges import allocator_ports_from
from ftcap_hil.config.scenario_tables import core_config_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.thruster_curves import limited_to_curves
from ftcap_hil.config.toml import HIL_DATA, read_toml
from ftcap_hil.config.vessel import surface_vessel_from
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.daemon import DaemonConfig
from ftcap_hil.runtime.estimation import OdometryLimits
from ftcap_hil.runtime.port_settings import PortSettings


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
    mode = d.enum("mode", Mode, Mode.FTCAP)
    if mode is Mode.ORACLE:
        raise d.error("mode", "'oracle' needs the true faults, which a daemon cannot know")
    return DaemonConfig(
        thrusters=ths,
        B=B,
        plant=plant,
        core=core_config_from(root, mode, B.shape[0]),
        rate_hz=d.number("rate_hz", 1.0 / 0.2827, positive=True),
        estimation_period_s=d.number("estimation_period_s", 0.2827, positive=True),
        setpoint_timeout_s=d.number("setpoint_timeout_s", 1.0, positive=True),
        telemetry_timeout_s=d.number("telemetry_timeout_s", 1.0, positive=True),
        esc_timeout_s=d.number("esc_timeout_s", 0.5, positive=True),
        status_period_s=d.number("status_period_s", 0.1, positive=True),
        wake_on_setpoint=d.boolean("wake_on_setpoint", True),
        vessel_clock=d.boolean("vessel_clock", True),
        odometry_limits=_odometry_limits(d),
        esc_stall_rpm=d.number("esc_stall_rpm", 50.0, lo=0.0),
        esc_stall_s=d.number("esc_stall_s", 1.0, positive=True),
    )


def _odometry_limits(d: Table) -> OdometryLimits:
    """``[daemon] odometry_*``: what the vessel can do (runtime/estimation.py)."""
    base = OdometryLimits()
    return OdometryLimits(
        *(d.number(f"odometry_{name}", getattr(base, name), positive=True) for name in base._fields)
    )


HOLD_PERIODS = 2.5  # the ESC stream's hold, at least, in the daemon's deadline periods


def load_daemon_config(path: str | Path | None, overrides: list[str] | None = None) -> LoadedConfig:
    """A TOML file (or the shipped ``allocator.toml`` when path is None) plus overrides;
    every table and key checked (an unknown one is a ConfigError naming file, table, key)."""
    doc = read_toml(path if path is not None else "allocator", HIL_DATA, overrides, "config")
    with Table.document(doc) as root:
        daemon = daemon_config_from(root)
        ports = allocator_ports_from(root, daemon.thrusters.m)
    # A hold shorter than the loop's deadline period would zero the thrusters between
    # every two cycles: it lasts at least HOLD_PERIODS of them.
    hold = max(ports.can.esc_hold_s, HOLD_PERIODS / daemon.rate_hz)
    ports = replace(ports, can=replace(ports.can, esc_hold_s=hold))
    # The allocator knows its thrusters' curves: it never asks for more than they can give.
    daemon = replace(daemon, thrusters=limited_to_curves(daemon.thrusters, ports.can.curves))
    return LoadedConfig(daemon, doc.data, doc.source, ports)
