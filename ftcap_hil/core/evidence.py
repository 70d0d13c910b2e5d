"""What the shell knows of the thrusters from outside the estimator, and how one cycle uses it.

The allocator's shell watches the ESC telemetry (``ftcap_hil.runtime.esc_watchdog``): a
thruster whose ESC fell silent is known **dead**, one whose ESC reports no rpm under command
is **stalled**. The shell builds one :class:`Evidence` per cycle and hands it to
:meth:`~ftcap_hil.core.cycle.FtcapCore.step`, which applies it once (:func:`apply_evidence`)
to what its estimation stage said; the rest of the cycle reads the :class:`Judged` result.
Pure: no I/O, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ftcap_hil.core.estimation.config import Estimate
from ftcap_hil.core.estimation.shaft import ShaftVerdict
from ftcap_hil.core.estimation.stages import StageOutput
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray


def _flags(name: str, value: object | None, m: int) -> BoolArray:
    """(m,) bools from ``value`` (None: all False); ValueError naming ``name`` otherwise."""
    if value is None:
        return np.zeros(m, dtype=bool)
    flags = np.asarray(value, dtype=bool)
    if flags.shape != (m,):
        raise ValueError(f"evidence.{name}: expected {m} flags, got shape {flags.shape}")
    return flags


@fast_init  # built every cycle by the shell (core/frozen.py)
@dataclass(frozen=True)
class Evidence:
    """Thruster failures known from outside the estimator, (m,) bool each.

    ``dead`` (a silent ESC): allocated exactly 0, no recovery probe, no dither. ``stalled``
    (no rpm under command): allocated as dead, its recovery probes go on, so that a shaft
    turning again is seen. Both are flagged faulty and reported at delta_hat 0. Build it with
    :meth:`of` (a thruster both dead and stalled counts as dead) or :meth:`none`.
    """

    dead: BoolArray
    stalled: BoolArray
    shaft: ShaftVerdict | None = None
    motion_confirmed: BoolArray | None = None  # motion-only removals held long enough
    motion: bool = True  # False: the drives alone decide
    dither: bool = False  # dither the thrusters whose drives report fresh telemetry
    # (m,) silent drives the motion has yet to judge: every live thruster dithers meanwhile
    explore: BoolArray | None = None

    @classmethod
    def of(cls, m: int, dead: object | None = None, stalled: object | None = None) -> Evidence:
        """The evidence on ``m`` thrusters (None: nothing known); ValueError for a flag
        vector that is not (m,)."""
        d = _flags("dead", dead, m)
        return cls(d, _flags("stalled", stalled, m) & ~d)

    @classmethod
    def none(cls, m: int) -> Evidence:
        """Nothing known from outside: every thruster as its estimate says."""
        return cls.of(m)

    def with_shaft(
        self,
        verdict: ShaftVerdict,
        motion_confirmed: BoolArray,
        motion: bool = True,
        dither: bool = False,
        explore: BoolArray | None = None,
    ) -> Evidence:
        """This evidence with the drives' verdict: actionable shaft losses are allocated at
        the effectiveness the drive shows (times the motion's hull factor), a stuck
        thruster's held force is compensated, and a motion-only removal of a thruster whose
        drive shows nothing wrong is only advisory until ``motion_confirmed``. ``motion``
        False: the drives alone decide (the motion's estimate is reported, never used).
        ``dither`` False: no dither on a thruster whose drive reports fresh telemetry (its
        drive judges it; probes of a thruster taken out go on), unless ``explore`` (m,) names
        a thruster whose drive is silent and that the motion has yet to judge, not out
        already: then every live thruster dithers."""
        return replace(
            self, shaft=verdict, motion_confirmed=motion_confirmed, motion=motion, dither=dither,
            explore=explore,
        )  # fmt: skip

    @property
    def out(self) -> BoolArray:
        """(m,) thrusters the evidence takes out of the allocation (dead or stalled)."""
        out: BoolArray = self.dead | self.stalled
        return out


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class Judged:
    """One cycle's stage output with the evidence applied: what the allocation reads.

    ``estimate`` as reported (delta_hat 0 where the evidence takes a thruster out);
    ``delta`` (m,) the effectiveness to allocate with; ``bf`` (k,) the bias wrench to
    allocate against; ``faulty`` (m,) the flags; ``quiet`` (m,) thrusters that get neither
    probe nor dither (commanded exactly 0); ``restorable`` (m,) thrusters the stage's
    decision removed that may come back at ``restore_at`` (m,), the stage's own delta_hat,
    when the allocation without them falls short of the demand (never one the evidence
    takes out, dead or stalled, never one whose estimate is below ``dead_threshold``).
    """

    estimate: Estimate
    delta: FloatArray
    bf: FloatArray
    faulty: BoolArray
    quiet: BoolArray
    restorable: BoolArray
    restore_at: FloatArray
    no_dither: BoolArray | None = None  # (m,) probes only: a shaft alarm, a motion suspect


def apply_evidence(
    evidence: Evidence, out: StageOutput, dead_threshold: float, B: FloatArray | None = None
) -> Judged:
    """The stage output ``out`` judged with ``evidence`` (:class:`Judged`); ``dead_threshold``:
    the allocator's (an estimate below it cannot be restored); ``B`` (k, m) to compensate a
    stuck thruster's held force (needed with a shaft verdict)."""
    m = out.delta_alloc.shape[0]
    quiet, no_dither = evidence.dead, np.zeros(m, dtype=bool)
    shaft_out = np.zeros(m, dtype=bool)
    if evidence.shaft is not None:
        out, stuck, no_dither = _with_shaft(evidence, out, B)
        quiet = quiet | stuck
        shaft_out = evidence.shaft.actionable & (evidence.shaft.delta < dead_threshold)
    taken = evidence.out
    est, delta = out.estimate, out.delta_alloc
    if True in taken.tolist():
        est = replace(est, delta_hat=np.where(taken, 0.0, est.delta_hat))
        delta = np.where(taken, 0.0, delta)
    dec = out.decision
    if dec is None:
        restorable = np.zeros(taken.shape, dtype=bool)
    else:
        usable = out.estimate.delta_hat >= dead_threshold
        restorable = dec.removed & ~taken & usable & ~shaft_out
    return Judged(
        estimate=est,
        delta=delta,
        bf=out.bf_alloc,
        faulty=out.faulty | taken,
        quiet=quiet,
        restorable=restorable,
        restore_at=out.estimate.delta_hat,
        no_dither=no_dither,
    )


def _with_shaft(
    evidence: Evidence, out: StageOutput, B: FloatArray | None
) -> tuple[StageOutput, BoolArray, BoolArray]:
    """The stage output with the drives' verdict folded in (:meth:`Evidence.with_shaft`),
    the stuck thrusters (held force compensated: quiet) and those to leave undithered."""
    v = evidence.shaft
    assert v is not None
    if B is None:
        raise ValueError("evidence: a shaft verdict needs B to compensate held forces")
    act = v.actionable
    stuck = v.stuck
    confirmed = evidence.motion_confirmed
    if confirmed is None:
        confirmed = np.zeros(act.shape, dtype=bool)
    # the motion alone suspects a thruster whose drive is fresh and clean: advisory
    advisory = v.fresh & ~act & (out.delta_alloc < 1.0) & ~confirmed
    shown = np.where(act, v.delta, 1.0)
    base = out.delta_alloc if evidence.motion else np.ones_like(out.delta_alloc)
    delta = np.where(advisory, 1.0, base * shown)
    held = np.where(stuck & np.isfinite(v.held_n), v.held_n, 0.0)
    est = replace(out.estimate, delta_hat=out.estimate.delta_hat * shown)
    dec = out.decision
    if dec is not None:
        dec = replace(dec, removed=dec.removed & ~advisory & (evidence.motion | act))
    bf = out.bf_alloc if evidence.motion else np.zeros_like(out.bf_alloc)
    judged = replace(
        out, estimate=est, delta_alloc=delta, bf_alloc=bf + B @ held,
        faulty=(out.faulty if evidence.motion else np.zeros_like(act)) | act, decision=dec,
    )  # fmt: skip
    quiet_drive = v.fresh if not evidence.dither else np.zeros_like(v.fresh)
    explore = evidence.explore
    if evidence.motion and explore is not None:
        out_already = evidence.out if dec is None else evidence.out | dec.removed
        if True in (explore & ~out_already).tolist():
            # a drive fallen silent says nothing of its thruster, so the motion must, and
            # the dither that informs it lives in the null space of every live thruster
            # together (one thruster alone has none): all dither, the fresh drives judging
            # the others meanwhile
            quiet_drive = np.zeros_like(v.fresh)
    return judged, stuck, v.alarm | advisory | quiet_drive
