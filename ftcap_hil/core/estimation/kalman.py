"""Fault estimation by a Kalman filter on the measured motion (mode ``ftcap``, the default).

The windowed estimator differences two noisy velocity samples into a wrench and fits it as if
it were exact: velocity noise sigma becomes wrench noise ~ M sigma sqrt(2) / T_s. This filter
uses the evidence as it is. Its state carries the dynamic state of the plant and the fault
parameters themselves::

    z = [s (k), delta (m), b (k)]        s = nu (vessel) or x (linear plant), b = B f + tau_env

    predict   s(t+1) = f(s(t), w, dt)    w = B diag(u) delta + b     (the allocator's model)
              delta, b: random walks (q_delta, q_bias per second)
    measure   y = s + v,  v ~ N(0, R),  R = diag(measurement_std^2)   (the sensor's noise)

With ``damping_error_std`` > 0 the state also carries the damping model's relative error per
axis, theta (k): w gains -theta * D(nu) nu, the model's damping force at the interval's start
times the error (a random walk of ``q_damping`` per sqrt(s) from a prior of that std). On a
moving vessel a damping error is a force that follows the speed, and so the thrust that holds
it: without these states it reads as effectiveness (CyberShip II on its waypoints, damping
30 % off: healthy thrusters flagged 31 % of the time), with them it is told apart by the
speed's own history.

``f`` is the plant's one-step map, the same discretisation the plant's ``inversion`` names
("euler": the paper's discrete model; "trapezoid": an explicit midpoint step, second-order
accurate for the continuous-time vessel), linearised each step (EKF). Model error and
unmodelled disturbances enter as process noise on s: ``model_error`` (a fraction of the
largest achievable wrench per axis, S) times G, the input gain of the step. The filter gives
every estimate a variance: P[delta_i, delta_i] is the square of the reported ``delta_std``.
Where the data carry no information about a thruster (its command near zero, no
excitation) its variance grows by q_delta per second and its estimate stays where it was.

A fault onset is a change the random walk would take long to follow. A CUSUM on the
normalised innovation (e^T S^-1 e, chi^2 with k degrees of freedom under no change) flags
it at a configured level; the parameters' covariance is then widened (``reset_std``) so the
filter re-converges in a few samples. The sample that raised the alarm usually straddles the
onset (part healthy, part faulty): it updates s only, never the parameters.

Decisions (flags, what the allocator uses) are taken from the estimate *and* its variance in
:mod:`ftcap_hil.core.estimation.decisions`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from ftcap_hil.core.estimation.config import Estimate, EstimatorConfig
from ftcap_hil.core.estimation.step_models import (
    LinearStep,
    StepModel,
    VesselStep,
    inv_small,
    step_model,
)
from ftcap_hil.core.estimation.wave_model import WaveModel
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.models.vessel3dof import PlantModel

# Re-exported: callers import the step models from here too.
__all__ = [
    "FilterOutput", "KalmanEstimator", "LinearStep", "StepModel", "VesselStep", "inv_small",
    "step_model",
]  # fmt: skip


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class FilterOutput:
    """What one filter update produced, besides the estimate itself."""

    estimate: Estimate
    delta_var: FloatArray  # (m,) variance of delta_hat
    bias_cov: FloatArray  # (k, k) covariance of b_hat
    nis: float  # normalised innovation squared of this sample (chi^2_k under no change)
    alarm: bool  # the change detector fired on this sample
    info: FloatArray  # (m,) Fisher information this sample carried about each delta_i


class KalmanEstimator:
    """See the module docstring. Call :meth:`update` once per estimation sample."""

    def __init__(
        self,
        B: FloatArray,
        scale: FloatArray,
        plant: PlantModel,
        config: EstimatorConfig | None = None,
    ) -> None:
        self.config = cfg = config or EstimatorConfig()
        self._B = np.array(B, dtype=np.float64)
        self._k, self._m = self._B.shape
        self._scale = np.asarray(scale, dtype=np.float64)
        std = self._measurement_std()
        self._model = step_model(plant, with_pose=std.size == 2 * self._k)
        if self._model.k != self._k:
            raise ValueError(f"plant has {self._model.k} dynamic states, B has {self._k} rows")
        self._pinv = np.linalg.pinv(self._B)
        k, m = self._k, self._m
        ks = self._ks = self._model.ns  # the tracked state: nu, or [eta, nu] with the pose
        self._waves = self._wave_model()
        self._nw = 2 * k if self._waves is not None else 0
        self._theta_end = ks + m + k  # z = [s, delta, b, wave states, damping error]
        self._damping = getattr(plant, "damping", None) if cfg.damping_error_std > 0.0 else None
        if cfg.damping_error_std > 0.0 and (self._damping is None or k != 3):
            raise ValueError(
                "estimator.damping_error_std: needs a vessel model with D(nu) nu (Vessel3DOF)"
            )
        self._d0 = self._theta_end + self._nw
        self._n = self._d0 + (k if self._damping is not None else 0)
        self._R = np.diag(np.square(std))
        self._theta0_var = np.concatenate(
            [np.full(m, cfg.initial_delta_std**2), np.square(cfg.initial_bias_rel * self._scale)]
        )
        self._reset_var = np.concatenate(
            [np.full(m, cfg.reset_std**2), np.square(cfg.reset_bias_rel * self._scale)]
        )
        self._F = np.eye(self._n)
        self._model_std = cfg.model_error * self._scale
        self._q_theta = np.concatenate(
            [np.full(m, cfg.q_delta**2), np.square(cfg.q_bias_rel * self._scale)]
        )
        self._theta_diag = (np.arange(ks, self._theta_end), np.arange(ks, self._theta_end))
        self._IKH = np.eye(self._n)
        self._s_diag = (np.arange(ks), np.arange(ks))
        self.z: FloatArray = np.zeros(self._n)
        self.P: FloatArray = np.zeros((self._n, self._n))
        self.reset()
        self._started = False
        self._cusum = 0.0
        self._since_alarm = 10**9
        self.samples = 0  # samples used since the start
        # Evidence since the change detector last rested at 0: (e, dE/ddelta, dE/db, S^-1)
        self._evidence: deque[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = deque(
            maxlen=40
        )
        self.suspects: BoolArray = np.zeros(self._m, dtype=bool)  # widened at the last alarm
        self.suspect_weight: FloatArray = np.zeros(self._m)  # their posterior odds, sum 1
        self.q_scale = 1.0  # process-noise scale learnt from the innovations

    def _wave_model(self) -> WaveModel | None:
        cfg = self.config
        if cfg.wave_period_s <= 0.0:
            return None
        std = cfg.wave_force_std
        if std is None:
            sigma = cfg.wave_force_rel * self._scale
        else:
            sigma = np.asarray(std, dtype=np.float64)
            if sigma.shape != (self._k,):
                raise ValueError(f"estimator.wave_force_std: expected {self._k} values, got {std}")
        return WaveModel(2.0 * math.pi / cfg.wave_period_s, cfg.wave_damping, sigma)

    def _measurement_std(self) -> FloatArray:
        std = self.config.measurement_std
        if std is None:
            return np.full(self._k, 1e-6)
        arr = np.asarray(std, dtype=np.float64)
        pose = 2 * self._k if self._k == 3 else self._k
        if arr.shape not in ((self._k,), (pose,)):
            raise ValueError(
                f"estimator.measurement_std: expected {self._k} values (the velocities) or "
                f"{pose} (pose and velocities), got {std}"
            )
        return np.maximum(arr, 1e-9)

    def reset(self, delta: FloatArray | None = None, bf: FloatArray | None = None) -> None:
        """Back to the initial state (optionally with given parameters)."""
        ks, m, e = self._ks, self._m, self._theta_end
        self.z = np.zeros(self._n)
        self.z[ks : ks + m] = 1.0 if delta is None else delta
        self.z[ks + m : e] = 0.0 if bf is None else bf
        self.P = np.zeros((self._n, self._n))
        self.P[:e, :e] = np.diag(np.concatenate([np.ones(ks), self._theta0_var]))
        if self._waves is not None:
            self.P[e : self._d0, e : self._d0] = self._waves.stationary_cov()
        d0 = self._d0
        self.P[d0:, d0:] = np.eye(self._n - d0) * self.config.damping_error_std**2
        self._started = False
        self._cusum = 0.0

    def forget(self, which: BoolArray) -> None:
        """The thrusters ``which`` (m,) back to their prior (delta 1, its prior variance, no
        correlation with the rest): what the motion learnt of them no longer holds (their
        drive, silent while it learnt, reports a healthy shaft again)."""
        for i in np.flatnonzero(which).tolist():
            j = self._ks + i
            self.z[j] = 1.0
            self.P[j, :] = 0.0
            self.P[:, j] = 0.0
            self.P[j, j] = self._theta0_var[i]

    def update(
        self, u: FloatArray, x_now: FloatArray, dt_s: float, x_prev: FloatArray | None = None
    ) -> FilterOutput:
        """One sample: the mean command u (m,) over the last ``dt_s`` and the measured plant
        state at its end (the plant's full state vector, e.g. [eta, nu]); ``x_prev``, the
        state at its start, is used only by the first sample (it fixes s)."""
        ks, m = self._ks, self._m
        y = self._model.dynamic_state(x_now)
        if not self._started:
            self._started = True
            self.P[:ks, :ks] = self._R
            if x_prev is None:  # nothing to learn from one state
                self.z[:ks] = y
                return self._output(0.0, False, np.zeros(m))
            self.z[:ks] = self._model.dynamic_state(x_prev)
        # P is only ever replaced, never written in place, from here on: no copy needed
        z_post, P_post = self.z.copy(), self.P
        s_pred, F = self._predict(u, dt_s)
        e = self._model.innovation(y, s_pred)
        S_inv = inv_small(self.P[:ks, :ks] + self._R)
        nis = float(e @ S_inv @ e)
        h = F[:ks, ks : ks + m].copy()  # how each delta_i moved this sample's prediction
        info = np.einsum("ji,jl,li->i", h, S_inv, h)
        self.samples += 1
        self._last_evidence = (e, h, F[:ks, ks + m : self._theta_end].copy(), S_inv)
        self._evidence.append(self._last_evidence)
        alarm = self._change_detected(nis)
        if not alarm:
            self._adapt(nis, dt_s)
            self._correct(self.P[:, :ks] @ S_inv, e)
            self._project()
            return self._output(nis, False, info)
        # A change: the parameters' old evidence is dropped (their covariance widened before
        # this sample's prediction). The sample that shows the change usually straddles the
        # onset: the reported estimate uses it (the immediate reaction), the filter goes on
        # from the state that used it for s only, as the windowed estimator evicts it.
        self.suspects = self._isolate()
        self.z, self.P = z_post, self._widened(P_post, self.suspects)
        s_pred, F = self._predict(u, dt_s)
        K = self.P[:, :ks] @ inv_small(self.P[:ks, :ks] + self._R)
        fast = self.z + K @ e
        K[ks:] = 0.0
        self._correct(K, e)
        self._project()
        out = self._output(nis, True, info)
        d = np.clip(fast[ks : ks + m], 0.0, 1.0)
        bf_fast = fast[ks + m : self._theta_end].copy()
        fast_est = replace(out.estimate, delta_hat=d, bf_hat=bf_fast, f_hat=self._pinv @ bf_fast)
        return replace(out, estimate=fast_est)

    def _correct(self, K: FloatArray, e: FloatArray) -> None:
        """Measurement update with gain K (n, k); Joseph form, which stays symmetric
        positive semi-definite when R << P_theta."""
        ks = self._ks
        self.z = self.z + K @ e
        IKH = self._IKH
        IKH[:, :ks] = -K
        s_diag = IKH.reshape(-1)[: ks * (self._n + 1) : self._n + 1]  # a view: I's first ks
        s_diag += 1.0
        P = IKH @ self.P @ IKH.T + K @ self._R @ K.T
        IKH[:, :ks] = 0.0  # back to the identity (the diagonal of the first k columns too)
        s_diag[:] = 1.0
        self.P = 0.5 * (P + P.T)

    def _project(self) -> None:
        """Bring delta back into [0, 1] by the covariance-weighted projection (Simon's
        estimate projection): the parameters correlated with a clipped delta_i move with it,
        so the state stays consistent with the data. A plain clip here made the estimate
        drift along the unobservable directions while commands saturated."""
        ks, m = self._ks, self._m
        values = self.z[ks : ks + m].tolist()  # Python floats: cheaper than numpy on (m,)
        active = [i for i, v in enumerate(values) if v < 0.0 or v > 1.0]  # NaN: never
        if not active:
            return
        targets = [0.0 if values[i] < 0.0 else 1.0 for i in active]
        rows = [ks + i for i in active]
        if len(rows) == 1 and self.P[rows[0], rows[0]] != 0.0:
            r = rows[0]  # one bound (the common case): numpy's 1 x 1 solve is this division
            self.z -= self.P[:, r] * ((self.z[r] - targets[0]) / self.P[r, r])
        else:
            PD = self.P[:, rows]  # P D^T
            gap = self.z[rows] - np.array(targets)
            self.z -= PD @ np.linalg.solve(self.P[np.ix_(rows, rows)], gap)
        np.clip(self.z[ks : ks + m], 0.0, 1.0, out=self.z[ks : ks + m])  # rounding only

    def _predict(self, u: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
        ks, m, e = self._ks, self._m, self._theta_end
        s, delta, b = self.z[:ks], self.z[ks : ks + m], self.z[ks + m : e]
        w = self._B @ (delta * u) + b
        wave = self._waves.step(dt) if self._waves is not None else None
        we, d0 = e + self._nw, self._d0
        if wave is not None:
            w = w + wave.mean @ self.z[e:we]
        dforce = None
        if self._damping is not None:
            # the damping the model misses: -theta * D(nu) nu at the interval's start
            dforce = -np.asarray(self._damping(s[ks - self._k :]), dtype=np.float64)
            w = w + dforce * self.z[d0:]
        s1, A, G = self._model.predict(s, w, dt)
        F = self._F  # identity outside the first ks rows (and the wave block): rewritten
        F[:ks, :ks] = A
        F[:ks, ks : ks + m] = G @ (self._B * u)
        F[:ks, ks + m : e] = G
        if wave is not None:
            F[:ks, e:we] = G @ wave.mean
            F[e:we, e:we] = wave.phi
        if dforce is not None:
            F[:ks, d0:] = G * dforce
        P = F @ self.P @ F.T
        Gq = G * self._model_std
        P[:ks, :ks] += self.q_scale * (Gq @ Gq.T)
        n1 = self._n + 1
        P.reshape(-1)[ks * n1 : e * n1 : n1] += self._q_theta * dt  # a view of P's diagonal
        if wave is not None:
            P[e:we, e:we] += wave.q
            self.z[e:we] = wave.phi @ self.z[e:we]
        if dforce is not None:
            P[d0:, d0:] += np.eye(self._k) * (self.config.q_damping**2 * dt)
        self.P = P
        self.z[:ks] = s1
        return s1, F

    def _adapt(self, nis: float, dt_s: float) -> None:
        """Scale the process noise so that the innovations have the size the filter expects
        (mean nis = k): smaller in a world the model matches, larger in a seaway or with a
        model error. A log-average, over the samples so far at first and then with the time
        constant ``adapt_s``; each sample's ratio clipped to [0.01, 100]; the sample of a
        change alarm left out."""
        cfg = self.config
        if cfg.adapt_s <= 0.0:
            return
        ratio = min(max(nis / self._ks, 0.01), 100.0)
        # 1/n at first (the scale settles within the first samples), then the time constant
        step = math.log(ratio) * min(1.0, max(dt_s / cfg.adapt_s, 1.0 / max(self.samples, 1)))
        self.q_scale = min(max(self.q_scale * math.exp(step), 1e-6), 1e6)

    def _change_detected(self, nis: float) -> bool:
        """CUSUM on nis - k: alarm above ``cusum_threshold`` (then restart), with a hold-off
        of m + k samples after an alarm so one onset is one alarm."""
        cfg, k = self.config, self._ks
        self._since_alarm += 1
        self._cusum = max(0.0, self._cusum + nis - k - cfg.cusum_drift)
        if self._cusum > cfg.cusum_threshold and self._since_alarm > self._m + k:
            self._cusum = 0.0
            self._since_alarm = 0
            return True
        if self._cusum == 0.0:
            self._evidence.clear()
            self._evidence.append(self._last_evidence)
        return False

    def excitation_for(self, info_rate: float, dt_s: float) -> FloatArray:
        """Command amplitude (N, (m,)) that alone brings each delta_i ``info_rate`` units of
        Fisher information per second at this sensor noise: (|G B_i| a_i)^2 / s^2 per
        sample, s^2 the innovation variance of a converged filter (about 2 R)."""
        k, ks = self._k, self._ks
        s0 = self.z[:ks] if self._started else np.zeros(ks)
        _s1, _A, G = self._model.predict(s0, np.zeros(k), dt_s)
        # the velocities' rows only (the last k of s): sized conservatively, without what
        # a measured pose adds over longer horizons
        gain = np.linalg.norm(G[ks - k :] @ self._B, axis=0)  # |G B_i| per unit command
        s2 = 2.0 * float(np.mean(np.diag(self._R)[ks - k :]))
        out: FloatArray = np.sqrt(info_rate * dt_s * s2) / np.maximum(gain, 1e-300)
        return out

    def _isolate(self) -> BoolArray:
        """Which thrusters may have changed: a generalized likelihood ratio per single
        thruster hypothesis over the evidence since the detector left 0 (mean innovation
        along G B_i u_i), Lambda_i = (sum h^T S^-1 e)^2 / sum h^T S^-1 h. Suspects: every
        thruster within ``isolation_margin`` of the best one (2.71: chi^2_1 at 90 %;
        a missed suspect is caught by the next alarm, a needless one only dips for a while)."""
        m = self._m
        a, c = np.zeros(m), np.zeros(m)
        for e, h, _g, s_inv in self._evidence:
            hs = s_inv @ h  # (k, m)
            a += e @ hs
            c += np.einsum("ji,ji->i", h, hs)
        lam = np.where(c > 0.0, a * a / np.maximum(c, 1e-300), 0.0)
        suspects: BoolArray = lam >= lam.max() - self.config.isolation_margin
        weight = np.where(suspects, np.exp(0.5 * (lam - lam.max())), 0.0)
        self.suspect_weight = weight / weight.sum()
        return suspects

    def _widened(self, P: FloatArray, suspects: BoolArray) -> FloatArray:
        """P with the suspects' delta and every bias raised to at least the reset level, and
        their correlations dropped (their old evidence no longer holds). The other thrusters
        keep what the filter knows of them: one failure does not make them unknown."""
        k = self._k
        wide = np.concatenate([suspects, np.ones(k, dtype=bool)])
        idx = self._ks + np.flatnonzero(wide)
        # each suspect widened in proportion to its posterior odds of being the one
        share = np.concatenate([self.suspect_weight, np.ones(k)])[wide]
        var = np.maximum(np.diag(P)[idx], share * self._reset_var[wide])
        out = P.copy()
        out[idx, :] = 0.0
        out[:, idx] = 0.0
        out[idx, idx] = var
        return out

    def _output(self, nis: float, alarm: bool, info: FloatArray) -> FilterOutput:
        ks, m = self._ks, self._m
        delta = self.z[ks : ks + m].copy()
        bf = self.z[ks + m : self._theta_end].copy()
        var = self.P.diagonal()[ks : ks + m].copy()
        est = Estimate(
            delta,
            bf,
            self._pinv @ bf,
            innovation=math.sqrt(nis / ks) if nis > 0 else 0.0,
            window_len=self.samples,
            restarted=alarm,
            delta_std=np.sqrt(np.maximum(var, 0.0)),
        )
        bias = slice(ks + m, self._theta_end)
        return FilterOutput(est, var, self.P[bias, bias].copy(), nis, alarm, info)
