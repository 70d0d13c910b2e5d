"""The physics of one actuator's output stage: a propeller on a driven shaft, or a servo.

**Shaft** (propellers, tunnel and azimuth thrusters), n in rev/s, D the diameter, after
Fossen (2021, ch. 9) and Smogeli (2006, NTNU, thrust and torque with in-flow)::

    T = k_T (n|n| - |n| V_a / (J_T D))        k_T = K_T0 rho D^4    (N)
    Q = k_Q (n|n| - |n| V_a / (J_Q D))        k_Q = K_Q0 rho D^5    (N m)
    V_a = (1 - w) v_axial                     in-flow along the thrust direction (m/s)

the linear open-water curves K_T(J) = K_T0 (1 - J / J_T), K_Q(J) = K_Q0 (1 - J / J_Q)
written in n, so that nothing is singular at n = 0. ``J_T`` < ``J_Q`` (K_T reaches zero
first) and the wake fraction ``w`` are typical of a fixed-pitch propeller (ASSUMED values
of :class:`Propeller`). The drive follows a speed reference n_ref:

* ``speed`` (a DP thruster's frequency converter, an ESC in closed-loop rpm mode):
  dn/dt = (n_ref - n) / T_n, solved exactly over a step; the torque is what the load
  takes at that speed.
* ``torque`` (a duty-cycle ESC such as a hobby or a T200's): I_s dn/dt = Q_m - Q(n) with
  Q_m = k_Q n_ref|n_ref| (the torque that holds n_ref in open water) and
  I_s = 2 k_Q n_max T_n / 2 (the linearised time constant is T_n at half the top speed),
  integrated in sub-steps of at most T_n / 8. A lighter load (a lost blade) then speeds the
  shaft up, a heavier one (fouling, in-flow) slows it down.

Electrical side: P = 2 pi |n| |Q| / efficiency, I = P / V + I_idle, at most the drive's
current limit (a jammed shaft under command draws the limit).

**Servo** (rudders, flaps): the deflection p in [-1, 1] of full follows the command with
dp/dt = (p_ref - p) / T; the force is p x its full-deflection force, the servo current
I_idle + I_load |p| x lift factor (the hinge moment follows the lift: a lost rudder blade
draws less).

Pure, vectorised over the m actuators, no clock.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FloatArray


class DriveKind(enum.Enum):
    """How a shaft's drive follows its reference (module docstring)."""

    SPEED = "speed"
    TORQUE = "torque"


@dataclass(frozen=True)
class Propeller:
    """Open-water propeller and drive of one shaft thruster. Defaults: a 30 mm model-boat
    propeller on a 12 V supply (``sim/esc_model.py``); ``j_thrust``, ``j_torque`` and
    ``wake_fraction`` ASSUMED (Wageningen B-series at P/D ~ 1: K_T falls to 0 at J ~ 1.0,
    K_Q at J ~ 1.2; a wake of 0.1 for an open propeller behind a small hull)."""

    diameter_m: float = 0.03
    k_t: float = 0.30
    k_q: float = 0.05
    rho_kgm3: float = 1025.0
    efficiency: float = 0.5
    voltage_v: float = 12.0
    idle_a: float = 0.05
    j_thrust: float = 1.0
    j_torque: float = 1.2
    wake_fraction: float = 0.1
    drive: DriveKind = DriveKind.SPEED
    current_limit_rel: float = 1.5  # the drive's current limit, x the current at full speed

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if name == "drive":
                continue
            low = 0.0 if name in ("idle_a", "wake_fraction") else 1e-12
            if not (math.isfinite(value) and value >= low):
                raise ValueError(f"propeller.{name}: expected a finite number > 0, got {value!r}")
        if self.wake_fraction >= 1.0:
            raise ValueError(f"propeller.wake_fraction: expected < 1, got {self.wake_fraction}")


@dataclass(frozen=True)
class Servo:
    """A deflected actuator (rudder): ``idle_a`` drawn at rest, ``load_a`` more at full
    deflection with full lift (ASSUMED: a hobby-class servo, 0.1 A idle, 1 A loaded)."""

    idle_a: float = 0.1
    load_a: float = 1.0
    voltage_v: float = 6.0

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"servo.{name}: expected a finite number >= 0, got {value!r}")


Actuator = Propeller | Servo


@dataclass(frozen=True)
class StageConstants:
    """The module docstring's constants per actuator, (m,) each (servo rows unused where a
    shaft constant has no meaning, and the reverse)."""

    is_shaft: np.ndarray  # bool
    k_thrust: FloatArray  # k_T, N s^2
    k_torque: FloatArray  # k_Q, N m s^2
    inflow_thrust: FloatArray  # (1 - w) / (J_T D): T = k_T (n|n| - |n| v_axial c_T)
    inflow_torque: FloatArray  # (1 - w) / (J_Q D)
    torque_drive: np.ndarray  # bool
    watts_per_amp: FloatArray  # efficiency V
    idle_a: FloatArray
    load_a: FloatArray  # servos: current at full deflection and lift
    voltage_v: FloatArray
    current_limit_rel: FloatArray

    @classmethod
    def of(cls, actuators: tuple[Actuator, ...]) -> StageConstants:
        shaft = np.array([isinstance(a, Propeller) for a in actuators])
        props = [a if isinstance(a, Propeller) else Propeller() for a in actuators]
        d = np.array([p.diameter_m for p in props])
        rho = np.array([p.rho_kgm3 for p in props])
        wake = np.array([p.wake_fraction for p in props])
        return cls(
            is_shaft=shaft,
            k_thrust=np.array([p.k_t for p in props]) * rho * d**4,
            k_torque=np.array([p.k_q for p in props]) * rho * d**5,
            inflow_thrust=(1.0 - wake) / (np.array([p.j_thrust for p in props]) * d),
            inflow_torque=(1.0 - wake) / (np.array([p.j_torque for p in props]) * d),
            torque_drive=shaft & np.array([p.drive is DriveKind.TORQUE for p in props]),
            watts_per_amp=np.array([p.efficiency * p.voltage_v for p in props]),
            idle_a=np.array([a.idle_a for a in actuators]),
            load_a=np.array([a.load_a if isinstance(a, Servo) else 0.0 for a in actuators]),
            voltage_v=np.array([a.voltage_v for a in actuators]),
            current_limit_rel=np.array([p.current_limit_rel for p in props]),
        )


def shaft_thrust(c: StageConstants, n: FloatArray, v_axial: FloatArray) -> FloatArray:
    """(m,) thrust T (N) at shaft speeds ``n`` (rev/s) and axial in-flow (m/s)."""
    return np.asarray(c.k_thrust * (n * np.abs(n) - np.abs(n) * v_axial * c.inflow_thrust))


def shaft_torque(c: StageConstants, n: FloatArray, v_axial: FloatArray) -> FloatArray:
    """(m,) torque Q (N m) the propeller takes at ``n`` and the in-flow, signed as n."""
    return np.asarray(c.k_torque * (n * np.abs(n) - np.abs(n) * v_axial * c.inflow_torque))


def speed_for(c: StageConstants, thrust: FloatArray) -> FloatArray:
    """(m,) n_ref (rev/s) that gives ``thrust`` (N) in open water: sign(T) sqrt(|T| / k_T)."""
    return np.asarray(np.sign(thrust) * np.sqrt(np.abs(thrust) / c.k_thrust))


def current_of(c: StageConstants, n: FloatArray, torque: FloatArray) -> FloatArray:
    """(m,) supply current (A) of a shaft turning at ``n`` against ``torque``."""
    return np.asarray(2.0 * math.pi * np.abs(n * torque) / c.watts_per_amp + c.idle_a)


def first_order(
    x0: FloatArray, target: FloatArray, tc_s: FloatArray, dt_s: float
) -> tuple[FloatArray, FloatArray]:
    """(end, mid) of dx/dt = (target - x) / T over ``dt_s`` from ``x0``, exact; T = 0
    reaches the target at once."""
    lagged = tc_s > 0.0
    tc = np.where(lagged, tc_s, 1.0)
    a_end = np.where(lagged, np.exp(-dt_s / tc), 0.0)
    a_mid = np.where(lagged, np.exp(-0.5 * dt_s / tc), 0.0)
    return target + (x0 - target) * a_end, target + (x0 - target) * a_mid


def torque_drive_step(
    c: StageConstants,
    n0: FloatArray,
    torque_ref: FloatArray,
    inertia: FloatArray,
    v_axial: FloatArray,
    dt_s: float,
    max_substep_s: float,
) -> tuple[FloatArray, FloatArray]:
    """(end, mid) of I dn/dt = Q_m - Q(n) over ``dt_s`` (semi-implicit Euler in sub-steps:
    the load's quadratic term is taken at the new speed, which keeps it stable)."""
    steps = max(2, 2 * math.ceil(dt_s / max_substep_s / 2))
    h = dt_s / steps
    n, mid = n0.copy(), n0.copy()
    for k in range(steps):
        # Q(n_new) ~ k_Q (n_new |n| - |n| v c_Q): linear in n_new
        a = c.k_torque * np.abs(n)
        drive = torque_ref + c.k_torque * np.abs(n) * v_axial * c.inflow_torque
        n = (inertia * n + h * drive) / (inertia + h * a)
        if k + 1 == steps // 2:
            mid = n.copy()
    return n, mid
