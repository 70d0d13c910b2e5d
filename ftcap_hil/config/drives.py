"""A preset's drives: each ``[[thruster]]``'s drive and propeller (or servo), the drives'
telemetry (``[telemetry]``), and the data sheet the allocator is told.

Per ``[[thruster]]``, either none of these keys (the preset has no drive model: the allocator
judges its thrusters by the motion alone) or, on every thruster, ``drive`` =
``"speed"`` | ``"torque"`` (a shaft: :class:`~sim.shaft.Propeller`) | ``"servo"`` (a
deflected actuator, :class:`~sim.shaft.Servo`), and:

* a shaft: ``diameter_m``, ``kt`` and ``kq`` (open-water K_T and K_Q at J = 0), optionally
  ``j_thrust``, ``j_torque``, ``wake_fraction``, ``efficiency``, ``voltage_v``, ``idle_a``
  (defaults: :class:`~sim.shaft.Propeller`'s); the water's density is the hull's;
* a servo: optionally ``idle_a``, ``load_a``, ``voltage_v``.

``[telemetry]``: the drives' reports, every key of :class:`~sim.feedback.FeedbackConfig`
(rate, latency, resolution, noise, drift, calibration errors) but ``seed``.

The data sheet (:func:`data_sheet`) is the drive as stated, scaled by the scenario's drive
errors (:class:`DriveErrors`): what the allocator is told is never more exact than that.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.core.estimation.shaft_types import DriveModel
from ftcap_hil.core.messages import FloatArray
from sim.feedback import FeedbackConfig
from sim.shaft import Actuator, DriveKind, Propeller, Servo

SHAFT_KEYS = (
    "diameter_m", "kt", "kq", "j_thrust", "j_torque", "wake_fraction", "efficiency",
    "voltage_v", "idle_a",
)  # fmt: skip
SERVO_KEYS = ("idle_a", "load_a", "voltage_v")
DRIVES = ("speed", "torque", "servo")


@dataclass(frozen=True)
class PresetDrives:
    """The drives of a preset's thrusters (in thruster order) and their telemetry."""

    actuators: tuple[Actuator, ...]
    feedback: FeedbackConfig


@dataclass(frozen=True)
class DriveErrors:
    """What the data sheet gets wrong, as fractions: the thrust and torque coefficients
    (told = true x (1 + error)), the drives' time constants; per thruster or one for all."""

    thrust_coefficient: tuple[float, ...] = (0.0,)
    torque_coefficient: tuple[float, ...] = (0.0,)
    time_constant: tuple[float, ...] = (0.0,)


def _actuator(t: Table, kind: str, rho: float) -> Actuator:
    if kind == "servo":
        t.allow(*SERVO_KEYS)
        return Servo(**{k: t.number(k, lo=0.0) for k in SERVO_KEYS if t.has(k)})
    t.allow(*SHAFT_KEYS)
    extra = {k: t.number(k, lo=0.0) for k in SHAFT_KEYS[3:] if t.has(k)}
    size = {"diameter_m": t.number("diameter_m", positive=True),
            "k_t": t.number("kt", positive=True), "k_q": t.number("kq", positive=True)}  # fmt: skip
    try:
        return Propeller(**size, rho_kgm3=rho, drive=DriveKind(kind), **extra)
    except ValueError as e:
        raise t.error(None, str(e)) from e


def drives_from(root: Table, rho_kgm3: float) -> PresetDrives | None:
    """The preset's drives (module docstring), or None when no thruster states one."""
    entries = root.tables("thruster")
    kinds = [e.choice("drive", DRIVES) if e.has("drive") else None for e in entries]
    if all(k is None for k in kinds):
        root.table("telemetry").finish()  # telemetry without drives: its keys are unknown
        return None
    if None in kinds:
        missing = [e.label for e, k in zip(entries, kinds, strict=True) if k is None]
        raise root.error("thruster", f"every thruster needs a drive once one has: {missing}")
    actuators = tuple(
        _actuator(e, k, rho_kgm3) for e, k in zip(entries, kinds, strict=True) if k is not None
    )
    feedback = read_dataclass(root.table("telemetry"), FeedbackConfig, exclude=("seed",))
    return PresetDrives(actuators, feedback)


def _per_thruster(values: Sequence[float], m: int) -> FloatArray:
    return np.broadcast_to(np.asarray(values, dtype=np.float64), (m,))


def data_sheet(
    actuators: Sequence[Actuator], full_force_n: FloatArray, time_constants_s: FloatArray,
    errors: DriveErrors = DriveErrors(),
) -> tuple[DriveModel, ...]:  # fmt: skip
    """The allocator's drive models: the truth's drives, off by ``errors``."""
    m = len(actuators)
    kt_e, kq_e, tc_e = (
        _per_thruster(getattr(errors, f.name), m) for f in dataclasses.fields(errors)
    )
    out = []
    for i, a in enumerate(actuators):
        full, tc = float(full_force_n[i]), float(time_constants_s[i]) * (1.0 + tc_e[i])
        if isinstance(a, Servo):
            out.append(DriveModel(full, tc, is_shaft=False))
            continue
        d, rho = a.diameter_m, a.rho_kgm3
        out.append(DriveModel(
            full, tc, True,
            k_thrust=a.k_t * rho * d**4 * (1.0 + kt_e[i]),
            k_torque=a.k_q * rho * d**5 * (1.0 + kq_e[i]),
            watts_per_amp=a.efficiency * a.voltage_v,
            idle_a=a.idle_a,
            inflow_thrust=(1.0 - a.wake_fraction) / (a.j_thrust * d),
            inflow_torque=(1.0 - a.wake_fraction) / (a.j_torque * d),
            speed_loop=a.drive is DriveKind.SPEED,
        ))  # fmt: skip
    return tuple(out)
