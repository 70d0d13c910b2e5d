"""Realistic vessel presets (``ftcap_hil/data/vessels/<name>.toml``) -> typed settings.

A preset file states one vessel's truth: the 3-DOF model (``[rigid_body]``,
``[added_mass]``, ``[damping]``, ``[model]``), the hull the environment acts on
(``[hull]``, ``[wind_coefficients]``), the thrusters (``[[thruster]]`` with their lag
``time_constant_s``), realistic environment levels (``[environment.current|wind|waves]``),
sensor noise levels (``[sensors]``) and the allocator's model error (``[mismatch]``).
Read with :class:`~ftcap_hil.config.tables.Table`: an unknown key is an error naming the
file, the table, the key and the nearest valid key. Angles are degrees in the file
(``_deg``) and radians here. ``apply_mismatch`` turns a preset into the model the allocator
is given; ``environment_levels`` reads a scenario's ``[environment]`` over a preset's levels.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.drives import PresetDrives, drives_from
from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.config.vessel import thruster_set_from
from ftcap_hil.core.effectiveness.geometry import ThrusterSet, effectiveness
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.vessel3dof import DAMPING_KEYS, Vessel3DOF
from sim.environment import (
    CurrentConfig,
    EnvironmentConfig,
    HullGeometry,
    WaveConfig,
    WindCoefficients,
    WindConfig,
)

PRESETS = "ftcap_hil.data.vessels"


@dataclass(frozen=True)
class SensorLevels:
    """Measurement noise, one standard deviation per axis (SI)."""

    position_std_m: float
    heading_std_rad: float
    velocity_std_m_s: float
    yaw_rate_std_rad_s: float


@dataclass(frozen=True)
class Mismatch:
    """The allocator's model error: ``mass`` and ``damping`` are fractions (+0.2 = +20 %)
    of M (M_RB and M_A) and of every damping coefficient; ``angle_deg`` (deg) and
    ``position_m`` ((dx, dy) m) offset thrusters named by name or 0-based index."""

    mass: float = 0.0
    damping: float = 0.0
    angle_deg: Mapping[str | int, float] = field(default_factory=dict)
    position_m: Mapping[str | int, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class AllocatorModel:
    """What the allocator is told: its vessel model and thruster geometry."""

    vessel: Vessel3DOF
    thrusters: ThrusterSet

    @property
    def B(self) -> FloatArray:
        return effectiveness(self.thrusters)


@dataclass(frozen=True)
class VesselPreset:
    """One preset: the truth, its environment levels, sensors and the stated mismatch."""

    name: str
    description: str
    source: str
    vessel: Vessel3DOF
    thrusters: ThrusterSet
    time_constants_s: FloatArray  # (m,) first-order thrust lag per thruster
    hull: HullGeometry
    environment: EnvironmentConfig
    sensors: SensorLevels
    mismatch: Mismatch
    drives: PresetDrives | None = None  # the thrusters' drives and telemetry (config/drives.py)
    # [diagnosis] as tuned for this vessel: the defaults of a scenario's own [diagnosis]
    diagnosis: Mapping[str, Any] = field(default_factory=dict)

    @property
    def B(self) -> FloatArray:
        """The true effectiveness matrix (3, m)."""
        return effectiveness(self.thrusters)


def preset_names() -> list[str]:
    """Names of the shipped presets."""
    return shipped_names(PRESETS)


def _numbers(t: Table, keys: tuple[str, ...]) -> dict[str, float]:
    """The ``keys`` given in ``t`` as finite floats (any of them may be absent)."""
    t.allow(*keys)
    return {k: t.number(k) for k in keys if t.has(k)}


def _vessel(root: Table) -> Vessel3DOF:
    values: dict[str, Any] = {}
    for table, keys in (
        ("rigid_body", ("mass_kg", "iz_kgm2", "xg_m")),
        ("added_mass", ("X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot")),
        ("damping", DAMPING_KEYS),
    ):
        values.update(_numbers(root.table(table, required=True), keys))
    coriolis = root.table("model").boolean("coriolis", True)
    try:
        return Vessel3DOF(**values, coriolis=coriolis)
    except (TypeError, ValueError) as e:
        raise root.error(None, f"vessel model: {e}") from e


def _thrusters(root: Table) -> tuple[ThrusterSet, FloatArray]:
    """``[[thruster]]``: the vessel tables' thruster reader, plus each thruster's first-order
    lag ``time_constant_s`` (s, >= 0)."""
    ths = thruster_set_from(root)
    if ths.dofs != 3:
        raise root.error("dofs", "a surface-vessel preset is allocated in 3 DOF (X, Y, N)")
    lags = [t.number("time_constant_s", lo=0.0) for t in root.tables("thruster")]
    return ths, np.array(lags)


def _fields_in_degrees(t: Table, cls: type, exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of ``cls`` given in ``t``, a ``*_rad`` field read from ``*_deg`` degrees;
    int fields are integers >= 1, ``force_factor`` is [X, Y, N] factors."""
    out: dict[str, Any] = {}
    for f in fields(cls):
        if not f.init or f.name in exclude:
            continue
        key = f.name[:-4] + "_deg" if f.name.endswith("_rad") else f.name
        t.allow(key)
        if not t.has(key):
            continue
        if key == "force_factor":
            out[f.name] = tuple(float(x) for x in t.vector(key, 3))
        elif f.type in (int, "int"):
            out[f.name] = t.integer(key, lo=1)
        else:
            v = t.number(key)
            out[f.name] = math.radians(v) if key.endswith("_deg") else v
    return out


# the sub-tables of [environment] and what each is read into
ENVIRONMENT_PARTS: tuple[tuple[str, type], ...] = (
    ("current", CurrentConfig),
    ("wind", WindConfig),
    ("waves", WaveConfig),
)


def _environment(root: Table, seed: int) -> EnvironmentConfig:
    env = root.table("environment")
    coef = WindCoefficients(**_numbers(root.table("wind_coefficients"), _keys(WindCoefficients)))
    parts: dict[str, Any] = {}
    try:
        for key, cls in ENVIRONMENT_PARTS:
            parts[key] = cls(**_fields_in_degrees(env.table(key), cls, exclude=("coefficients",)))
        return EnvironmentConfig(
            current=parts["current"],
            wind=replace(parts["wind"], coefficients=coef),
            waves=parts["waves"],
            seed=seed,
        )
    except ValueError as e:
        raise env.error(None, str(e)) from e


def environment_levels(env_t: Table, env: EnvironmentConfig) -> EnvironmentConfig:
    """``env`` with the levels that ``env_t`` (an ``[environment]`` table with
    ``[environment.current|wind|waves]``) states: the keys of a preset's own environment
    (angles as ``*_deg`` degrees), each replacing that one value; a key left out keeps
    ``env``'s. ``env_t`` is finished here: an unknown table or key, or a value out of range,
    is a ConfigError naming the file, the table and the key."""
    given = {
        key: _fields_in_degrees(env_t.table(key), cls, exclude=("coefficients",))
        for key, cls in ENVIRONMENT_PARTS
    }
    env_t.finish()
    try:
        return replace(env, **{k: replace(getattr(env, k), **v) for k, v in given.items()})
    except ValueError as e:
        raise env_t.error(None, str(e)) from e


def _keys(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls) if f.init)


def _sensors(root: Table) -> SensorLevels:
    t = root.table("sensors", required=True)
    return SensorLevels(
        t.number("position_std_m", lo=0.0),
        math.radians(t.number("heading_std_deg", lo=0.0)),
        t.number("velocity_std_m_s", lo=0.0),
        math.radians(t.number("yaw_rate_std_deg_s", lo=0.0)),
    )


def _mismatch(root: Table) -> Mismatch:
    """``[mismatch]``: mass, damping (fractions); angle_deg and position_m tables keyed by
    thruster name (checked against the thrusters by :func:`_resolve`)."""
    t = root.table("mismatch")
    angles_t, offsets_t = t.table("angle_deg"), t.table("position_m")
    angles: dict[str | int, float] = {k: angles_t.number(k) for k in angles_t.data}
    offsets: dict[str | int, tuple[float, float]] = {}
    for k in offsets_t.data:
        dx, dy = offsets_t.vector(k, 2)
        offsets[k] = (float(dx), float(dy))
    return Mismatch(t.number("mass", 0.0), t.number("damping", 0.0), angles, offsets)


def _diagnosis(root: Table) -> dict[str, Any]:
    """``[diagnosis]``: checked as DiagnosisConfig keys, kept as written."""
    t = root.table("diagnosis")
    read_dataclass(t, DiagnosisConfig)
    return dict(t.data)


def load_preset(
    name_or_path: str | Path, overrides: list[str] | None = None, seed: int = 0
) -> VesselPreset:
    """A preset by shipped name (``preset_names()``) or path; ``seed`` goes into its
    EnvironmentConfig. Raises ConfigError naming the file, table and key on bad input."""
    doc = read_toml(name_or_path, PRESETS, overrides, what="vessel preset")
    with Table.document(doc) as root:
        head = root.table("preset", required=True)
        thrusters, lags = _thrusters(root)
        hull_t = root.table("hull", required=True)
        try:
            hull = HullGeometry(**_numbers(hull_t, _keys(HullGeometry)))
        except TypeError as e:
            raise hull_t.error(None, str(e)) from e
        preset = VesselPreset(
            name=head.string("name", doc.source),
            description=head.string("description", ""),
            source=doc.source,
            vessel=_vessel(root),
            thrusters=thrusters,
            time_constants_s=lags,
            hull=hull,
            environment=_environment(root, seed),
            sensors=_sensors(root),
            mismatch=_mismatch(root),
            drives=drives_from(root, hull.rho_water_kg_m3),
            diagnosis=_diagnosis(root),
        )
    _resolve(preset.thrusters, preset.mismatch, doc.source)
    return preset


def _resolve(
    ths: ThrusterSet, mm: Mismatch, where: str
) -> tuple[dict[int, float], dict[int, tuple[float, float]]]:
    """Mismatch keys (names or indices) -> thruster indices; ConfigError on an unknown one."""

    def index(key: str | int, table: str) -> int:
        if isinstance(key, int) and 0 <= key < ths.m:
            return key
        if isinstance(key, str) and key in ths.names:
            return ths.names.index(key)
        near = difflib.get_close_matches(str(key), ths.names, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else f" (thrusters: {ths.names})"
        raise ConfigError(f"{where}.mismatch.{table}: unknown thruster {key!r}{hint}")

    angles = {index(k, "angle_deg"): float(v) for k, v in mm.angle_deg.items()}
    offsets = {index(k, "position_m"): (float(v[0]), float(v[1])) for k, v in mm.position_m.items()}
    return angles, offsets


def apply_mismatch(
    preset: VesselPreset,
    mass: float | None = None,
    damping: float | None = None,
    angle_deg: Mapping[str | int, float] | None = None,
    position_m: Mapping[str | int, tuple[float, float]] | None = None,
) -> AllocatorModel:
    """The allocator's model of ``preset``: M x (1 + mass), damping x (1 + damping), and
    thrusters turned by ``angle_deg`` (deg, positive clockwise seen from above) and moved by
    ``position_m`` (m, body frame). Arguments left None take the preset's stated mismatch;
    with none stated the result is the truth itself."""
    mm = preset.mismatch
    mm = Mismatch(
        mm.mass if mass is None else mass,
        mm.damping if damping is None else damping,
        mm.angle_deg if angle_deg is None else angle_deg,
        mm.position_m if position_m is None else position_m,
    )
    if not mm.mass > -1.0 or not mm.damping >= -1.0:
        raise ConfigError(
            f"mismatch: need mass > -1 and damping >= -1, got {mm.mass}, {mm.damping}"
        )
    angles, offsets = _resolve(preset.thrusters, mm, preset.source)
    thrusters = tuple(
        replace(
            t,
            angle_rad=t.angle_rad + math.radians(angles.get(i, 0.0)),
            x_m=t.x_m + offsets.get(i, (0.0, 0.0))[0],
            y_m=t.y_m + offsets.get(i, (0.0, 0.0))[1],
        )
        for i, t in enumerate(preset.thrusters.thrusters)
    )
    vessel = preset.vessel.scaled(1.0 + mm.mass, 1.0 + mm.damping)
    return AllocatorModel(vessel, ThrusterSet(thrusters))
