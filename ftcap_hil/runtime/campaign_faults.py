"""A random generator of faults for campaigns, as scenario ``[[fault]]`` tables.

Every fault is one the scenario format expresses, so that every generated run replays from
its scenario file alone. Per fault, from ``rng``:

* the thruster: uniform over the allowed ones, without repetition within a run;
* the onset: uniform in ``onset``; the end: onset + uniform in ``duration``, or never;
* the severity, by kind: ``dead`` delta 0; ``partial`` delta uniform in ``partial_delta``;
  ``bias`` delta 1 and a force of random sign, uniform in ``bias`` x the thruster's range;
  ``stuck`` delta 0 and such a force from ``stuck`` (stuck at a constant thrust; with
  ``causes``, cause ``held`` and labelled so: a silent drive holding that force);
  ``intermittent`` dead for uniform(``intermittent_on``) s, healthy for
  uniform(``intermittent_off``) s, repeated from the onset to the end; ``ramp`` delta falling
  linearly from 1 to uniform(``ramp_delta``) over uniform(``ramp_s``) s; ``frozen`` the
  output frozen at its onset value (``kind = "stuck"``); ``transient`` dead for
  uniform(``transient_s``) s, then working again; ``double`` two thrusters dead at once;
  ``telemetry-lost`` a thruster that works as commanded while its drive stops reporting.
* with ``causes``, the physical cause (``cause = ...``) among those that give the kind's
  loss (:data:`CAUSES`), so that the drives' telemetry shows each kind in its several
  signatures and "telemetry silent = dead" earns nothing (``telemetry-lost`` always has
  its cause).

Draws happen in a fixed order, so a seed gives the same faults on every machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import DrawnKind, FaultSpec, Range
from ftcap_hil.core.faults import Cause
from ftcap_hil.core.messages import FloatArray

#: The causes a kind is drawn from (``[faults] causes = true``); a kind not here keeps the
#: default cause of its delta and bias (core.faults.default_cause).
CAUSES: dict[DrawnKind, tuple[Cause, ...]] = {
    DrawnKind.DEAD: (Cause.DRIVE_DEAD, Cause.POWER_LOST, Cause.JAMMED),
    DrawnKind.TRANSIENT: (Cause.DRIVE_DEAD, Cause.POWER_LOST, Cause.JAMMED),
    DrawnKind.DOUBLE: (Cause.DRIVE_DEAD, Cause.POWER_LOST, Cause.JAMMED),
    DrawnKind.INTERMITTENT: (Cause.DRIVE_DEAD, Cause.POWER_LOST),
    DrawnKind.PARTIAL: (Cause.WEAK_MOTOR, Cause.LOST_BLADE, Cause.FOULED, Cause.HULL_LOSS),
    DrawnKind.RAMP: (Cause.WEAK_MOTOR, Cause.FOULED, Cause.HULL_LOSS),
}
RAMP_STEPS = 10  # a ramp's delta is written as this many equal steps (the format's ramp)


@dataclass(frozen=True)
class GeneratedFault:
    """One drawn fault: its thruster (0-based), kind and ``[[fault]]`` entries (1-based
    thruster, as a scenario file has them)."""

    thruster: int
    kind: DrawnKind
    tables: tuple[dict[str, Any], ...]

    @property
    def label(self) -> str:
        """The results' kind label: the drawn kind, but ``held`` for a ``stuck`` fault whose
        cause says so (a drive fallen silent with its force left on the hull: only the motion
        can see it), so that a per-kind table never calls it a frozen shaft."""
        if any(t.get("cause") == Cause.HELD.value for t in self.tables):
            return Cause.HELD.value
        return self.kind.value


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


def _with_cause(
    rng: np.random.Generator, kind: DrawnKind, tables: list[dict[str, Any]], spec: FaultSpec
) -> tuple[dict[str, Any], ...]:
    """The tables with one drawn cause (``spec.causes``; one draw per fault, always made so
    that switching causes on does not shift the other draws)."""
    options = CAUSES.get(kind, ())
    pick = int(rng.integers(len(options))) if options else 0
    if spec.causes and kind is DrawnKind.STUCK:  # its one cause, written out (no draw)
        return tuple({**t, "cause": Cause.HELD.value} for t in tables)
    if not spec.causes or not options:
        return tuple(tables)
    return tuple({**t, "cause": options[pick].value} for t in tables)


def _shaped(
    rng: np.random.Generator, i: int, kind: DrawnKind, start: float, end: float,
    spec: FaultSpec,
) -> list[dict[str, Any]] | None:  # fmt: skip
    """The tables of the kinds that are not one constant (delta, bias) step, else None."""
    if kind is DrawnKind.RAMP:
        final, ramp_s = _uniform(rng, spec.ramp_delta), _uniform(rng, spec.ramp_s)
        t = _table(i, start, end, final, 0.0)
        return [{**t, "kind": "ramp", "ramp_s": max(ramp_s, 1e-3)}]
    if kind is DrawnKind.FROZEN:  # the format's frozen output: no delta or bias of its own
        t = {k: v for k, v in _table(i, start, end, 0.0, 0.0).items() if k not in ("delta", "bias")}
        return [{**t, "kind": "stuck"}]
    if kind is DrawnKind.TRANSIENT:
        return [_table(i, start, min(end, start + _uniform(rng, spec.transient_s)), 0.0, 0.0)]
    if kind is DrawnKind.TELEMETRY_LOST:
        return [{**_table(i, start, end, 1.0, 0.0), "cause": Cause.TELEMETRY_LOST.value}]
    return None


def one_fault(
    rng: np.random.Generator,
    i: int,
    kind: DrawnKind,
    u_range: float,
    duration_s: float,
    spec: FaultSpec,
) -> GeneratedFault:
    """One fault of ``kind`` on thruster i (0-based) of range ``u_range`` (N); a ``double``
    fault's half (:func:`random_faults` draws its two thrusters)."""
    start = _uniform(rng, spec.onset)
    end = math.inf if spec.duration is None else start + _uniform(rng, spec.duration)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    if kind is DrawnKind.INTERMITTENT:
        tables = _intermittent(rng, i, start, min(end, duration_s), spec)
        return GeneratedFault(i, kind, _with_cause(rng, kind, tables, spec))
    shaped = _shaped(rng, i, kind, start, end, spec)
    if shaped is not None:
        return GeneratedFault(i, kind, _with_cause(rng, kind, shaped, spec))
    delta, bias = {
        DrawnKind.DEAD: (0.0, 0.0),
        DrawnKind.PARTIAL: (_uniform(rng, spec.partial_delta), 0.0),
        DrawnKind.BIAS: (1.0, sign * _uniform(rng, spec.bias) * u_range),
        DrawnKind.STUCK: (0.0, sign * _uniform(rng, spec.stuck) * u_range),
        DrawnKind.DOUBLE: (0.0, 0.0),
    }[kind]
    return GeneratedFault(
        i, kind, _with_cause(rng, kind, [_table(i, start, end, delta, bias)], spec)
    )


def random_faults(
    rng: np.random.Generator,
    u_range: FloatArray,
    duration_s: float,
    spec: FaultSpec,
    kind: DrawnKind | None = None,
) -> list[GeneratedFault]:
    """``spec.count`` faults on distinct thrusters (a ``double`` one takes two, dead from
    the same onset); every kind is ``kind`` if given, else drawn from ``spec.kinds``.
    u_range (m,): max |u| per thruster (N)."""
    allowed = list(spec.thrusters if spec.thrusters is not None else range(u_range.size))
    if any(not 0 <= i < u_range.size for i in allowed):
        raise ValueError(f"faults.thrusters: the vessel has {u_range.size} thrusters")
    if kind is None and DrawnKind.DOUBLE in spec.kinds:
        raise ValueError("faults.kinds: 'double' needs each_kind = true (one case per kind)")
    need = spec.count * (2 if kind is DrawnKind.DOUBLE else 1)
    if need > len(allowed):
        raise ValueError(
            f"faults.count = {spec.count} but only {len(allowed)} thrusters allowed"
            + (" (a double fault takes two)" if need > spec.count else "")
        )
    chosen = rng.choice(allowed, size=need, replace=False)
    out: list[GeneratedFault] = []
    for i in sorted(int(j) for j in chosen[: spec.count]):
        k = kind if kind is not None else spec.kinds[int(rng.integers(len(spec.kinds)))]
        out.append(one_fault(rng, i, k, float(u_range[i]), duration_s, spec))
    for partner, first in zip(chosen[spec.count :], list(out), strict=False):
        twin = one_fault(
            rng, int(partner), first.kind, float(u_range[int(partner)]), duration_s, spec
        )
        start, end = first.tables[0]["from"], first.tables[0].get("until")
        tables = tuple({**t, "from": start, **({"until": end} if end else {})} for t in twin.tables)
        out.append(GeneratedFault(int(partner), first.kind, tables))
    return out
