"""A bank of m actuators: commands (N) -> produced forces over time, and what their drives
measure (shaft speed or deflection, current).

Per actuator ``i``, per step of ``dt_s`` with the faults (``Truth``) held over the step::

    q   = clip(rint(u * 8191 / u_max_abs), -8191, 8191) * u_max_abs / 8191   CAN int14 levels
    q   = 0                              if |q| <= deadband_n       (the ESC does not start)
    c   = g_fwd q  if q >= 0  else  g_rev q        asymmetric thrust of a fixed-pitch propeller

``c`` is the force a healthy actuator gives in steady state in open water. A **shaft**
(:class:`~sim.shaft.Propeller`) turns n_ref = sign(c) sqrt(|c| / k_T) through its drive
with time constant ``T`` and gives T = k_T (n|n| - |n| V_a ...) against the in-flow; a
**servo** (:class:`~sim.shaft.Servo`, rudders) deflects towards c / full_force_n. The
produced force is ``F = hull T + f`` (``f`` a force outside the actuator). Physics in
:mod:`sim.shaft`; with no lag, no in-flow and healthy actuators ``F = c + f`` exactly, and
:meth:`ThrusterBankConfig.ideal` gives ``F = delta u + f`` as ``sim/vessel.py`` does.

Each fault's :class:`~ftcap_hil.core.faults.Cause` sets factors on the drive and the
propeller so that, in steady state in open water, the share of the force reaching the hull
is the fault's ``delta`` whatever the cause and the drive kind (:func:`signature`)::

    cause           speed-drive shaft                   torque-drive shaft  servo
    weak-motor      n = sqrt(delta) n_ref               torque x delta      deflection x delta
    lost-blade      K_T, K_Q x delta                    K_T x delta^2, K_Q x delta   lift x delta
    fouled          K_T x delta, K_Q x (1 + g (1-d))    K_T x delta K_Q             lift x delta
    drive-dead      not driven: n -> 0 with T, idle current, reports 0 rpm
    power-lost      not driven, reports nothing
    held            not driven by the command, reports nothing; its force is the bias
    jammed          n = 0 at once, current at the drive's limit under command
    stuck           the state (speed, deflection) frozen at the onset
    telemetry-lost  healthy, reports nothing
    ventilation     healthy between bursts; in a burst K_T x (1 - loss), K_Q x (1 - 0.8 loss)
    hull-loss       healthy shaft, hull x delta

Ventilation bursts arrive as a Poisson process of ``ventilation.rate_hz`` per actuator and
last an exponential time of mean ``ventilation.mean_s`` (seeded). Pure, vectorised, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.faults import Cause, Truth
from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray
from sim.shaft import (
    Actuator,
    Propeller,
    Servo,
    StageConstants,
    current_of,
    first_order,
    shaft_thrust,
    shaft_torque,
    speed_for,
    torque_drive_step,
)

DEFAULT_PROPELLER = Propeller()
RAW_MAX = 8191  # esc.RawCommand int14, kept symmetric: [-8191, 8191]
__all__ = ["Propeller", "Servo", "ThrusterBank", "ThrusterBankConfig", "Ventilation"]


@dataclass(frozen=True)
class Ventilation:
    """Bursts of lost load (ASSUMED after Smogeli 2006: 30-80 % thrust loss for fractions
    of a second to seconds when a propeller near the surface draws air in waves)."""

    rate_hz: float = 0.3
    mean_s: float = 0.5
    loss: float = 0.6

    def __post_init__(self) -> None:
        if not (self.rate_hz >= 0.0 and self.mean_s > 0.0 and 0.0 <= self.loss < 1.0):
            raise ValueError(f"thrusters.ventilation: bad values {self}")


def _per_thruster(value: float | Sequence[float] | FloatArray, m: int, name: str) -> FloatArray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ValueError(f"thrusters.{name}: expected {m} finite values >= 0, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class ThrusterBankConfig:
    """Per-actuator (m,) constants of the module docstring; build with :meth:`create`.
    ``full_force_n``: a shaft's force at its top speed (its current limit and a torque
    drive's inertia scale with it), a servo's at full deflection."""

    time_constant_s: FloatArray  # T, s (0: no lag)
    forward_gain: FloatArray  # g_fwd, thrust per commanded N for q >= 0 (> 0)
    reverse_gain: FloatArray  # g_rev, for q < 0 (> 0; 0.6-0.8 for fixed pitch)
    deadband_n: FloatArray  # N, commands with |q| <= deadband_n give no thrust
    u_max_abs: FloatArray | None  # N at raw +-8191; None: no quantisation
    actuators: tuple[Actuator, ...]
    full_force_n: FloatArray
    fouled_torque_gain: float = 1.0
    ventilation: Ventilation = field(default_factory=Ventilation)
    seed: int = 0

    @classmethod
    def create(
        cls,
        m: int,
        time_constant_s: float | Sequence[float] = 0.0,
        forward_gain: float | Sequence[float] = 1.0,
        reverse_gain: float | Sequence[float] = 1.0,
        deadband_n: float | Sequence[float] = 0.0,
        u_max_abs: float | Sequence[float] | None = None,
        actuator: Actuator | Sequence[Actuator] = DEFAULT_PROPELLER,
        full_force_n: float | Sequence[float] | None = None,
        fouled_torque_gain: float = 1.0,
        ventilation: Ventilation = Ventilation(),
        seed: int = 0,
    ) -> ThrusterBankConfig:
        """Validate and broadcast scalars to the m actuators; ValueError names the field.
        ``full_force_n`` defaults to ``u_max_abs`` (1 N without one)."""
        gains = [_per_thruster(g, m, n) for g, n in ((forward_gain, "forward_gain"),
                                                     (reverse_gain, "reverse_gain"))]  # fmt: skip
        if any(np.any(g <= 0.0) for g in gains):
            raise ValueError(f"thrusters: gains must be > 0, got {[g.tolist() for g in gains]}")
        u_max = None if u_max_abs is None else _per_thruster(u_max_abs, m, "u_max_abs")
        if u_max is not None and np.any(u_max <= 0.0):
            raise ValueError(f"thrusters.u_max_abs: must be > 0, got {u_max.tolist()}")
        acts = (actuator,) * m if isinstance(actuator, Propeller | Servo) else tuple(actuator)
        if len(acts) != m:
            raise ValueError(f"thrusters.actuator: expected 1 or {m} actuators, got {len(acts)}")
        full = u_max if full_force_n is None else _per_thruster(full_force_n, m, "full_force_n")
        full = np.ones(m) if full is None else full
        if np.any(full <= 0.0):
            raise ValueError(f"thrusters.full_force_n: must be > 0, got {full.tolist()}")
        if not (math.isfinite(fouled_torque_gain) and fouled_torque_gain >= 0.0):
            raise ValueError(
                f"thrusters.fouled_torque_gain: expected >= 0, got {fouled_torque_gain}"
            )
        return cls(
            _per_thruster(time_constant_s, m, "time_constant_s"), gains[0], gains[1],
            _per_thruster(deadband_n, m, "deadband_n"), u_max, acts, full,
            fouled_torque_gain, ventilation, seed,
        )  # fmt: skip

    @classmethod
    def ideal(cls, m: int) -> ThrusterBankConfig:
        """No lag, no asymmetry, no dead band, no quantisation: ``F = delta u + f``."""
        return cls.create(m)

    @property
    def m(self) -> int:
        return int(self.time_constant_s.shape[0])


def quantise(u: FloatArray, u_max_abs: FloatArray) -> FloatArray:
    """(m,) forces in N -> the nearest of the 16383 int14 levels over +-u_max_abs (N),
    clipped at the ends; rounding half-to-even, error at most u_max_abs / 16382."""
    raw = np.minimum(np.maximum(np.rint(u * (RAW_MAX / u_max_abs)), -RAW_MAX), RAW_MAX)
    return np.asarray(raw * (u_max_abs / RAW_MAX))


@dataclass(frozen=True)
class Signature:
    """Per actuator (m,): the factors of the module docstring's table for one truth."""

    drive: FloatArray  # weak motor: speed factor (speed drive) / torque factor (torque drive)
    k_t: FloatArray  # thrust (or lift) coefficient factor
    k_q: FloatArray  # torque coefficient factor (shafts)
    hull: FloatArray  # share of the actuator's force that reaches the hull
    driven: BoolArray  # False: drive dead, power lost, jammed
    jammed: BoolArray
    frozen: BoolArray  # stuck: the state holds
    reports: BoolArray
    ventilating: BoolArray


def signature(
    causes: Sequence[Cause], delta: FloatArray, torque_drive: BoolArray, is_shaft: BoolArray,
    fouled_torque_gain: float = 1.0,
) -> Signature:  # fmt: skip
    """The module docstring's factors of each actuator, (m,) each."""
    d = np.minimum(np.maximum(np.asarray(delta, dtype=np.float64), 0.0), 1.0)
    kind = np.array([c.value for c in causes])
    weak, lost, fouled = kind == "weak-motor", kind == "lost-blade", kind == "fouled"
    k_q = np.where(fouled, 1.0 + fouled_torque_gain * (1.0 - d), np.where(lost, d, 1.0))
    k_q = np.where(is_shaft, k_q, 1.0)
    lift = np.where(lost | fouled, d, 1.0)
    k_t = np.where(torque_drive & lost, d * d, np.where(torque_drive & fouled, d * k_q, lift))
    drive = np.where(weak, np.where(torque_drive | ~is_shaft, d, np.sqrt(d)), 1.0)
    held = kind == "held"  # its force is the fault's bias, outside the bank
    off = (kind == "drive-dead") | (kind == "power-lost") | (kind == "jammed") | held
    silent = (kind == "power-lost") | (kind == "telemetry-lost") | held
    return Signature(
        drive, k_t, k_q, np.where(kind == "hull-loss", d, 1.0), ~off, kind == "jammed",
        kind == "stuck", ~silent, kind == "ventilation",
    )  # fmt: skip


@dataclass(frozen=True)
class BankOutput:
    """One step's result, (m,) each: forces in N, the drives' state at the end of the step."""

    produced: FloatArray  # F = hull T + f at the end of the step
    produced_mean: FloatArray  # F averaged over the step (Simpson on start, middle, end)
    target: FloatArray  # c: the force the command asks of a healthy actuator
    speed: FloatArray  # shafts: rev/s; servos: deflection, fraction of full
    torque: FloatArray  # shafts: N m (0 for servos)
    current_a: FloatArray  # supply current, A
    reports: BoolArray  # False: this drive sends nothing
    voltage_v: FloatArray
    is_shaft: BoolArray

    @property
    def rpm(self) -> FloatArray:
        """Signed shaft speed in rpm (NaN for servos)."""
        return np.asarray(np.where(self.is_shaft, 60.0 * self.speed, math.nan))


class ThrusterBank:
    """The m actuators' state: shaft speed (rev/s) or deflection; module docstring."""

    def __init__(self, config: ThrusterBankConfig, h0: FloatArray | None = None) -> None:
        self.config = config
        self._c = c = StageConstants.of(config.actuators)
        top = speed_for(c, config.full_force_n)  # rev/s at the full force
        # torque drive: I = 2 k_Q (n_max / 2) T  (T at half the top speed)
        self._inertia = c.k_torque * top * config.time_constant_s
        self._limit_a = c.current_limit_rel * current_of(c, top, c.k_torque * top**2)
        self._state = np.zeros(self.m)
        if h0 is not None:
            self._state = self._state_for(np.array(h0, dtype=np.float64).reshape(self.m))
        self._rng = np.random.default_rng(config.seed)
        self._burst_left = np.zeros(self.m)  # s of ventilation burst still to come

    @property
    def m(self) -> int:
        return self.config.m

    def _state_for(self, force: FloatArray) -> FloatArray:
        """The steady state of a healthy actuator giving ``force`` in open water."""
        servo = force / self.config.full_force_n
        return np.asarray(np.where(self._c.is_shaft, speed_for(self._c, force), servo))

    def _open_water(self, state: FloatArray) -> FloatArray:
        """The force a healthy actuator gives at ``state`` in open water, N."""
        shaft = self._c.k_thrust * state * np.abs(state)
        return np.asarray(np.where(self._c.is_shaft, shaft, state * self.config.full_force_n))

    @property
    def shaft_thrust(self) -> FloatArray:
        """(m,) the force each actuator's state gives on a healthy propeller in open water
        now, N (a stuck actuator's held force)."""
        return self._open_water(self._state)

    def target(self, u: FloatArray) -> FloatArray:
        """(m,) c of the module docstring for commands ``u`` (m,) N, before faults."""
        cfg = self.config
        q = np.asarray(u, dtype=np.float64)
        if q.shape != (self.m,) or not np.all(np.isfinite(q)):
            raise ValueError(f"thruster commands: expected {self.m} finite forces, got {q}")
        if cfg.u_max_abs is not None:
            q = quantise(q, cfg.u_max_abs)
        q = np.where(np.abs(q) <= cfg.deadband_n, 0.0, q)
        return np.asarray(np.where(q >= 0.0, cfg.forward_gain * q, cfg.reverse_gain * q))

    def step(
        self, u: FloatArray, truth: Truth, dt_s: float, v_axial: FloatArray | None = None
    ) -> BankOutput:
        """Advance ``dt_s`` (s) with commands ``u`` (m,) N and ``truth`` held over the step;
        ``v_axial`` (m,) m/s: the water's speed through each actuator along its thrust
        direction (None: open water at rest)."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s: expected a finite positive step, got {dt_s}")
        c, cfg = self._c, self.config
        va = np.zeros(self.m) if v_axial is None else np.asarray(v_axial, dtype=np.float64)
        sig = signature(
            truth.causes(), truth.delta, c.torque_drive, c.is_shaft, cfg.fouled_torque_gain
        )
        target = self.target(u)
        ref = self._state_for(target)
        start = self._state
        end, mid = self._advance(start, ref, sig, va, dt_s)
        start = np.where(cfg.time_constant_s > 0.0, start, mid)  # no lag: at once
        self._state = end
        vent = self._ventilation(sig.ventilating, dt_s)
        kt, kq = (
            sig.k_t * (1.0 - cfg.ventilation.loss * vent),
            sig.k_q * (1.0 - 0.8 * cfg.ventilation.loss * vent),
        )
        forces = [self._force(s, va, kt, sig.hull) for s in (start, mid, end)]
        mean = (forces[0] + 4.0 * forces[1] + forces[2]) / 6.0
        torque = np.where(c.is_shaft, kq * shaft_torque(c, end, va), 0.0)
        return BankOutput(
            forces[2] + truth.f, mean + truth.f, target, end, torque,
            self._current(end, torque, ref, kt, sig), sig.reports, c.voltage_v.copy(),
            c.is_shaft.copy(),
        )  # fmt: skip

    def _advance(
        self, s0: FloatArray, ref: FloatArray, sig: Signature, va: FloatArray, dt_s: float
    ) -> tuple[FloatArray, FloatArray]:
        """(end, mid) states over the step under the drive's dynamics and the faults."""
        c, tc = self._c, self.config.time_constant_s
        speed_ref = np.where(c.torque_drive, ref, ref * sig.drive)
        goal = np.where(sig.driven, speed_ref, 0.0)
        end, mid = first_order(s0, goal, tc, dt_s)
        torque = c.torque_drive & (tc > 0.0)  # without inertia a torque drive is at speed
        if np.any(torque):
            q_ref = np.where(sig.driven, sig.drive * c.k_torque * ref * np.abs(ref), 0.0)
            inertia = np.where(torque, self._inertia, 1.0)
            load = self._c.k_torque * sig.k_q
            tend, tmid = _torque_step(c, s0, q_ref, inertia, load, va, dt_s, tc)
            end, mid = np.where(torque, tend, end), np.where(torque, tmid, mid)
        frozen = sig.frozen | sig.jammed  # a jammed shaft stops, a jammed servo holds
        hold = np.where(sig.jammed & c.is_shaft, 0.0, s0)
        return np.where(frozen, hold, end), np.where(frozen, hold, mid)

    def _force(self, s: FloatArray, va: FloatArray, kt: FloatArray, hull: FloatArray) -> FloatArray:
        c = self._c
        shaft = shaft_thrust(c, s, va)
        force = np.where(c.is_shaft, shaft, s * self.config.full_force_n)
        return np.asarray(hull * kt * force)

    def _current(
        self, s: FloatArray, torque: FloatArray, ref: FloatArray, kt: FloatArray,
        sig: Signature,
    ) -> FloatArray:  # fmt: skip
        """Supply current (A): the shaft's power, a jammed drive's limit under command, a
        servo's hinge load."""
        c = self._c
        shaft = current_of(c, s, torque)
        top = speed_for(c, self.config.full_force_n)
        pull = np.minimum(np.abs(ref) / (0.05 * top), 1.0)  # a blocked speed loop saturates
        shaft = np.where(sig.jammed, c.idle_a + (self._limit_a - c.idle_a) * pull, shaft)
        shaft = np.where(sig.driven | sig.jammed, shaft, c.idle_a)
        servo = c.idle_a + c.load_a * np.where(sig.jammed, 1.0, np.abs(s) * sig.driven * kt)
        return np.asarray(np.where(c.is_shaft, shaft, servo))

    def _ventilation(self, active: BoolArray, dt_s: float) -> FloatArray:
        """(m,) share of the step each actuator spends in a burst (its own draws)."""
        v = self.config.ventilation
        share = np.zeros(self.m)
        if not np.any(active) or v.rate_hz <= 0.0:
            self._burst_left[:] = 0.0
            return share
        draw = self._rng.random(self.m) < v.rate_hz * dt_s
        starts = active & (self._burst_left <= 0.0) & draw
        length = self._rng.exponential(v.mean_s, self.m)
        self._burst_left = np.where(starts, length, self._burst_left)
        share = np.where(active, np.minimum(self._burst_left, dt_s) / dt_s, 0.0)
        self._burst_left = np.where(active, np.maximum(self._burst_left - dt_s, 0.0), 0.0)
        return share


def _torque_step(
    c: StageConstants, s0: FloatArray, q_ref: FloatArray, inertia: FloatArray,
    load: FloatArray, va: FloatArray, dt_s: float, tc: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The torque drives' (end, mid) with the faults' K_Q factor on the load."""
    shaped = StageConstants(**{**vars(c), "k_torque": load})
    sub = float(np.min(np.where(tc > 0.0, tc, np.inf))) / 8.0
    return torque_drive_step(shaped, s0, q_ref, inertia, va, dt_s, sub)


def esc_statuses(out: BankOutput) -> list[EscStatus]:
    """One ``EscStatus`` per reporting shaft of a step's output (servos and silent ones
    skipped)."""
    return [
        EscStatus(int(i), float(out.rpm[i]), float(out.current_a[i]), float(out.voltage_v[i]))
        for i in np.flatnonzero(out.reports & out.is_shaft)
    ]
