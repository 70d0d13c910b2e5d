"""What the operator does not know, drawn per seed: a realistic scenario's ``[uncertainty]``.

An operator knows the vessel's model to within its identification error and each
thruster's and sensor's data sheet, not the truth. With ``[uncertainty]`` the truth stays
the preset; per seed (``[scenario] seed``) the allocator's model and the truth's
departures from the data sheets are drawn uniformly within the stated half-ranges::

    [uncertainty]
    mass = 0.2               # the allocator's M_RB (mass, inertia) x (1 + U(-0.2, 0.2))
    added_mass = 0.2         # its added-mass derivatives x (1 + U(-0.2, 0.2))
    damping = 0.3            # its damping coefficients x (1 + U(-0.3, 0.3))
    angle_deg = 5.0          # `angled` thrusters (chosen at random) turned by +-U(0, 5) deg
    angled = 1
    thrust_coefficient = 0.1 # each true thruster's thrust per commanded N x (1 + U(-0.1, 0.1))
    time_constant = 0.25     # each true drive's lag x (1 + U(-0.25, 0.25)) of its data sheet
    noise = 0.5              # the true sensor noise per axis x (1 + U(-0.5, 0.5)) of its sheet
    sensor_bias_rel = 0.5    # a drifting sensor bias of U(0, 0.5) x the noise std
    delay_s = 0.2            # a sensor delay of U(0, 0.2) s
    dropout_p = 0.05         # a dropout probability of U(0, 0.05)
    sea_state = 0.2          # the true Hs and Tp x (1 + U(-0.2, 0.2)) of the stated levels

The estimator is then told the data sheets (the preset's noise levels and time constants),
the sea state as stated in the scenario (a forecast: the wave model is sized on the stated
Hs and Tp, on another realisation of that sea) and the drawn model. Every half-range is 0
(nothing drawn) unless given; the draws come from their own random stream of the seed, so
one seed gives the same vessel in every mode. Pure: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ftcap_hil.config.tables import Table

#: Half-range keys: the value is a fraction (or seconds, a probability) >= 0.
RANGES = (
    "mass", "added_mass", "damping", "angle_deg", "thrust_coefficient", "time_constant",
    "noise", "sensor_bias_rel", "delay_s", "dropout_p", "sea_state",
)  # fmt: skip
ADDED_MASS = ("X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot")


@dataclass(frozen=True)
class Uncertainty:
    """The half-ranges of ``[uncertainty]`` (module docstring); all 0: nothing drawn."""

    mass: float = 0.0
    added_mass: float = 0.0
    damping: float = 0.0
    angle_deg: float = 0.0
    angled: int = 1
    thrust_coefficient: float = 0.0
    time_constant: float = 0.0
    noise: float = 0.0
    sensor_bias_rel: float = 0.0
    delay_s: float = 0.0
    dropout_p: float = 0.0
    sea_state: float = 0.0

    @classmethod
    def read(cls, t: Table) -> Uncertainty:
        """From the ``[uncertainty]`` table (strict: unknown keys are errors)."""
        his = {"mass": 0.9, "added_mass": 0.9, "damping": 1.0, "angle_deg": 45.0,
               "thrust_coefficient": 0.9, "time_constant": 0.9, "noise": 0.9,
               "dropout_p": 1.0, "sea_state": 0.9}  # fmt: skip
        values = {k: t.number(k, 0.0, lo=0.0, hi=his.get(k)) for k in RANGES}
        angled = t.integer("angled", 1, lo=0)
        t.finish()
        return cls(**values, angled=angled)

    @property
    def any(self) -> bool:
        """Whether anything is drawn."""
        return any(getattr(self, f.name) > 0.0 for f in fields(self) if f.name != "angled")

    def draw(self, seed: int, m: int) -> Drawn:
        """This seed's draw for a vessel of ``m`` thrusters (module docstring)."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))

        def rel(r: float, n: int | None = None) -> float | np.ndarray:
            return 1.0 + rng.uniform(-r, r, n)

        turned = rng.choice(m, size=min(self.angled, m), replace=False)
        angles = {int(i): float(rng.choice([-1.0, 1.0]) * rng.uniform(0.0, self.angle_deg))
                  for i in turned}  # fmt: skip
        return Drawn(
            mass=float(rel(self.mass)),
            added_mass=float(rel(self.added_mass)),
            damping=float(rel(self.damping)),
            angle_deg={i: a for i, a in angles.items() if a != 0.0},
            thrust_gain=np.asarray(rel(self.thrust_coefficient, m)),
            lag_factor=np.asarray(rel(self.time_constant, m)),
            noise_factor=np.asarray(rel(self.noise, 6)),
            sensor_bias_rel=float(rng.uniform(0.0, self.sensor_bias_rel)),
            delay_s=float(rng.uniform(0.0, self.delay_s)),
            dropout_p=float(rng.uniform(0.0, self.dropout_p)),
            hs_factor=float(rel(self.sea_state)),
            tp_factor=float(rel(self.sea_state)),
        )


@dataclass(frozen=True)
class Drawn:
    """One seed's draw: the allocator's model factors (``mass``, ``added_mass``,
    ``damping``: multipliers; ``angle_deg``: thruster index -> degrees) and the truth's
    departures from the data sheets (per thruster ``thrust_gain``, ``lag_factor``; per
    sensor axis ``noise_factor``; the sensor's bias level, delay and dropouts; the sea's
    ``hs_factor`` and ``tp_factor``)."""

    mass: float
    added_mass: float
    damping: float
    angle_deg: dict[int, float]
    thrust_gain: np.ndarray
    lag_factor: np.ndarray
    noise_factor: np.ndarray
    sensor_bias_rel: float
    delay_s: float
    dropout_p: float
    hs_factor: float
    tp_factor: float

    def describe(self) -> str:
        """One line for logs and replays: what this seed's vessel is."""
        angles = ", ".join(f"#{i + 1} {a:+.1f} deg" for i, a in sorted(self.angle_deg.items()))
        return (
            f"model mass x{self.mass:.3f}, added mass x{self.added_mass:.3f}, damping "
            f"x{self.damping:.3f}{'; ' + angles if angles else ''}; truth thrust x"
            f"{_span(self.thrust_gain)}, lag x{_span(self.lag_factor)}, noise x"
            f"{_span(self.noise_factor)}, bias {self.sensor_bias_rel:.2f} sigma, delay "
            f"{self.delay_s:.3f} s, dropouts {self.dropout_p:.3f}, Hs x{self.hs_factor:.3f}, "
            f"Tp x{self.tp_factor:.3f}"
        )


def _span(x: np.ndarray) -> str:
    lo, hi = float(np.min(x)), float(np.max(x))
    return f"{lo:.3f}" if math.isclose(lo, hi) else f"{lo:.3f}-{hi:.3f}"
