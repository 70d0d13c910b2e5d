"""One allocator cycle: estimate faults -> bounds -> allocate. Pure: no I/O, no clock.

Call order per cycle t (Algorithm 1 of the paper):

    sample = Observation(x(t-1), x(t), dt_s)         # by the caller, from telemetry
    evidence = Evidence.of(m, dead, stalled)         # by the caller, from the ESC telemetry
    result = core.step(tau_d(t), sample, elapsed_s=elapsed_s, evidence=evidence)
    send(result.u)

``sample`` is None when telemetry is stale; ``dt_s`` is the estimation interval on the
vessel's clock, ``elapsed_s`` the time since the last cycle (for the rate limits).

``step`` assumes that the command acting over the last estimation interval is the one it
returned last time (``u_sample`` overrides that: the daemon passes the time average of what
it sent). The centre of the rate box is always the last command (``reset_command`` sets it,
e.g. after the shell had to send zero).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ftcap_hil.core.allocation.allocator import Allocation, Allocator, AllocatorConfig
from ftcap_hil.core.allocation.excitation import Excitation, ExcitationConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.estimation.config import Estimate, EstimatorConfig, EstimatorKind, wrench_scale
from ftcap_hil.core.estimation.decisions import Decision
from ftcap_hil.core.estimation.shaft import (
    DiagnosisConfig,
    DriveModel,
    DriveReport,
    ShaftDiagnoser,
    ShaftVerdict,
)
from ftcap_hil.core.estimation.stages import (
    EstimationStage,
    IdentityStage,
    KalmanStage,
    Observation,
    OracleStage,
    Sample,
    StageOutput,
    WindowedStage,
)
from ftcap_hil.core.estimation.windowed import LiteralEstimator, WindowedEstimator
from ftcap_hil.core.evidence import Evidence, Judged, apply_evidence
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.models.vessel3dof import PlantModel
from ftcap_hil.core.status import Mode

# A demand unmet by more than this fraction of the wrench range on an axis brings removed
# thrusters back at their estimate for that cycle (FtcapCore._unremove_if_short).
SHORT_FRACTION = 0.02


@dataclass(frozen=True)
class CoreConfig:
    """Everything one :class:`FtcapCore` is built from: the mode (:class:`Mode`), the
    estimator, allocator and excitation settings, and the fault-flag thresholds (fractions
    of full effectiveness, 0 < fault_threshold <= fault_clear <= 1 in practice)."""

    mode: Mode = Mode.FTCAP
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    allocator: AllocatorConfig = field(default_factory=AllocatorConfig)
    excitation: ExcitationConfig = field(default_factory=ExcitationConfig)
    # Fault flags, with hysteresis: flagged when delta_hat drops below fault_threshold,
    # cleared when it rises above fault_clear (when each stage may change them: estimation.py).
    fault_threshold: float = 0.85
    fault_clear: float = 0.95
    # First-order lag of each thruster's force behind its command (s, (m,) or empty: none),
    # as its data sheet or a step test gives it; the estimator then compares the motion with
    # the lagged force, not with the command.
    thruster_lag_s: tuple[float, ...] = ()
    # The drives' diagnosis (core/estimation/shaft.py), used when FtcapCore has drive models.
    diagnosis: DiagnosisConfig = field(default_factory=DiagnosisConfig)


class ThrustLag:
    """The mean force a first-order lag (time constants T, (m,) s) delivers over an interval
    of dt under a constant command c: F_mean = c + (F0 - c) T/dt (1 - exp(-dt/T)), exact;
    F0 is the force at the interval's start, carried from one call to the next."""

    def __init__(self, time_constants_s: FloatArray) -> None:
        self._tc = np.asarray(time_constants_s, dtype=np.float64)
        self._f = np.zeros(self._tc.size)

    def mean_force(self, c: FloatArray, dt_s: float) -> FloatArray:
        """The interval's mean force (m,) under the command ``c`` (m,) held for ``dt_s``."""
        lagged = self._tc > 0.0
        tc = np.where(lagged, self._tc, 1.0)
        a = np.where(lagged, np.exp(-dt_s / tc), 0.0)
        b = np.where(lagged, tc / dt_s * (1.0 - a), 0.0)
        mean: FloatArray = c + (self._f - c) * b
        self._f = c + (self._f - c) * a
        return mean


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class CycleResult:
    """What one :meth:`FtcapCore.step` produced; per-thruster arrays are (m,)."""

    u: FloatArray  # (m,) command to send (N)
    estimate: Estimate
    allocation: Allocation
    faulty: BoolArray  # (m,), see CoreConfig.fault_threshold / fault_clear
    probing: BoolArray  # (m,), a recovery probe is active
    estimation_frozen: bool
    decision: Decision | None = None  # the Kalman stage's decision (in use, observable, bias)
    shaft: ShaftVerdict | None = None  # the drives' verdict (None: no drive models)


def _finite(sample: Sample) -> bool:
    if isinstance(sample, Observation):
        return sample.finite()
    return math.isfinite(float(np.sum(sample)))


class FtcapCore:
    """The allocator's cycle (module docstring): fault estimation, excitation, allocation.

    ``B`` (k, m): effectiveness matrix, k = 3 for a surface vessel (tau = [X (N), Y (N),
    N (N*m)], body frame) or 1 for the linear plant; ``thrusters``: the m thrusters' limits;
    ``period_s``: the allocation period (s). The mode picks the estimation stage
    (core/estimation/stages.py): ``FTCAP`` the Kalman estimator (or the windowed one with
    ``estimator.kind = EstimatorKind.WINDOWED``), ``FTCAP_LITERAL`` the paper's literal one,
    ``ORACLE`` the truth handed in to :meth:`step`, ``CAP`` / ``NONE`` none (Delta_hat = I,
    f_hat = 0). ``plant``: the allocator's model of the plant, needed by the Kalman
    estimator and to invert :class:`Observation` samples for the windowed one. Pure and
    single-threaded: the caller hands in measurements and times, the core reads no clock.
    ValueError if ``B`` and ``thrusters`` disagree on m.
    """

    def __init__(
        self,
        B: FloatArray,
        thrusters: ThrusterSet,
        period_s: float,
        config: CoreConfig | None = None,
        plant: PlantModel | None = None,
        drives: Sequence[DriveModel] | None = None,
    ):
        self.config = config or CoreConfig()
        self.B = np.array(B, dtype=np.float64)
        self.k, self.m = self.B.shape
        if thrusters.m != self.m:
            raise ValueError(f"B has {self.m} columns but the vessel has {thrusters.m} thrusters")
        self.scale = wrench_scale(self.B, thrusters.u_min, thrusters.u_max)
        self.allocator = Allocator(self.B, thrusters, period_s, self.scale, self.config.allocator)
        self.u_range = np.maximum(np.abs(thrusters.u_min), np.abs(thrusters.u_max))
        self.excitation = Excitation(self.B, self.u_range, self.config.excitation)
        self.stage = self._make_stage(plant)
        lag = self.config.thruster_lag_s
        if lag and len(lag) != self.m:
            raise ValueError(f"thruster_lag_s: expected {self.m} time constants, got {lag}")
        self._lag = ThrustLag(np.array(lag)) if lag and max(lag) > 0.0 else None
        self._unsized = isinstance(self.stage, KalmanStage) and self.config.excitation.info_rate > 0
        self.u_prev = np.zeros(self.m)
        self.shaft: ShaftDiagnoser | None = None
        if drives is not None and self.config.mode is Mode.FTCAP and self.config.diagnosis.enabled:
            if len(drives) != self.m:
                raise ValueError(f"drives: expected {self.m} drive models, got {len(drives)}")
            self.shaft = ShaftDiagnoser(drives, self.config.diagnosis)
        self._motion_only_s = np.zeros(self.m)  # a motion-only removal held this long
        self._silent_known = np.zeros(self.m, dtype=bool)  # judged since its drive fell silent
        self._spoken = np.zeros(self.m, dtype=bool)  # its drive has reported at least once
        self._was_silent = np.zeros(self.m, dtype=bool)  # had spoken, silent at the last cycle
        self._fell = np.zeros(self.m, dtype=bool)  # fell silent at this cycle
        self._silent_info = np.zeros(self.m)  # the motion's information since the fall
        self._held_before = np.zeros(self.m, dtype=bool)  # motion's losses before a silence
        self._shown = np.zeros(self.m, dtype=bool)  # its drive showed an actionable loss
        self._period_s = period_s
        self._estimates = self.config.mode.estimates
        # Pure functions of their inputs, kept while those are the very same objects (a
        # cycle without a new sample: the stage hands back its last output): the judged
        # output, and the excitation of a cycle that does not advance it.
        self._no_evidence = Evidence.none(self.m)
        self._judged: tuple[Evidence, StageOutput, Judged, bool] | None = None
        self._excited: tuple[Judged, int, tuple[FloatArray | None, FloatArray | None]] | None
        self._excited = None

    def _size_excitation(self, estimation_dt_s: float) -> None:
        """Raise the dither and probe amplitudes to what the sensor's noise needs (see
        ExcitationConfig.info_rate), once the estimation period is known."""
        assert isinstance(self.stage, KalmanStage)
        exc = self.config.excitation
        need = self.stage.filter.excitation_for(exc.info_rate, estimation_dt_s) / self.u_range
        frac = float(min(max(need.max(), 0.0), exc.amplitude_max))
        sized = replace(
            exc,
            dither_amplitude=max(exc.dither_amplitude, frac),
            probe_amplitude=max(exc.probe_amplitude, frac),
        )
        self.excitation.config = sized
        self.config = replace(self.config, excitation=sized)
        self._unsized = False
        self._excited = None

    def _make_stage(self, plant: PlantModel | None) -> EstimationStage:
        cfg = self.config
        on, off = cfg.fault_threshold, cfg.fault_clear
        if cfg.mode is Mode.ORACLE:
            return OracleStage(self.B, on, off)
        if cfg.mode is Mode.FTCAP_LITERAL:
            literal = LiteralEstimator(self.B, self.scale, cfg.estimator)
            return WindowedStage(literal, plant, on, off)
        if cfg.mode is not Mode.FTCAP:
            return IdentityStage(self.m, self.k)
        if cfg.estimator.kind is EstimatorKind.WINDOWED:
            windowed = WindowedEstimator(self.B, self.scale, cfg.estimator)
            return WindowedStage(windowed, plant, on, off)
        if plant is None:
            raise ValueError("the Kalman estimator needs the plant model (FtcapCore(plant=...))")
        return KalmanStage(self.B, self.scale, self.u_range, plant, cfg.estimator, on, off)

    def step(
        self,
        tau_d: FloatArray,
        w: Sample | None,
        truth: Truth | None = None,
        u_sample: FloatArray | None = None,
        elapsed_s: float | None = None,
        evidence: Evidence | None = None,
        feedback: Sequence[DriveReport] = (),
        t_s: float | None = None,
    ) -> CycleResult:
        """One cycle; returns the command to send and what led to it.

        tau_d (k,): demanded wrench, body frame. w: the last estimation interval's sample,
        an :class:`Observation` (or, for the windowed and literal estimators, the actuator
        wrench (k,) already inverted from it), or None when there is no new sample
        (estimates held; the excitation does not advance). u_sample (m,): the command that
        was acting over that interval (its time average); defaults to the last command.
        elapsed_s: time since the last cycle, for the rate limits; defaults to the configured
        period. truth: the true faults, needed in ``ORACLE`` mode only (ValueError without).
        evidence: thrusters known dead or stalled from outside (the ESC telemetry; None:
        nothing known), applied once to the stage's output (:func:`apply_evidence`).
        feedback: the drive reports received since the last cycle and ``t_s`` the time now
        (s, the reports' clock), for the drives' diagnosis (with drive models only): the
        motion filter is then fed the thrust the measured speeds imply, and the verdict
        joins the evidence (:meth:`Evidence.with_shaft`).
        """
        w, u_sample = self._sample(w, self.u_prev if u_sample is None else u_sample)
        ev = self._no_evidence if evidence is None else evidence
        verdict = None
        if self.shaft is not None and t_s is not None:
            verdict, u_sample = self._diagnose(feedback, t_s, w is not None, u_sample)
        out = self.stage.update(w, u_sample, truth)
        if verdict is not None:
            ev = self._with_drives(ev, verdict, out, elapsed_s, w is not None)
        seen, restorable = self._judge(ev, out)
        u_pref, probe = self._excite(seen, advance=w is not None)

        def allocate(delta: FloatArray) -> Allocation:
            return self.allocator.allocate(
                tau_d, delta, seen.bf, self.u_prev, u_pref, probe, elapsed_s
            )

        alloc = allocate(seen.delta)
        if restorable:
            alloc = self._unremove_if_short(alloc, seen, allocate)
        self.u_prev = alloc.u
        if self.shaft is not None and t_s is not None:
            self.shaft.command(t_s, alloc.u)
        return CycleResult(
            alloc.u,
            seen.estimate,
            alloc,
            seen.faulty,
            np.zeros(self.m, dtype=bool) if probe is None else probe > 0,
            estimation_frozen=self._estimates and w is None,
            decision=out.decision,
            shaft=verdict,
        )

    def _judge(self, ev: Evidence, out: StageOutput) -> tuple[Judged, bool]:
        """:func:`apply_evidence` (kept while ``ev`` and ``out`` are the same objects) and
        whether any thruster is restorable."""
        last = self._judged
        if last is not None and last[0] is ev and last[1] is out:
            return last[2], last[3]
        seen = apply_evidence(ev, out, self.config.allocator.dead_threshold, self.B)
        restorable = True in seen.restorable.tolist()
        self._judged = (ev, out, seen, restorable)
        return seen, restorable

    def _sample(self, w: Sample | None, u_sample: FloatArray) -> tuple[Sample | None, FloatArray]:
        """The sample the stage gets (None if non-finite, or so large its sum overflows)
        and the command's mean over it (lagged by the thrusters' time constants)."""
        if w is not None and not _finite(w):
            w = None
        if self._unsized and isinstance(w, Observation) and w.finite():
            self._size_excitation(w.dt_s)
        if self._lag is not None and isinstance(w, Observation):
            u_sample = self._lag.mean_force(u_sample, w.dt_s)
        return w, u_sample

    def _diagnose(
        self, feedback: Sequence[DriveReport], t_s: float, sampled: bool, u_sample: FloatArray
    ) -> tuple[ShaftVerdict, FloatArray]:
        """The drives' verdict at ``t_s`` after ``feedback``; on a new estimation sample the
        motion filter's input: the (lagged) command times the effectiveness the drive shows
        (1 where it shows nothing the allocator acts on), as the allocation multiplies the
        motion's estimate by the drive's: the motion judges the whole thruster where the
        drive sees nothing wrong (a weak motor or a hull loss its test misses, as with no
        drives) and the rest of a loss the drive has named (its shown effectiveness off
        the truth); a stuck shaft's input is the thrust its frozen speed implies (its held
        force is compensated apart). Where a drive turns actionable, what the motion learnt
        of its thruster is dropped: the drive's verdict explains that loss from then on.

        Not the measured speeds' thrust where the drive is healthy: on a thruster turning
        as commanded it adds the data sheet's K_T error and the telemetry's latency to the
        motion's input (CyberShip II, a drawn model error: the starboard propeller's
        estimate 0.55 against 0.89 on the command, a false alarm held for the whole run)."""
        assert self.shaft is not None
        for report in feedback:
            self.shaft.report(report)
        verdict = self.shaft.verdict(t_s)
        shown = verdict.fresh & verdict.actionable
        turned = shown & ~self._shown
        self._shown = shown
        if True in turned.tolist() and isinstance(self.stage, KalmanStage):
            self.stage.forget(turned)
        if sampled:
            implied = self.shaft.take_thrust_means()
            u_sample = u_sample * np.where(shown, verdict.delta, 1.0)
            stuck = shown & verdict.stuck & np.isfinite(implied)
            if True in stuck.tolist():
                u_sample = np.where(stuck, implied, u_sample)
        return verdict, u_sample

    def _with_drives(
        self, ev: Evidence, verdict: ShaftVerdict, out: StageOutput, elapsed_s: float | None,
        sampled: bool = True,
    ) -> Evidence:  # fmt: skip
        """``ev`` with the drives' verdict and the diagnosis's switches (motion, dither);
        ``sampled``: this cycle brought a new estimation sample."""
        self._drives_back(verdict, out)
        confirmed = self._motion_confirmed(out, verdict, elapsed_s)
        diag = self.config.diagnosis
        explore = self._explore(out, verdict, sampled)
        return ev.with_shaft(verdict, confirmed, diag.motion, diag.dither, explore)

    def _drives_back(self, verdict: ShaftVerdict, out: StageOutput) -> None:
        """A drive that speaks again after a silence and shows a healthy shaft: the motion's
        opinion of its thruster, learnt while only the motion could judge it (a power loss,
        an intermittent connector), is dropped, so that a fault that ended is not held
        against it (nor removed again after ``motion_removal_s`` as an advisory). So is a
        loss it came to hold during the silence against a thruster whose drive reports a
        healthy shaft: that may be the silent thruster's loss charged to a neighbour (the
        supply vessel's two mains, one losing power spell after spell: the other held at
        0.1-0.5 from the second spell on and removed for 273 s). Losses it held before the
        silence began are kept."""
        back = self._was_silent & verdict.fresh & ~verdict.alarm
        self._spoken = self._spoken | verdict.fresh
        silent = ~verdict.fresh & self._spoken
        losses = out.delta_alloc < 1.0
        if True not in self._was_silent.tolist():
            self._held_before = losses  # the losses held when no drive was silent yet
        self._fell = silent & ~self._was_silent
        self._was_silent = silent
        if True in back.tolist() and isinstance(self.stage, KalmanStage):
            charged = verdict.fresh & ~verdict.actionable & losses & ~self._held_before
            drop = back | charged
            self.stage.forget(drop)
            self._motion_only_s = np.where(drop, 0.0, self._motion_only_s)

    def _explore(self, out: StageOutput, verdict: ShaftVerdict, sampled: bool = True) -> BoolArray:
        """Thrusters whose drive is silent and that the motion has not judged since the drive
        fell silent: they need the dither. The question a silent drive raises is whether
        its thruster still pushes (power lost) or not (telemetry lost), and the allocator
        acts on the answer below ``removal_threshold``: judged, once the Fisher information
        of the samples taken since the fall (``sampled``: this cycle's output is new) puts
        its standard deviation s so that delta_hat - z_flag s clears that threshold, or
        under ``observable_std`` whatever the estimate; or once it is taken out. Not the
        posterior's deviation: a thruster the motion knew well before (a prior of 0.05, a
        main propeller's history) is known as it was, not as it is, and the dither ended at
        the fall (the supply vessel's mains, power lost, were never isolated fused, where the
        motion alone took 10-30 s). Without the Kalman stage's decision: the estimate's own
        deviation under ``observable_std``. Once judged, not again until the drive has
        spoken and fallen silent anew, so that a drive that only lost its telemetry costs
        the boat one spell of dither. A drive that has not reported yet (the start, before
        its first sample) has not fallen silent."""
        silent = ~verdict.fresh & self._spoken
        est_cfg = self.config.estimator
        dec = out.decision
        if dec is not None and dec.info is not None:
            gained = dec.info if sampled else np.zeros(self.m)
            self._silent_info = np.where(silent & ~self._fell, self._silent_info + gained, 0.0)
            s = 1.0 / np.sqrt(np.maximum(self._silent_info, 1e-300))
            pushes = out.estimate.delta_hat - est_cfg.z_flag * s > est_cfg.removal_threshold
            seen = pushes | (s <= est_cfg.observable_std)
        else:
            std = out.estimate.delta_std
            seen = np.ones(self.m, dtype=bool) if std is None else std < est_cfg.observable_std
        self._silent_known = silent & (self._silent_known | seen)
        explore: BoolArray = silent & ~self._silent_known
        return explore

    def _motion_confirmed(
        self, out: StageOutput, verdict: ShaftVerdict, elapsed_s: float | None
    ) -> BoolArray:
        """Thrusters the motion alone has kept removed (drive fresh and clean) for
        ``diagnosis.motion_removal_s``: only then is that removal acted upon."""
        suspect = verdict.fresh & ~verdict.actionable & (out.delta_alloc < 1.0)
        dt = self._period_s if elapsed_s is None else elapsed_s
        self._motion_only_s = np.where(suspect, self._motion_only_s + dt, 0.0)
        confirmed: BoolArray = self._motion_only_s >= self.config.diagnosis.motion_removal_s
        return confirmed

    def _excite(self, seen: Judged, advance: bool) -> tuple[FloatArray | None, FloatArray | None]:
        """The excitation's preferred command and probe limits (``FTCAP`` mode only; None
        otherwise); a quiet thruster (known dead) gets neither: exactly 0."""
        if self.config.mode is not Mode.FTCAP:
            return None, None
        cycle = self.excitation.cycle
        last = self._excited
        if not advance and last is not None and last[0] is seen and last[1] == cycle:
            return last[2]  # the same inputs at the same point of the sequence
        dead = seen.delta < self.config.allocator.dead_threshold
        exc = self.excitation(seen.delta, dead, advance=advance, still=seen.no_dither)
        u_pref, probe = exc.u_pref, exc.probe_limit
        if True in seen.quiet.tolist():
            u_pref = np.where(seen.quiet, 0.0, u_pref)
            probe = np.where(seen.quiet, 0.0, probe)
        self._excited = (seen, cycle, (u_pref, probe))
        return u_pref, probe

    def _unremove_if_short(
        self, alloc: Allocation, seen: Judged, allocate: Callable[[FloatArray], Allocation]
    ) -> Allocation:
        """Removal is an economy, never a loss of authority: when the allocation without the
        removed thrusters leaves part of the demand unmet (more than ``SHORT_FRACTION`` of the
        wrench range on an axis), allocate again (``allocate``: the cycle's allocation for an
        effectiveness vector) with the restorable ones (:class:`Judged`) at their estimated
        effectiveness and keep whichever plan meets more of the demand (scaled norm of the
        shortfall).

        Why: a removed thruster is one whose estimate says it gives a third of its thrust or
        less, and on two parallel thrusters one that is stuck on can make the healthy one
        look weak. Taken out, the vessel may then have no way left to oppose the stuck
        thrust: measured on the CyberShip II with its port propeller stuck at +2.9 N, the
        starboard one removed and the boat pushed 46 m off station where CAP held 0.9 m.
        Commanded at its estimate it still pushes, and its data start flowing again.
        """
        back = seen.restorable
        if True not in back.tolist():
            return alloc
        short = np.abs(alloc.unallocated) / self.scale
        if short.max() <= SHORT_FRACTION:
            return alloc
        retry = allocate(np.where(back, seen.restore_at, seen.delta))
        if np.linalg.norm(retry.unallocated / self.scale) < np.linalg.norm(short):
            return retry
        return alloc

    def retune(
        self, allocator: AllocatorConfig | None = None, excitation: ExcitationConfig | None = None
    ) -> None:
        """Change allocation weights / excitation without touching the estimator's state."""
        if allocator is not None:
            self.allocator.retune(allocator)
            self.config = replace(self.config, allocator=allocator)
            self._judged = None  # judged with the old dead threshold
        if excitation is not None:
            self.excitation.config = excitation
            self.config = replace(self.config, excitation=excitation)
        self._excited = None

    def reset_command(self, u: FloatArray | None = None) -> None:
        """Tell the core what is on the actuators now (e.g. zero after a watchdog stop)."""
        self.u_prev = np.zeros(self.m) if u is None else np.array(u, dtype=np.float64)
