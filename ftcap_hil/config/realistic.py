"""Scenarios on a realistic vessel preset: the truth is the preset, the allocator is told the
preset with a stated mismatch (docs/scenarios.md#realistic-scenarios).

A realistic scenario is a scenario file whose ``[plant]`` names a preset
(``ftcap_hil/data/vessels``)::

    [plant]
    kind = "preset"
    preset = "cybership2"          # shipped name or a path (relative: to the scenario file)
    inversion = "trapezoid"        # how the allocator inverts a step (its truth is continuous)
    substeps = 4                   # RK4 substeps of the truth per step

    [conditions]                   # which of the preset's realism acts (all true by default)
    environment = true             # current, wind, waves at the preset's levels ([environment])
    sensors = true                 # position, heading, velocity noise at the preset's levels
    thruster_lag = true            # the preset's first-order time constants
    quantization = true            # the 14-bit command path
    reverse_gain = 1.0             # reverse thrust per commanded N (1: as the allocator assumes)
    deadband_rel = 0.0             # dead band, fraction of each thruster's range
    drive_telemetry = true         # the drives' telemetry reaches the allocator (if any)

    [environment.current]          # the environment's levels: any key of the preset's own
    speed_m_s = 0.15               # [environment.current|wind|waves] replaces its value
    direction_deg = 90.0           # (the rest stay the preset's); unknown keys are errors
    [environment.waves]
    hs_m = 0.05

    [mismatch]                     # the allocator's model against the truth (the preset's own
    mass = 0.2                     # [mismatch] when absent): fractions, degrees, metres
    damping = -0.3
    angle_deg = { port_rudder = 5.0 }
    thrust_coefficient = 0.05      # the drives' data sheets: K_T, K_Q, time constants off by
    torque_coefficient = 0.08      # these fractions (one, or one per thruster)
    drive_time_constant = 0.25

    [sensor]                       # beyond the preset's noise levels
    bias_rel = 0.0                 # slowly drifting bias, std as a fraction of the noise std
    bias_tau_s = 60.0
    delay_s = 0.0
    dropout_p = 0.0

    [uncertainty]                  # or: the model error and the truth's departures from
    mass = 0.2                     # the data sheets drawn per seed (config/uncertainty.py)

    [controller]                   # eq. (24) sized to the allocator's inertia
    period_s = 12.0                # natural period of each axis (s)
    damping = 0.9

The other tables ([scenario], [[reference]], [[fault]], [estimator], [allocator],
[excitation], [diagnosis]: its keys over the preset's own) are those of every scenario file
(:mod:`ftcap_hil.config.scenario_tables`);
``[scenario] estimation_period_s`` (s, a multiple of ``dt``) spaces the estimation samples
over several wave periods. The estimator
is told the preset's sensor levels (``measurement_std``) unless the file states them. A
plain scenario's ``[vessel]`` and ``[noise]`` are refused: the preset's thrusters and
sensor levels stand in for them.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.drives import DriveErrors, data_sheet
from ftcap_hil.config.presets import (
    AllocatorModel,
    VesselPreset,
    apply_mismatch,
    environment_levels,
    load_preset,
    preset_names,
)
from ftcap_hil.config.realistic_truth import sheet_noise, truth_of
from ftcap_hil.config.scenario_tables import scenario_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.uncertainty import ADDED_MASS, Drawn, Uncertainty
from ftcap_hil.config.vessel import PlantKind
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.config import EstimatorConfig
from ftcap_hil.core.estimation.shaft_types import DriveModel
from ftcap_hil.core.models.controllers import PoseController
from ftcap_hil.core.models.plants import Inversion
from ftcap_hil.core.scenario import Integrator, Scenario
from sim.environment import (
    CurrentConfig,
    Environment,
    EnvironmentConfig,
    HullGeometry,
    WindConfig,
)
from sim.sensors import SensorConfig
from sim.truth import TruthConfig

OWN_TABLES = (
    "plant", "conditions", "environment", "mismatch", "sensor", "controller", "uncertainty",
)  # fmt: skip
# tables of a plain scenario that would be silently replaced here, and what replaces them
PLAIN_ONLY = {
    "vessel": "the thrusters are the preset's ([plant] preset, [mismatch])",
    "noise": "the sensor noise is the preset's ([conditions] sensors, [sensor])",
}


def is_realistic(data: dict[str, Any]) -> bool:
    """Whether a scenario document names a vessel preset."""
    plant = data.get("plant")
    return isinstance(plant, dict) and plant.get("kind") == PlantKind.PRESET.value


def anchor_preset(data: Mapping[str, Any], base: Path | None) -> dict[str, Any]:
    """``data`` with a relative ``[plant] preset`` path made absolute against ``base``, the
    folder of the file that names it, so that the document reads the same from any working
    directory (and written elsewhere, as a campaign's replay file). A file of that name in
    ``base`` comes first, then a shipped preset of that name; an absolute path, a shipped
    name, a document without a ``preset`` or ``base`` None leave ``data`` as it is."""
    out = dict(data)
    plant = data.get("plant")
    value = plant.get("preset") if isinstance(plant, dict) else None
    if base is None or not isinstance(plant, dict) or not isinstance(value, str):
        return out
    path = base / value
    if Path(value).is_absolute() or (
        not path.is_file() and value.removesuffix(".toml") in preset_names()
    ):
        return out
    out["plant"] = {**plant, "preset": str(path.resolve())}
    return out


def parse_realistic(data: dict[str, Any], where: str) -> Scenario:
    """The scenario of a realistic scenario document (module docstring)."""
    root = Table(data, where)
    for name in OWN_TABLES:
        root.allow(name)
    for name, why in PLAIN_ONLY.items():
        if name in data:
            raise root.error(None, f"unknown table {name!r} in a realistic scenario: {why}")
    seed = _seed(data, where)
    plant_t = root.table("plant", required=True)
    plant_t.allow("kind")
    preset = _preset(plant_t, seed)
    inversion = plant_t.enum("inversion", Inversion, Inversion.TRAPEZOID)
    substeps = plant_t.integer("substeps", 4, lo=1)
    plant_t.finish()
    errors = _drive_errors(root.table("mismatch"))
    unc = Uncertainty.read(root.table("uncertainty"))
    drawn = unc.draw(seed, preset.thrusters.m) if unc.any else None
    told = _allocator_model(preset, root.table("mismatch"), inversion, drawn)
    with Table(_common_tables(data, told.thrusters, preset.diagnosis), where) as common:
        sc = scenario_from(common)
    stated = environment_levels(root.table("environment"), preset.environment)
    truth, sensor = truth_of(preset, root, seed, substeps, sc.dt_s, stated, drawn)
    controller = _controller(root.table("controller"), np.diag(told.vessel.mass_matrix))
    core = _told_sheets(sc.core, preset, truth, sensor)
    core = dataclasses.replace(core, estimator=_told_waves(core.estimator, truth, stated))
    return dataclasses.replace(
        sc,
        plant=told.vessel,
        controller=controller,
        core=core,
        integrator=Integrator.RK4,
        rk4_substeps=substeps,
        truth=truth,
        length_m=preset.hull.l_oa_m,
        drives=_drives_told(preset, truth, errors),
    )


def _preset(plant_t: Table, seed: int) -> VesselPreset:
    """``[plant] preset``, loaded; its errors (no such file, a bad preset file) also name
    the scenario file and the key."""
    name = plant_t.string("preset")
    try:
        return load_preset(name, seed=seed)
    except ConfigError as e:
        raise plant_t.error("preset", str(e)) from e


def _drive_errors(mm: Table) -> DriveErrors:
    """``[mismatch]`` ``thrust_coefficient``, ``torque_coefficient``, ``drive_time_constant``:
    what the drives' data sheets get wrong (fractions, one or one per thruster)."""
    keys = {"thrust_coefficient": "thrust_coefficient", "torque_coefficient": "torque_coefficient",
            "drive_time_constant": "time_constant"}  # fmt: skip
    given: dict[str, tuple[float, ...]] = {}
    for key, field in keys.items():
        mm.allow(key)
        if mm.has(key):
            value = mm.value(key)
            given[field] = tuple(float(v) for v in (value if isinstance(value, list) else [value]))
    return DriveErrors(**given)


def _drives_told(
    preset: VesselPreset, truth: TruthConfig, errors: DriveErrors
) -> tuple[DriveModel, ...] | None:
    """The drives' data sheets the allocator is told (None: no telemetry to judge them by)."""
    if preset.drives is None or truth.feedback is None:
        return None
    full = np.maximum(np.abs(preset.thrusters.u_min), np.abs(preset.thrusters.u_max))
    return data_sheet(preset.drives.actuators, full, truth.bank.time_constant_s, errors)


def _told_sheets(
    core: CoreConfig, preset: VesselPreset, truth: TruthConfig, sensor: SensorConfig | None
) -> CoreConfig:
    """The allocator is told the data sheets: each thruster's lag as the preset states it
    (when the truth has lag) and, unless the file sets ``[estimator] measurement_std``, the
    preset's sensor noise levels, whatever the truth's draw (:mod:`config.uncertainty`)."""
    if truth.bank.time_constant_s.any():
        core = dataclasses.replace(core, thruster_lag_s=tuple(preset.time_constants_s.tolist()))
    if core.estimator.measurement_std is None and sensor is not None:
        std = tuple(float(v) for v in sheet_noise(preset))  # pose and velocities: PoseStep
        core = dataclasses.replace(
            core, estimator=dataclasses.replace(core.estimator, measurement_std=std)
        )
    return core


def _told_waves(
    est: EstimatorConfig, truth: TruthConfig, stated: EnvironmentConfig
) -> EstimatorConfig:
    """The estimator is told the sea state as a DP system's wave model is tuned: the peak
    period and the first-order load's level per axis of the sea the scenario states (a
    forecast: the truth's may be drawn off it, :mod:`config.uncertainty`), measured over 10
    minutes at rest on another realisation of it (a different seed), unless the file sets
    ``[estimator] wave_period_s``."""
    env = truth.environment
    if env is None or truth.hull is None or not env.waves.enabled or est.wave_period_s > 0.0:
        return est
    waves = dataclasses.replace(stated, seed=env.seed, current=CurrentConfig(), wind=WindConfig())
    std = est.wave_force_std or _wave_load_std(waves, truth.hull)
    return dataclasses.replace(est, wave_period_s=waves.waves.tp_s, wave_force_std=std)


@functools.lru_cache(maxsize=256)
def _wave_load_std(waves: EnvironmentConfig, hull: HullGeometry) -> tuple[float, ...]:
    """The first-order wave load's std per axis over 10 minutes at rest, on the realisation
    of seed + 1 (cached: the modes of a campaign case, and its replays, ask for the same)."""
    sea = Environment(waves, hull, seed=waves.seed + 1)
    t = np.arange(0.0, 600.0, waves.waves.tp_s / 20.0)
    loads = sea.wave_wrench(t, np.zeros(6))  # (n, 3): the sea's components at once
    return tuple(float(v) for v in loads.std(axis=0))


def _seed(data: dict[str, Any], where: str) -> int:
    seed = data.get("scenario", {}).get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{where}: [scenario] seed: expected an integer >= 0, got {seed!r}")
    return seed


def _allocator_model(
    preset: VesselPreset, mm: Table, inversion: Inversion, drawn: Drawn | None = None
) -> AllocatorModel:
    """The allocator's model: the preset with the file's mismatch (else the preset's own),
    or with this seed's ``drawn`` model error (then ``[mismatch]`` may state only the drives'
    data-sheet errors)."""
    if drawn is not None:
        return _drawn_model(preset, mm, inversion, drawn)
    kwargs: dict[str, Any] = {}
    if mm.has("mass"):
        kwargs["mass"] = mm.number("mass", lo=-0.9)
    if mm.has("damping"):
        kwargs["damping"] = mm.number("damping", lo=-1.0)
    angles = mm.value("angle_deg", None)
    positions = mm.value("position_m", None)
    mm.finish()
    if angles is not None:
        if not isinstance(angles, dict):
            raise mm.error("angle_deg", f"expected a table of thruster = degrees, got {angles!r}")
        kwargs["angle_deg"] = angles
    if positions is not None:
        if not isinstance(positions, dict):
            raise mm.error(
                "position_m", f"expected a table of thruster = [dx, dy], got {positions!r}"
            )
        kwargs["position_m"] = {k: tuple(v) for k, v in positions.items()}
    told = apply_mismatch(preset, **kwargs)
    vessel = dataclasses.replace(told.vessel, inversion=inversion)
    return dataclasses.replace(told, vessel=vessel)


def _drawn_model(
    preset: VesselPreset, mm: Table, inversion: Inversion, drawn: Drawn
) -> AllocatorModel:
    for key in ("mass", "damping", "angle_deg", "position_m"):
        if mm.has(key):
            raise mm.error(key, "the model error is drawn ([uncertainty]): state it there only")
    mm.finish()
    names = [t.name for t in preset.thrusters.thrusters]
    told = apply_mismatch(
        preset,
        mass=drawn.mass - 1.0,
        damping=drawn.damping - 1.0,
        angle_deg={names[i]: a for i, a in drawn.angle_deg.items()},
        position_m={},
    )
    v = told.vessel
    added = {k: getattr(v, k) * drawn.added_mass for k in ADDED_MASS}
    vessel = dataclasses.replace(v, inversion=inversion, **added)
    return dataclasses.replace(told, vessel=vessel)


def _common_tables(
    data: dict[str, Any], thrusters: ThrusterSet, preset_diagnosis: Mapping[str, Any]
) -> dict[str, Any]:
    """The document with the preset's tables replaced by a plain vessel the common scenario
    loader reads (its thrusters are the allocator's; its plant is replaced afterwards)."""
    out = {k: copy.deepcopy(v) for k, v in data.items() if k not in OWN_TABLES}
    out["plant"] = {"kind": "vessel", "mass_kg": 1.0, "iz_kgm2": 1.0}
    out["vessel"] = {
        "thruster": [
            {
                "name": t.name, "x": t.x_m, "y": t.y_m, "angle_deg": math.degrees(t.angle_rad),
                "u_min": t.u_min, "u_max": t.u_max,
                **({"rate_max": t.rate_max} if t.rate_max is not None else {}),
                **({"step_max": t.step_max} if t.step_max is not None else {}),
            }
            for t in thrusters.thrusters
        ]
    }  # fmt: skip
    out["controller"] = {}
    out["diagnosis"] = {**preset_diagnosis, **data.get("diagnosis", {})}
    return out


def _controller(t: Table, inertia: np.ndarray) -> PoseController:
    period = t.number("period_s", 12.0, positive=True)
    damping = t.number("damping", 0.9, positive=True)
    t.finish()
    return PoseController.for_vessel(inertia, period, damping)
