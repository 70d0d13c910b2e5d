"""Each thruster judged by its own drive: shaft speed and current against a data-sheet model.

The allocator knows, per actuator, what an operator knows from the data sheets
(:class:`DriveModel`): the thrust and torque coefficients k_T = K_T0 rho D^4 and
k_Q = K_Q0 rho D^5 of the propeller, the drive's time constant, the motor's efficiency,
supply voltage and idle current (a servo: its force at full deflection and time constant).
It never sees the simulator's truth. From the commands it sent it predicts the speed the
drive should have (a first-order lag of n_ref = sign(u) sqrt(|u| / k_T), or for a servo of
u / full force) and compares every telemetry sample with it, at the sample's own time::

    r_T = sgn(T_p) (T_m - T_p) / sigma_T             thrust implied by the speed, T = k_T n|n|,
                                                      against the lagged command's (N): a
                                                      deficit is negative either way round
    r_Q = (I_m - I(n_m)) / sigma_I                    the current against what the load at
                                                      the measured speed draws (A)
    sigma_T = band_rel |T_p| + band_abs full, and T_m - T_p taken from the nearest of
              the predictions with the lag T_n (1 + lag_uncertainty)^(+-1) and within
              +-timing_s (the drive's lag and the sample's time are known no better)
    sigma_I = current_rel (I(n_m) - I_idle) + current_abs

Each residual feeds two one-sided CUSUMs, S <- max(0, S + |r| - k) on its own side, updated
only while the thruster is commanded above ``floor_rel`` of its full force (below it the
speed says little: PX4's motor-failure check keeps a throttle floor for the same reason);
an alarm is S > h. From the alarms, the measured speed and current, one hypothesis per
thruster (:class:`Hypothesis`) and the effectiveness its drive shows::

    no telemetry for telemetry_timeout_s        TELEMETRY_LOST  (not a thruster fault: 1)
    thrust low, |n_m| ~ 0, current near idle     DRIVE_DEAD      0
    thrust low, |n_m| ~ 0, current drawn         JAMMED          0
    speed flat while the command moves           STUCK           0, its held force k_T n_m|n_m|
    thrust low, load consistent                  WEAK            (n_m / n_p)^2
    load low for hold_s, thrust consistent       LOAD_LOSS       torque ratio (lost blade)
    load high for hold_s                         LOAD_GAIN       2 - torque ratio (fouling)
    load low for less than hold_s                VENTILATION     1 (transient: never removed)

An alarm clears once the residuals stay within ``clear_z`` for ``clear_s`` of commanded
time; a thruster that is not turning is seen again only when it is commanded (the cycle's
probes). Thresholds are not tuned here: they come from healthy runs on calibration seeds
(``bench/calibrate_shaft.py``). Pure: the time is handed in, no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.estimation.shaft_channel import Channel
from ftcap_hil.core.estimation.shaft_types import (
    NOT_TURNING,
    DiagnosisConfig,
    DriveModel,
    DriveReport,
    Hypothesis,
    ShaftVerdict,
    verdict_without_telemetry,
)
from ftcap_hil.core.messages import FloatArray

__all__ = [
    "DiagnosisConfig",
    "DriveModel",
    "DriveReport",
    "Hypothesis",
    "ShaftDiagnoser",
    "ShaftVerdict",
    "verdict_without_telemetry",
]

RATIO_MAX = 4.0  # the thrust the speed shows over the predicted, at most (twice the speed)


def _thrust_ratio(n_m: float, n_p: float) -> float:
    """(n_m / n_p)^2 where both turn the same way (else 0), at most RATIO_MAX: a speed
    predicted near 0 (a frozen shaft's command gone to 0) gave 1e300 and OverflowError."""
    if not n_p or n_m * n_p <= 0.0:
        return 0.0
    r = n_m / n_p
    return min(r * r, RATIO_MAX)


@dataclass(frozen=True)
class ResidualSample:
    """One healthy, commanded sample's raw residuals: thruster ``index`` at ``t_s``, the
    predicted thrust (N) and the thrust error outside the prediction's range (N, signed as
    the thrust), the predicted load current above idle and its error (A, NaN: none)."""

    index: int
    t_s: float
    thrust_n: float
    thrust_error_n: float
    load_a: float
    load_error_a: float


class ShaftDiagnoser:
    """The module docstring's diagnosis of ``m`` actuators. Call :meth:`command` with every
    command sent, :meth:`feedback` with every telemetry sample, :meth:`verdict` when a
    decision is needed; every time is the caller's (s, one clock)."""

    def __init__(self, models: Sequence[DriveModel], config: DiagnosisConfig | None = None):
        self.config = cfg = config or DiagnosisConfig()
        self._ch = [Channel(mdl, cfg) for mdl in models]
        self.m = len(self._ch)
        # set to a list to collect the raw residuals of healthy commanded samples, for
        # fitting the bands on healthy runs (bench/calibrate_shaft.py); None: not kept
        self.trace: list[ResidualSample] | None = None

    def command(self, t_s: float, u: FloatArray) -> None:
        """The commands ``u`` (m,) N sent at ``t_s``: the prediction moves to them."""
        for ch, ui in zip(self._ch, np.asarray(u, dtype=np.float64).tolist(), strict=True):
            ch.advance(t_s)
            ch.ref = ch.reference(ui)

    def feedback(self, t_received_s: float, index: int, speed: float, current_a: float) -> None:
        """One drive's report (speed rev/s or deflection, current A) received at
        ``t_received_s``; it was measured ``latency_s`` earlier. The in-flow's share of the
        load is learnt (the channel's load model), not told. A sample for an unknown
        actuator or with a non-finite speed is ignored."""
        if not (0 <= index < self.m and math.isfinite(speed)):
            return
        ch, cfg = self._ch[index], self.config
        t_s = t_received_s - cfg.latency_s
        t_measured_s = t_received_s
        ch.advance(t_received_s)
        speeds = ch.predicted_at(t_s)
        n_p = ch.speed_scale * speeds[0]
        t_p = ch.open_water(n_p)
        mdl = ch.model
        t_m = ch.open_water(speed)
        sigma_t = cfg.band_rel * abs(t_p) + cfg.band_abs * mdl.full_force_n
        # what the prediction says for a faster or slower drive, and within +-timing_s:
        # a measurement inside that range is no evidence
        shifted = (ch.predicted_at(t_s + d)[0] for d in (-cfg.timing_s, cfg.timing_s))
        around = [ch.open_water(ch.speed_scale * n) for n in (*speeds[1:], *shifted)]
        lo, hi = min(t_p, *around), max(t_p, *around)
        # in the direction of the predicted thrust: a deficit is negative either way round
        ch.r_t = math.copysign(1.0, t_p) * (t_m - min(max(t_m, lo), hi)) / sigma_t
        ch.t_m, ch.t_p, ch.sig_t = t_m, t_p, sigma_t
        ch.steady = hi - lo <= 0.1 * abs(t_p)
        ch.r_q = math.nan
        if ch.load_visible and math.isfinite(current_a):
            i_pred = ch.current_at(speed)
            sigma_i = cfg.current_rel * (i_pred - mdl.idle_a) + cfg.current_abs
            ch.r_q = (current_a - i_pred) / sigma_i
            ch.i_m, ch.i_pred, ch.sig_i = current_a, i_pred, sigma_i
        ch.speed_m = speed
        ch.last_sample_s = t_measured_s
        ch.thrust_sum += t_m
        ch.thrust_count += 1
        floor = cfg.probe_rel if ch.hyp in NOT_TURNING else cfg.floor_rel
        commanded = abs(t_p) >= floor * mdl.full_force_n
        if self.trace is not None and commanded and ch.hyp is Hypothesis.HEALTHY:
            self.trace.append(ResidualSample(
                index, t_measured_s, t_p, ch.r_t * sigma_t, ch.i_pred - mdl.idle_a,
                ch.r_q * ch.sig_i if math.isfinite(ch.r_q) else math.nan,
            ))  # fmt: skip
        self._judge(ch, t_measured_s, speed, n_p, current_a, commanded)

    def _judge(
        self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float,
        commanded: bool,
    ) -> None:  # fmt: skip
        cfg = self.config
        if ch.hyp is Hypothesis.TELEMETRY_LOST:
            ch.hyp = Hypothesis.HEALTHY
        ch.recent.append((t_s, n_m, n_p))
        while ch.recent and ch.recent[0][0] < t_s - cfg.stuck_window_s:
            ch.recent.popleft()
        if not commanded and ch.hyp not in (Hypothesis.STUCK,):
            return  # little evidence either way: hold the decision and the tests
        ch.thrust.update(ch.r_t, cfg.cusum_k)
        if math.isfinite(ch.r_q):
            ch.load.update(ch.r_q, cfg.cusum_k)
        if n_p:
            ch.ratio_t += 0.2 * (_thrust_ratio(n_m, n_p) - ch.ratio_t)
        if math.isfinite(ch.r_q):
            i_pred = ch.current_at(n_m) - ch.model.idle_a
            if i_pred > 1e-9:
                ch.ratio_q += 0.2 * ((current_a - ch.model.idle_a) / i_pred - ch.ratio_q)
        if ch.hyp is Hypothesis.HEALTHY:
            commissioning = ch.seen < cfg.cal_samples
            ch.seen += 1
            quiet = abs(ch.r_t) < cfg.clear_z
            gap = self._sample_gap(ch)
            if ch.steady and (quiet or commissioning):
                ch.calibrate(gap, n_m, n_p / ch.speed_scale)
            if ch.load_visible and math.isfinite(current_a):
                ch.load_model.learn(gap, n_m, current_a)  # a static map: any healthy sample
            if commissioning:
                ch.thrust.reset()  # the tests start on the calibrated model
                ch.load.reset()
                return
            self._raise(ch, t_s, n_m, n_p, current_a)
        else:
            self._follow(ch, t_s, n_m, n_p, current_a)

    def _raise(self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """A healthy thruster's tests: which alarm, if any, starts an episode."""
        h = self.config.cusum_h
        if ch.thrust.high > h and not ch.thrust.low > h and not self._flat(ch):
            ch.thrust.high = 0.0  # more thrust than asked and following the command: no fault
        if ch.thrust.low > h or ch.thrust.high > h:
            ch.hyp = self._thrust_cause(ch, n_m, n_p, current_a)
        elif ch.load.low > h:
            ch.hyp = Hypothesis.VENTILATION
        elif ch.load.high > h:
            ch.hyp = Hypothesis.VENTILATION  # a load step: confirmed as fouling after hold_s
        else:
            return
        ch.since_s, ch.calm_s, ch.held_t = t_s, 0.0, ch.t_m
        ch.ratio_t = _thrust_ratio(n_m, n_p)

    def _thrust_cause(self, ch: Channel, n_m: float, n_p: float, current_a: float) -> Hypothesis:
        cfg, mdl = self.config, ch.model
        if self._flat(ch):
            return Hypothesis.STUCK
        if abs(n_m) < cfg.stall_rel * abs(n_p):
            if not mdl.is_shaft:
                return Hypothesis.DRIVE_DEAD
            drawn = ch.current_at(n_p) - mdl.idle_a
            if math.isfinite(current_a) and current_a - mdl.idle_a > cfg.jam_current_rel * drawn:
                return Hypothesis.JAMMED
            return Hypothesis.DRIVE_DEAD
        return Hypothesis.WEAK

    def _flat(self, ch: Channel) -> bool:
        """The speed held (within a fifth of it) while the prediction moved by more than 5 %
        of its size over ``stuck_window_s``."""
        if len(ch.recent) < 3:
            return False
        speeds = [r[1] for r in ch.recent]
        preds = [r[2] for r in ch.recent]
        moved = max(preds) - min(preds)
        held = max(speeds) - min(speeds)
        scale = max(abs(p) for p in preds) or 1.0
        return moved > 0.05 * scale and held < 0.2 * moved

    def _follow(self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """An episode in progress: confirm a load change, re-judge, or clear."""
        cfg = self.config
        quiet = self._healthy_fits(ch)
        if ch.hyp is Hypothesis.STUCK:
            quiet = quiet and not self._flat(ch)
        ch.calm_s = ch.calm_s + self._sample_gap(ch) if quiet else 0.0
        if ch.calm_s >= cfg.clear_s:
            ch.hyp = Hypothesis.HEALTHY
            ch.thrust.reset()
            ch.load.reset()
            ch.ratio_t = ch.ratio_q = 1.0
            return
        h = cfg.cusum_h
        if ch.hyp is Hypothesis.VENTILATION and t_s - ch.since_s >= cfg.hold_s:
            if ch.load.low > h:
                ch.hyp = Hypothesis.LOAD_LOSS
            elif ch.load.high > h:
                ch.hyp = Hypothesis.LOAD_GAIN
        elif ch.hyp in (Hypothesis.WEAK, Hypothesis.VENTILATION):
            if ch.thrust.high > h and not ch.thrust.low > h and not self._flat(ch):
                ch.thrust.high = 0.0  # more thrust than asked, following the command
            if ch.thrust.low > h or ch.thrust.high > h:
                ch.hyp = self._thrust_cause(ch, n_m, n_p, current_a)

    def _healthy_fits(self, ch: Channel) -> bool:
        """The last sample is within ``clear_z`` of the healthy prediction and closer to it
        than to the episode's fault (a transient only needs the first)."""
        z_clear = self.config.clear_z
        load = math.isfinite(ch.r_q)
        if ch.hyp is Hypothesis.VENTILATION:
            return abs(ch.r_t) < z_clear and not (load and abs(ch.r_q) > z_clear)
        if ch.hyp in (Hypothesis.LOAD_LOSS, Hypothesis.LOAD_GAIN):
            if not load:
                return False
            drawn = ch.i_pred - ch.model.idle_a
            z_fault = (ch.i_m - ch.model.idle_a - ch.ratio_q * drawn) / ch.sig_i
            gone = abs(ch.ratio_q - 1.0) < 0.15  # the fault's own estimate is back
            return abs(ch.r_q) < z_clear and (gone or abs(ch.r_q) < abs(z_fault))
        shown = _effectiveness(ch.hyp, ch)
        fault = ch.held_t if ch.hyp is Hypothesis.STUCK else shown * ch.t_p
        z_fault = (ch.t_m - fault) / ch.sig_t
        gone = ch.hyp is Hypothesis.WEAK and shown > 0.9
        return abs(ch.r_t) < z_clear and (gone or abs(ch.r_t) < abs(z_fault))

    @staticmethod
    def _sample_gap(ch: Channel) -> float:
        r = ch.recent
        return r[-1][0] - r[-2][0] if len(r) >= 2 else 0.0

    def report(self, r: DriveReport) -> None:
        """:meth:`feedback` of a :class:`DriveReport`."""
        self.feedback(r.t_s, r.index, r.speed, r.current_a)

    def take_thrust_means(self) -> FloatArray:
        """(m,) the mean thrust the measured speeds implied since the last call (N; NaN
        where no sample came), for the motion filter's input; starts the next interval."""
        out = np.full(self.m, math.nan)
        for i, ch in enumerate(self._ch):
            if ch.thrust_count:
                out[i] = ch.thrust_sum / ch.thrust_count
            ch.thrust_sum, ch.thrust_count = 0.0, 0
        return out

    def verdict(self, t_s: float) -> ShaftVerdict:
        """Every actuator's hypothesis and shaft-evidenced effectiveness at ``t_s``."""
        cfg = self.config
        hyps, delta, held, thrust, fresh, alarm, rt, rq = [], [], [], [], [], [], [], []
        for ch in self._ch:
            ok = t_s - ch.last_sample_s <= cfg.telemetry_timeout_s
            hyp = ch.hyp if ok else Hypothesis.TELEMETRY_LOST
            hyps.append(hyp)
            fresh.append(ok)
            alarm.append(hyp not in (Hypothesis.HEALTHY, Hypothesis.TELEMETRY_LOST))
            thrust.append(ch.open_water(ch.speed_m) if ok else math.nan)
            held.append(thrust[-1] if hyp is Hypothesis.STUCK else math.nan)
            delta.append(_effectiveness(hyp, ch))
            rt.append(ch.r_t)
            rq.append(ch.r_q)
        return ShaftVerdict(
            tuple(hyps), np.array(delta), np.array(held), np.array(thrust),
            np.array(fresh, dtype=bool), np.array(alarm, dtype=bool), np.array(rt), np.array(rq),
        )  # fmt: skip


def _effectiveness(hyp: Hypothesis, ch: Channel) -> float:
    """The share of the healthy force the drive shows under ``hyp``."""
    if hyp in (Hypothesis.DRIVE_DEAD, Hypothesis.JAMMED, Hypothesis.STUCK):
        return 0.0
    if hyp is Hypothesis.WEAK:
        return min(max(ch.ratio_t, 0.0), 1.0)
    if hyp is Hypothesis.LOAD_LOSS:
        return min(max(ch.ratio_q, 0.0), 1.0)
    if hyp is Hypothesis.LOAD_GAIN:
        return min(max(2.0 - ch.ratio_q, 0.0), 1.0)
    return 1.0
