"""Each thruster judged by its own drive: shaft speed and current against a data-sheet model.

The allocator knows, per actuator, what an operator knows from the data sheets
(:class:`DriveModel`): the thrust and torque coefficients k_T = K_T0 rho D^4 and
k_Q = K_Q0 rho D^5 of the propeller, the drive's time constant, the motor's efficiency,
supply voltage and idle current (a servo: its force at full deflection and time constant).
It never sees the simulator's truth. From the commands it sent it predicts the speed the
drive should have (a first-order lag of n_ref = sign(u) sqrt(|u| / k_T), or for a servo of
u / full force) and compares every telemetry sample with it, at the sample's own time::

    r_T = (k_T n_m|n_m| - k_T n_p|n_p|) / sigma_T     thrust implied by the speed, against
                                                      the lagged command's (N)
    r_Q = (I_m - I(n_m)) / sigma_I                    the current against what the load at
                                                      the measured speed draws (A)
    sigma_T = band_rel |T_p| + band_abs full + band_rate |dT_p/dt| tau
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

import enum
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import BoolArray, FloatArray


class Hypothesis(enum.Enum):
    """What a thruster's drive says about it (module docstring)."""

    HEALTHY = "healthy"
    TELEMETRY_LOST = "telemetry-lost"
    DRIVE_DEAD = "drive-dead"
    JAMMED = "jammed"
    STUCK = "stuck"
    WEAK = "weak"
    LOAD_LOSS = "load-loss"
    LOAD_GAIN = "load-gain"
    VENTILATION = "ventilation"


# What the allocator may act on: a removal or a partial loss needs one of these.
ACTIONABLE = frozenset(
    {Hypothesis.DRIVE_DEAD, Hypothesis.JAMMED, Hypothesis.STUCK, Hypothesis.WEAK,
     Hypothesis.LOAD_LOSS, Hypothesis.LOAD_GAIN}
)  # fmt: skip


_NOT_TURNING = frozenset({Hypothesis.DRIVE_DEAD, Hypothesis.JAMMED})


@dataclass(frozen=True)
class DriveModel:
    """One actuator as its data sheets give it. A shaft: ``k_thrust`` N/(rev/s)^2,
    ``k_torque`` N m/(rev/s)^2, ``watts_per_amp`` = efficiency x voltage, ``inflow_*`` =
    (1 - w) / (J_0 D) (0: in-flow not modelled); a servo (``is_shaft`` False): only
    ``full_force_n`` and ``time_constant_s`` matter."""

    full_force_n: float
    time_constant_s: float
    is_shaft: bool = True
    k_thrust: float = 1.0
    k_torque: float = 0.0
    watts_per_amp: float = 1.0
    idle_a: float = 0.0
    inflow_thrust: float = 0.0
    inflow_torque: float = 0.0

    def __post_init__(self) -> None:
        for name in ("full_force_n", "k_thrust", "watts_per_amp"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"drive model: {name} must be > 0, got {getattr(self, name)}")
        if not self.time_constant_s >= 0.0:
            raise ValueError(
                f"drive model: time_constant_s must be >= 0, got {self.time_constant_s}"
            )


@dataclass(frozen=True)
class DiagnosisConfig:
    """Bands, tests and decisions of the module docstring. The bands are residual
    standard deviations fitted on healthy data; ``cusum_*`` in band units."""

    floor_rel: float = 0.1
    probe_rel: float = 0.03  # a thruster that is not turning is judged again from this
    band_rel: float = 0.03
    band_abs: float = 0.005
    band_rate: float = 0.5
    current_rel: float = 0.03
    current_abs: float = 0.02
    cusum_k: float = 1.0
    cusum_h: float = 12.0
    stall_rel: float = 0.1  # |n_m| below this share of the predicted speed: not turning
    jam_current_rel: float = 0.5  # drawn current (above idle) of the predicted: jammed
    stuck_window_s: float = 2.0
    hold_s: float = 3.0
    clear_z: float = 2.5
    clear_s: float = 1.0
    telemetry_timeout_s: float = 0.5
    latency_s: float = 0.0  # the telemetry's known latency: samples are judged at t - latency
    cal_tau_s: float = 60.0  # online calibration of speed and current scales (0: off)
    cal_limit: float = 0.15  # ... within this share of the data sheet
    cal_samples: int = 20  # commanded samples that commission the model, before any test

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"diagnosis.{name}: expected a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class ShaftVerdict:
    """Per thruster (m,): the hypothesis, the effectiveness its drive shows (1 where it
    shows nothing wrong), a stuck thruster's held force (N, NaN otherwise), the thrust the
    latest speed implies (N, NaN without telemetry), whether telemetry is fresh, whether a
    shaft alarm is up (no dither on it), and the latest normalised residuals."""

    hypothesis: tuple[Hypothesis, ...]
    delta: FloatArray
    held_n: FloatArray
    thrust_n: FloatArray
    fresh: BoolArray
    alarm: BoolArray
    r_thrust: FloatArray
    r_load: FloatArray

    @property
    def actionable(self) -> BoolArray:
        """(m,) the drive itself shows a loss the allocator may act on."""
        return np.array([h in ACTIONABLE for h in self.hypothesis], dtype=bool)


def verdict_without_telemetry(m: int) -> ShaftVerdict:
    """The verdict when no drive reports at all (motion-only)."""
    nan = np.full(m, math.nan)
    return ShaftVerdict(
        (Hypothesis.TELEMETRY_LOST,) * m, np.ones(m), nan, nan.copy(), np.zeros(m, bool),
        np.zeros(m, bool), nan.copy(), nan.copy(),
    )  # fmt: skip


class _Cusum:
    """Two one-sided CUSUMs of a normalised residual."""

    def __init__(self) -> None:
        self.low = 0.0
        self.high = 0.0

    def update(self, z: float, k: float) -> None:
        """One residual ``z`` (band units) with allowance ``k``."""
        self.low = max(0.0, self.low - z - k)
        self.high = max(0.0, self.high + z - k)

    def reset(self) -> None:
        """Back to zero (a new episode, or the model just calibrated)."""
        self.low = self.high = 0.0


class _Channel:
    """One actuator's prediction, tests and decision state."""

    def __init__(self, model: DriveModel, cfg: DiagnosisConfig) -> None:
        self.model, self.cfg = model, cfg
        self.n_pred = 0.0  # predicted speed (rev/s) or deflection
        self.t_pred = 0.0
        self.ref = 0.0
        self.history: deque[tuple[float, float, float]] = deque()  # (t, n_pred, T_pred)
        self.thrust = _Cusum()
        self.load = _Cusum()
        self.hyp = Hypothesis.TELEMETRY_LOST
        self.since_s = 0.0  # when the current alarm episode began
        self.calm_s = 0.0  # commanded time with small residuals in an alarm
        self.last_sample_s = -math.inf
        self.speed_m = math.nan
        self.r_t = self.r_q = math.nan
        self.ratio_t = 1.0  # EWMA of (n_m / n_p)^2 (weak)
        self.ratio_q = 1.0  # EWMA of the torque ratio (load)
        self.t_m = self.t_p = self.held_t = 0.0  # last thrusts: implied, predicted, held (N)
        self.sig_t = self.sig_i = 1.0  # last bands
        self.i_m = self.i_pred = 0.0  # last current: measured, predicted (A)
        self.cal_count = 0  # healthy, commanded, steady samples calibrated on
        self.seen = 0  # commanded samples (the first cal_samples commission the model)
        self.steady = False  # the last sample's prediction was not moving
        self.speed_scale = 1.0  # calibrated on healthy data: true / data-sheet speed
        self.current_scale = 1.0  # ... and drawn current above idle
        self.recent: deque[tuple[float, float, float]] = deque()  # (t, n_m, n_p) for stuck

    # --- prediction -------------------------------------------------------------------

    def reference(self, u: float) -> float:
        """The speed (deflection) a healthy drive settles at for the force ``u`` (N)."""
        m = self.model
        if m.is_shaft:
            return math.copysign(math.sqrt(abs(u) / m.k_thrust), u)
        return u / m.full_force_n

    def open_water(self, n: float) -> float:
        """The force (N) a healthy actuator gives at speed (deflection) ``n`` at rest."""
        m = self.model
        return m.k_thrust * n * abs(n) if m.is_shaft else n * m.full_force_n

    def advance(self, t_s: float) -> None:
        """The prediction carried to ``t_s`` under the reference in force."""
        h = t_s - self.t_pred
        if h <= 0.0:
            return
        tc = self.model.time_constant_s
        a = math.exp(-h / tc) if tc > 0.0 else 0.0
        self.n_pred = self.ref + (self.n_pred - self.ref) * a
        self.t_pred = t_s
        self.history.append((t_s, self.n_pred, self.open_water(self.n_pred)))
        keep = t_s - max(2.0, 4.0 * self.cfg.latency_s + self.cfg.stuck_window_s)
        while len(self.history) > 2 and self.history[1][0] < keep:
            self.history.popleft()

    def predicted_at(self, t_s: float) -> tuple[float, float, float]:
        """(n_p, T_p, dT_p/dt) at ``t_s`` from the history (linear between entries)."""
        hist = self.history
        if not hist:
            return 0.0, 0.0, 0.0
        prev = hist[0]
        for entry in hist:
            if entry[0] >= t_s:
                dt = entry[0] - prev[0]
                if dt <= 0.0:
                    return entry[1], entry[2], 0.0
                w = (t_s - prev[0]) / dt
                rate = (entry[2] - prev[2]) / dt
                return prev[1] + w * (entry[1] - prev[1]), prev[2] + w * (entry[2] - prev[2]), rate
            prev = entry
        return prev[1], prev[2], 0.0

    def current_at(self, n: float, v_axial: float, scale: float = 1.0) -> float:
        """The current (A) the load at speed ``n`` and in-flow ``v_axial`` draws, its part
        above idle times ``scale`` (the calibration)."""
        m = self.model
        q = m.k_torque * (n * abs(n) - abs(n) * v_axial * m.inflow_torque)
        return scale * 2.0 * math.pi * abs(n * q) / m.watts_per_amp + m.idle_a

    def calibrate(self, gap_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """Healthy and commanded: move the scales towards what this sample shows."""
        cfg = self.cfg
        if cfg.cal_tau_s <= 0.0 or n_p == 0.0 or n_m * n_p <= 0.0:
            return
        self.cal_count += 1  # a running mean at first, then the time constant
        w = min(max(gap_s / cfg.cal_tau_s, 1.0 / self.cal_count), 1.0)
        lo, hi = 1.0 - cfg.cal_limit, 1.0 + cfg.cal_limit
        raw_n = n_m / n_p  # n_p: the data sheet's prediction, uncalibrated
        if not lo <= raw_n <= hi:  # beyond what a data sheet gets wrong: a fault, not this
            self.cal_count -= 1
            return
        self.speed_scale = min(max(self.speed_scale + w * (raw_n - self.speed_scale), lo), hi)
        drawn = self.current_at(n_m, 0.0) - self.model.idle_a
        if math.isfinite(current_a) and drawn > 1e-9:
            raw_i = (current_a - self.model.idle_a) / drawn
            self.current_scale = min(
                max(self.current_scale + w * (raw_i - self.current_scale), lo), hi
            )


class ShaftDiagnoser:
    """The module docstring's diagnosis of ``m`` actuators. Call :meth:`command` with every
    command sent, :meth:`feedback` with every telemetry sample, :meth:`verdict` when a
    decision is needed; every time is the caller's (s, one clock)."""

    def __init__(self, models: Sequence[DriveModel], config: DiagnosisConfig | None = None):
        self.config = cfg = config or DiagnosisConfig()
        self._ch = [_Channel(mdl, cfg) for mdl in models]
        self.m = len(self._ch)

    def command(self, t_s: float, u: FloatArray) -> None:
        """The commands ``u`` (m,) N sent at ``t_s``: the prediction moves to them."""
        for ch, ui in zip(self._ch, np.asarray(u, dtype=np.float64).tolist(), strict=True):
            ch.advance(t_s)
            ch.ref = ch.reference(ui)

    def feedback(
        self, t_received_s: float, index: int, speed: float, current_a: float,
        v_axial: float = 0.0,
    ) -> None:  # fmt: skip
        """One drive's report (speed rev/s or deflection, current A) received at
        ``t_received_s``; it was measured ``latency_s`` earlier. ``v_axial``: the in-flow
        the allocator estimates (m/s). A sample for an unknown actuator or with a
        non-finite speed is ignored."""
        if not (0 <= index < self.m and math.isfinite(speed)):
            return
        ch, cfg = self._ch[index], self.config
        t_s = t_received_s - cfg.latency_s
        t_measured_s = t_received_s
        ch.advance(t_received_s)
        n_p, t_p, rate = ch.predicted_at(t_s)
        n_p *= ch.speed_scale
        t_p = ch.open_water(n_p)
        rate *= ch.speed_scale**2
        mdl = ch.model
        t_m = ch.open_water(speed)
        sigma_t = (
            cfg.band_rel * abs(t_p) + cfg.band_abs * mdl.full_force_n
            + cfg.band_rate * abs(rate) * mdl.time_constant_s
        )  # fmt: skip
        ch.r_t = (t_m - t_p) / sigma_t
        ch.t_m, ch.t_p, ch.sig_t = t_m, t_p, sigma_t
        ch.steady = abs(rate) * mdl.time_constant_s <= 0.1 * abs(t_p)
        ch.r_q = math.nan
        if mdl.is_shaft and mdl.k_torque > 0.0 and math.isfinite(current_a):
            i_pred = ch.current_at(speed, v_axial, ch.current_scale)
            sigma_i = cfg.current_rel * (i_pred - mdl.idle_a) + cfg.current_abs
            ch.r_q = (current_a - i_pred) / sigma_i
            ch.i_m, ch.i_pred, ch.sig_i = current_a, i_pred, sigma_i
        ch.speed_m = speed
        ch.last_sample_s = t_measured_s
        floor = cfg.probe_rel if ch.hyp in _NOT_TURNING else cfg.floor_rel
        commanded = abs(t_p) >= floor * mdl.full_force_n
        self._judge(ch, t_measured_s, speed, n_p, current_a, commanded)

    def _judge(
        self, ch: _Channel, t_s: float, n_m: float, n_p: float, current_a: float,
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
        if abs(n_p) > 0.0:
            same_way = (n_m / n_p) ** 2 if n_m * n_p > 0.0 else 0.0
            ch.ratio_t += 0.2 * (same_way - ch.ratio_t)
        if math.isfinite(ch.r_q):
            i_pred = ch.current_at(n_m, 0.0) - ch.model.idle_a
            if i_pred > 1e-9:
                ch.ratio_q += 0.2 * ((current_a - ch.model.idle_a) / i_pred - ch.ratio_q)
        if ch.hyp is Hypothesis.HEALTHY:
            commissioning = ch.seen < cfg.cal_samples
            ch.seen += 1
            quiet = abs(ch.r_t) < cfg.clear_z and not abs(ch.r_q) > cfg.clear_z
            if ch.steady and (quiet or commissioning):
                ch.calibrate(self._sample_gap(ch), n_m, n_p / ch.speed_scale, current_a)
            if commissioning:
                ch.thrust.reset()  # the tests start on the calibrated model
                ch.load.reset()
                return
            self._raise(ch, t_s, n_m, n_p, current_a)
        else:
            self._follow(ch, t_s, n_m, n_p, current_a)

    def _raise(self, ch: _Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
        """A healthy thruster's tests: which alarm, if any, starts an episode."""
        h = self.config.cusum_h
        if ch.thrust.low > h or ch.thrust.high > h:
            ch.hyp = self._thrust_cause(ch, n_m, n_p, current_a)
        elif ch.load.low > h:
            ch.hyp = Hypothesis.VENTILATION
        elif ch.load.high > h:
            ch.hyp = Hypothesis.VENTILATION  # a load step: confirmed as fouling after hold_s
        else:
            return
        ch.since_s, ch.calm_s, ch.held_t = t_s, 0.0, ch.t_m
        ch.ratio_t = (n_m / n_p) ** 2 if n_p and n_m * n_p > 0.0 else 0.0

    def _thrust_cause(self, ch: _Channel, n_m: float, n_p: float, current_a: float) -> Hypothesis:
        cfg, mdl = self.config, ch.model
        if self._flat(ch):
            return Hypothesis.STUCK
        if abs(n_m) < cfg.stall_rel * abs(n_p):
            if not mdl.is_shaft:
                return Hypothesis.DRIVE_DEAD
            drawn = ch.current_at(n_p, 0.0) - mdl.idle_a
            if math.isfinite(current_a) and current_a - mdl.idle_a > cfg.jam_current_rel * drawn:
                return Hypothesis.JAMMED
            return Hypothesis.DRIVE_DEAD
        return Hypothesis.WEAK

    def _flat(self, ch: _Channel) -> bool:
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

    def _follow(self, ch: _Channel, t_s: float, n_m: float, n_p: float, current_a: float) -> None:
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
        elif ch.hyp in (Hypothesis.WEAK, Hypothesis.VENTILATION) and (
            ch.thrust.low > h or ch.thrust.high > h
        ):
            ch.hyp = self._thrust_cause(ch, n_m, n_p, current_a)

    def _healthy_fits(self, ch: _Channel) -> bool:
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
    def _sample_gap(ch: _Channel) -> float:
        r = ch.recent
        return r[-1][0] - r[-2][0] if len(r) >= 2 else 0.0

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


def _effectiveness(hyp: Hypothesis, ch: _Channel) -> float:
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
