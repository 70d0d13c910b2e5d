"""One actuator's state in the drives' diagnosis (:mod:`ftcap_hil.core.estimation.shaft`):
the data-sheet prediction of its speed under the commands sent, its history, the
calibration of speed and current scales, the residual tests and the episode in progress."""

from __future__ import annotations

import math
from collections import deque

from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig, DriveModel, Hypothesis


class Cusum:
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


class Channel:
    """One actuator's prediction, tests and decision state."""

    def __init__(self, model: DriveModel, cfg: DiagnosisConfig) -> None:
        self.model, self.cfg = model, cfg
        self.n_pred = 0.0  # predicted speed (rev/s) or deflection
        self.t_pred = 0.0
        self.ref = 0.0
        self.history: deque[tuple[float, float, float]] = deque()  # (t, n_pred, T_pred)
        self.thrust = Cusum()
        self.load = Cusum()
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
        self.thrust_sum, self.thrust_count = 0.0, 0  # implied thrust since the last take

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
