"""A simple random generator of step faults for campaigns, as scenario ``[[fault]]`` tables.

Until the core has a generator of realistic faults (ramps, stuck at the last command), this
one draws piecewise-constant faults that today's scenario format expresses, so that every
generated run replays from its scenario file alone. Per fault, from ``rng``:

* the thruster: uniform over the allowed ones, without repetition within a run;
* the onset: uniform in ``onset``; the end: onset + uniform in ``duration``, or never;
* the severity, by kind: ``dead`` delta 0; ``partial`` delta uniform in ``partial_delta``;
  ``bias`` delta 1 and a force of random sign, uniform in ``bias`` x the thruster's range;
  ``stuck`` delta 0 and such a force from ``stuck`` (stuck at a constant thrust);
  ``intermittent`` dead for uniform(``intermittent_on``) s, healthy for
  uniform(``intermittent_off``) s, repeated from the onset to the end.

Draws happen in a fixed order, so a seed gives the same faults on every machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import DrawnKind, FaultSpec, Range
from ftcap_hil.core.messages import FloatArray


@dataclass(frozen=True)
class GeneratedFault:
    """One drawn fault: its thruster (0-based), kind and ``[[fault]]`` entries (1-based
    thruster, as a scenario file has them)."""

    thruster: int
    kind: DrawnKind
    tables: tuple[dict[str, Any], ...]


def _uniform(rng: np.random.Generator, r: Range) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else r[0]


def _table(i: int, start: float, end: float, delta: float, bias: float) -> dict[str, Any]:
    t: dict[str, Any] = {"thruster": i + 1, "from": start, "delta": delta, "bias": bias}
    if math.isfinite(end):
        t["until"] = end
    return t


def _intermittent(
    rng: np.random.Generator, i: int, start: float, end: float, spec: FaultSpec
) -> list[dict[str, Any]]:
    out, t = [], start
    while t < end:
        on = max(_uniform(rng, spec.intermittent_on), 1e-3)
        out.append(_table(i, t, min(t + on, end), 0.0, 0.0))
        t += on + max(_uniform(rng, spec.intermittent_off), 1e-3)
    return out


def one_fault(
    rng: np.random.Generator,
    i: int,
    kind: DrawnKind,
    u_range: float,
    duration_s: float,
    spec: FaultSpec,
) -> GeneratedFault:
    """One fault of ``kind`` on thruster i (0-based) of range ``u_range`` (N)."""
    start = _uniform(rng, spec.onset)
    end = math.inf if spec.duration is None else start + _uniform(rng, spec.duration)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if kind is DrawnKind.INTERMITTENT:
        return GeneratedFault(
            i, kind, tuple(_intermittent(rng, i, start, min(end, duration_s), spec))
        )
    delta, bias = {
        DrawnKind.DEAD: (0.0, 0.0),
        DrawnKind.PARTIAL: (_uniform(rng, spec.partial_delta), 0.0),
        DrawnKind.BIAS: (1.0, sign * _uniform(rng, spec.bias) * u_range),
        DrawnKind.STUCK: (0.0, sign * _uniform(rng, spec.stuck) * u_range),
    }[kind]
    return GeneratedFault(i, kind, (_table(i, start, end, delta, bias),))


def random_faults(
    rng: np.random.Generator,
    u_range: FloatArray,
    duration_s: float,
    spec: FaultSpec,
    kind: DrawnKind | None = None,
) -> list[GeneratedFault]:
    """``spec.count`` faults on distinct thrusters; every kind is ``kind`` if given, else
    drawn from ``spec.kinds``. u_range (m,): max |u| per thruster (N)."""
    allowed = list(spec.thrusters if spec.thrusters is not None else range(u_range.size))
    if any(not 0 <= i < u_range.size for i in allowed):
        raise ValueError(f"faults.thrusters: the vessel has {u_range.size} thrusters")
    if spec.count > len(allowed):
        raise ValueError(f"faults.count = {spec.count} but only {len(allowed)} thrusters allowed")
    chosen = rng.choice(allowed, size=spec.count, replace=False)
    out = []
    for i in sorted(int(j) for j in chosen):
        k = kind if kind is not None else spec.kinds[int(rng.integers(len(spec.kinds)))]
        out.append(one_fault(rng, i, k, float(u_range[i]), duration_s, spec))
    return out
