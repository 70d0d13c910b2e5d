"""The simulated vessel's configuration file (``vessel.toml``): [sim], [esc], [vessel], [plant]
and the bridge tables, read into the process shell's settings and the truth model's config.
A key left out takes the default of :class:`ShellSettings`, of the truth model's
:class:`~sim.vessel.VesselSimConfig` or of its ESC model (``sim.esc_model.DEFAULT_ESC``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ftcap_hil.config.bridges import PortSettings, vessel_ports_from
from ftcap_hil.config.live_scenario import fit_node_ids
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.config.table_dataclass import defaults_of
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import HIL_DATA, read_toml
from ftcap_hil.config.vessel import surface_vessel_from
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import SurfaceVessel
from ftcap_hil.core.scenario import Scenario
from sim.esc_model import DEFAULT_ESC, EscModel
from sim.truth import TruthConfig
from sim.vessel import SilentWindow, VesselSimConfig


@dataclass(frozen=True)
class ShellSettings:
    """What the process shell needs beyond the simulation itself (rates in wall-clock Hz)."""

    rate_hz: float = 50.0
    telemetry_rate_hz: float = 20.0
    esc_status_rate_hz: float = 10.0
    realtime_factor: float = 1.0  # sim seconds per wall second
    fault_injection_enabled: bool = False  # SYS_FAILURE_EN at start-up
    hold: bool = False  # at t = 0 until released (SIM_HOLD = 0, by the ground station)


@dataclass(frozen=True)
class VesselConfig:
    """The sim process's file: shell settings, the truth model, the merged TOML, the file's
    name, and the ports ([can], [mavlink], [zenoh]) to open."""

    shell: ShellSettings
    sim: VesselSimConfig
    raw: dict[str, Any]  # the merged TOML
    source: str
    ports: PortSettings
    truth: TruthConfig | None = None  # a realistic scenario's truth (None: the paper plant)
    scenario: Scenario | None = None  # that scenario


def silent_windows(sim: Table, m: int) -> tuple[SilentWindow, ...]:
    """``silent_thrusters = [2]`` (always silent) and ``[[sim.silent]]`` windows
    ``{thruster = 2, from = 5.0, until = 10.0}`` (1-based thruster, sim seconds)."""
    always = sim.integers("silent_thrusters", None, [], lo=1, hi=m)
    out = [SilentWindow(n - 1) for n in always]
    for w in sim.tables("silent"):
        start = w.number("from", 0.0)
        end = w.number("until", math.inf)
        if end <= start:
            raise w.error("until", f"expected a time after from = {start:g}, got {end:g}")
        out.append(SilentWindow(w.integer("thruster", lo=1, hi=m) - 1, start, end))
    return tuple(out)


def esc_model_from(t: Table) -> EscModel:
    """``[esc]``: the ESC telemetry model (sim/esc_model.py), every key optional."""
    d = DEFAULT_ESC
    return EscModel(
        t.number("k_rpm", d.k_rpm, lo=0.0),
        t.number("k_i", d.k_i, lo=0.0),
        t.number("idle_a", d.idle_a, lo=0.0),
        t.number("voltage_v", d.voltage_v, lo=0.0),
    )


def shell_settings_from(sim: Table) -> ShellSettings:
    """The process shell's part of ``[sim]``: rates (wall-clock Hz) and SYS_FAILURE_EN."""
    d = defaults_of(ShellSettings)

    def rate(key: str) -> float:
        return sim.number(key, d[key], positive=True)

    return ShellSettings(
        rate("rate_hz"),
        rate("telemetry_rate_hz"),
        rate("esc_status_rate_hz"),
        rate("realtime_factor"),
        sim.boolean("fault_injection_enabled", d["fault_injection_enabled"]),
        sim.boolean("hold", d["hold"]),
    )


def sim_config_from(
    root: Table,
    plant: SurfaceVessel,
    thrusters: ThrusterSet,
    B: FloatArray,
    schedule: FaultSchedule | None,
) -> VesselSimConfig:
    """The truth model's part of [sim], and [esc], around an already parsed plant."""
    s, d = root.table("sim"), defaults_of(VesselSimConfig)
    return VesselSimConfig(
        plant=plant,
        thrusters=thrusters,
        B=B,
        x0=s.vector("x0", 6, d["x0"].tolist()),  # [north m, east m, psi rad, u m/s, v m/s, r rad/s]
        command_timeout_s=s.number("command_timeout_s", d["command_timeout_s"], positive=True),
        schedule=schedule,
        silent=silent_windows(s, thrusters.m),
        esc=esc_model_from(root.table("esc")),
        default_weak_delta=s.number("default_weak_delta", d["default_weak_delta"], lo=0.0, hi=1.0),
        default_bias_n=s.number("default_bias_n", d["default_bias_n"]),
        rk4_substeps=s.integer("rk4_substeps", d["rk4_substeps"], lo=1),
    )


def _scenario(sim: Table, scenario: str | None) -> Scenario | None:
    """``--scenario`` (or ``sim.scenario``) read, or None."""
    name = sim.string("scenario", None)
    if scenario is None and name is None:
        return None
    try:
        return load_scenario(scenario or str(name))
    except ConfigError as e:
        raise (e if scenario else sim.error("scenario", str(e))) from e


def _schedule(sc: Scenario | None, m: int) -> FaultSchedule | None:
    if sc is None:
        return None
    if sc.faults.m != m:
        raise ConfigError(f"scenario {sc.name!r}: {sc.faults.m} thrusters, vessel has {m}")
    return sc.faults


def _realistic(sim: VesselSimConfig, sc: Scenario) -> VesselSimConfig:
    """The sim's config around a realistic scenario's truth: its thrusters (names and
    limits, as the CAN commands are scaled), its true B, initial state and faults."""
    assert sc.truth is not None
    return replace(
        sim, plant=None, thrusters=sc.thrusters, B=sc.truth.B, x0=sc.x0.astype(float),
        schedule=sc.faults, silent=tuple(w for w in sim.silent if w.thruster < sc.thrusters.m),
    )  # fmt: skip


def load_config(
    path: str | Path | None, overrides: list[str], scenario: str | None = None
) -> VesselConfig:
    """TOML file (shipped ``vessel.toml`` if None) + overrides; ConfigError names the key.

    ``scenario`` (or ``sim.scenario``): a scenario file or shipped name whose [[fault]]
    schedule gives the true faults by sim time. A plain scenario's plant and thrusters are
    not used; a realistic one's truth replaces the file's vessel (``truth``,
    :mod:`ftcap_hil.config.live_scenario`).
    """
    doc = read_toml(path if path is not None else "vessel", HIL_DATA, overrides, "config")
    with Table.document(doc) as root:
        plant, ths, B = surface_vessel_from(root, "the simulator")
        sim_t = root.table("sim")
        sc = _scenario(sim_t, scenario)
        live = sc if sc is not None and sc.truth is not None else None
        shell = shell_settings_from(sim_t)
        sim = sim_config_from(root, plant, ths, B, None if live else _schedule(sc, ths.m))
        if live is not None:
            sim = _realistic(sim, live)
            fit_node_ids(doc.data, live.thrusters.m, doc.source)
        ports = vessel_ports_from(root, sim.thrusters.m)
    truth = None if live is None else live.truth
    return VesselConfig(shell, sim, doc.data, doc.source, ports, truth, live)
