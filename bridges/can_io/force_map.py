"""Thruster force (N) <-> DroneCAN ``esc.RawCommand`` value (int14) mapping.

Pure numpy, no CAN library. Two maps with one interface (:class:`ForceMap`):

* :class:`ForceRawMap`, linear: raw proportional to force (below);
* :class:`CurveForceMap`, per-thruster
  :class:`~ftcap_hil.core.effectiveness.thruster_curve.ThrusterCurve`
  (nonlinear, asymmetric, optionally unidirectional)::

      raw_i = clip(rint(x_i(u_i) * 8191), -8191, 8191),   u_i = T_i(raw_i / 8191)

The allocator encodes with the curve it believes in; the simulated vessel decodes with the
physical curve of its own file, so a wrong curve on the allocator's side shows up as thrust
the allocator did not ask for.

The linear mapping, per thruster ``i`` with force ``u_i`` (N)::

    s_i   = RAW_MAX / u_max_abs_i                  (raw counts per newton)
    raw_i = 0                                      if |u_i| <= deadband_n_i
          = clip(round(u_i * s_i), -RAW_MAX, RAW_MAX)   otherwise

    u_i   = raw_i / s_i                            (inverse, for decode)

``RAW_MAX = 8191``: the DSDL type is int14, range [-8192, 8191]; we keep the range symmetric
so that full reverse and full ahead have the same magnitude. ``u_max_abs_i`` is the larger
magnitude of the thruster's amplitude limits (``from_limits``), so ``raw = +-8191`` is the
thruster's full force in that direction on the stronger side. Rounding is half-to-even
(``numpy.rint``); the quantization error of the round trip is at most ``u_max_abs_i / 16382``.

Non-finite forces are a programming error on the caller's side: ``to_raw`` raises
``NonFiniteCommand`` rather than emit a guess onto the bus.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from ftcap_hil.core.effectiveness.thruster_curve import ThrusterCurve
from ftcap_hil.core.errors import FtcapError

RAW_MAX = 8191
#: DroneCAN ``uavcan.equipment.esc.RawCommand.cmd`` holds at most 20 elements.
MAX_THRUSTERS = 20

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class NonFiniteCommand(FtcapError, ValueError):
    """A thruster force vector contained NaN or +-inf; nothing was sent."""


class ForceMap(Protocol):
    """What the CAN adapters need of a force <-> raw map."""

    @property
    def m(self) -> int:
        """Number of thrusters."""
        ...

    def to_raw(self, u: Sequence[float] | FloatArray) -> IntArray:
        """Forces (m,) in N -> raw int14 commands (m,)."""
        ...

    def to_force(self, raw: Sequence[int] | IntArray) -> FloatArray:
        """Raw commands (m,) -> forces (m,) in N."""
        ...


def _forces(u: Sequence[float] | FloatArray, m: int) -> FloatArray:
    arr = np.asarray(u, dtype=np.float64)
    if arr.shape != (m,):
        raise ValueError(f"thruster forces: expected shape ({m},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteCommand(f"thruster forces must be finite, got {arr.tolist()}")
    return arr


def _raws(raw: Sequence[int] | IntArray, m: int) -> FloatArray:
    arr = np.asarray(raw, dtype=np.float64)
    if arr.shape != (m,):
        raise ValueError(f"raw commands: expected shape ({m},), got {arr.shape}")
    return np.clip(arr, -RAW_MAX, RAW_MAX)


@dataclass(frozen=True)
class ForceRawMap:
    """Per-thruster linear force <-> raw map with an optional deadband.

    Attributes:
        u_max_abs: (m,) force in N that maps to raw +-8191, each finite and > 0.
        deadband_n: (m,) forces with ``|u| <= deadband_n`` are sent as raw 0 (N, >= 0).
    """

    u_max_abs: FloatArray
    deadband_n: FloatArray

    @classmethod
    def create(
        cls, u_max_abs: Sequence[float] | FloatArray, deadband_n: float | Sequence[float] = 0.0
    ) -> ForceRawMap:
        """Validate and build; ``deadband_n`` may be a scalar applied to every thruster."""
        u_max = np.array(u_max_abs, dtype=np.float64).reshape(-1)
        m = u_max.shape[0]
        if not 1 <= m <= MAX_THRUSTERS:
            raise ValueError(f"u_max_abs: need 1..{MAX_THRUSTERS} thrusters, got {m}")
        if not np.all(np.isfinite(u_max)) or np.any(u_max <= 0.0):
            raise ValueError(f"u_max_abs: every value must be finite and > 0, got {u_max}")
        dead = np.broadcast_to(np.asarray(deadband_n, dtype=np.float64), (m,)).copy()
        if not np.all(np.isfinite(dead)) or np.any(dead < 0.0):
            raise ValueError(f"deadband_n: every value must be finite and >= 0, got {dead}")
        u_max.setflags(write=False)
        dead.setflags(write=False)
        return cls(u_max, dead)

    @classmethod
    def from_limits(
        cls,
        u_min: Sequence[float] | FloatArray,
        u_max: Sequence[float] | FloatArray,
        deadband_n: float | Sequence[float] = 0.0,
    ) -> ForceRawMap:
        """Scale from amplitude limits ``u_min <= u <= u_max`` (N): ``max(|u_min|, |u_max|)``."""
        lo = np.asarray(u_min, dtype=np.float64)
        hi = np.asarray(u_max, dtype=np.float64)
        if lo.shape != hi.shape:
            raise ValueError(f"u_min/u_max: shapes differ, {lo.shape} vs {hi.shape}")
        return cls.create(np.maximum(np.abs(lo), np.abs(hi)), deadband_n)

    @property
    def m(self) -> int:
        """Number of thrusters."""
        return int(self.u_max_abs.shape[0])

    def to_raw(self, u: Sequence[float] | FloatArray) -> IntArray:
        """Forces (m,) in N -> raw int14 commands (m,), clipped to [-8191, 8191].

        Raises ``NonFiniteCommand`` on NaN/inf and ``ValueError`` on a wrong length; the
        caller's array is never modified.
        """
        arr = _forces(u, self.m)
        lim = self.u_max_abs  # clip first: a huge finite force must not overflow to inf
        raw = np.rint(np.clip(arr, -lim, lim) * (RAW_MAX / lim))
        raw[np.abs(arr) <= self.deadband_n] = 0.0
        return np.clip(raw, -RAW_MAX, RAW_MAX).astype(np.int64)

    def to_force(self, raw: Sequence[int] | IntArray) -> FloatArray:
        """Raw commands (m,) -> forces (m,) in N. Values outside +-8191 (only -8192) clip."""
        return _raws(raw, self.m) * (self.u_max_abs / RAW_MAX)

    def quantum_n(self) -> FloatArray:
        """(m,) force in N of one raw count; the round-trip error is at most half of it."""
        return self.u_max_abs / RAW_MAX


@dataclass(frozen=True)
class CurveForceMap:
    """Per-thruster curve map (module docstring) with an optional deadband.

    Attributes:
        curves: (m,) one :class:`ThrusterCurve` per thruster, in the vessel file's order.
        deadband_n: (m,) forces with ``|u| <= deadband_n`` are sent as raw 0 (N, >= 0).
    """

    curves: tuple[ThrusterCurve, ...]
    deadband_n: FloatArray

    @classmethod
    def create(
        cls, curves: Sequence[ThrusterCurve], deadband_n: float | Sequence[float] = 0.0
    ) -> CurveForceMap:
        """Validate and build; ``deadband_n`` may be a scalar applied to every thruster."""
        chosen = tuple(curves)
        if not 1 <= len(chosen) <= MAX_THRUSTERS:
            raise ValueError(f"curves: need 1..{MAX_THRUSTERS} thrusters, got {len(chosen)}")
        if not all(isinstance(c, ThrusterCurve) for c in chosen):
            raise ValueError("curves: expected ThrusterCurve values")
        dead = np.broadcast_to(np.asarray(deadband_n, dtype=np.float64), (len(chosen),)).copy()
        if not np.all(np.isfinite(dead)) or np.any(dead < 0.0):
            raise ValueError(f"deadband_n: every value must be finite and >= 0, got {dead}")
        dead.setflags(write=False)
        return cls(chosen, dead)

    @property
    def m(self) -> int:
        """Number of thrusters."""
        return len(self.curves)

    @property
    def reversible(self) -> tuple[bool, ...]:
        """(m,) False for a thruster that cannot push backwards (give it u_min = 0)."""
        return tuple(c.reversible for c in self.curves)

    def to_raw(self, u: Sequence[float] | FloatArray) -> IntArray:
        """Forces (m,) in N -> raw int14 commands (m,) through each curve's inverse.

        Thrust beyond a curve's end saturates; a negative force on a unidirectional thruster
        gives raw 0. Raises ``NonFiniteCommand`` on NaN/inf, ``ValueError`` on a wrong length.
        """
        arr = _forces(u, self.m)
        x = np.array([c.fraction_for(v) for c, v in zip(self.curves, arr, strict=True)])
        raw = np.rint(x * RAW_MAX)
        raw[np.abs(arr) <= self.deadband_n] = 0.0
        return np.clip(raw, -RAW_MAX, RAW_MAX).astype(np.int64)

    def to_force(self, raw: Sequence[int] | IntArray) -> FloatArray:
        """Raw commands (m,) -> thrust (m,) in N through each curve."""
        x = _raws(raw, self.m) / RAW_MAX
        return np.array([float(c.thrust(v)) for c, v in zip(self.curves, x, strict=True)])
