"""Underwater vehicles (``ftcap_hil/data/underwater/<name>.toml``) -> a 6-DOF rigid body and
its thrusters.

A file holds ``[vessel]`` with ``dofs = 6`` and its ``[[vessel.thruster]]`` entries (the
vessel tables' reader, with ``z`` and ``elevation_deg``; optionally each thruster's
``time_constant_s`` and drive, and ``[vessel.telemetry]``, as in a surface preset:
config/drives.py), ``[rigid_body]``, ``[added_mass]``, ``[damping]`` and optionally the
drives' ``[diagnosis]`` (what ``bench/calibrate_rov.py`` prints; docs/vessels.md).
Every key is read or refused: an unknown one is an error naming the file, the table and
the key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftcap_hil.config.drives import PresetDrives, data_sheet, drives_from
from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.config.vessel import thruster_set_from
from ftcap_hil.core.effectiveness.geometry import ThrusterSet, effectiveness
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig, DriveModel
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.vehicle6dof import Vehicle6DOF

VEHICLES = "ftcap_hil.data.underwater"


@dataclass(frozen=True)
class UnderwaterVehicle:
    """A shipped or user vehicle: its rigid body, its thrusters (6 DOF) and where it came
    from."""

    name: str
    source: str
    body: Vehicle6DOF
    thrusters: ThrusterSet
    time_constants_s: FloatArray  # (m,) each thruster's first-order lag, s
    drives: PresetDrives | None = None  # the drives and their telemetry (None: none given)
    diagnosis: DiagnosisConfig = DiagnosisConfig()  # the file's [diagnosis] over the defaults

    def drive_models(self) -> tuple[DriveModel, ...]:
        """The drives' data sheet as the allocator is told it (no errors: these are the
        file's figures); ValueError without drives."""
        if self.drives is None:
            raise ValueError(f"{self.name}: no drives in the vehicle file")
        return data_sheet(self.drives.actuators, self.thrusters.u_max, self.time_constants_s)

    @property
    def B(self) -> FloatArray:
        """The effectiveness matrix (6, m) for [X, Y, Z, K, M, N]."""
        return effectiveness(self.thrusters)


def vehicle_names() -> list[str]:
    """Names of the shipped underwater vehicles."""
    return shipped_names(VEHICLES)


def _triple(t: Table, key: str, positive: bool = False) -> tuple[float, float, float]:
    a, b, c = (float(v) for v in t.vector(key, 3, positive=positive))
    return a, b, c


def _six(t: Table, key: str) -> tuple[float, ...]:
    return tuple(float(v) for v in t.vector(key, 6, lo=0.0))


def load_vehicle(name_or_path: str | Path, overrides: list[str] | None = None) -> UnderwaterVehicle:
    """A vehicle by shipped name (:func:`vehicle_names`) or path. Raises ConfigError naming
    the file, table and key on bad input."""
    doc = read_toml(name_or_path, VEHICLES, overrides, what="underwater vehicle")
    with Table.document(doc) as root:
        vessel_t = root.table("vessel", required=True)
        thrusters = thruster_set_from(vessel_t)
        if thrusters.dofs != 6:
            raise vessel_t.error("dofs", "an underwater vehicle is allocated in 6 DOF: dofs = 6")
        lags = np.array(
            [t.number("time_constant_s", 0.0, lo=0.0) for t in vessel_t.tables("thruster")]
        )
        rb = root.table("rigid_body", required=True)
        rho = rb.number("water_density_kgm3", positive=True)
        drives = drives_from(vessel_t, rho)
        diagnosis = read_dataclass(root.table("diagnosis"), DiagnosisConfig)
        added = root.table("added_mass", required=True)
        damping = root.table("damping", required=True)
        try:
            body = Vehicle6DOF(
                mass_kg=rb.number("mass_kg", positive=True),
                volume_m3=rb.number("volume_m3", positive=True),
                water_density_kgm3=rho,
                gravity_ms2=rb.number("gravity_ms2", positive=True),
                inertia_kgm2=_triple(rb, "inertia_kgm2", positive=True),
                cg_m=_triple(rb, "cg_m"),
                cb_m=_triple(rb, "cb_m"),
                added_mass=_six(added, "diagonal"),
                damping_linear=_six(damping, "linear"),
                damping_quadratic=_six(damping, "quadratic"),
            )
        except ValueError as e:
            raise rb.error(None, str(e)) from e
    return UnderwaterVehicle(
        name=Path(doc.source).stem, source=doc.source, body=body, thrusters=thrusters,
        time_constants_s=lags, drives=drives, diagnosis=diagnosis,
    )  # fmt: skip
