"""Per-run and per-fault metrics of a campaign run, pure numpy on a :class:`RunRecord`.

Definitions (docs/campaigns.md gives them with their rationale). Cycle k has time t_k and
period T_s; per thruster i: the true effectiveness delta_i and bias f_i, the estimate
delta_hat_i, the core's flag ``faulty_i`` (F) and ``dead_i`` (R: taken out of the
allocation, the effectiveness the allocator used below its dead threshold).

* A *fault episode* is a maximal run of cycles in which a thruster's truth is not nominal
  (delta_i != 1 or f_i != 0); it is *detectable* when its delta drops below the core's
  fault threshold; the detection reference t_d is the first such cycle. A frozen output
  (``[[fault]] kind = "stuck"``) is recorded as delta 0 and f = the held force: a fault.
* Thruster i is *healthy* at k when its truth is nominal: a flag or a removal that outlives
  its fault (an intermittent fault's off-spell, a fault that ended) is false, as it is for
  the boat; how long it lasts is also the recovery's (below).
* Detection / removal delay: first cycle >= t_d with F_i / R_i, minus t_d. Isolation delay:
  first cycle >= t_d at which i is flagged or removed and no healthy thruster is.
* Correct isolation: isolated in at least ``isolation_hold`` of the episode's tail (its
  last ``tail_fraction``). Errors after convergence: means over that tail.
* Time to estimate: first cycle from which |delta_hat_i - delta_i| < ``convergence_tol``
  holds for ``converge_hold_s`` (or to the episode's end).
* Recovery (an episode that ends before the run): first cycle after the end from which the
  thruster stays in the allocation (not R) at its true effectiveness (|delta_hat_i - 1| <
  ``convergence_tol``) for ``recovery_hold_s``; likewise unflagged (not F).
* False alarms: rising edges of F on healthy thrusters; false-alarm *episodes*: the same
  with a rise less than ``episode_merge_s`` after the thruster's previous fall merged into
  that episode; removal *switches*: changes of R (in or out) on healthy thrusters. Rates per
  hour of healthy operation of the whole vessel (thruster-hours healthy / m). Time flagged /
  removed: healthy thruster-seconds.
* Deviation: horizontal distance to the fault-free (``none``) run of the same case;
  tracking error: to the reference. Both per fault phase (RMS and max).
* Cause: what physically happened at the episode's onset (the truth's cause); *drive
  visible* when the drive's own telemetry shows it (:data:`DRIVE_VISIBLE`: dead, jammed,
  frozen shaft, lost blade, a weak motor down by ``WEAK_VISIBLE`` or more); the drive's
  *verdict*: the hypothesis its diagnosis gave most often while the thruster was isolated
  in the episode; the cause is *named* when that verdict is the one the cause shows
  (:data:`NAMED_BY`; a jammed servo holds its deflection: named stuck). *Visible from*:
  when the drive can first show it (the onset; a weak motor's ramp, once down by
  ``WEAK_VISIBLE``); the visible delay: first cycle from then with i isolated, minus then.

A delay that never happens is None (JSON null).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import MetricParams
from ftcap_hil.core.estimation.shaft_types import HYPOTHESES_BY_CODE, Hypothesis
from ftcap_hil.core.faults import Cause, default_cause
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.report.records import RunRecord

KINDS = ("dead", "stuck", "frozen", "partial", "bias", "mixed", "intermittent")

#: The causes a drive's telemetry shows by itself (speed, current): issue 29's
#: "drive-visible" faults; a weak motor only from this loss of force on (delta <= 0.7).
DRIVE_VISIBLE = frozenset(
    {Cause.DRIVE_DEAD, Cause.JAMMED, Cause.STUCK, Cause.LOST_BLADE, Cause.WEAK_MOTOR}
)
WEAK_VISIBLE = 0.3
#: The drive's verdict that names each cause (on a servo, :data:`NAMED_ON_SERVO` first).
NAMED_BY: dict[Cause, Hypothesis] = {
    Cause.DRIVE_DEAD: Hypothesis.DRIVE_DEAD,
    Cause.JAMMED: Hypothesis.JAMMED,
    Cause.STUCK: Hypothesis.STUCK,
    Cause.WEAK_MOTOR: Hypothesis.WEAK,
    Cause.LOST_BLADE: Hypothesis.LOAD_LOSS,
    Cause.FOULED: Hypothesis.LOAD_GAIN,
    Cause.POWER_LOST: Hypothesis.TELEMETRY_LOST,
    Cause.HELD: Hypothesis.TELEMETRY_LOST,
    Cause.TELEMETRY_LOST: Hypothesis.TELEMETRY_LOST,
    Cause.VENTILATION: Hypothesis.VENTILATION,
    Cause.HULL_LOSS: Hypothesis.HEALTHY,
}
#: A jammed servo holds its deflection (sim/thrusters.py), and its force with it: the
#: verdict that says so, and gives the allocator the held force, is a stuck one.
NAMED_ON_SERVO: dict[Cause, Hypothesis] = {Cause.JAMMED: Hypothesis.STUCK}


@dataclass(frozen=True)
class Reference:
    """What a run needs of its fault-free run: positions (n, 1 or 2) and commands (n, m)."""

    pos: FloatArray
    u: FloatArray


@dataclass(frozen=True)
class Episode:
    thruster: int  # 0-based
    start: int  # first cycle index
    end: int  # one past the last cycle index
    kind: str


def _stack(rec: RunRecord, prefix: str) -> FloatArray:
    m = rec.scenario.thrusters.m
    return np.column_stack([rec.columns[f"{prefix}_{i}"] for i in range(1, m + 1)])


def positions(rec: RunRecord) -> FloatArray:
    c = rec.columns
    return c["x"][:, None] if "x" in c else np.column_stack([c["north"], c["east"]])


def reference_of(rec: RunRecord) -> Reference:
    return Reference(positions(rec), _stack(rec, "u"))


def runs_of(mask: BoolArray) -> list[tuple[int, int]]:
    """Maximal runs [a, b) of True in a 1-D mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def first_held(mask: BoolArray, a: int, b: int, hold: int) -> int | None:
    """First k in [a, b) with mask true on [k, min(k + hold, b)), else None."""
    for s, e in runs_of(mask[a:b]):
        if e - s >= hold or a + e == b:
            return a + int(s)
    return None


def classify(delta: FloatArray, f: FloatArray) -> str:
    """Kind of a fault from its truth over the episode (a generator's label wins)."""
    weak, biased = bool(np.any(delta < 1.0)), bool(np.any(f != 0.0))
    if np.min(delta) == 0.0:
        return "stuck" if biased else "dead"
    if weak:
        return "mixed" if biased else "partial"
    return "bias"


def episodes(rec: RunRecord, kinds: Mapping[int, str] | None = None) -> list[Episode]:
    delta, f = _stack(rec, "delta"), _stack(rec, "f")
    out = []
    for i in range(delta.shape[1]):
        for a, b in runs_of((delta[:, i] != 1.0) | (f[:, i] != 0.0)):
            kind = (kinds or {}).get(i) or classify(delta[a:b, i], f[a:b, i])
            out.append(Episode(i, int(a), int(b), kind))
    return out


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _rms(x: FloatArray) -> float | None:
    return _num(float(np.sqrt(np.mean(x**2)))) if x.size else None


def _next_starts(eps: list[Episode], n: int) -> list[int]:
    """Per episode: where its thruster's next episode starts (n: none)."""
    return [
        min((e.start for e in eps if e.thruster == ep.thruster and e.start >= ep.end), default=n)
        for ep in eps
    ]


class _Run:
    """The arrays one record's metrics are computed from."""

    def __init__(self, rec: RunRecord, ref: Reference | None, p: MetricParams) -> None:
        sc = rec.scenario
        self.rec, self.t, self.dt = rec, rec.t, sc.dt_s
        self.delta, self.f = _stack(rec, "delta"), _stack(rec, "f")
        self.dh, self.fh = _stack(rec, "delta_hat"), _stack(rec, "f_hat")
        self.flag = _stack(rec, "faulty") > 0.5
        self.drive = _stack(rec, "drive") if "drive_1" in rec.columns else None
        self.dead = _stack(rec, "dead") > 0.5
        self.hold = max(1, int(round(p.recovery_hold_s / self.dt)))
        self.healthy = (self.delta == 1.0) & (self.f == 0.0)
        self.merge = max(1, int(round(p.episode_merge_s / self.dt)))
        self.tol = p.convergence_tol
        self.u_range = np.maximum(np.abs(sc.thrusters.u_min), np.abs(sc.thrusters.u_max))
        self.threshold = sc.core.fault_threshold
        out = self.flag | self.dead
        self.isolated = out & ~np.any(out & self.healthy, axis=1, keepdims=True)
        n = self.t.size if ref is None else min(self.t.size, ref.pos.shape[0])
        self.ref = ref
        self.dev = None if ref is None else np.linalg.norm(positions(rec)[:n] - ref.pos[:n], axis=1)

    def back(self, mask: BoolArray, ep: Episode, limit: int) -> int | None:
        """First cycle after the episode from which ``mask`` (flag or removal) of its
        thruster stays off for the recovery hold, before ``limit``."""
        return first_held(~mask[:, ep.thruster], ep.end, limit, self.hold)

    def restored(self, ep: Episode, limit: int) -> int | None:
        """First cycle after the episode from which its thruster stays in the allocation at
        its true effectiveness (not removed, |delta_hat - delta| < tol) for the hold."""
        i = ep.thruster
        good = ~self.dead[:, i] & (np.abs(self.dh[:, i] - self.delta[:, i]) < self.tol)
        return first_held(good, ep.end, limit, self.hold)

    def delay(self, mask: BoolArray, a: int, b: int) -> float | None:
        hit = np.flatnonzero(mask[a:b])
        return float(self.t[a + hit[0]] - self.t[a]) if hit.size else None

    def used(self, ep: Episode, p: MetricParams) -> bool | None:
        if self.ref is None:
            return None
        n = max(1, int(round(p.used_window_s / self.dt)))
        u = np.abs(self.ref.u[ep.start : min(ep.start + n, ep.end), ep.thruster])
        return bool(np.mean(u >= p.used_fraction * self.u_range[ep.thruster]) >= 0.5)


def _recovery(r: _Run, ep: Episode, limit: int, p: MetricParams) -> dict[str, Any]:
    if ep.end >= r.t.size:
        return {"ended": False, "recovery_s": None, "recovery_unflag_s": None}
    t_end = r.t[ep.end]
    back, clear = r.restored(ep, limit), r.back(r.flag, ep, limit)
    return {
        "ended": True,
        "recovery_s": None if back is None else float(r.t[back] - t_end),
        "recovery_unflag_s": None if clear is None else float(r.t[clear] - t_end),
    }


def fault_metrics(r: _Run, ep: Episode, limit: int, p: MetricParams) -> dict[str, Any]:
    """One fault episode's row (module docstring); limit: where its recovery window ends."""
    i, a, b = ep.thruster, ep.start, ep.end
    below = np.flatnonzero(r.delta[a:b, i] < r.threshold)
    d0 = a + int(below[0]) if below.size else None
    tail = slice(b - max(1, int(round(p.tail_fraction * (b - a)))), b)
    err = np.abs(r.dh[:, i] - r.delta[:, i])
    hold = max(1, int(round(p.converge_hold_s / r.dt)))
    conv = first_held(err < p.convergence_tol, a, b, hold)
    out: dict[str, Any] = {
        "thruster": i + 1,
        "kind": ep.kind,
        "onset_s": float(r.t[a]),
        "end_s": float(r.t[b - 1] + r.dt),
        "delta_min": float(np.min(r.delta[a:b, i])),
        "bias_max": float(np.max(np.abs(r.f[a:b, i]))),
        "detectable": d0 is not None,
        "used": r.used(ep, p),
        "detection_delay_s": None if d0 is None else r.delay(r.flag[:, i], d0, b),
        "removal_delay_s": None if d0 is None else r.delay(r.dead[:, i], d0, b),
        "isolation_delay_s": None if d0 is None else r.delay(r.isolated[:, i], d0, b),
        "correct_isolation": None
        if d0 is None
        else bool(np.mean(r.isolated[tail, i]) >= p.isolation_hold),
        "delta_error": _num(float(np.mean(err[tail]))),
        "bias_error": _num(float(np.mean(np.abs(r.fh[tail, i] - r.f[tail, i])))),
        "converge_s": None if conv is None else float(r.t[conv] - r.t[a]),
        "deviation_rms": None if r.dev is None else _rms(r.dev[a:b]),
    }
    out.update(_cause(r, ep))
    out.update(_recovery(r, ep, limit, p))
    return out


def _cause(r: _Run, ep: Episode) -> dict[str, Any]:
    """The episode's true cause, whether the drive can show it, the drive's verdict while
    the thruster was isolated and whether it names the cause (module docstring)."""
    i, a, b = ep.thruster, ep.start, ep.end
    delta_min = float(np.min(r.delta[a:b, i]))
    cause = r.rec.scenario.faults.at(float(r.t[a])).causes()[i]
    if cause is Cause.HEALTHY:  # a record whose truth is not its scenario's schedule
        cause = default_cause(delta_min, False, float(np.max(np.abs(r.f[a:b, i]))))
    visible = cause in DRIVE_VISIBLE and (
        cause is not Cause.WEAK_MOTOR or delta_min <= 1.0 - WEAK_VISIBLE
    )
    # from when the drive can show it: a weak motor (a ramp) once down by WEAK_VISIBLE
    seen = np.flatnonzero(r.delta[a:b, i] <= 1.0 - WEAK_VISIBLE) if visible else None
    if seen is not None and cause is not Cause.WEAK_MOTOR:
        seen = np.zeros(1, dtype=np.intp)
    v0 = None if seen is None or not seen.size else a + int(seen[0])
    drives = r.rec.scenario.drives
    named = NAMED_BY.get(cause)
    if drives is not None and not drives[i].is_shaft:
        named = NAMED_ON_SERVO.get(cause, named)
    verdict = None
    if r.drive is not None:
        codes = r.drive[a:b, i][r.isolated[a:b, i]]
        codes = codes[np.isfinite(codes) & (codes >= 1)].astype(int)  # 0: no diagnosis
        if codes.size:
            verdict = HYPOTHESES_BY_CODE[int(np.bincount(codes).argmax())]
    return {
        "cause": cause.value,
        "drive_visible": visible,
        "drive_verdict": None if verdict is None else verdict.value,
        "cause_named": None if verdict is None else verdict is named,
        "visible_s": None if v0 is None else float(r.t[v0] - r.t[a]),
        "visible_delay_s": None if v0 is None else r.delay(r.isolated[:, i], v0, b),
    }


def _episode_count(mask: BoolArray, healthy: BoolArray, merge: int) -> int:
    """Rising edges of ``mask`` (one thruster) on healthy cycles, a rise less than ``merge``
    cycles after the previous fall counting with that episode."""
    count, last_fall = 0, None
    for a, b in runs_of(mask):
        if healthy[a] and (last_fall is None or a - last_fall >= merge):
            count += 1
        last_fall = b
    return count


def _switches(mask: BoolArray, healthy: BoolArray) -> int:
    """Changes of ``mask`` (one thruster, either way) at healthy cycles."""
    change = np.flatnonzero(np.diff(mask.astype(np.int8))) + 1
    return int(np.sum(healthy[change]))


def healthy_metrics(r: _Run) -> dict[str, Any]:
    """False alarms, their episodes, removal switches and time flagged / removed of healthy
    thrusters (module docstring)."""
    h, m = r.healthy, r.healthy.shape[1]
    prev = np.vstack([np.zeros((1, m), dtype=bool), r.flag[:-1]])
    alarms = int(np.sum(r.flag & ~prev & h))
    removals = int(np.sum(r.dead & ~np.vstack([prev[:1], r.dead[:-1]]) & h))
    episodes_ = sum(_episode_count(r.flag[:, i], h[:, i], r.merge) for i in range(m))
    switches = sum(_switches(r.dead[:, i], h[:, i]) for i in range(m))
    healthy_s = float(np.sum(h)) * r.dt
    hours = healthy_s / m / 3600.0
    flagged_s = float(np.sum(r.flag & h)) * r.dt
    removed_s = float(np.sum(r.dead & h)) * r.dt
    return {
        "healthy_hours": hours,
        "healthy_thruster_s": healthy_s,
        "false_alarms": alarms,
        "false_alarm_episodes": episodes_,
        "false_removals": removals,
        "removal_switches": switches,
        "false_alarm_rate_per_h": alarms / hours if hours > 0 else None,
        "false_alarm_episodes_per_h": episodes_ / hours if hours > 0 else None,
        "removal_switches_per_h": switches / hours if hours > 0 else None,
        "healthy_flagged_s": flagged_s,
        "healthy_removed_s": removed_s,
        "healthy_flagged_frac": flagged_s / healthy_s if healthy_s > 0 else None,
        "healthy_removed_frac": removed_s / healthy_s if healthy_s > 0 else None,
        "healthy_delta_hat_min": _num(float(np.min(r.dh[h]))) if h.any() else None,
    }


def tracking_error(rec: RunRecord) -> FloatArray:
    """(n,) horizontal distance from the reference (|x - ref_x| for the linear plant)."""
    c = rec.columns
    ref = c["ref_x"][:, None] if "x" in c else np.column_stack([c["ref_north"], c["ref_east"]])
    return np.asarray(np.linalg.norm(positions(rec) - ref, axis=1))


def _phase_rows(r: _Run) -> list[dict[str, Any]]:
    out = []
    trk = tracking_error(r.rec)
    for start, end in r.rec.scenario.phases():
        sel = (r.t >= start) & (r.t < end)
        dev = None if r.dev is None else r.dev[sel[: r.dev.size]]
        out.append(
            {
                "start_s": start,
                "end_s": end,
                "deviation_rms": None if dev is None else _rms(dev),
                "deviation_max": None if dev is None or not dev.size else float(np.max(dev)),
                "tracking_rms": _rms(trk[sel]),
                "tracking_max": float(np.max(trk[sel])) if sel.any() else None,
            }
        )
    return out


def run_metrics(
    rec: RunRecord,
    ref: Reference | None,
    params: MetricParams,
    kinds: Mapping[int, str] | None = None,
) -> dict[str, Any]:
    """The metrics of one run: scalars, ``phases`` (deviation per fault phase) and
    ``faults`` (one row per episode). ref: the fault-free run (None: no deviation)."""
    eps = episodes(rec, kinds)
    r = _Run(rec, ref, params)
    k = rec.scenario.B.shape[0]
    gap = _stack_k(rec, "v_dem", k) - _stack_k(rec, "v_ach", k)
    limits = _next_starts(eps, r.t.size)
    rows = [fault_metrics(r, ep, lim, params) for ep, lim in zip(eps, limits, strict=True)]
    return {
        "cycles": int(r.t.size),
        "deviation_rms": None if r.dev is None else _rms(r.dev),
        "deviation_max": None if r.dev is None or not r.dev.size else float(np.max(r.dev)),
        "unallocated_rms": _rms(np.linalg.norm(gap, axis=1)),
        "fallback_cycles": int(np.sum(rec.columns["fallback"])),
        "solve_us_median": _num(float(np.median(rec.columns["solve_us"]))) if r.t.size else None,
        **healthy_metrics(r),
        "phases": _phase_rows(r),
        "faults": rows,
    }


def _stack_k(rec: RunRecord, prefix: str, k: int) -> FloatArray:
    return np.column_stack([rec.columns[f"{prefix}_{j}"] for j in range(1, k + 1)])
