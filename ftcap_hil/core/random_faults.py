"""Random fault schedules for campaigns: which thruster, when, what kind, how severe.

:func:`random_faults` draws a :class:`~ftcap_hil.core.faults.FaultSchedule` from a numpy
``Generator``; the same seed gives the same schedule. Per event, in this order:

* kind: uniform over ``spec.kinds``;
* thruster: uniform over the m thrusters, distinct across events while there are enough
  (``spec.distinct``), else with replacement;
* onset: uniform in ``spec.onset`` (fractions of ``duration_s``);
* end: with probability ``spec.end_probability`` the fault ends after a length uniform in
  ``spec.length`` (fractions of ``duration_s``), else it lasts to the end of the run (an
  intermittent fault then ends at ``duration_s``, since it needs a finite end);
* severity, by kind: STEP, RAMP and INTERMITTENT take a delta uniform in ``spec.delta``
  (0 is a dead thruster), RAMP a ``ramp_s`` uniform in ``spec.ramp_s``, INTERMITTENT an
  ``on_s`` and ``off_s`` uniform in theirs; BIAS a bias of random sign whose magnitude is
  uniform in ``spec.bias`` times the thruster's ``force_scale_n`` (pass the thrusters'
  force limits to state biases as fractions of them); STUCK has none.

Every event draws the same number of values whatever its kind, so changing one range
changes no other draw. Events come out sorted by onset: a later onset overrides. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.faults import EventKind, FaultEvent, FaultSchedule
from ftcap_hil.core.messages import FloatArray

Range = tuple[float, float]


def _check_range(name: str, r: Range, lo: float = 0.0, hi: float = math.inf) -> None:
    a, b = r
    if not (lo <= a <= b <= hi and math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"random faults: {name} must satisfy {lo} <= low <= high <= {hi}, got {r}")


@dataclass(frozen=True)
class RandomFaultSpec:
    """The distribution :func:`random_faults` draws from (module docstring)."""

    kinds: tuple[EventKind, ...] = tuple(EventKind)
    count: tuple[int, int] = (1, 1)  # number of events, uniform in [low, high]
    onset: Range = (0.2, 0.6)  # fraction of the run
    end_probability: float = 0.0
    length: Range = (0.1, 0.3)  # fraction of the run, for faults that end
    delta: Range = (0.0, 0.7)
    bias: Range = (0.1, 0.5)  # magnitude, times force_scale_n
    ramp_s: Range = (5.0, 30.0)
    on_s: Range = (1.0, 5.0)
    off_s: Range = (1.0, 10.0)
    distinct: bool = True

    def __post_init__(self) -> None:
        if not self.kinds or not all(isinstance(k, EventKind) for k in self.kinds):
            raise ValueError(f"random faults: kinds must be EventKind values, got {self.kinds}")
        lo, hi = self.count
        if not (isinstance(lo, int) and isinstance(hi, int) and 0 <= lo <= hi):
            raise ValueError(
                f"random faults: count must be integers 0 <= low <= high, got {self.count}"
            )
        if not 0.0 <= self.end_probability <= 1.0:
            raise ValueError(
                f"random faults: end_probability not in [0, 1]: {self.end_probability}"
            )
        _check_range("onset", self.onset, 0.0, 1.0)
        _check_range("length", self.length)
        _check_range("delta", self.delta, 0.0, 1.0)
        _check_range("bias", self.bias)
        for name in ("ramp_s", "on_s", "off_s"):
            _check_range(name, getattr(self, name), 1e-9)
        if self.length[0] <= 0.0 or self.onset[1] >= 1.0:
            raise ValueError(
                f"random faults: need length > 0 and onset < 1, got {self.length}, {self.onset}"
            )


def _thrusters(rng: np.random.Generator, m: int, n: int, distinct: bool) -> list[int]:
    if distinct and n <= m:
        return [int(i) for i in rng.permutation(m)[:n]]
    return [int(i) for i in rng.integers(0, m, size=n)]


def _event(
    rng: np.random.Generator, spec: RandomFaultSpec, i: int, duration_s: float, scale: float
) -> FaultEvent:
    """One event on thruster ``i``; always 9 draws, in the module docstring's order."""
    kind = spec.kinds[int(rng.integers(len(spec.kinds)))]
    u = rng.random(8).tolist()

    def pick(r: Range, x: float) -> float:
        return float(r[0] + x * (r[1] - r[0]))

    start = duration_s * pick(spec.onset, u[0])
    end = start + duration_s * pick(spec.length, u[2]) if u[1] < spec.end_probability else math.inf
    delta = np.float64(pick(spec.delta, u[3]))
    sign = 1.0 if u[4] < 0.5 else -1.0
    bias = np.float64(sign * scale * pick(spec.bias, u[5]))
    if kind is EventKind.STEP:
        return FaultEvent(start, end, i, delta, None)
    if kind is EventKind.RAMP:
        return FaultEvent(start, end, i, delta, None, kind, ramp_s=pick(spec.ramp_s, u[6]))
    if kind is EventKind.INTERMITTENT:
        on_s, off_s = pick(spec.on_s, u[6]), pick(spec.off_s, u[7])
        end = min(end, duration_s)
        return FaultEvent(start, end, i, delta, None, kind, on_s=on_s, off_s=off_s)
    if kind is EventKind.BIAS:
        return FaultEvent(start, end, i, None, bias, kind)
    return FaultEvent(start, end, i, None, None, kind)


def random_faults(
    rng: np.random.Generator,
    m: int,
    duration_s: float,
    spec: RandomFaultSpec | None = None,
    force_scale_n: float | FloatArray = 1.0,
) -> FaultSchedule:
    """A random :class:`FaultSchedule` for ``m`` thrusters over a run of ``duration_s`` (s),
    drawn from ``spec`` (defaults: :class:`RandomFaultSpec`) with ``rng``; biases are
    ``spec.bias`` times ``force_scale_n`` (scalar or (m,), N). See the module docstring."""
    spec = RandomFaultSpec() if spec is None else spec
    if m < 1 or not (math.isfinite(duration_s) and duration_s > 0.0):
        raise ValueError(f"random faults: need m >= 1 and duration > 0, got {m}, {duration_s}")
    scale = np.broadcast_to(np.asarray(force_scale_n, dtype=np.float64), (m,))
    if not np.all(np.isfinite(scale) & (scale >= 0.0)):
        raise ValueError(f"random faults: force_scale_n must be finite and >= 0, got {scale}")
    n = int(rng.integers(spec.count[0], spec.count[1] + 1))
    events = [
        _event(rng, spec, i, duration_s, float(scale[i]))
        for i in _thrusters(rng, m, n, spec.distinct)
    ]
    return FaultSchedule(m, tuple(sorted(events, key=lambda ev: ev.start)))
