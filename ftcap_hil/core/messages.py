"""Messages exchanged between the bridges (adapters) and the allocator / vessel shells.

Everything is SI and body-frame unless the field name says otherwise:

* wrench ``tau``: (3,) = [surge force X (N), sway force Y (N), yaw moment N (N*m)],
  body frame (x forward, y starboard, z down, as in NED / Fossen).
* pose ``eta``: (3,) = [north (m), east (m), psi (rad)], NED.
* body velocities ``nu``: (3,) = [u (m/s), v (m/s), r (rad/s)].
* thruster forces ``u``: (m,) in N, one per thruster, in the order of the vessel file.

Stamps are ``time.monotonic_ns()`` of the receiving process unless named otherwise.
Bridges validate on receipt: a message whose ``checked`` constructor raises
:class:`~ftcap_hil.core.errors.MalformedMessage` is counted and dropped.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ftcap_hil.core.errors import MalformedMessage

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]


def finite_vector(name: str, value: object, length: int | None = None) -> FloatArray:
    """``value`` as a 1-D float64 array (of ``length`` if given) with finite entries, else
    MalformedMessage naming ``name``; what cannot be converted raises numpy's own error."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1 or (length is not None and arr.shape[0] != length):
        raise MalformedMessage(
            f"{name}: expected a vector of length {length}, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise MalformedMessage(f"{name}: non-finite value in {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class WrenchSetpoint:
    """Demanded generalized force in the body frame: [X (N), Y (N), N (N*m)]."""

    tau: FloatArray

    @classmethod
    def checked(cls, tau: object) -> WrenchSetpoint:
        """Validate ``tau`` (3 finite numbers) or raise MalformedMessage."""
        return cls(finite_vector("wrench", tau, 3))


@dataclass(frozen=True)
class Odometry:
    """Vessel state: eta = [north, east, psi] (m, m, rad), nu = [u, v, r] (m/s, m/s, rad/s)."""

    eta: FloatArray
    nu: FloatArray
    time_s: float = math.nan  # sender's clock (sim time), informative only

    @classmethod
    def checked(cls, eta: object, nu: object, time_s: float = math.nan) -> Odometry:
        """Validate ``eta`` and ``nu`` (3 finite numbers each) or raise MalformedMessage."""
        return cls(finite_vector("eta", eta, 3), finite_vector("nu", nu, 3), float(time_s))


@dataclass(frozen=True)
class ThrusterCommand:
    """Per-thruster force commands u (N), shape (m,)."""

    u: FloatArray

    @classmethod
    def checked(cls, u: object, m: int | None = None) -> ThrusterCommand:
        """Validate ``u`` (finite, length ``m`` if given) or raise MalformedMessage."""
        return cls(finite_vector("thruster command", u, m))


class FaultKind(enum.Enum):
    """Fault injected into one thruster (mapped to effectiveness delta and bias f)."""

    OK = "ok"  # delta = 1, f = 0
    OFF = "off"  # delta = 0, f = 0
    STUCK = "stuck"  # delta = 0, f = last produced force (or the given value)
    WEAK = "weak"  # delta = given value in [0, 1], f = 0
    BIAS = "bias"  # delta unchanged, f = given value (N)


@dataclass(frozen=True)
class FaultInjection:
    """Live fault injection request for thruster ``index`` (0-based)."""

    index: int
    kind: FaultKind
    value: float = math.nan  # delta for WEAK, force (N) for BIAS / STUCK; NaN = default


@dataclass(frozen=True)
class EscStatus:
    """ESC telemetry for one thruster, as reported on the CAN bus."""

    index: int
    rpm: float
    current_a: float
    voltage_v: float = math.nan
    error_count: int = 0
