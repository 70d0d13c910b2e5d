"""Realistic vessel presets (``ftcap_hil/data/vessels/<name>.toml``) -> typed settings.

A preset file states one vessel's truth: the 3-DOF model (``[rigid_body]``,
``[added_mass]``, ``[damping]``, ``[model]``), the hull the environment acts on
(``[hull]``, ``[wind_coefficients]``), the thrusters (``[[thruster]]`` with their lag
``time_constant_s``), realistic environment levels (``[environment.current|wind|waves]``),
sensor noise levels (``[sensors]``) and the allocator's model error (``[mismatch]``).
Every key is checked: an unknown one is an error naming the file, the table, the key and
the nearest valid key. Angles are degrees in the file (``_deg``) and radians here.
``apply_mismatch`` turns a preset into the model the allocator is given.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.geometry import Thruster, ThrusterSet, effectiveness
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.vessel3dof import DAMPING_KEYS, Vessel3DOF
from sim.environment import (
    CurrentConfig,
    EnvironmentConfig,
    HullGeometry,
    WaveConfig,
    WindCoefficients,
    WindConfig,
)

PRESETS = "ftcap_hil.data.vessels"
TOP: tuple[str, ...] = ("preset", "rigid_body", "added_mass", "damping", "model", "hull")
TOP += ("wind_coefficients", "thruster", "environment", "sensors", "mismatch")
THRUSTER_KEYS: tuple[str, ...] = ("name", "x", "y", "angle_deg", "u_min", "u_max")
THRUSTER_KEYS += ("time_constant_s", "rate_max", "step_max")


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

    @property
    def B(self) -> FloatArray:
        """The true effectiveness matrix (3, m)."""
        return effectiveness(self.thrusters)


def preset_names() -> list[str]:
    """Names of the shipped presets."""
    return shipped_names(PRESETS)


def strict_keys(table: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> None:
    """ConfigError for the first key of ``table`` not in ``allowed``, with the nearest."""
    for key in table:
        if key not in allowed:
            near = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else f" (known: {', '.join(allowed)})"
            raise ConfigError(f"{where}: unknown key {key!r}{hint}")


def _sub(table: Mapping[str, Any], key: str, where: str, required: bool = True) -> dict[str, Any]:
    value = table.get(key, None if required else {})
    if not isinstance(value, dict):
        raise ConfigError(f"{where}.{key}: expected a table, got {value!r}")
    return value


def _num(table: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in table:
        if default is None:
            raise ConfigError(f"{where}.{key}: missing")
        return default
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def _numbers(table: Mapping[str, Any], where: str, allowed: tuple[str, ...]) -> dict[str, float]:
    strict_keys(table, allowed, where)
    return {k: _num(table, k, where) for k in table}


def _dataclass_keys(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls) if f.init)


def _vessel(data: Mapping[str, Any], where: str) -> Vessel3DOF:
    values: dict[str, Any] = {}
    for table, keys in (
        ("rigid_body", ("mass_kg", "iz_kgm2", "xg_m")),
        ("added_mass", ("X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot")),
        ("damping", DAMPING_KEYS),
    ):
        values.update(_numbers(_sub(data, table, where), f"{where}.{table}", keys))
    model = _sub(data, "model", where, required=False)
    strict_keys(model, ("coriolis",), f"{where}.model")
    if not isinstance(model.get("coriolis", True), bool):
        raise ConfigError(f"{where}.model.coriolis: expected true or false")
    try:
        return Vessel3DOF(**values, coriolis=model.get("coriolis", True))
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from e


def _thruster(t: Any, where: str) -> tuple[Thruster, float]:
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: expected a table, got {t!r}")
    strict_keys(t, THRUSTER_KEYS, where)
    if not isinstance(t.get("name"), str) or not t["name"]:
        raise ConfigError(f"{where}.name: expected a non-empty string")
    th = Thruster(
        name=t["name"],
        x_m=_num(t, "x", where),
        y_m=_num(t, "y", where),
        angle_rad=math.radians(_num(t, "angle_deg", where)),
        u_min=_num(t, "u_min", where),
        u_max=_num(t, "u_max", where),
        rate_max=_num(t, "rate_max", where) if "rate_max" in t else None,
        step_max=_num(t, "step_max", where) if "step_max" in t else None,
    )
    if not th.u_min <= 0.0 <= th.u_max or th.u_min == th.u_max:
        raise ConfigError(f"{where}: need u_min <= 0 <= u_max, got {th.u_min}, {th.u_max}")
    lag = _num(t, "time_constant_s", where)
    if lag < 0.0:
        raise ConfigError(f"{where}.time_constant_s: must be >= 0, got {lag}")
    return th, lag


def _thrusters(data: Mapping[str, Any], where: str) -> tuple[ThrusterSet, FloatArray]:
    entries = data.get("thruster")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}.thruster: expected a non-empty list of [[thruster]]")
    parsed = [_thruster(t, f"{where}.thruster[{i}]") for i, t in enumerate(entries)]
    names = [th.name for th, _ in parsed]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}.thruster: duplicate names in {names}")
    return ThrusterSet(tuple(th for th, _ in parsed)), np.array([lag for _, lag in parsed])


def _angles(values: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    """``*_deg`` file keys -> ``*_rad`` fields."""
    return {
        (k[:-4] + "_rad" if k.endswith("_deg") else k): (
            math.radians(v) if k.endswith("_deg") else v
        )
        for k, v in values.items()
        if k in keys
    }


def _file_keys(cls: type, exclude: tuple[str, ...] = ()) -> tuple[str, ...]:
    keys = [k[:-4] + "_deg" if k.endswith("_rad") else k for k in _dataclass_keys(cls)]
    return tuple(k for k in keys if k not in exclude)


def _environment(data: Mapping[str, Any], where: str, seed: int) -> EnvironmentConfig:
    env = _sub(data, "environment", where, required=False)
    w = f"{where}.environment"
    strict_keys(env, ("current", "wind", "waves"), w)
    coef_table = _sub(data, "wind_coefficients", where, False)
    coef_values: dict[str, Any] = _numbers(
        coef_table, f"{where}.wind_coefficients", _dataclass_keys(WindCoefficients)
    )
    coef = WindCoefficients(**coef_values)
    parts: dict[str, Any] = {}
    classes: tuple[tuple[str, type], ...] = (
        ("current", CurrentConfig),
        ("wind", WindConfig),
        ("waves", WaveConfig),
    )
    for key, cls in classes:
        allowed = _file_keys(cls, exclude=("coefficients",))
        table = dict(_sub(env, key, w, False))
        factor = table.pop("force_factor", None) if key == "waves" else None
        values: dict[str, Any] = _numbers(table, f"{w}.{key}", allowed)
        if factor is not None:
            values["force_factor"] = _triple(factor, f"{w}.{key}.force_factor")
        if "n_components" in values:
            n = values["n_components"]
            if n != int(n) or n < 1:
                raise ConfigError(f"{w}.{key}.n_components: expected an integer >= 1, got {n}")
            values["n_components"] = int(n)
        parts[key] = cls(**_angles(values, allowed))
    try:
        return EnvironmentConfig(
            current=parts["current"],
            wind=replace(parts["wind"], coefficients=coef),
            waves=parts["waves"],
            seed=seed,
        )
    except ValueError as e:
        raise ConfigError(f"{w}: {e}") from e


def _triple(v: Any, where: str) -> tuple[float, float, float]:
    if not (isinstance(v, list) and len(v) == 3):
        raise ConfigError(f"{where}: expected [X, Y, N] factors, got {v!r}")
    x, y, n = (_num({"v": e}, "v", where) for e in v)
    return (x, y, n)


def _sensors(data: Mapping[str, Any], where: str) -> SensorLevels:
    allowed = ("position_std_m", "heading_std_deg", "velocity_std_m_s", "yaw_rate_std_deg_s")
    v = _numbers(_sub(data, "sensors", where), f"{where}.sensors", allowed)
    missing = [k for k in allowed if k not in v]
    if missing or any(x < 0.0 for x in v.values()):
        raise ConfigError(f"{where}.sensors: need {list(allowed)} >= 0 (missing {missing})")
    return SensorLevels(
        v["position_std_m"],
        math.radians(v["heading_std_deg"]),
        v["velocity_std_m_s"],
        math.radians(v["yaw_rate_std_deg_s"]),
    )


def _mismatch(data: Mapping[str, Any], where: str) -> Mismatch:
    t = _sub(data, "mismatch", where, required=False)
    w = f"{where}.mismatch"
    strict_keys(t, ("mass", "damping", "angle_deg", "position_m"), w)
    angles: dict[str | int, float] = {
        k: _num(_sub(t, "angle_deg", w, False), k, f"{w}.angle_deg")
        for k in _sub(t, "angle_deg", w, False)
    }
    offsets: dict[str | int, tuple[float, float]] = {}
    for k, v in _sub(t, "position_m", w, False).items():
        if not (isinstance(v, list) and len(v) == 2):
            raise ConfigError(f"{w}.position_m.{k}: expected [dx, dy], got {v!r}")
        offsets[k] = (
            _num({"dx": v[0]}, "dx", f"{w}.position_m.{k}"),
            _num({"dy": v[1]}, "dy", f"{w}.position_m.{k}"),
        )
    return Mismatch(_num(t, "mass", w, 0.0), _num(t, "damping", w, 0.0), angles, offsets)


def load_preset(
    name_or_path: str | Path, overrides: list[str] | None = None, seed: int = 0
) -> VesselPreset:
    """A preset by shipped name (``preset_names()``) or path; ``seed`` goes into its
    EnvironmentConfig. Raises ConfigError naming the file, table and key on bad input."""
    doc = read_toml(name_or_path, PRESETS, overrides, what="vessel preset")
    data, where = doc.data, doc.source
    strict_keys(data, TOP, where)
    head = _sub(data, "preset", where)
    strict_keys(head, ("name", "description"), f"{where}.preset")
    thrusters, lags = _thrusters(data, where)
    hull_keys = _dataclass_keys(HullGeometry)
    hull_values = _numbers(_sub(data, "hull", where), f"{where}.hull", hull_keys)
    try:
        hull = HullGeometry(**hull_values)
    except TypeError as e:
        raise ConfigError(f"{where}.hull: {e}") from e
    preset = VesselPreset(
        name=str(head.get("name", where)),
        description=str(head.get("description", "")),
        source=where,
        vessel=_vessel(data, where),
        thrusters=thrusters,
        time_constants_s=lags,
        hull=hull,
        environment=_environment(data, where, seed),
        sensors=_sensors(data, where),
        mismatch=_mismatch(data, where),
    )
    _resolve(preset.thrusters, preset.mismatch, where)
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
