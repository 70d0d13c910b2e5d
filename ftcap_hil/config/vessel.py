"""Vessel and plant tables: thruster geometry and limits, and the plant model's parameters.

``[vessel]``: ``preset = "paper-4.2"`` (with optional ``l``, ``u_limit``, ``step_limit`` or
``rate_limit``) or a list of ``[[vessel.thruster]]``; ``[plant]``: ``kind = "linear"`` or
``"vessel"`` with the model's parameters (docs/scenarios.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ftcap_hil.config.tables import dataclass_from_table, get, number, vector
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.geometry import Thruster, ThrusterSet, effectiveness, paper_four_thrusters
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.plants import LinearPlant, SurfaceVessel


def _number(table: dict[str, Any], key: str, where: str) -> float:
    if key not in table:
        raise ConfigError(f"{where}.{key}: missing")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {value!r}")
    return float(value)


def _optional(table: dict[str, Any], key: str, where: str) -> float | None:
    return _number(table, key, where) if key in table else None


def thruster_from_table(table: dict[str, Any], where: str) -> Thruster:
    """One ``[[thruster]]`` entry: name, x, y, angle_deg (or direction = [dx, dy]),
    u_min, u_max, and optionally rate_max (N/s) or step_max (N per cycle)."""
    name = str(table.get("name", where))
    if "direction" in table:
        d = table["direction"]
        if not (isinstance(d, Sequence) and len(d) == 2):
            raise ConfigError(f"{where}.direction: expected [dx, dy], got {d!r}")
        angle = math.atan2(float(d[1]), float(d[0]))
        if math.hypot(float(d[0]), float(d[1])) == 0.0:
            raise ConfigError(f"{where}.direction: zero vector")
    else:
        angle = math.radians(_number(table, "angle_deg", where))
    thruster = Thruster(
        name=name,
        x_m=_number(table, "x", where),
        y_m=_number(table, "y", where),
        angle_rad=angle,
        u_min=_number(table, "u_min", where),
        u_max=_number(table, "u_max", where),
        rate_max=_optional(table, "rate_max", where),
        step_max=_optional(table, "step_max", where),
    )
    if not thruster.u_min <= 0.0 <= thruster.u_max or thruster.u_min == thruster.u_max:
        raise ConfigError(
            f"{where}: need u_min <= 0 <= u_max, got {thruster.u_min}, {thruster.u_max}"
        )
    if thruster.rate_max is not None and thruster.step_max is not None:
        raise ConfigError(f"{where}: give rate_max or step_max, not both")
    for key in ("rate_max", "step_max"):
        value = getattr(thruster, key)
        if value is not None and value <= 0.0:
            raise ConfigError(f"{where}.{key}: must be > 0, got {value}")
    return thruster


def thrusters_from_table(table: dict[str, Any], where: str = "vessel") -> ThrusterSet:
    """A vessel table: either ``preset = "paper-4.2"`` (with optional l, u_limit, and
    step_limit (N per allocator cycle, the paper's form) or rate_limit (N/s))
    or a list ``thruster = [{...}, ...]`` (TOML ``[[vessel.thruster]]``)."""
    preset = table.get("preset")
    if preset is not None:
        if preset != "paper-4.2":
            raise ConfigError(f"{where}.preset: unknown preset {preset!r} (known: 'paper-4.2')")
        unknown = set(table) - {"preset", "l", "u_limit", "step_limit", "rate_limit"}
        if unknown:
            raise ConfigError(f"{where}: unknown keys {sorted(unknown)} for the paper-4.2 preset")
        values = {"l": 0.3, "u_limit": 0.1, "step_limit": 0.09}
        for key in ("l", "u_limit", "step_limit", "rate_limit"):
            if key in table:
                values[key] = _number(table, key, where)
                if values[key] <= 0.0:
                    raise ConfigError(f"{where}.{key}: must be > 0, got {values[key]}")
        return paper_four_thrusters(
            l_m=values["l"],
            u_limit=values["u_limit"],
            step_limit=values["step_limit"],
            rate_limit=values.get("rate_limit"),
        )
    entries = table.get("thruster")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}.thruster: expected a non-empty list of thrusters")
    thrusters = tuple(
        thruster_from_table(t, f"{where}.thruster[{i}]") for i, t in enumerate(entries)
    )
    names = [t.name for t in thrusters]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}.thruster: duplicate names in {names}")
    return ThrusterSet(thrusters)


def load_vessel(path: str | Path) -> ThrusterSet:
    """Read a vessel TOML file (top-level table as in ``thrusters_from_table``)."""
    doc = read_toml(path, what="vessel file")
    return thrusters_from_table(doc.data.get("vessel", doc.data), where=doc.source)


def plant_from_tables(
    data: dict[str, Any], where: str
) -> tuple[LinearPlant | SurfaceVessel, ThrusterSet, FloatArray]:
    plant_t = get(data, "plant", where)
    kind = get(plant_t, "kind", f"{where}.plant")
    if kind == "linear":
        a = number(plant_t, "a", f"{where}.plant", 1.2)
        b_v = number(plant_t, "b_v", f"{where}.plant", 1.0)
        b_u = vector(get(plant_t, "b_u", f"{where}.plant"), f"{where}.plant.b_u")
        act = get(data, "actuators", where)
        lo, hi = (
            number(act, "u_min", f"{where}.actuators"),
            number(act, "u_max", f"{where}.actuators"),
        )
        step = number(act, "step_max", f"{where}.actuators", math.inf)
        ths = ThrusterSet(
            tuple(
                Thruster(
                    f"U{i + 1}",
                    0.0,
                    0.0,
                    0.0,
                    lo,
                    hi,
                    step_max=step if math.isfinite(step) else None,
                )
                for i in range(b_u.size)
            )
        )
        return LinearPlant(a=a, b_v=b_v), ths, b_u[None, :]
    if kind == "vessel":
        params: dict[str, Any] = {
            k: number(plant_t, k, f"{where}.plant")
            for k in plant_t
            if k not in ("kind", "inversion")
        }
        if "inversion" in plant_t:
            params["inversion"] = plant_t["inversion"]
        vessel = dataclass_from_table(SurfaceVessel, params, f"{where}.plant")
        ths = thrusters_from_table(get(data, "vessel", where), f"{where}.vessel")
        return vessel, ths, effectiveness(ths)
    raise ConfigError(f"{where}.plant.kind: expected 'linear' or 'vessel', got {kind!r}")
