"""One actuator's state in the drives' diagnosis (:mod:`ftcap_hil.core.estimation.shaft`):
the data-sheet prediction of its speed under the commands sent, its history, the
calibration of speed and current scales, the residual tests and the episode in progress."""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig, DriveModel, Hypothesis

RATIO_MAX = 4.0  # the thrust the speed shows over the predicted, at most (twice the speed)
AMPLITUDE_TAU_S = 1.0  # the weak motor's and the load's amplitudes: their memory, s


def _time(entry: tuple[float, float, float, float]) -> float:
    """A history entry's time (the bisection's key)."""
    return entry[0]


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


def kalman3(
    theta: list[float], cov: list[float], phi: tuple[float, float, float], residual: float,
    noise_var: float, clip_z: float,
) -> None:  # fmt: skip
    """One measurement update of a three-coefficient linear Kalman filter, in place, in
    floats (the maps learn on every telemetry sample: numpy's per-call cost on 3-vectors
    was a third of the offline loop; :func:`kalman3_reference` is the same algebra in numpy,
    the reference a test holds this to). ``cov`` is the 3 x 3 covariance row by row, ``phi``
    the regressor, ``residual`` the measurement's innovation before clipping, which is
    clipped to ``clip_z`` of its spread."""
    p0, p1, p2 = phi
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = cov
    g0 = a00 * p0 + a01 * p1 + a02 * p2  # P phi
    g1 = a10 * p0 + a11 * p1 + a12 * p2
    g2 = a20 * p0 + a21 * p1 + a22 * p2
    h0 = p0 * a00 + p1 * a10 + p2 * a20  # phi P
    h1 = p0 * a01 + p1 * a11 + p2 * a21
    h2 = p0 * a02 + p1 * a12 + p2 * a22
    s = h0 * p0 + h1 * p1 + h2 * p2 + noise_var
    k0, k1, k2 = g0 / s, g1 / s, g2 / s
    bound = clip_z * math.sqrt(s)
    r = min(max(residual, -bound), bound)
    theta[0] += k0 * r
    theta[1] += k1 * r
    theta[2] += k2 * r
    cov[:] = (
        a00 - k0 * h0, a01 - k0 * h1, a02 - k0 * h2,
        a10 - k1 * h0, a11 - k1 * h1, a12 - k1 * h2,
        a20 - k2 * h0, a21 - k2 * h1, a22 - k2 * h2,
    )  # fmt: skip


def kalman3_reference(
    theta: list[float], cov: list[float], phi: tuple[float, float, float], residual: float,
    noise_var: float, clip_z: float,
) -> None:  # fmt: skip
    """:func:`kalman3` in numpy (the algebra as written: the reference)."""
    t, p, f = np.array(theta), np.array(cov).reshape(3, 3), np.array(phi)
    s = float(f @ p @ f) + noise_var
    gain = p @ f / s
    bound = clip_z * math.sqrt(s)
    t = t + gain * min(max(residual, -bound), bound)
    p = p - np.outer(gain, f @ p)
    theta[:] = t.tolist()
    cov[:] = p.ravel().tolist()


class LoadModel:
    """The current a shaft draws, learnt on healthy data as a small Kalman filter of three
    coefficients (a, c, o) on the data sheet's full-speed load L::

        I - I_idle = L (a nu^3 + c sgn(n) nu^2 + o),  nu = |n| / n_full

    ``a`` is the current sense's scale (within ``cal_limit`` of 1), ``c`` the in-flow's share
    (the water's axial speed through the propeller, unknown to the allocator: current,
    vessel speed; within +-0.3), ``o`` the current sense's offset (its drift). Each walks by
    its prior's size over ``cal_tau_s``; the first samples commission them from the prior.
    ``theta`` and ``P`` (3 x 3, row by row) are lists of floats: :func:`kalman3`."""

    def __init__(self, model: DriveModel, cfg: DiagnosisConfig, n_full: float) -> None:
        self.cfg, self.idle_a = cfg, model.idle_a
        self.n_full = max(n_full, 1e-12)
        self.load_a = 2.0 * math.pi * model.k_torque * self.n_full**3 / model.watts_per_amp
        self.theta = [1.0, 0.0, 0.0]
        noise = cfg.current_abs / max(self.load_a, 1e-12)
        self.R = noise * noise
        self._prior = (cfg.cal_limit**2, 0.1**2, 4.0 * self.R)  # offset: 2 bands
        self.P = _diagonal(self._prior)

    def _phi(self, n: float) -> tuple[float, float, float]:
        nu = abs(n) / self.n_full
        return nu**3, math.copysign(nu * nu, n), 1.0

    def current(self, n: float) -> float:
        """The current (A) a healthy shaft at speed ``n`` draws."""
        f0, f1, f2 = self._phi(n)
        a, c, o = self.theta
        return self.idle_a + self.load_a * (f0 * a + f1 * c + f2 * o)

    def learn(self, gap_s: float, n: float, current_a: float) -> None:
        """One healthy, commanded sample (a static map: steady or not): the coefficients
        move towards it."""
        cfg, P = self.cfg, self.P
        if cfg.cal_tau_s > 0.0:
            walk = gap_s / cfg.cal_tau_s
            P[0] += self._prior[0] * walk
            P[4] += self._prior[1] * walk
            P[8] += self._prior[2] * walk
        phi = self._phi(n)
        y = (current_a - self.idle_a) / self.load_a
        a, c, o = self.theta
        # innovations clipped to clear_z of their spread: a fault is learnt no faster than
        # the coefficients may walk, a bias of the prior is learnt all the same
        kalman3(self.theta, P, phi, y - (phi[0] * a + phi[1] * c + phi[2] * o), self.R,
                cfg.clear_z)  # fmt: skip
        lo, hi = 1.0 - cfg.cal_limit, 1.0 + cfg.cal_limit
        a, c, o = self.theta
        self.theta = [min(max(a, lo), hi), min(max(c, -0.3), 0.3), o]


def _diagonal(d: tuple[float, float, float]) -> list[float]:
    """A 3 x 3 diagonal matrix, row by row."""
    return [d[0], 0.0, 0.0, 0.0, d[1], 0.0, 0.0, 0.0, d[2]]


class SpeedMap:
    """The speed a healthy drive reaches for a data-sheet speed x, learnt on healthy data as
    a small Kalman filter of three coefficients, as :class:`LoadModel`::

        n = s_ahead max(x, 0) + s_astern min(x, 0) + o

    ``s_*`` the data sheet's error ahead and astern (within ``cal_limit`` of 1: a propeller
    is not symmetric), ``o`` the in-flow's offset (rev/s; 2 % of the full speed a priori,
    at most 10 %): a torque-controlled drive in an axial in-flow V_a settles near
    n_ref + V_a / (2 J_Q D) in either direction, so a current or the hull's own motion
    shifts its speed by an amount that does not scale with it. The scales are constants of
    the drive, learnt once; the offset walks by its prior's size over ``cal_tau_s``, as the
    in-flow does. A drive closing a speed loop holds its speed whatever the in-flow: its map
    has no offset (an offset free to walk there learns a weak motor's deficit at the speed
    a DP thruster holds, a few per cent of the full speed, as if it were in-flow). Each
    sample teaches only what the drive's lag cannot explain (the error outside the
    prediction's range): a reversal in progress says nothing about the scales.
    Innovations are clipped to ``clear_z`` of their spread, so a fault is learnt no faster
    than the coefficients may walk. ``spread(x)`` is the map's own remaining uncertainty
    there: large in a direction or at a speed it has not yet been calibrated on. A servo's
    position loop knows no in-flow and its travel no data-sheet scale: its map does not
    learn (the identity, no spread)."""

    def __init__(
        self, cfg: DiagnosisConfig, n_full: float, learns: bool = True, offset: bool = True,
    ) -> None:  # fmt: skip
        self.cfg = cfg
        self.n_full = max(n_full, 1e-12)
        self.theta = [1.0, 1.0, 0.0]
        inflow = 0.02 * self.n_full if offset else 0.0
        prior = (cfg.cal_limit**2, cfg.cal_limit**2, inflow**2)
        self._prior = prior if learns else (0.0, 0.0, 0.0)
        self.P = _diagonal(self._prior)
        self.learns = learns

    def speed(self, x: float) -> float:
        """The healthy speed for the data-sheet speed ``x`` (0 at 0: no command, no test)."""
        if not x:
            return 0.0
        s_ahead, s_astern, o = self.theta
        return (s_ahead * x if x > 0.0 else s_astern * x) + o

    def data_sheet(self, n: float) -> float:
        """The data-sheet speed that maps to the measured ``n`` (the inverse of speed)."""
        s_ahead, s_astern, o = self.theta
        x = n - o
        return x / (s_ahead if x >= 0.0 else s_astern)

    def spread(self, x: float) -> float:
        """The map's standard deviation at ``x`` (rev/s): phi P phi, phi = (x+, x-, 1)."""
        P = self.P
        if x > 0.0:  # phi = (x, 0, 1)
            var = P[0] * x * x + (P[2] + P[6]) * x + P[8]
        elif x < 0.0:  # phi = (0, x, 1)
            var = P[4] * x * x + (P[5] + P[7]) * x + P[8]
        else:
            var = P[8]
        return math.sqrt(max(var, 0.0))

    def learn(self, gap_s: float, x: float, error: float, sigma: float) -> None:
        """One healthy, commanded sample: data-sheet speed ``x``, the measured speed's
        ``error`` outside the prediction's range, the band ``sigma`` of the measurement."""
        cfg = self.cfg
        if cfg.cal_tau_s <= 0.0 or x == 0.0 or not self.learns:
            return
        self.P[8] += self._prior[2] * (gap_s / cfg.cal_tau_s)  # the in-flow moves
        phi = (max(x, 0.0), min(x, 0.0), 1.0)
        kalman3(self.theta, self.P, phi, error, sigma * sigma, cfg.clear_z)
        lo, hi, off = 1.0 - cfg.cal_limit, 1.0 + cfg.cal_limit, 0.1 * self.n_full
        a, b, o = self.theta
        self.theta = [min(max(a, lo), hi), min(max(b, lo), hi), min(max(o, -off), off)]


class Channel:
    """One actuator's prediction, tests and decision state."""

    def __init__(self, model: DriveModel, cfg: DiagnosisConfig) -> None:
        self.model, self.cfg = model, cfg
        # predicted speed (rev/s) or deflection under the data sheet's time constant, and
        # under a faster and a slower one (the lag is known to lag_uncertainty)
        self.n_pred = [0.0, 0.0, 0.0]
        spread = 1.0 + cfg.lag_uncertainty
        tc = model.time_constant_s
        self._tcs = (tc, tc / spread, tc * spread)
        self.t_pred = 0.0
        self.ref = 0.0  # the steady speed the command asks for (in the told in-flow)
        self.q_ref = 0.0  # a torque drive's: its open-water speed n_0 |n_0| (the motor torque)
        self.inflow = 0.0  # the told axial in-flow, m/s
        # a torque drive's speed follows I dn/dt = Q_m - Q(n), its lag ~ T n_top / (2 |n|):
        # five times the data sheet's at a tenth of the top speed (a T200 at hover)
        self.torque_drive = model.is_shaft and not model.speed_loop
        self.history: deque[tuple[float, float, float, float]] = deque()  # (t, 3 speeds)
        self.thrust = Cusum()
        self.load = Cusum()
        self.hyp = Hypothesis.TELEMETRY_LOST
        self.since_s = 0.0  # when the current alarm episode began
        self.calm_s = 0.0  # commanded time with small residuals in an alarm
        self.frozen_s = 0.0  # healthy: how long the speed has held while the command moved
        self.weak_s = 0.0  # healthy: how long the amplitude has stayed under the weak gate
        self.load_fed = False  # the last sample fed the load test
        self.last_sample_s = -math.inf
        self.speed_m = math.nan
        self.r_t = self.r_q = math.nan
        # the force's share the speed shows, in least squares over the last second (weak):
        # (n_m / n_p)^2 for a shaft, the deflections' ratio for a servo
        self.ratio_t = 1.0
        self.sum_mp, self.sum_pp = 0.0, 0.0  # its exponentially weighted sums
        self.amplitude_since_s = -math.inf  # when those sums last started from nothing
        self.ratio_q = 1.0  # the load current's ratio, in least squares likewise (load)
        self.sum_qp, self.sum_pp_q = 0.0, 0.0
        self.n_p = self.held_n = 0.0  # last predicted speed, a stuck episode's held speed
        self.x_p = 0.0  # last data-sheet speed (the speed map's input)
        self.band_n = 1.0  # last band of the telemetry alone
        self.range_n = 0.0  # last width of the prediction's range (the lag's uncertainty)
        self.sig_n = self.sig_i = 1.0  # last bands (speed, current)
        self.i_m = self.i_pred = 0.0  # last current: measured, predicted (A)
        self.seen = 0  # commanded samples (the first cal_samples commission the model)
        n_full = abs(self.reference(model.full_force_n))
        self._inertias = tuple(n_full * t for t in self._tcs)  # I / k_Q per lag, rev s
        # true against data sheet
        self.speed_map = SpeedMap(cfg, n_full, model.is_shaft, offset=not model.speed_loop)
        # the band: bands_rel |n| + bands_res x the telemetry's resolution, never under half
        # a step (a reading is known no better than its rounding: a servo 1 step off centre
        # reads 0 or 1 step whatever its fault)
        rel, res = (
            (cfg.band_rel, cfg.band_res) if model.is_shaft
            else (cfg.servo_band_rel, cfg.servo_band_res)
        )  # fmt: skip
        self.bands = (rel, max(res, 0.5) * cfg.speed_resolution)
        self.load_model = LoadModel(model, cfg, n_full)
        # a load current lost in the sensor's noise says nothing (a small tunnel thruster)
        self.load_visible = (
            model.is_shaft
            and model.k_torque > 0.0
            and (self.load_model.load_a >= cfg.load_snr * cfg.current_abs)
        )
        # (t, n_m, n_p, n_fast) for stuck: n_fast the prediction of a drive as quick as the
        # lag's uncertainty allows
        self.recent: deque[tuple[float, float, float, float]] = deque()
        self.n_fast = 0.0  # the last sample's quick prediction
        # the window's moves (ShaftDiagnoser._moves), kept for the window they were taken on
        self.moves_key: tuple[int, float, float] | None = None
        self.moves = (0.0, 0.0, 1.0, 0.0, 1.0)
        self.thrust_sum, self.thrust_count = 0.0, 0  # implied thrust since the last take
        # a stalled episode's current evidence: samples, sums of the current above idle and
        # of what the predicted speed would draw (jammed or dead, judged on their means)
        self.stall_k, self.stall_excess, self.stall_drawn = 0, 0.0, 0.0

    # --- prediction -------------------------------------------------------------------

    def reference(self, u: float) -> float:
        """The speed (deflection) a healthy drive settles at for the force ``u`` (N) in
        open water."""
        m = self.model
        if m.is_shaft:
            return math.copysign(math.sqrt(abs(u) / m.k_thrust), u)
        return u / m.full_force_n

    def set_command(self, u: float, inflow: float = 0.0) -> None:
        """The command ``u`` (N) sent, in the told axial ``inflow`` (m/s, along the thrust).
        A torque drive settles off its open-water speed n_0 there: its motor torque holds
        k_Q n_0 |n_0| against the propeller's k_Q (n |n| - |n| V_a c_Q), so
        n = a + sign(n_0) sqrt(a^2 + n_0^2), a = V_a c_Q / 2; a speed loop holds n_0."""
        n0 = self.reference(u)
        self.ref, self.q_ref, self.inflow = n0, n0 * abs(n0), inflow
        if inflow and n0 and self.torque_drive:
            a = 0.5 * inflow * self.model.inflow_torque
            self.ref = a + math.copysign(math.sqrt(a * a + n0 * n0), n0)

    def amplitude(self, n_m: float, n_p: float, gap_s: float) -> None:
        """``ratio_t`` after a sample ``gap_s`` after the last: k = sum n_m n_p / sum n_p^2
        over about the last AMPLITUDE_TAU_S (exponential weights, in time: the supply
        vessel's drives report at 2 Hz, CyberShip II's at 10), the speed's least-squares
        amplitude against the prediction, squared for a shaft (thrust goes as the speed
        squared), as is for a servo (its force goes as the deflection; squared, a servo at
        0.7 was shown at 0.49).
        Weighted by n_p^2, so a sample predicted near 0 (a reversal, where the lag's error is
        the whole speed) counts for little, where a mean of ratios was biased up by them (a
        weak motor at 0.5 shown at 0.55-0.64 on CyberShip II)."""
        w = -math.expm1(-gap_s / AMPLITUDE_TAU_S)
        self.sum_mp += w * (n_m * n_p - self.sum_mp)
        self.sum_pp += w * (n_p * n_p - self.sum_pp)
        k = self.sum_mp / self.sum_pp if self.sum_pp > 0.0 else 1.0
        k = min(k, math.sqrt(RATIO_MAX)) if k > 0.0 else 0.0
        self.ratio_t = k * k if self.model.is_shaft else k  # a servo's force: its deflection

    def restart_amplitude(self, t_s: float) -> None:
        """``ratio_t`` from nothing at ``t_s`` (an episode has cleared: the speeds it held,
        a stalled shaft's zeros, say nothing of the motor's strength now)."""
        self.ratio_t, self.sum_mp, self.sum_pp = 1.0, 0.0, 0.0
        self.amplitude_since_s = t_s

    def amplitude_full(self, t_s: float) -> bool:
        """``ratio_t`` rests on a whole AMPLITUDE_TAU_S of samples, not on the few since
        :meth:`restart_amplitude`."""
        return t_s - self.amplitude_since_s >= AMPLITUDE_TAU_S

    def load_amplitude(self, excess_a: float, drawn_a: float, gap_s: float) -> None:
        """``ratio_q`` after a sample: the current above idle over what the measured speed
        should draw (``drawn_a`` > 0), in least squares as :meth:`amplitude`."""
        w = -math.expm1(-gap_s / AMPLITUDE_TAU_S)
        self.sum_qp += w * (excess_a * drawn_a - self.sum_qp)
        self.sum_pp_q += w * (drawn_a * drawn_a - self.sum_pp_q)
        if self.sum_pp_q > 0.0:
            self.ratio_q = self.sum_qp / self.sum_pp_q

    def open_water(self, n: float) -> float:
        """The force (N) a healthy actuator gives at speed (deflection) ``n`` at rest."""
        m = self.model
        return m.k_thrust * n * abs(n) if m.is_shaft else n * m.full_force_n

    def advance(self, t_s: float) -> None:
        """The prediction carried to ``t_s`` under the reference in force."""
        h = t_s - self.t_pred
        if h <= 0.0:
            return
        if self.torque_drive and self._tcs[0] > 0.0:
            pairs = zip(self.n_pred, self._inertias, strict=True)
            self.n_pred = [self._torque_drive(n, inertia, h) for n, inertia in pairs]
        else:
            self.n_pred = [
                self.ref + (n - self.ref) * (math.exp(-h / tc) if tc > 0.0 else 0.0)
                for n, tc in zip(self.n_pred, self._tcs, strict=True)
            ]
        self.t_pred = t_s
        n0, n1, n2 = self.n_pred
        self.history.append((t_s, n0, n1, n2))
        keep = t_s - max(2.0, 4.0 * self.cfg.latency_s + self.cfg.stuck_window_s)
        while len(self.history) > 2 and self.history[1][0] < keep:
            self.history.popleft()

    def _torque_drive(self, n: float, inertia: float, h: float) -> float:
        """A torque drive's speed after ``h`` s from ``n``: I dn/dt = Q_m - Q(n) per k_Q,
        Q(n) = n |n| - |n| V_a c_Q, semi-implicit Euler in sub-steps of a tenth of the
        fastest lag (the quadratic load at the new speed: stable), as the truth steps it."""
        if h >= 100.0 * self._tcs[2]:  # a long pause (the first command on a process's
            return self.ref  # monotonic clock): settled at the steady speed, whatever the lag
        c_q = self.model.inflow_torque * self.inflow
        steps = max(1, math.ceil(h / (0.1 * self._tcs[1])))  # at most 2250
        dt = h / steps
        for _ in range(steps):
            drive = self.q_ref + abs(n) * c_q
            n = (inertia * n + dt * drive) / (inertia + dt * abs(n))
        return n

    def restart(self, t_s: float, speed: float) -> None:
        """The prediction restarted from the measured ``speed`` at ``t_s`` (after a telemetry
        gap: the drive may have stopped, been restarted or rebooted meanwhile); the tests and
        the stuck window start again."""
        n = self.speed_map.data_sheet(speed)
        self.n_pred = [n, n, n]
        self.t_pred = t_s
        self.history.clear()
        self.history.append((t_s, n, n, n))
        self.recent.clear()
        self.frozen_s = self.weak_s = 0.0
        self.thrust.reset()
        self.load.reset()

    def predicted_at(self, t_s: float) -> tuple[float, float, float]:
        """The three predicted speeds (nominal, fast, slow lag) at ``t_s`` from the
        history, linear between entries."""
        hist = self.history
        if not hist:
            return 0.0, 0.0, 0.0
        # the first entry at or after t_s (the times strictly increase: advance), and the one
        # before it (the first itself if it is the first)
        i = bisect.bisect_left(hist, t_s, key=_time)
        if i == len(hist):
            last = hist[-1]
            return last[1], last[2], last[3]
        entry, prev = hist[i], hist[max(i - 1, 0)]
        dt = entry[0] - prev[0]
        w = 1.0 if dt <= 0.0 else (t_s - prev[0]) / dt
        a, b, c = (p + w * (e - p) for p, e in zip(prev[1:], entry[1:], strict=True))
        return a, b, c

    def current_at(self, n: float) -> float:
        """The current (A) a healthy shaft at speed ``n`` draws (:class:`LoadModel`)."""
        return self.load_model.current(n)
