"""ESC telemetry of a simulated thruster: shaft speed and current from the force it produces.

A fixed-pitch propeller in open water (Fossen, ch. 9), n in rev/s, D the diameter::

    thrust  F = K_T rho D^4 n^2          ->  rpm = sign(F) k_rpm sqrt(|F|),
                                             k_rpm = 60 / sqrt(K_T rho D^4)
    power   P = 2 pi n Q = 2 pi K_Q rho D^5 n^3
              = k_p |F|^1.5,                 k_p = 2 pi K_Q / (K_T^1.5 sqrt(rho) D)
    current I = P / (efficiency V) + idle = k_i |F|^1.5 + idle_a

Defaults (``EscModel.from_propeller()``): a 30 mm model-boat propeller, K_T = 0.30,
K_Q = 0.05, sea water rho = 1025 kg/m^3, electrical-to-shaft efficiency 0.5 on a 12 V
supply, 0.05 A drawn by the idle ESC. That gives k_rpm ~ 3800 rpm/sqrt(N) (about 1200 rpm
at the paper's 0.1 N limit) and k_i ~ 0.33 A/N^1.5 (about 0.06 A at 0.1 N, idle included).

A thruster that does not respond to its command (delta = 0: OFF, STUCK, WEAK 0) reports
0 rpm and the idle current whatever bias it still produces: its ESC sees a stalled motor,
so ESC telemetry alone never reveals a stuck thruster's bias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray


@dataclass(frozen=True)
class EscModel:
    """rpm = sign(F) k_rpm sqrt(|F|) (F in N); current_a = k_i |F|^1.5 + idle_a (A)."""

    k_rpm: float  # rpm per sqrt(N)
    k_i: float  # A per N^1.5
    idle_a: float = 0.05
    voltage_v: float = 12.0

    def __post_init__(self) -> None:
        for name in ("k_rpm", "k_i", "idle_a", "voltage_v"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"esc.{name}: expected a finite number >= 0, got {value!r}")

    @classmethod
    def from_propeller(
        cls,
        diameter_m: float = 0.03,
        k_t: float = 0.30,
        k_q: float = 0.05,
        rho_kgm3: float = 1025.0,
        efficiency: float = 0.5,
        voltage_v: float = 12.0,
        idle_a: float = 0.05,
    ) -> EscModel:
        """Constants of the module docstring from open-water propeller coefficients."""
        k_rpm = 60.0 / math.sqrt(k_t * rho_kgm3 * diameter_m**4)
        k_p = 2.0 * math.pi * k_q / (k_t**1.5 * math.sqrt(rho_kgm3) * diameter_m)
        return cls(k_rpm, k_p / (efficiency * voltage_v), idle_a, voltage_v)

    def rpm(self, force: FloatArray, responding: BoolArray) -> FloatArray:
        """(m,) signed shaft speed in rpm; 0 where ``responding`` is False."""
        rpm = np.sign(force) * self.k_rpm * np.sqrt(np.abs(force))
        return np.where(responding, rpm, 0.0)

    def current_a(self, force: FloatArray, responding: BoolArray) -> FloatArray:
        """(m,) supply current in A; the idle current where ``responding`` is False."""
        load = self.k_i * np.abs(force) ** 1.5
        return np.where(responding, load, 0.0) + self.idle_a

    def statuses(
        self, force: FloatArray, responding: BoolArray, report: BoolArray
    ) -> list[EscStatus]:
        """One ``EscStatus`` per thruster where ``report`` is True (silent ESCs are skipped)."""
        rpm = self.rpm(force, responding)
        current = self.current_a(force, responding)
        return [
            EscStatus(int(i), float(rpm[i]), float(current[i]), self.voltage_v)
            for i in np.flatnonzero(report)
        ]


DEFAULT_ESC = EscModel.from_propeller()
