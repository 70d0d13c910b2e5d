"""Thruster curves: ESC command fraction <-> thrust (N), nonlinear and asymmetric.

A curve is a monotone table of points ``(x_j, T_j)``: ``x`` is the ESC command as a fraction
of full scale (-1 = full reverse, 0 = stop, +1 = full ahead; DroneCAN's RawCommand carries it
as ``x * 8191``), ``T`` the bollard thrust in N it gives. Between points the curve is linear::

    T(x)  = interp(clip(x, x_0, x_k), x_j, T_j)           thrust of a command
    x(T)  = 0                               if T == 0        command for a thrust (inverse)
          = interp(T, T_j, x_j) on the forward branch     if T > 0  (x >= x_fwd)
          = interp(T, T_j, x_j) on the reverse branch     if T < 0  (x <= x_rev)

where ``[x_rev, x_fwd]`` is the dead zone (T = 0 there: the ESC does not turn the propeller).
Outside the dead zone T is strictly increasing in x, so the inverse is unique; a thrust
beyond a branch's end saturates at the end. ``x(T)`` lands on the dead zone's edge for a tiny
thrust, as a real ESC needs. A **unidirectional** curve has no point below x = 0: commands
below zero give no thrust and ``x(T < 0) = 0``; the allocator must be told so with
``u_min = 0`` for that thruster (it cannot push backwards).

Curves come from a table (:meth:`ThrusterCurve.from_table`, :meth:`from_mapping` for a TOML
table) or from a polynomial per branch sampled onto a table (:meth:`from_polynomial`);
:meth:`linear` is the straight line of the plain force map. Pure numpy; the same curve
serves the allocator (thrust -> command) and the simulated ESC (command -> thrust).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.messages import FloatArray

_MAX_POINTS = 4096


class CurveError(ConfigError):
    """A thruster curve that is not a monotone table through (0, 0); names the field."""


def _array(name: str, values: object) -> FloatArray:
    try:
        arr = np.array(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise CurveError(f"{name}: expected a list of numbers, got {values!r:.80}") from e
    if not np.all(np.isfinite(arr)):
        raise CurveError(f"{name}: every value must be finite, got {arr.tolist()}")
    return arr


def _check(name: str, x: FloatArray, t: FloatArray) -> None:
    if x.shape != t.shape or not 2 <= x.shape[0] <= _MAX_POINTS:
        raise CurveError(
            f"{name}: fraction and thrust_n need the same length, 2..{_MAX_POINTS}, "
            f"got {x.shape[0]} and {t.shape[0]}"
        )
    if np.any(np.diff(x) <= 0.0) or x[0] < -1.0 or x[-1] > 1.0:
        raise CurveError(f"{name}: fraction must rise strictly within [-1, 1], got {x.tolist()}")
    if not np.any(x == 0.0) or t[x == 0.0][0] != 0.0:
        raise CurveError(f"{name}: the table needs the point (0, 0), got fraction {x.tolist()}")
    if np.any(np.diff(t) < 0.0) or np.any(t[x < 0.0] > 0.0) or np.any(t[x > 0.0] < 0.0):
        raise CurveError(f"{name}: thrust_n must rise with fraction through 0, got {t.tolist()}")
    fwd, rev = _branches(x, t)
    if any(np.any(np.diff(b[1]) <= 0.0) for b in (fwd, rev)):
        raise CurveError(f"{name}: thrust_n must rise strictly outside the dead zone")
    if t[-1] <= 0.0:
        raise CurveError(f"{name}: the curve gives no forward thrust, got {t.tolist()}")


@dataclass(frozen=True)
class ThrusterCurve:
    """One thruster's curve (module docstring); build with a ``from_*`` constructor.

    Attributes:
        fraction: (k,) ESC command fractions, strictly increasing within [-1, 1], holding 0.
        thrust_n: (k,) bollard thrust in N at each fraction, rising through (0, 0).
        name: what it is (a thruster model and voltage), for messages.
    """

    fraction: FloatArray
    thrust_n: FloatArray
    name: str = ""

    @classmethod
    def from_table(
        cls, fraction: Sequence[float] | FloatArray, thrust_n: Sequence[float] | FloatArray,
        name: str = "curve",
    ) -> ThrusterCurve:  # fmt: skip
        """Validate a table; CurveError names ``name`` and what is wrong."""
        x, t = _array(f"{name}.fraction", fraction), _array(f"{name}.thrust_n", thrust_n)
        _check(name, x, t)
        x.setflags(write=False)
        t.setflags(write=False)
        return cls(x, t, name)

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], source: str = "curve") -> ThrusterCurve:
        """A curve from a parsed TOML table ``{name, fraction, thrust_n, ...}``; other keys
        (``source``, ``notes``) are documentation and are ignored."""
        missing = [k for k in ("fraction", "thrust_n") if k not in table]
        if missing:
            raise CurveError(f"{source}: missing key(s) {missing}")
        return cls.from_table(table["fraction"], table["thrust_n"], str(table.get("name", source)))

    @classmethod
    def linear(cls, thrust_max_n: float, name: str = "linear") -> ThrusterCurve:
        """T = thrust_max_n x: the plain linear map, symmetric forward and reverse."""
        return cls.from_table([-1.0, 0.0, 1.0], [-thrust_max_n, 0.0, thrust_max_n], name)

    @classmethod
    def from_polynomial(
        cls, forward: Sequence[float], reverse: Sequence[float] | None = None, *,
        dead_zone: float = 0.0, points: int = 101, name: str = "polynomial",
    ) -> ThrusterCurve:  # fmt: skip
        """Sample ``T = sum_k c_k s^k`` per branch, ``s = (|x| - d) / (1 - d)`` in [0, 1]
        past the dead zone ``d``; forward coefficients in N, reverse ones give the reverse
        thrust's magnitude (None: unidirectional). ``points`` samples per branch."""
        if not 0.0 <= dead_zone < 1.0 or not 2 <= points <= _MAX_POINTS // 2 - 2:
            raise CurveError(f"{name}: need 0 <= dead_zone < 1 and a sane points, got "
                             f"{dead_zone}, {points}")  # fmt: skip
        s = np.linspace(0.0, 1.0, points)
        x_fwd = dead_zone + (1.0 - dead_zone) * s
        t_fwd = np.polynomial.polynomial.polyval(s, _array(f"{name}.forward", forward))
        xs, ts = [np.array([0.0]), x_fwd], [np.array([0.0]), t_fwd]
        if reverse is not None:
            t_rev = np.polynomial.polynomial.polyval(s, _array(f"{name}.reverse", reverse))
            xs.insert(0, -x_fwd[::-1])
            ts.insert(0, -t_rev[::-1])
        x, t = np.concatenate(xs), np.concatenate(ts)
        keep = np.concatenate([np.diff(x) > 0.0, [True]])  # dead_zone 0: 0 appears twice
        return cls.from_table(x[keep], t[keep], name)

    def scaled(self, thrust_max_n: float) -> ThrusterCurve:
        """The same shape with every thrust multiplied so that full ahead gives
        ``thrust_max_n`` (N, > 0); reverse keeps its ratio to forward. For a model of a
        thruster whose size differs from the one the table was measured on."""
        if not (np.isfinite(thrust_max_n) and thrust_max_n > 0.0):
            raise CurveError(f"{self.name}: scale to a thrust > 0 N, got {thrust_max_n!r}")
        thrust = self.thrust_n * (thrust_max_n / self.thrust_max_n)
        thrust[-1] = thrust_max_n  # exactly, whatever the rounding of the factor
        return ThrusterCurve.from_table(self.fraction, thrust, self.name)

    @property
    def reversible(self) -> bool:
        """False for a unidirectional thruster (no point below x = 0)."""
        return bool(self.fraction[0] < 0.0)

    @property
    def thrust_max_n(self) -> float:
        """Thrust at the top of the table (N, > 0)."""
        return float(self.thrust_n[-1])

    @property
    def thrust_min_n(self) -> float:
        """Thrust at the bottom of the table (N, <= 0; 0 for a unidirectional thruster)."""
        return float(self.thrust_n[0])

    def thrust(self, x: float | FloatArray) -> FloatArray:
        """Thrust in N of command fractions ``x`` (any shape); clipped to the table's ends."""
        xc = np.clip(np.asarray(x, dtype=np.float64), self.fraction[0], self.fraction[-1])
        return np.asarray(np.interp(xc, self.fraction, self.thrust_n))

    def fraction_for(self, thrust_n: float | FloatArray) -> FloatArray:
        """Command fractions for thrusts in N (any shape): the inverse of :meth:`thrust`,
        saturating at the table's ends; 0 for zero thrust."""
        t = np.asarray(thrust_n, dtype=np.float64)
        (xf, tf), (xr, tr) = _branches(self.fraction, self.thrust_n)
        out = np.where(t > 0.0, np.interp(t, tf, xf), 0.0)
        if self.reversible:
            out = np.where(t < 0.0, -np.interp(-t, tr, xr), out)
        return np.asarray(out)


Branch = tuple[FloatArray, FloatArray]


def _branches(x: FloatArray, t: FloatArray) -> tuple[Branch, Branch]:
    """(forward, reverse) branches as (|x|, |T|) rising from the dead zone's edge: each
    starts at its last T = 0 point (the reverse one mirrored; (0, 0) alone if it has none)."""
    fwd = x >= 0.0
    xr = np.concatenate([[0.0], -x[~fwd][::-1]])
    tr = np.concatenate([[0.0], -t[~fwd][::-1]])
    return _from_edge(x[fwd], t[fwd]), _from_edge(xr, tr)


def _from_edge(x: FloatArray, t: FloatArray) -> Branch:
    start = int(np.flatnonzero(t == 0.0)[-1])
    return x[start:], t[start:]
