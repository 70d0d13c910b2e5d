"""Daemon configuration (TOML). Precedence: command-line ``--set KEY=VALUE`` > file > defaults.

Sections: ``[daemon]`` (loop, watchdogs, mode), ``[vessel]`` and ``[plant]`` (as in scenario
files), ``[estimator]``, ``[allocation]``, ``[excitation]`` (core tunables), and one table per
bridge: ``[mavlink]``, ``[zenoh]``, ``[can]`` (read by the process that wires the bridges).
The shipped defaults are ``ftcap_hil/data/hil/allocator.toml``; see docs/hil.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ftcap_hil.config.tables import dataclass_from_table
from ftcap_hil.config.toml import HIL_DATA, read_toml
from ftcap_hil.config.vessel import plant_from_tables
from ftcap_hil.core.allocator import AllocatorConfig
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimator import EstimatorConfig
from ftcap_hil.core.excitation import ExcitationConfig
from ftcap_hil.core.plants import SurfaceVessel
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.daemon import DaemonConfig

_DAEMON_KEYS = {
    "rate_hz",
    "estimation_period_s",
    "setpoint_timeout_s",
    "telemetry_timeout_s",
    "esc_timeout_s",
    "status_period_s",
    "wake_on_setpoint",
    "vessel_clock",
    "mode",
}


@dataclass(frozen=True)
class LoadedConfig:
    daemon: DaemonConfig
    raw: dict[str, Any]  # the merged TOML, for the bridge sections
    source: str


def _positive(d: dict[str, Any], key: str, default: float) -> float:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v > 0):
        raise ConfigError(f"daemon.{key}: expected a positive number, got {v!r}")
    return float(v)


def daemon_config_from(data: dict[str, Any], where: str) -> DaemonConfig:
    d = data.get("daemon", {})
    unknown = set(d) - _DAEMON_KEYS
    if unknown:
        raise ConfigError(f"{where}.daemon: unknown keys {sorted(unknown)}")
    plant, ths, B = plant_from_tables(data, where)
    if not isinstance(plant, SurfaceVessel):
        raise ConfigError(f"{where}.plant.kind: the daemon drives a vessel, got {plant!r}")
    try:
        mode = Mode(d.get("mode", "ftcap"))
    except ValueError:
        raise ConfigError(
            f"{where}.daemon.mode: {d.get('mode')!r} not in {[m.value for m in Mode]}"
        ) from None
    if mode is Mode.ORACLE:
        raise ConfigError(
            f"{where}.daemon.mode: 'oracle' needs the true faults, which a daemon cannot know"
        )
    core = CoreConfig(
        mode=mode,
        estimator=dataclass_from_table(
            EstimatorConfig, data.get("estimator", {}), f"{where}.estimator"
        ),
        allocator=dataclass_from_table(
            AllocatorConfig, data.get("allocation", {}), f"{where}.allocation"
        ),
        excitation=dataclass_from_table(
            ExcitationConfig, data.get("excitation", {}), f"{where}.excitation"
        ),
    )
    wake = d.get("wake_on_setpoint", True)
    if not isinstance(wake, bool):
        raise ConfigError(f"{where}.daemon.wake_on_setpoint: expected true/false, got {wake!r}")
    vessel_clock = d.get("vessel_clock", True)
    if not isinstance(vessel_clock, bool):
        raise ConfigError(f"{where}.daemon.vessel_clock: expected true/false, got {vessel_clock!r}")
    return DaemonConfig(
        thrusters=ths,
        B=B,
        plant=plant,
        core=core,
        rate_hz=_positive(d, "rate_hz", 1.0 / 0.2827),
        estimation_period_s=_positive(d, "estimation_period_s", 0.2827),
        setpoint_timeout_s=_positive(d, "setpoint_timeout_s", 1.0),
        telemetry_timeout_s=_positive(d, "telemetry_timeout_s", 1.0),
        esc_timeout_s=_positive(d, "esc_timeout_s", 0.5),
        status_period_s=_positive(d, "status_period_s", 0.1),
        wake_on_setpoint=wake,
        vessel_clock=vessel_clock,
    )


def load_daemon_config(path: str | Path | None, overrides: list[str] | None = None) -> LoadedConfig:
    """A TOML file (or the shipped ``allocator.toml`` when path is None) plus overrides."""
    doc = read_toml(path if path is not None else "allocator", HIL_DATA, overrides, "config")
    return LoadedConfig(daemon_config_from(doc.data, doc.source), doc.data, doc.source)
