"""The simulated vessel's configuration file (``vessel.toml``): [sim], [esc], [vessel], [plant]
and the bridge tables, read into the process shell's settings and the truth model's config.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.config.toml import HIL_DATA, read_toml
from ftcap_hil.config.vessel import plant_from_tables
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.geometry import ThrusterSet
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.plants import SurfaceVessel
from ftcap_hil.runtime.vessel_process import ShellSettings, VesselConfig
from sim.esc_model import DEFAULT_ESC, EscModel
from sim.vessel import SilentWindow, VesselSimConfig

SIM_KEYS = {
    "rate_hz", "telemetry_rate_hz", "esc_status_rate_hz", "command_timeout_s",
    "realtime_factor", "rk4_substeps", "x0", "fault_injection_enabled",
    "default_weak_delta", "default_bias_n", "scenario", "silent_thrusters", "silent",
}  # fmt: skip


def number(
    table: dict[str, Any],
    key: str,
    where: str,
    default: float,
    lo: float = -math.inf,
    positive: bool = False,
) -> float:
    """``table[key]`` as a finite float (default if absent); ConfigError naming the key."""
    v = table.get(key, default)
    ok = not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)
    if not ok or v < lo or (positive and v <= 0):
        bound = "> 0" if positive else f">= {lo}" if lo > -math.inf else "finite"
        raise ConfigError(f"{where}.{key}: expected a number {bound}, got {v!r}")
    return float(v)


def _thruster_number(value: Any, m: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= m:
        raise ConfigError(f"{where}: expected a thruster number 1..{m} (1-based), got {value!r}")
    return value - 1


def silent_windows(sim: dict[str, Any], m: int, where: str = "sim") -> tuple[SilentWindow, ...]:
    """``silent_thrusters = [2]`` (always silent) and ``[[sim.silent]]`` windows
    ``{thruster = 2, from = 5.0, until = 10.0}`` (1-based thruster, sim seconds)."""
    always = sim.get("silent_thrusters", [])
    if not isinstance(always, list):
        raise ConfigError(f"{where}.silent_thrusters: expected a list, got {always!r}")
    out = [SilentWindow(_thruster_number(n, m, f"{where}.silent_thrusters")) for n in always]
    windows = sim.get("silent", [])
    if not isinstance(windows, list) or not all(isinstance(w, dict) for w in windows):
        raise ConfigError(f"{where}.silent: expected a list of tables, got {windows!r}")
    for k, w in enumerate(windows):
        w_where = f"{where}.silent[{k}]"
        unknown = set(w) - {"thruster", "from", "until"}
        if unknown:
            raise ConfigError(f"{w_where}: unknown keys {sorted(unknown)}")
        index = _thruster_number(w.get("thruster"), m, f"{w_where}.thruster")
        start = number(w, "from", w_where, 0.0)
        end = w.get("until", math.inf)
        if end != math.inf:
            end = number(w, "until", w_where, math.inf)
        out.append(SilentWindow(index, start, float(end)))
    return tuple(out)


def esc_model_from(table: dict[str, Any], where: str = "esc") -> EscModel:
    unknown = set(table) - {"k_rpm", "k_i", "idle_a", "voltage_v"}
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)}")
    d = DEFAULT_ESC
    return EscModel(
        number(table, "k_rpm", where, d.k_rpm, lo=0.0),
        number(table, "k_i", where, d.k_i, lo=0.0),
        number(table, "idle_a", where, d.idle_a, lo=0.0),
        number(table, "voltage_v", where, d.voltage_v, lo=0.0),
    )


def initial_state(sim: dict[str, Any], where: str = "sim") -> FloatArray:
    x0 = sim.get("x0", [0.0] * 6)
    try:
        arr = np.asarray(x0, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([])
    if arr.shape != (6,) or not np.all(np.isfinite(arr)):
        raise ConfigError(
            f"{where}.x0: expected [north, east, psi, u, v, r] (6 numbers), got {x0!r}"
        )
    return arr


def shell_settings_from(sim: dict[str, Any], where: str = "sim") -> ShellSettings:
    enabled = sim.get("fault_injection_enabled", False)
    if not isinstance(enabled, bool):
        raise ConfigError(f"{where}.fault_injection_enabled: expected true/false, got {enabled!r}")
    return ShellSettings(
        number(sim, "rate_hz", where, 50.0, positive=True),
        number(sim, "telemetry_rate_hz", where, 20.0, positive=True),
        number(sim, "esc_status_rate_hz", where, 10.0, positive=True),
        number(sim, "realtime_factor", where, 1.0, positive=True),
        enabled,
    )


def sim_config_from(
    data: dict[str, Any],
    plant: SurfaceVessel,
    thrusters: ThrusterSet,
    B: FloatArray,
    schedule: FaultSchedule | None,
    where: str,
) -> VesselSimConfig:
    """The [sim] and [esc] tables of ``data`` around an already parsed plant and thrusters."""
    s = data.get("sim", {})
    w = f"{where}.sim"
    if unknown := set(s) - SIM_KEYS:
        raise ConfigError(f"{w}: unknown keys {sorted(unknown)}")
    substeps = s.get("rk4_substeps", 8)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"{w}.rk4_substeps: expected an integer >= 1, got {substeps!r}")
    weak = number(s, "default_weak_delta", w, 0.5, lo=0.0)
    if weak > 1.0:
        raise ConfigError(f"{w}.default_weak_delta: expected a number in [0, 1], got {weak}")
    return VesselSimConfig(
        plant=plant,
        thrusters=thrusters,
        B=B,
        x0=initial_state(s, w),
        command_timeout_s=number(s, "command_timeout_s", w, 0.5, positive=True),
        schedule=schedule,
        silent=silent_windows(s, thrusters.m, w),
        esc=esc_model_from(data.get("esc", {}), f"{where}.esc"),
        default_weak_delta=weak,
        default_bias_n=number(s, "default_bias_n", w, 0.08),
        rk4_substeps=substeps,
    )


def load_config(
    path: str | Path | None, overrides: list[str], scenario: str | None = None
) -> VesselConfig:
    """TOML file (shipped ``vessel.toml`` if None) + overrides; ConfigError names the key.

    ``scenario`` (or ``sim.scenario``): a scenario file or shipped name whose [[fault]]
    schedule gives the true faults by sim time; its plant and thrusters are not used.
    """
    doc = read_toml(path if path is not None else "vessel", HIL_DATA, overrides, "config")
    data, where = doc.data, doc.source
    plant, ths, B = plant_from_tables(data, where)
    if not isinstance(plant, SurfaceVessel):
        raise ConfigError(f"{where}.plant.kind: the simulator runs a vessel, got {plant!r}")
    sim_table = data.get("sim", {})
    scenario = scenario or sim_table.get("scenario")
    schedule = None
    if scenario is not None:
        schedule = load_scenario(str(scenario)).faults
        if schedule.m != ths.m:
            raise ConfigError(f"scenario {scenario!r}: {schedule.m} thrusters, vessel has {ths.m}")
    shell = shell_settings_from(sim_table, f"{where}.sim")
    sim = sim_config_from(data, plant, ths, B, schedule, where)
    return VesselConfig(shell, sim, data, where)
