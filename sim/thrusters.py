"""A bank of m thrusters: commands (N) -> produced forces over time, and their ESC telemetry.

Per thruster ``i``, per step of ``dt_s`` with the faults (``Truth``) held over the step::

    q   = clip(rint(u * 8191 / u_max_abs), -8191, 8191) * u_max_abs / 8191   CAN int14 levels
    q   = 0                              if |q| <= deadband_n       (the ESC does not start)
    c   = g_fwd q  if q >= 0  else  g_rev q        asymmetric thrust of a fixed-pitch propeller
    c   = 0                              if the ESC is dead (the shaft is not driven)
    H  <- c + (H - c) exp(-dt/T)         first-order lag dH/dt = (c - H)/T, exact over the step
    H  <- H                              while ``truth.stuck``: frozen at its onset value
    F   = delta H + f                    produced force (``f``: a force outside the propeller)

``H`` is the thrust the shaft would give on a healthy propeller; ``u_max_abs = None`` skips
the quantisation, ``T = 0`` makes the lag instantaneous. With every option off
(:meth:`ThrusterBankConfig.ideal`) ``F = delta u + f`` exactly, as in ``sim/vessel.py``.

ESC telemetry follows the real shaft through the open-water propeller (Fossen, ch. 9)::

    n_cmd = sign(H) sqrt(|H| / (g_dir K_T rho D^4))       shaft speed the command asks, rev/s
    n     = s n_cmd                                         actual speed
    T     = k_T g_dir K_T rho D^4 n^2 = delta H             thrust: k_T s^2 = delta
    Q     = k_Q K_Q rho D^5 n^2                             torque (K_Q the same both ways)
    rpm   = 60 n,  current = 2 pi |n| Q / (efficiency V) + idle_a

The factors (s, k_T, k_Q) come from each thruster's :class:`ThrusterFault` and delta
(:func:`signature`), so each fault kind has its own signature at the same command: a weak
motor turns slower (s = sqrt(delta)); a fouled propeller turns at speed with K_T down and
K_Q up (more current, less thrust); a lost blade turns at speed with K_T and K_Q down
together; a stuck thruster reports the rpm of the force it holds; a dead ESC reports
nothing, or 0 rpm and its idle current (``DeadEsc.ZERO``). A healthy thruster with unit
gains gives exactly ``sim/esc_model.py``'s rpm and current. Pure, vectorised, no clock.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.faults import Truth
from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray, IntArray

RAW_MAX = 8191  # esc.RawCommand int14, kept symmetric: [-8191, 8191]


class ThrusterFault(enum.Enum):
    """The physical cause behind a thruster's (delta, stuck); it shapes the ESC telemetry."""

    HEALTHY = "healthy"
    WEAK_MOTOR = "weak-motor"  # the shaft turns slower: s = sqrt(delta)
    FOULED = "fouled"  # s = 1, K_T * delta, K_Q * (1 + fouled_torque_gain (1 - delta))
    LOST_BLADE = "lost-blade"  # s = 1, K_T * delta, K_Q * delta
    STUCK = "stuck"  # output frozen; reports the held force's rpm
    DEAD_ESC = "dead-esc"  # not driven, no telemetry (or 0 rpm)


class DeadEsc(enum.Enum):
    """What a dead ESC reports."""

    SILENT = "silent"  # nothing
    ZERO = "zero"  # 0 rpm and the idle current


@dataclass(frozen=True)
class Propeller:
    """Open-water propeller and drive of one thruster (defaults: ``sim/esc_model.py``'s
    30 mm model-boat propeller on a 12 V supply)."""

    diameter_m: float = 0.03
    k_t: float = 0.30
    k_q: float = 0.05
    rho_kgm3: float = 1025.0
    efficiency: float = 0.5
    voltage_v: float = 12.0
    idle_a: float = 0.05

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            low = 0.0 if name == "idle_a" else 1e-12
            if not (math.isfinite(value) and value >= low):
                raise ValueError(f"propeller.{name}: expected a finite number > 0, got {value!r}")


def _per_thruster(value: float | Sequence[float] | FloatArray, m: int, name: str) -> FloatArray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ValueError(f"thrusters.{name}: expected {m} finite values >= 0, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class ThrusterBankConfig:
    """Per-thruster (m,) constants of the module docstring; build with :meth:`create`."""

    time_constant_s: FloatArray  # T, s (0: no lag)
    forward_gain: FloatArray  # g_fwd, thrust per commanded N for q >= 0 (> 0)
    reverse_gain: FloatArray  # g_rev, for q < 0 (> 0; 0.6-0.8 for fixed pitch)
    deadband_n: FloatArray  # N, commands with |q| <= deadband_n give no thrust
    u_max_abs: FloatArray | None  # N at raw +-8191; None: no quantisation
    propellers: tuple[Propeller, ...]
    fouled_torque_gain: float = 1.0
    dead_esc: DeadEsc = DeadEsc.SILENT

    @classmethod
    def create(
        cls,
        m: int,
        time_constant_s: float | Sequence[float] = 0.0,
        forward_gain: float | Sequence[float] = 1.0,
        reverse_gain: float | Sequence[float] = 1.0,
        deadband_n: float | Sequence[float] = 0.0,
        u_max_abs: float | Sequence[float] | None = None,
        propeller: Propeller | Sequence[Propeller] = Propeller(),
        fouled_torque_gain: float = 1.0,
        dead_esc: DeadEsc = DeadEsc.SILENT,
    ) -> ThrusterBankConfig:
        """Validate and broadcast scalars to the m thrusters; ValueError names the field."""
        gains = [_per_thruster(g, m, n) for g, n in ((forward_gain, "forward_gain"),
                                                     (reverse_gain, "reverse_gain"))]  # fmt: skip
        if any(np.any(g <= 0.0) for g in gains):
            raise ValueError(f"thrusters: gains must be > 0, got {[g.tolist() for g in gains]}")
        u_max = None if u_max_abs is None else _per_thruster(u_max_abs, m, "u_max_abs")
        if u_max is not None and np.any(u_max <= 0.0):
            raise ValueError(f"thrusters.u_max_abs: must be > 0, got {u_max.tolist()}")
        props = (propeller,) * m if isinstance(propeller, Propeller) else tuple(propeller)
        if len(props) != m:
            raise ValueError(f"thrusters.propeller: expected 1 or {m} propellers, got {len(props)}")
        if not (math.isfinite(fouled_torque_gain) and fouled_torque_gain >= 0.0):
            raise ValueError(
                f"thrusters.fouled_torque_gain: expected >= 0, got {fouled_torque_gain}"
            )
        return cls(
            _per_thruster(time_constant_s, m, "time_constant_s"), gains[0], gains[1],
            _per_thruster(deadband_n, m, "deadband_n"), u_max, props, fouled_torque_gain,
            dead_esc,
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
    """Per thruster (m,): shaft speed factor s, K_T and K_Q factors, whether the thruster
    follows its command and whether its ESC reports (module docstring)."""

    speed: FloatArray
    k_t: FloatArray
    k_q: FloatArray
    responds: BoolArray
    reports: BoolArray

    @property
    def thrust_factor(self) -> FloatArray:
        """k_T s^2: thrust over the healthy thrust at the commanded speed."""
        return np.asarray(self.k_t * self.speed**2)

    @property
    def torque_factor(self) -> FloatArray:
        """k_Q s^2: torque over the healthy torque at the commanded speed."""
        return np.asarray(self.k_q * self.speed**2)


_CODE = {kind: i for i, kind in enumerate(ThrusterFault)}
_KINDS = list(ThrusterFault)
_HEALTHY, _WEAK, _FOULED, _LOST, _STUCK, _DEAD = (_CODE[k] for k in ThrusterFault)


def _cause_codes(truth: Truth, causes: Sequence[ThrusterFault] | None) -> IntArray:
    """(m,) integer codes of :func:`causes_for` (vectorised: this runs every step)."""
    if causes is None:
        d = truth.delta
        base = np.where(d <= 0.0, _DEAD, np.where(d < 1.0, _WEAK, _HEALTHY))
    else:
        base = np.array([_CODE[c] for c in causes])
    return np.asarray(np.where(truth.stuck, _STUCK, base))


def causes_for(truth: Truth, causes: Sequence[ThrusterFault] | None = None) -> list[ThrusterFault]:
    """Each thruster's cause: STUCK where ``truth.stuck``; else the given cause; else, with
    none given, DEAD_ESC at delta = 0, WEAK_MOTOR at 0 < delta < 1, HEALTHY at delta = 1."""
    return [_KINDS[i] for i in _cause_codes(truth, causes).tolist()]


def _signature(
    code: IntArray, delta: FloatArray, fouled_torque_gain: float, dead_esc: DeadEsc
) -> Signature:
    d = np.minimum(np.maximum(delta, 0.0), 1.0)
    fouled, lost, dead = code == _FOULED, code == _LOST, code == _DEAD
    at_speed = fouled | lost
    speed = np.where(dead, 0.0, np.where(at_speed, 1.0, np.sqrt(d)))
    k_q = np.where(fouled, 1.0 + fouled_torque_gain * (1.0 - d), np.where(lost, d, 1.0))
    responds = ~dead & (code != _STUCK)
    reports = ~dead | (dead_esc is DeadEsc.ZERO)
    return Signature(speed, np.where(at_speed, d, 1.0), k_q, responds, reports)


def signature(
    causes: Sequence[ThrusterFault], delta: FloatArray, fouled_torque_gain: float = 1.0,
    dead_esc: DeadEsc = DeadEsc.SILENT,
) -> Signature:  # fmt: skip
    """The (s, k_T, k_Q, responds, reports) of each thruster (module docstring), (m,) each."""
    code = np.array([_CODE[c] for c in causes])
    return _signature(code, np.asarray(delta, dtype=np.float64), fouled_torque_gain, dead_esc)


@dataclass(frozen=True)
class BankOutput:
    """One step's result, (m,) each: forces in N, telemetry at the end of the step."""

    produced: FloatArray  # F = delta H + f at the end of the step
    produced_mean: FloatArray  # F averaged over the step (exact for the lag)
    target: FloatArray  # c: the thrust the command asks of a healthy propeller
    rpm: FloatArray  # signed shaft speed, rpm (0 where the ESC is dead)
    current_a: FloatArray  # supply current, A
    reports: BoolArray  # False: this ESC sends nothing
    voltage_v: FloatArray


class ThrusterBank:
    """The m thrusters' state ``H`` (N, (m,)); see the module docstring."""

    def __init__(self, config: ThrusterBankConfig, h0: FloatArray | None = None) -> None:
        m = config.m
        self.config = config
        self._h = np.zeros(m) if h0 is None else np.array(h0, dtype=np.float64).reshape(m)
        props = config.propellers
        p = {k: np.array([getattr(pr, k) for pr in props]) for k in vars(props[0])}
        self._thrust_k = p["k_t"] * p["rho_kgm3"] * p["diameter_m"] ** 4  # T / n^2, N s^2
        self._torque_k = p["k_q"] * p["rho_kgm3"] * p["diameter_m"] ** 5  # Q / n^2
        self._watts_per_amp = p["efficiency"] * p["voltage_v"]
        self._idle_a, self._voltage_v = p["idle_a"], p["voltage_v"]
        self._lag_dt_s = math.nan
        self._lag = (np.zeros(m), np.zeros(m))

    def _lag_factors(self, dt_s: float) -> tuple[FloatArray, FloatArray]:
        """(a, b): H_end = c + (H0 - c) a and H_mean = c + (H0 - c) b over a step of dt_s;
        both 0 without lag. Kept for the last dt_s (the step is usually fixed)."""
        if dt_s != self._lag_dt_s:
            tc = self.config.time_constant_s
            lagged = tc > 0.0
            a = np.where(lagged, np.exp(-dt_s / np.where(lagged, tc, 1.0)), 0.0)
            self._lag = (a, np.where(lagged, tc / dt_s * (1.0 - a), 0.0))
            self._lag_dt_s = dt_s
        return self._lag

    @property
    def m(self) -> int:
        return self.config.m

    @property
    def shaft_thrust(self) -> FloatArray:
        """(m,) H: the thrust each shaft gives on a healthy propeller now, N."""
        return self._h.copy()

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
        self, u: FloatArray, truth: Truth, dt_s: float,
        causes: Sequence[ThrusterFault] | None = None,
    ) -> BankOutput:  # fmt: skip
        """Advance ``dt_s`` (s) with commands ``u`` (m,) N and ``truth`` held over the step;
        ``causes`` (m,) per :func:`causes_for`."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s: expected a finite positive step, got {dt_s}")
        cfg = self.config
        code = _cause_codes(truth, causes)
        sig = _signature(code, truth.delta, cfg.fouled_torque_gain, cfg.dead_esc)
        c = np.where(sig.responds | truth.stuck, self.target(u), 0.0)
        a, b = self._lag_factors(dt_s)
        h0 = self._h
        end = np.where(truth.stuck, h0, c + (h0 - c) * a)
        mean = np.where(truth.stuck, h0, c + (h0 - c) * b)
        self._h = end
        rpm, current = self._telemetry(end, sig)
        return BankOutput(
            truth.delta * end + truth.f, truth.delta * mean + truth.f, c, rpm, current,
            sig.reports, self._voltage_v.copy(),
        )  # fmt: skip

    def _telemetry(self, h: FloatArray, sig: Signature) -> tuple[FloatArray, FloatArray]:
        """(rpm, current in A) of shafts at healthy thrust ``h`` with signature ``sig``."""
        cfg = self.config
        gain = np.where(h >= 0.0, cfg.forward_gain, cfg.reverse_gain)
        n = sig.speed * np.sign(h) * np.sqrt(np.abs(h) / (gain * self._thrust_k))
        torque = sig.k_q * self._torque_k * n**2
        current = 2.0 * math.pi * np.abs(n) * torque / self._watts_per_amp
        return 60.0 * n, current + self._idle_a


def esc_statuses(out: BankOutput) -> list[EscStatus]:
    """One ``EscStatus`` per reporting thruster of a step's output (silent ones skipped)."""
    return [
        EscStatus(int(i), float(out.rpm[i]), float(out.current_a[i]), float(out.voltage_v[i]))
        for i in np.flatnonzero(out.reports)
    ]
