"""Each thruster judged by its own drive: shaft speed and current against a data-sheet model.

The allocator knows, per actuator, what an operator knows from the data sheets
(:class:`DriveModel`): the thrust and torque coefficients k_T = K_T0 rho D^4 and
k_Q = K_Q0 rho D^5 of the propeller, the drive's time constant, the motor's efficiency,
supply voltage and idle current (a servo: its force at full deflection and time constant).
It never sees the simulator's truth. From the commands it sent it predicts the speed the
drive should have (a first-order lag of n_ref = sign(u) sqrt(|u| / k_T), or for a servo of
u / full force) and compares every telemetry sample with it, at the sample's own time, in the
quantity the drive measures: its speed, at the speed it runs::

    r_n = sgn(n_p) (n_m - n_p) / sigma_n             the measured speed against the lagged
                                                      command's (rev/s): a deficit is
                                                      negative either way round
    r_Q = (I_m - I(n_m)) / sigma_I                    the current against what the load at
                                                      the measured speed draws (A)
    sigma_n = band_rel |n_p| + max(band_res, 1/2) speed_resolution + spread(n_p) (servos:
              their own servo_band_*; a reading is known no better than its rounding),
              n_p through the learnt speed map (SpeedMap: its spread is what it does not
              know yet), and n_m - n_p taken from the nearest of the
              predictions with the lag T_n (1 + lag_uncertainty)^(+-1) and within
              +-timing_s (the drive's lag and the sample's time are known no better)
    sigma_I = current_rel (I(n_m) - I_idle) + current_abs

The band is what the telemetry resolves at the operating point (the data sheet's share of
the speed, the lag, the reading's resolution), never a share of the rating: a DP thruster
at 1 % of its rated force turns at 10 % of its rated speed, tens of resolution steps, and
a shaft reading 0 rpm there is dozens of bands off. Each residual feeds two one-sided
CUSUMs, S <- max(0, S + |r| - k) on its own side (one sample moves S by at most 0.6 h),
updated while the shaft should be turning measurably: the whole predicted range one way
and ``floor_z`` bands from zero; the load's only while the speed fits (within
``clear_z``) and the current the speed draws is ``floor_z`` bands above idle: a load
hypothesis needs a shaft turning as commanded, under a load the sensor resolves. After a
telemetry gap the prediction restarts from the measured speed. An alarm is S > h
(``cusum_h`` for the speed, ``load_h`` for the load). From the alarms, the measured
speed and current, one hypothesis per thruster (:class:`Hypothesis`) and the
effectiveness its drive shows::

    no telemetry for telemetry_timeout_s        TELEMETRY_LOST  (not a thruster fault: 1)
    speed off, |n_m| ~ 0, current near idle      DRIVE_DEAD      0
    speed off, |n_m| ~ 0, current drawn          JAMMED          0  (the episode's mean current)
    speed flat while the command moves           STUCK           0, its held force k_T n_m|n_m|
      (measurably: floor_z bands, for stuck_hold_s; or after a speed alarm)
    speed low, load consistent                   WEAK            (n_m / n_p)^2
      (or, without the speed test, an amplitude down by more than twice the largest
      healthy loss ``amplitude_loss`` and cal_limit, for amplitude_hold_s)
    load low for hold_s, thrust consistent       LOAD_LOSS       torque ratio (lost blade)
    load high for hold_s                         LOAD_GAIN       2 - torque ratio (fouling)
    load low for less than hold_s                VENTILATION     1 (transient: never removed)

in that order: a shaft at 0 rpm under command is dead or jammed whatever its load says.

An alarm clears once the residuals stay within ``clear_z`` for ``clear_s`` of commanded
time; a thruster that is not turning is seen again whenever it is commanded to turn
measurably (the cycle's probes). Thresholds are not tuned here: they come from healthy runs
on calibration seeds (``bench/calibrate_shaft.py``). Pure: the time is handed in, no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.estimation.shaft_channel import Channel
from ftcap_hil.core.estimation.shaft_types import (
    LOAD,
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


@dataclass(frozen=True)
class ResidualSample:
    """One healthy, commanded sample's raw residuals: thruster ``index`` at ``t_s``, the
    predicted speed (rev/s; a servo: deflection) and the speed error outside the
    prediction's range (signed as the speed), the predicted load current above idle and its
    error (A, NaN: none), and the speed map's uncertainty that widened the band."""

    index: int
    t_s: float
    speed: float
    speed_error: float
    load_a: float
    load_error_a: float
    speed_spread: float = 0.0  # the speed map's own uncertainty there (rev/s)
    shaft: bool = True  # False: a servo (its deflection, its own bands)
    ratio: float = 1.0  # the force the speed's amplitude shows over the predicted (ratio_t)


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

    def command(self, t_s: float, u: FloatArray, inflow: FloatArray | None = None) -> None:
        """The commands ``u`` (m,) N sent at ``t_s``: the prediction moves to them.
        ``inflow`` (m,) m/s: the water's speed through each thruster along its thrust that
        the navigation knows (the vehicle's own velocity), None: not told (the speed map
        learns it as it learns a current)."""
        us = np.asarray(u, dtype=np.float64).tolist()
        vas = [0.0] * len(us) if inflow is None else np.asarray(inflow, dtype=np.float64).tolist()
        for ch, ui, va in zip(self._ch, us, vas, strict=True):
            ch.advance(t_s)
            ch.set_command(ui, va)

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
        if t_measured_s - ch.last_sample_s > cfg.telemetry_timeout_s:
            ch.restart(t_s, speed)  # after a gap: the drive is where it says, not predicted
        ch.advance(t_received_s)
        speeds = ch.predicted_at(t_s)
        smap = ch.speed_map
        n_p = smap.speed(speeds[0])
        # what the prediction says for a faster or slower drive, and within +-timing_s:
        # a measurement inside that range is no evidence
        shifted = (ch.predicted_at(t_s + d)[0] for d in (-cfg.timing_s, cfg.timing_s))
        around = [smap.speed(n) for n in (*speeds[1:], *shifted)]
        ch.n_fast = around[0]
        lo, hi = min(n_p, *around), max(n_p, *around)
        rel, resolved = ch.bands
        band = rel * abs(n_p) + resolved  # what the telemetry resolves there
        sigma_n = band + smap.spread(speeds[0])  # and what the speed map does not know yet
        # in the direction of the predicted speed: a deficit is negative either way round
        ch.r_t = math.copysign(1.0, n_p) * (speed - min(max(speed, lo), hi)) / sigma_n
        ch.n_p, ch.x_p, ch.sig_n, ch.band_n, ch.range_n = n_p, speeds[0], sigma_n, band, hi - lo
        ch.r_q = math.nan
        mdl = ch.model
        if ch.load_visible and math.isfinite(current_a):
            i_pred = ch.current_at(speed)
            sigma_i = cfg.current_rel * (i_pred - mdl.idle_a) + cfg.current_abs
            ch.r_q = (current_a - i_pred) / sigma_i
            ch.i_m, ch.i_pred, ch.sig_i = current_a, i_pred, sigma_i
        ch.speed_m = speed
        ch.last_sample_s = t_measured_s
        ch.thrust_sum += ch.open_water(speed)  # the thrust the speed implies (N)
        ch.thrust_count += 1
        # turning measurably: the whole predicted range one way, floor_z bands from zero
        least = min(abs(lo), abs(hi)) if lo * hi > 0.0 else 0.0
        commanded = least >= cfg.floor_z * (rel * least + resolved)
        healthy = ch.hyp is Hypothesis.HEALTHY
        tested = self._judge(ch, t_measured_s, speed, n_p, current_a, commanded)
        if self.trace is not None and tested and healthy:
            self.trace.append(ResidualSample(
                index, t_measured_s, n_p, ch.r_t * sigma_n, ch.i_pred - mdl.idle_a,
                ch.r_q * ch.sig_i if ch.load_fed else math.nan,
                sigma_n - ch.band_n, mdl.is_shaft, ch.ratio_t,
            ))  # fmt: skip

    def _judge(
        self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float,
        commanded: bool,
    ) -> bool:  # fmt: skip
        """One sample judged; True if it fed the tests (commanded, commissioned)."""
        cfg = self.config
        if ch.hyp is Hypothesis.TELEMETRY_LOST:
            ch.hyp = Hypothesis.HEALTHY
            ch.stall_k, ch.stall_excess, ch.stall_drawn = 0, 0.0, 0.0
        ch.recent.append((t_s, n_m, n_p, ch.n_fast))
        while ch.recent and ch.recent[0][0] < t_s - cfg.stuck_window_s:
            ch.recent.popleft()
        if not commanded and ch.hyp not in (Hypothesis.STUCK,):
            return False  # little evidence either way: hold the decision and the tests
        # one sample moves a CUSUM by at most 0.6 h: no single reading raises an alarm
        cap = 0.6 * cfg.cusum_h + cfg.cusum_k
        ch.thrust.update(min(max(ch.r_t, -cap), cap), cfg.cusum_k)
        # the load is judged only where the speed fits and the load is measurable: the
        # current the speed draws floor_z bands above idle (near standstill the in-flow's
        # share and the sensor's noise are all there is, and a lost blade is invisible)
        fits = abs(ch.r_t) < cfg.clear_z
        drawn = ch.i_pred - ch.model.idle_a
        ch.load_fed = math.isfinite(ch.r_q) and fits and drawn >= cfg.floor_z * ch.sig_i
        if ch.load_fed:
            cap = 0.6 * cfg.load_h + cfg.cusum_k
            ch.load.update(min(max(ch.r_q, -cap), cap), cfg.cusum_k)
        gap = self._sample_gap(ch)
        if n_p:
            ch.amplitude(n_m, n_p, gap)
        if math.isfinite(ch.r_q):
            i_pred = ch.current_at(n_m) - ch.model.idle_a
            if i_pred > 1e-9:
                ch.load_amplitude(current_a - ch.model.idle_a, i_pred, gap)
        if ch.hyp is Hypothesis.HEALTHY:
            commissioning = ch.seen < cfg.cal_samples
            ch.seen += 1
            # every healthy sample, its innovation clipped (a fault is learnt no faster than
            # the map may walk, a wrong start is unlearnt all the same), but a shaft held
            # still while its command moves: the stuck test's signature
            if commissioning or not self._flat(ch):
                error = math.copysign(1.0, n_p) * ch.r_t * ch.sig_n  # outside the lag's range
                # a sample in a transient, where the lag's range is wide, weighs little
                ch.speed_map.learn(gap, ch.x_p, error, ch.band_n + ch.range_n)
            if ch.load_visible and math.isfinite(current_a):
                ch.load_model.learn(gap, n_m, current_a)  # a static map: any healthy sample
            if commissioning:
                ch.thrust.reset()  # the tests start on the calibrated model
                ch.load.reset()
                return False
            self._raise(ch, t_s, n_m, n_p, current_a)
        else:
            self._follow(ch, t_s, n_m, n_p, current_a)
        return True

    def _raise(self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """A healthy thruster's tests: which alarm, if any, starts an episode."""
        h, h_load = self.config.cusum_h, self.config.load_h
        if ch.thrust.high > h and not ch.thrust.low > h and not self._flat(ch):
            ch.thrust.high = 0.0  # more thrust than asked and following the command: no fault
        # a shaft held still while its command moves measurably: frozen, whatever the sign
        # of the residuals (a command swinging about the held speed resets either CUSUM)
        ch.frozen_s = ch.frozen_s + self._sample_gap(ch) if self._frozen(ch) else 0.0
        cfg = self.config
        down = ch.ratio_t < 1.0 - max(cfg.cal_limit, 2.0 * cfg.amplitude_loss)
        down = down and ch.amplitude_full(t_s)
        ch.weak_s = ch.weak_s + self._sample_gap(ch) if down else 0.0
        if ch.weak_s >= cfg.amplitude_hold_s:
            ch.hyp = self._thrust_cause(ch, n_m, n_p, current_a)  # down by far more than a
            # healthy amplitude ever was: named at once (weak, or whatever a stall shows)
        elif ch.thrust.low > h or ch.thrust.high > h or ch.frozen_s >= cfg.stuck_hold_s:
            hyp = self._thrust_cause(ch, n_m, n_p, current_a)
            if hyp is Hypothesis.WEAK and ch.ratio_t > 1.0 - self.config.cal_limit:
                # a deficit within the sheet's errors so far: held at the threshold, named as
                # soon as the amplitude shows the loss (a drive dying as its speed decays)
                ch.thrust.low, ch.thrust.high = min(ch.thrust.low, h), min(ch.thrust.high, h)
                return
            ch.hyp = hyp
        elif ch.load.low > h_load:
            ch.hyp = Hypothesis.VENTILATION
        elif ch.load.high > h_load:
            ch.hyp = Hypothesis.VENTILATION  # a load step: confirmed as fouling after hold_s
        else:
            return
        ch.since_s, ch.calm_s, ch.held_n = t_s, 0.0, n_m

    def _thrust_cause(self, ch: Channel, n_m: float, n_p: float, current_a: float) -> Hypothesis:
        """In physical order: a shaft that does not turn under command is dead or jammed
        whatever else it shows; then a speed that holds while the command moves; then weak."""
        if abs(n_m) < self.config.stall_rel * abs(n_p):
            return self._stalled(ch, n_p, current_a)
        if self._flat(ch):
            return Hypothesis.STUCK
        return Hypothesis.WEAK

    def _stalled(self, ch: Channel, n_p: float, current_a: float) -> Hypothesis:
        """A shaft not turning under command: jammed if it draws current, a share of what the
        commanded speed draws and measurably above idle (floor_z bands of the episode's mean,
        which averages the reading's noise down by up to half: not its drift), else dead."""
        cfg, mdl = self.config, ch.model
        if not mdl.is_shaft:
            return Hypothesis.DRIVE_DEAD
        if math.isfinite(current_a):
            ch.stall_k += 1
            ch.stall_excess += current_a - mdl.idle_a
            ch.stall_drawn += ch.current_at(n_p) - mdl.idle_a
        if not ch.stall_k:
            return Hypothesis.DRIVE_DEAD
        k = ch.stall_k
        noise = cfg.floor_z * cfg.current_abs / math.sqrt(min(k, 4))
        if ch.stall_excess / k > max(cfg.jam_current_rel * ch.stall_drawn / k, noise):
            return Hypothesis.JAMMED
        return Hypothesis.DRIVE_DEAD

    @staticmethod
    def _moves(ch: Channel) -> tuple[float, float, float, float, float]:
        """Over ``stuck_window_s``: how far the prediction moved, how far the measured speed
        did, the prediction's size, and how far the quick drive's prediction moved the same
        way as the nominal one did from the window's start to its end (0 where the two went
        opposite ways) and its size (0, 0, 1, 0, 1 with fewer than three samples). Kept
        while the window holds the same samples (a sample asks for it two or three times)."""
        recent = ch.recent
        if len(recent) < 3:
            return 0.0, 0.0, 1.0, 0.0, 1.0
        key = (len(recent), recent[0][0], recent[-1][0])
        if ch.moves_key == key:
            return ch.moves
        speeds = [r[1] for r in recent]
        preds = [r[2] for r in recent]
        fast = [r[3] for r in recent]
        scale = max(max(preds), -min(preds)) or 1.0
        scale_fast = max(max(fast), -min(fast)) or 1.0
        ch.moves_key = key
        same_way = (preds[-1] - preds[0]) * (fast[-1] - fast[0]) > 0.0
        ch.moves = (max(preds) - min(preds), max(speeds) - min(speeds), scale,
                    max(fast) - min(fast) if same_way else 0.0, scale_fast)  # fmt: skip
        return ch.moves

    @staticmethod
    def _held(moved: float, held: float, scale: float) -> bool:
        """The speed held (within a fifth of it) while the prediction moved by more than 5 %
        of its size."""
        return moved > 0.05 * scale and held < 0.2 * moved

    def _flat(self, ch: Channel) -> bool:
        """:meth:`_held` over ``stuck_window_s``."""
        return self._held(*self._moves(ch)[:3])

    def _frozen(self, ch: Channel) -> bool:
        """:meth:`_flat`, and the prediction's move measurable: ``floor_z`` bands at the
        speed it runs (a healthy drive, even one lagging 1 + ``lag_uncertainty`` times its
        data sheet, follows such a move by more than half of it; a frozen shaft not at all);
        the same of the prediction for a drive as much quicker than its sheet, moving the
        same way: one that has already arrived holds the speed the nominal prediction is
        still moving to, and where the two go opposite ways (past a peak of the command) a
        drive with a lag between them stands still (the supply vessel's tunnels, their
        sheets' lag 25 % slow, were named stuck for a report on healthy runs); a frozen
        shaft is left behind by both."""
        moved, held, scale, moved_fast, scale_fast = self._moves(ch)
        floor = self.config.floor_z * ch.sig_n
        return (
            self._held(moved, held, scale) and moved >= floor
            and self._held(moved_fast, held, scale_fast) and moved_fast >= floor
        )  # fmt: skip

    def _follow(self, ch: Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """An episode in progress: confirm a load change, re-judge, or clear."""
        cfg = self.config
        quiet = self._healthy_fits(ch)
        if ch.hyp is Hypothesis.STUCK:
            quiet = quiet and not self._flat(ch)
        ch.calm_s = ch.calm_s + self._sample_gap(ch) if quiet else 0.0
        if ch.calm_s >= cfg.clear_s:
            ch.hyp = Hypothesis.HEALTHY
            ch.frozen_s = ch.weak_s = 0.0
            ch.stall_k, ch.stall_excess, ch.stall_drawn = 0, 0.0, 0.0
            ch.thrust.reset()
            ch.load.reset()
            ch.restart_amplitude(t_s)
            ch.ratio_q = 1.0
            return
        h, h_load = cfg.cusum_h, cfg.load_h
        if ch.hyp is Hypothesis.VENTILATION and t_s - ch.since_s >= cfg.hold_s:
            if ch.load.low > h_load:
                ch.hyp = Hypothesis.LOAD_LOSS
            elif ch.load.high > h_load:
                ch.hyp = Hypothesis.LOAD_GAIN
        elif ch.hyp in (Hypothesis.DRIVE_DEAD, Hypothesis.JAMMED):
            if ch.model.is_shaft and abs(n_m) < cfg.stall_rel * abs(n_p):
                ch.hyp = self._stalled(ch, n_p, current_a)  # the current's mean, updated
        elif ch.hyp in (Hypothesis.WEAK, Hypothesis.VENTILATION, *LOAD):
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
        amplitude = math.sqrt(shown) if ch.model.is_shaft else shown
        fault = ch.held_n if ch.hyp is Hypothesis.STUCK else amplitude * ch.n_p
        z_fault = (ch.speed_m - fault) / ch.sig_n
        gone = ch.hyp is Hypothesis.WEAK and shown > 1.0 - self.config.cal_limit
        # a weak speed inside the prediction's range (r_t exactly 0) fits either: no evidence
        # of health (a drive named weak on its amplitude while its command swings would
        # clear on such samples within clear_s, and be named again, and again)
        inside = ch.hyp is Hypothesis.WEAK and ch.r_t == 0.0
        return abs(ch.r_t) < z_clear and (gone or (not inside and abs(ch.r_t) < abs(z_fault)))

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
