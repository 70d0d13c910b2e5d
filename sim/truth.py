"""The vessel's truth: dynamics, environment, thrusters and sensor in one pure model.

The offline simulator (``ftcap_hil.runtime.offline``) steps a :class:`TruthModel` when a
scenario has a truth (the realistic scenarios); the simulated vessel process (``ftcap-hil
sim``) does not: it steps the plant of ``sim/vessel.py``. The truth is separate from what the
allocator is told (its own plant and thruster geometry): a scenario states both, or a
mismatch on top of a preset. Per step of ``dt_s`` with the commands ``u`` (m,) N held::

    environment at the step's start  -> current (NED), wind + wave wrench (body)
    in-flow per thruster: (nu_xy - R(psi)^T current) . its thrust direction (from B's column)
    thruster bank (drives, propellers, asymmetry, dead band, int14, faults) -> F (m,)
    tau = B_true F_mean                 the wrench the thrusters really produce
    x <- vessel.step_rk4(x, tau, dt, current, tau_env)       x = [north, east, psi, u, v, r]
    sensor(t, x)  -> odometry samples delivered by now (noise, bias, rate, delay, dropouts)
    feedback(t, bank) -> the drives' speed and current reports delivered by now

Pure: no I/O, no clock; every random stream comes from the configured seeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.faults import Truth
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.vessel3dof import Vessel3DOF
from sim.environment import Environment, EnvironmentConfig, HullGeometry
from sim.feedback import FeedbackConfig, FeedbackSample, FeedbackSensor
from sim.sensors import Measurement, OdometrySensor, SensorConfig
from sim.thrusters import BankOutput, ThrusterBank, ThrusterBankConfig


@dataclass(frozen=True)
class TruthConfig:
    """What the vessel really is (module docstring). ``B`` (3, m): the true effectiveness
    of the true thruster geometry; ``environment`` None: calm; ``sensor`` None: the exact
    state at every step; ``substeps``: RK4 substeps per step."""

    vessel: Vessel3DOF
    B: FloatArray
    bank: ThrusterBankConfig
    hull: HullGeometry | None = None
    environment: EnvironmentConfig | None = None
    sensor: SensorConfig | None = None
    substeps: int = 4
    seed: int = 0
    feedback: FeedbackConfig | None = None  # the drives' telemetry (None: none reported)

    def __post_init__(self) -> None:
        if self.B.shape != (3, self.bank.m):
            raise ValueError(f"truth: B has shape {self.B.shape}, the bank {self.bank.m} thrusters")
        if self.environment is not None and self.hull is None:
            raise ValueError("truth: an environment needs the hull geometry")
        if self.substeps < 1:
            raise ValueError(f"truth.substeps: expected >= 1, got {self.substeps}")


@dataclass(frozen=True)
class TruthStep:
    """What one step did: the state at its end (t_s), the forces and the wrench that acted
    (means over the step), the environment at its start, the thruster bank's output."""

    t_s: float
    x: FloatArray
    produced: FloatArray
    tau: FloatArray
    current_ned: FloatArray
    tau_env: FloatArray
    bank: BankOutput
    measurements: list[Measurement] = field(default_factory=list)
    feedback: list[FeedbackSample] = field(default_factory=list)


class TruthModel:
    """See the module docstring. ``x0``: [north, east, psi, u, v, r]."""

    def __init__(self, config: TruthConfig, x0: FloatArray, t0_s: float = 0.0) -> None:
        self.config = config
        self._x = np.array(x0, dtype=np.float64)
        self._t = float(t0_s)
        self._bank = ThrusterBank(config.bank)
        xy = config.B[:2]
        norm = np.linalg.norm(xy, axis=0)
        self._directions = xy / np.where(norm > 0.0, norm, 1.0)  # (2, m) unit thrust directions
        env = config.environment
        self._env = None
        if env is not None and config.hull is not None:
            environment = Environment(env, config.hull, seed=config.seed)
            self._env = None if environment.calm else environment
        self._sensor = None if config.sensor is None else OdometrySensor(config.sensor)
        fb = config.feedback
        self._feedback = None if fb is None else FeedbackSensor(fb, config.bank.m)

    @property
    def t_s(self) -> float:
        return self._t

    @property
    def x(self) -> FloatArray:
        return self._x.copy()

    @property
    def shaft_thrust(self) -> FloatArray:
        """(m,) what each healthy shaft would give now (for a stuck thruster's held force)."""
        return self._bank.shaft_thrust

    def start(self) -> list[Measurement]:
        """The odometry delivered at the start (before the first step)."""
        return self._measure()

    def step(self, u: FloatArray, truth: Truth, dt_s: float) -> TruthStep:
        """Advance ``dt_s`` with commands ``u`` (m,) N and the faults ``truth`` held."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s: expected a finite positive step, got {dt_s}")
        cfg = self.config
        current, tau_env = np.zeros(2), np.zeros(3)
        if self._env is not None:
            sample = self._env.sample(self._t, self._x)
            current, tau_env = sample.current_ned, sample.tau_env
        out = self._bank.step(u, truth, dt_s, self._axial_inflow(current))
        tau = cfg.B @ out.produced_mean
        cur = current if self._env is not None else None
        env = tau_env if self._env is not None else None
        # psi stays continuous (the records' convention); a shell that publishes wraps it
        self._x = cfg.vessel.step_rk4(self._x, tau, dt_s, cfg.substeps, cur, env)
        self._t += dt_s
        measured = self._measure()
        fb = [] if self._feedback is None else self._feedback.step(self._t, out)
        return TruthStep(
            self._t, self._x.copy(), out.produced_mean, tau, current, tau_env, out, measured, fb
        )

    def _axial_inflow(self, current_ned: FloatArray) -> FloatArray:
        """(m,) m/s: the water's speed through each thruster along its thrust direction."""
        psi = self._x[2]
        c, s = math.cos(psi), math.sin(psi)
        cur_body = np.array([c * current_ned[0] + s * current_ned[1],
                             -s * current_ned[0] + c * current_ned[1]])  # fmt: skip
        return np.asarray(self._directions.T @ (self._x[3:5] - cur_body))

    def _measure(self) -> list[Measurement]:
        if self._sensor is None:
            return [Measurement(self._t, self._t, self._x[:3].copy(), self._x[3:].copy())]
        return self._sensor.step(self._t, self._x)
