"""True thruster faults over time: what the vessel's thrusters actually do.

A fault acts per thruster as ``F_i = delta_i u_i + f_i`` (eq. 23 of the paper): ``delta`` (m,)
in [0, 1] is the effectiveness, ``f`` (m,) the bias force in N. A :class:`FaultSchedule` says
which (delta, f) hold when (``Truth`` at a time); :func:`injection_plan` turns a schedule
into the live fault injections (MAV_CMD_INJECT_FAILURE, Zenoh ``fault/inject``) that
reproduce it on a healthy vessel. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FaultKind, FloatArray


@dataclass(frozen=True)
class Truth:
    """The faults actually acting (for the oracle and for metrics): ``delta`` (m,)
    effectiveness in [0, 1], ``f`` (m,) bias force per thruster in N."""

    delta: FloatArray
    f: FloatArray


@dataclass(frozen=True)
class FaultEvent:
    """From ``start`` (inclusive) until ``end`` (exclusive; inf = forever): either one thruster
    (``thruster`` 0-based, scalar delta/bias) or all (vectors). Later events override."""

    start: float
    end: float
    thruster: int | None
    delta: FloatArray | None
    bias: FloatArray | None


@dataclass(frozen=True)
class FaultSchedule:
    """The true faults of ``m`` thrusters over time: ``events`` in order, later ones win."""

    m: int
    events: tuple[FaultEvent, ...] = ()

    def at(self, t: float) -> Truth:
        """The faults acting at time ``t`` (s, or steps for a discrete plant)."""
        delta, f = np.ones(self.m), np.zeros(self.m)
        for ev in self.events:
            if not ev.start <= t < ev.end:
                continue
            sel = slice(None) if ev.thruster is None else ev.thruster
            if ev.delta is not None:
                delta[sel] = ev.delta
            if ev.bias is not None:
                f[sel] = ev.bias
        return Truth(delta, f)

    def change_times(self) -> list[float]:
        """Every time at which some fault starts or ends, sorted (finite ends only)."""
        times = {ev.start for ev in self.events} | {
            ev.end for ev in self.events if math.isfinite(ev.end)
        }
        return sorted(times)


@dataclass(frozen=True)
class Injection:
    """One MAV_CMD_INJECT_FAILURE: at mission time ``at_s``, ``kind`` on ``thruster``
    (0-based) with ``value`` (delta for WEAK, N for BIAS / STUCK, NaN otherwise)."""

    at_s: float
    thruster: int
    kind: FaultKind
    value: float = math.nan


def _injections_for(
    i: int, at_s: float, before: tuple[float, float], after: tuple[float, float]
) -> list[Injection]:
    """Injections taking thruster i from (delta, f) ``before`` to ``after``. The vessel's
    WEAK clears the bias and BIAS keeps delta, so a weak and biased thruster is WEAK then
    BIAS; delta = 0 with a bias is STUCK at that force."""
    (d0, f0), (d1, f1) = before, after
    if (d1, f1) == (1.0, 0.0):
        return [Injection(at_s, i, FaultKind.OK)]
    if d1 == 0.0:
        return [Injection(at_s, i, FaultKind.OFF if f1 == 0.0 else FaultKind.STUCK,
                          math.nan if f1 == 0.0 else f1)]  # fmt: skip
    out: list[Injection] = []
    if d1 != d0:
        out.append(Injection(at_s, i, FaultKind.WEAK, d1))
    if f1 != 0.0 or (d1 == d0 and f0 != 0.0):
        out.append(Injection(at_s, i, FaultKind.BIAS, f1))
    return out


def injection_plan(schedule: FaultSchedule, duration_s: float) -> list[Injection]:
    """The injections that reproduce ``schedule`` on a healthy vessel, in time order;
    changes at or after ``duration_s`` are left out."""
    m = schedule.m
    prev = Truth(np.ones(m), np.zeros(m))
    plan: list[Injection] = []
    for t in schedule.change_times():
        if t >= duration_s:
            break
        now = schedule.at(t)
        for i in range(m):
            before = (float(prev.delta[i]), float(prev.f[i]))
            after = (float(now.delta[i]), float(now.f[i]))
            if before != after:
                plan += _injections_for(i, t, before, after)
        prev = now
    return plan
