"""Vessel and plant tables: thruster geometry and limits, and the plant model's parameters.

``[vessel]``: ``preset = "paper-4.2"`` (with optional ``l``, ``u_limit``, ``step_limit`` or
``rate_limit``) or a list of ``[[vessel.thruster]]``; ``[plant]``: ``kind = "linear"`` (with
``[actuators]``) or ``"vessel"`` with the model's parameters (docs/scenarios.md). Read with
:class:`~ftcap_hil.config.tables.Table`: an unknown key is an error.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.effectiveness.geometry import (
    WRENCH_AXES,
    Thruster,
    ThrusterSet,
    effectiveness,
    paper_four_thrusters,
)
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import LinearPlant, SurfaceVessel

PRESETS = ("paper-4.2",)


class PlantKind(enum.Enum):
    """``[plant] kind``: which plant model a file describes."""

    LINEAR = "linear"  # section 4.1, with [actuators]
    VESSEL = "vessel"  # section 4.2's vessel model, with [vessel]
    PRESET = "preset"  # a realistic vessel preset (scenario files only, config/realistic.py)


def _direction(t: Table) -> tuple[float, float]:
    """(azimuth, elevation) in rad from ``angle_deg`` (+ ``elevation_deg``) or ``direction``
    = [dx, dy] or [dx, dy, dz] (body axes, z down)."""
    if t.has("direction"):
        if t.has("angle_deg") or t.has("elevation_deg"):
            raise t.error(None, "give angle_deg (and elevation_deg) or direction, not both")
        d = t.vector("direction")
        if d.size not in (2, 3):
            raise t.error("direction", f"expected [dx, dy] or [dx, dy, dz], got {d.size} numbers")
        dx, dy, dz = float(d[0]), float(d[1]), float(d[2]) if d.size == 3 else 0.0
        horizontal = math.hypot(dx, dy)
        if math.hypot(horizontal, dz) == 0.0:
            raise t.error("direction", "zero vector")
        t.allow("angle_deg", "elevation_deg")
        return math.atan2(dy, dx), math.atan2(dz, horizontal)
    t.allow("direction")
    elevation = t.number("elevation_deg", 0.0, lo=-90.0, hi=90.0)
    return math.radians(t.number("angle_deg")), math.radians(elevation)


def thruster_from(t: Table) -> Thruster:
    """One ``[[thruster]]`` entry, of a vessel table or a vessel preset alike: ``name``
    (default ``T<n>``, 1-based), ``x``, ``y`` and optionally ``z`` (m; z down), ``angle_deg``
    (with optional ``elevation_deg``, positive down) or ``direction = [dx, dy(, dz)]``,
    ``u_min`` <= 0 <= ``u_max`` (N), and optionally ``rate_max`` (N/s) or ``step_max`` (N per
    cycle), not both."""
    name = t.string("name", f"T{(t.index or 0) + 1}")
    angle, elevation = _direction(t)
    thruster = Thruster(
        name=name,
        x_m=t.number("x"),
        y_m=t.number("y"),
        z_m=t.number("z", 0.0),
        angle_rad=angle,
        elevation_rad=elevation,
        u_min=t.number("u_min"),
        u_max=t.number("u_max"),
        rate_max=t.number("rate_max", None, positive=True),
        step_max=t.number("step_max", None, positive=True),
    )
    if not thruster.u_min <= 0.0 <= thruster.u_max or thruster.u_min == thruster.u_max:
        raise t.error(None, f"need u_min <= 0 <= u_max, got {thruster.u_min}, {thruster.u_max}")
    if thruster.rate_max is not None and thruster.step_max is not None:
        raise t.error(None, "give rate_max or step_max, not both")
    return thruster


def thruster_set_from(t: Table) -> ThrusterSet:
    """The ``[[thruster]]`` array of ``t`` (at least one, :func:`thruster_from` each), with
    distinct names, and ``dofs`` (3, the default: X, Y, N; 6 for an underwater vehicle): the
    one reader of thruster tables (vessel tables and presets)."""
    dofs = t.integer("dofs", 3)
    if dofs not in WRENCH_AXES:
        raise t.error("dofs", f"expected 3 (X, Y, N) or 6 (X, Y, Z, K, M, N), got {dofs}")
    thrusters = tuple(thruster_from(e) for e in t.tables("thruster", required=True))
    names = [th.name for th in thrusters]
    if len(set(names)) != len(names):
        raise t.error("thruster", f"duplicate names in {names}")
    return ThrusterSet(thrusters, dofs)


def _preset(t: Table) -> ThrusterSet:
    t.choice("preset", PRESETS)
    step = t.number("step_limit", None, positive=True)
    rate = t.number("rate_limit", None, positive=True)
    if step is not None and rate is not None:
        raise t.error(None, "give step_limit (N per cycle) or rate_limit (N/s), not both")
    return paper_four_thrusters(
        l_m=t.number("l", 0.3, positive=True),
        u_limit=t.number("u_limit", 0.1, positive=True),
        step_limit=0.09 if step is None else step,
        rate_limit=rate,
    )


def thrusters_from(t: Table) -> ThrusterSet:
    """A vessel table: either ``preset = "paper-4.2"`` (with optional l, u_limit, and
    step_limit (N per allocator cycle, the paper's form) or rate_limit (N/s)) or a list
    ``[[vessel.thruster]]`` (:func:`thruster_from`)."""
    if t.has("preset"):
        return _preset(t)
    return thruster_set_from(t)


def thrusters_from_table(table: Mapping[str, Any], file: str = "vessel file") -> ThrusterSet:
    """:func:`thrusters_from` on a plain ``[vessel]`` mapping (unknown keys refused)."""
    with Table(table, file, "vessel") as t:
        return thrusters_from(t)


def load_vessel(path: str | Path) -> ThrusterSet:
    """A vessel TOML file: a ``[vessel]`` table, or the vessel keys at the top level."""
    doc = read_toml(path, what="vessel file")
    with Table.document(doc) as root:
        return thrusters_from(root.table("vessel") if root.has("vessel") else root)


def _linear(root: Table, plant_t: Table) -> tuple[LinearPlant, ThrusterSet, FloatArray]:
    b_u = plant_t.vector("b_u")
    act = root.table("actuators", required=True)
    lo, hi = act.number("u_min"), act.number("u_max")
    if not lo <= 0.0 <= hi or lo == hi:
        raise act.error(None, f"need u_min <= 0 <= u_max, got {lo}, {hi}")
    step = act.number("step_max", None, positive=True)
    ths = ThrusterSet(
        tuple(Thruster(f"U{i + 1}", 0.0, 0.0, 0.0, lo, hi, step_max=step) for i in range(b_u.size))
    )
    plant = LinearPlant(a=plant_t.number("a", 1.2), b_v=plant_t.number("b_v", 1.0))
    return plant, ths, b_u[None, :]


def plant_from(root: Table) -> tuple[LinearPlant | SurfaceVessel, ThrusterSet, FloatArray]:
    """``[plant]`` (+ ``[actuators]`` for the linear plant, ``[vessel]`` for the vessel) of a
    file: the plant model, its thrusters and B (k x m)."""
    plant_t = root.table("plant", required=True)
    kind = plant_t.enum("kind", PlantKind)
    if kind is PlantKind.PRESET:  # dispatched before this reader: a scenario file's realistic form
        raise plant_t.error("kind", "'preset' (a vessel preset) is for scenario files only")
    if kind is PlantKind.LINEAR:
        return _linear(root, plant_t)
    vessel = read_dataclass(plant_t, SurfaceVessel, exclude=("k", "state_labels"))
    vessel_t = root.table("vessel", required=True)
    ths = thrusters_from(vessel_t)
    if ths.dofs != 3:
        raise vessel_t.error("dofs", "the surface-vessel plant is simulated in 3 DOF (X, Y, N)")
    return vessel, ths, effectiveness(ths)


def surface_vessel_from(root: Table, what: str) -> tuple[SurfaceVessel, ThrusterSet, FloatArray]:
    """:func:`plant_from` for a process that drives a vessel (``what``: "the daemon")."""
    plant, ths, B = plant_from(root)
    if not isinstance(plant, SurfaceVessel):
        raise ConfigError(f"{root.file}: [plant] kind: {what} drives a vessel, got 'linear'")
    return plant, ths, B
