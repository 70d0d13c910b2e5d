"""Fault estimation: steps 1 and 2 of F-TCAP (eqs. 9-12).

Each cycle the estimator receives the command u (m,) that was applied over the last step and
the generalized force w (k,) the plant model infers from the state change over that step
(``plants.*.measured_wrench``), w = B (Delta u + f) + noise.

``WindowedEstimator`` (the default) identifies theta = [delta (m), b = B f (k)] jointly by
bounded least squares over the last N samples, penalising the change from the previous
estimate (the R-term of eq. 10, here for delta *and* b):

    min_theta  sum_j || S^-1 (Phi_j theta - w_j) ||^2 + || theta - theta_prev ||^2_Lambda
    s.t.       0 <= delta_i <= 1,         Phi_j = [B diag(u_j), I_k]

S = diag(max achievable |tau| per axis) makes the axes commensurate. Only B f is
identifiable when B has a null space, so b is estimated, and a per-thruster f_hat is reported
as its minimum-norm preimage pinv(B) b. Directions the window does not excite (a thruster held
at a constant command: delta_i * const looks like a bias; a thruster not used at all) stay at
the previous estimate through the Lambda term instead of drifting. When the one-step
innovation jumps above a threshold (a fault onset), the window is restarted so that pre-fault
samples cannot bias the new estimate.

``LiteralEstimator`` is the paper read literally: step 1 puts the whole residual of the last
step into the bias (eq. 9), so the slack of eq. (11) is zero at Gamma = 0 and Delta_hat never
leaves its initial value (docs/algorithm.md). It is kept for comparison.
"""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.estimation.config import Estimate, EstimatorConfig
from ftcap_hil.core.messages import FloatArray


class WindowedEstimator:
    """Joint windowed estimate of delta (m,) and b = B f (k,) (module docstring).

    ``B`` (k, m) effectiveness matrix, ``scale`` (k,) S per axis (:func:`wrench_scale`).
    The normal equations are running sums: each sample's contribution Phi_j^T Phi_j,
    Phi_j^T w_j is stored in a ring buffer, added on arrival and subtracted on eviction, and
    the sums are rebuilt from the buffer once per window so that rounding cannot accumulate.
    A restart zeroes the buffer.
    """

    def __init__(self, B: FloatArray, scale: FloatArray, config: EstimatorConfig | None = None):
        import daqp

        self._daqp = daqp.solve
        self.config = config or EstimatorConfig()
        self._B = np.array(B, dtype=np.float64)
        self._k, self._m = self._B.shape
        self._s = np.array(scale, dtype=np.float64)
        self._Bs = self._B / self._s[:, None]  # S^-1 B
        self._pinv = np.linalg.pinv(self._B)
        n, p = self.config.window, self._m + self._k
        self._Phi = np.zeros((self._k, p))  # one sample's regressor, S^-1 [B diag(u), I]
        self._Phi[:, self._m :] = np.diag(1.0 / self._s)
        self._Hbuf = np.zeros((n, p, p))
        self._gbuf = np.zeros((n, p))
        self._H = np.zeros((p, p))
        self._g = np.zeros(p)
        self._E2 = np.zeros(n)  # squared past innovations, for the adaptive threshold
        self._count = 0  # samples in the window since the last restart
        self._head = 0
        self._since_restart = 0
        self._lam = np.concatenate(
            [
                np.full(self._m, self.config.prior_weight_delta),
                np.full(self._k, self.config.prior_weight_bias) / self._s**2,
            ]
        )
        self._lam_diag = np.diag(self._lam)
        self._lo = np.concatenate([np.zeros(self._m), np.full(self._k, -1e20)])
        self._hi = np.concatenate([np.ones(self._m), np.full(self._k, 1e20)])
        self._no_rows = np.zeros((0, p))
        self._sense = np.zeros(p, dtype=np.int32)
        self._holdoff = self.config.holdoff or p
        self._provisional: int | None = None  # slot of the straddling sample after a restart
        self.theta = np.concatenate([np.ones(self._m), np.zeros(self._k)])
        self._uf: FloatArray | None = None  # prefilter states
        self._wf: FloatArray | None = None

    def _restart(self) -> None:
        self._Hbuf[:] = 0.0
        self._gbuf[:] = 0.0
        self._H[:] = 0.0
        self._g[:] = 0.0
        self._E2[:] = 0.0
        self._count = self._since_restart = 0

    def reset(self, delta: FloatArray | None = None, bf: FloatArray | None = None) -> None:
        """Empty the window and start from ``delta`` (m,) and ``bf`` (k,) (default 1 and 0)."""
        self.theta = np.concatenate(
            [np.ones(self._m) if delta is None else delta, np.zeros(self._k) if bf is None else bf]
        )
        self._restart()

    def update(self, u: FloatArray, w: FloatArray) -> Estimate:
        """Add one sample and re-fit: ``u`` (m,) the command (N) applied over the step,
        ``w`` (k,) the actuator wrench measured over it (N, N, N*m); both finite."""
        m = self._m
        pred = self._B @ (self.theta[:m] * u) + self.theta[m:]
        e = float(np.abs((w - pred) / self._s).max())
        rms = math.sqrt(self._E2.sum() / self._count) if self._count else 0.0
        restarted = e > max(self.config.change_floor, self.config.change_factor * rms) and (
            self._since_restart >= self._holdoff
        )
        evicted = self._provisional is not None
        if self._provisional is not None:
            self._drop(self._provisional)
            self._provisional = None
        if restarted:
            self._restart()
        a = self.config.prefilter
        if a > 0.0:
            # The innovation test above uses the raw sample (a jump is not smeared); the fit
            # uses the filtered one, whose state starts afresh at a restart, and again at the
            # first clean sample after it, so that the new window holds neither pre-onset data
            # nor, once evicted, the straddling sample.
            if restarted or evicted or self._uf is None or self._wf is None:
                self._uf, self._wf = np.array(u, dtype=np.float64), np.array(w, dtype=np.float64)
            else:
                self._uf = a * self._uf + (1.0 - a) * u
                self._wf = a * self._wf + (1.0 - a) * w
            u, w = self._uf, self._wf
        self._add_sample(u, w, e)
        if restarted and self.config.evict_straddling:
            # It straddles the onset: used alone now, evicted at the next clean sample (why:
            # docs/decisions.md).
            self._provisional = (self._head - 1) % self.config.window
        self.theta = self._solve()
        return self.estimate(innovation=e, restarted=restarted)

    def _drop(self, slot: int) -> None:
        self._H -= self._Hbuf[slot]
        self._g -= self._gbuf[slot]
        self._Hbuf[slot] = 0.0
        self._gbuf[slot] = 0.0
        self._E2[slot] = 0.0
        self._count -= 1

    def _add_sample(self, u: FloatArray, w: FloatArray, e: float) -> None:
        h = self._head
        phi = self._Phi
        phi[:, : self._m] = self._Bs * u
        Hj = phi.T @ phi
        gj = phi.T @ (w / self._s)
        self._H += Hj - self._Hbuf[h]  # the slot holds the evicted sample (zero if none)
        self._g += gj - self._gbuf[h]
        self._Hbuf[h], self._gbuf[h], self._E2[h] = Hj, gj, e * e
        self._head = (h + 1) % self.config.window
        self._count = min(self._count + 1, self.config.window)
        self._since_restart += 1
        if self._head == 0:
            self._H = self._Hbuf.sum(axis=0)
            self._g = self._gbuf.sum(axis=0)

    def _solve(self) -> FloatArray:
        H = self._H + self._lam_diag
        g = self._g + self._lam * self.theta
        # daqp (dual active set, C) solves this 7-variable box QP in a few microseconds,
        # cheaper than numpy's generic solve plus a fallback when a bound is active.
        x, _f, flag, _info = self._daqp(H, -g, self._no_rows, self._hi, self._lo, self._sense)
        x = np.asarray(x, dtype=np.float64)
        if flag >= 1 and math.isfinite(x.sum()):
            np.minimum(np.maximum(x, self._lo, out=x), self._hi, out=x)
            return x
        theta = np.asarray(np.linalg.lstsq(H, g, rcond=None)[0], dtype=np.float64)
        return np.clip(theta, self._lo, self._hi)  # not reached in practice: H is PD

    def estimate(self, innovation: float = 0.0, restarted: bool = False) -> Estimate:
        """The current estimate (copies), with the diagnostics handed in."""
        delta = self.theta[: self._m].copy()
        bf = self.theta[self._m :].copy()
        return Estimate(delta, bf, self._pinv @ bf, innovation, self._count, restarted)


class LiteralEstimator:
    """Eqs. (9)-(11) as printed (module docstring); ``B`` (k, m), ``scale`` (k,) as for
    :class:`WindowedEstimator`."""

    def __init__(self, B: FloatArray, scale: FloatArray, config: EstimatorConfig | None = None):
        self.config = config or EstimatorConfig()
        self._B = np.array(B, dtype=np.float64)
        self._k, self._m = self._B.shape
        self._s = np.array(scale, dtype=np.float64)
        self._pinv = np.linalg.pinv(self._B)
        self.delta = np.ones(self._m)
        self.bf = np.zeros(self._k)
        self._hist: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = []

    def reset(self, delta: FloatArray | None = None, bf: FloatArray | None = None) -> None:
        """Forget the history and start from ``delta`` (m,) and ``bf`` (k,) (default 1, 0)."""
        self.delta = np.ones(self._m) if delta is None else delta.copy()
        self.bf = np.zeros(self._k) if bf is None else bf.copy()
        self._hist.clear()

    def update(self, u: FloatArray, w: FloatArray) -> Estimate:
        """Steps 1 and 2 as printed for one sample: ``u`` (m,) N, ``w`` (k,) N / N*m."""
        # Step 1, eq. (9): B f_hat(t-1) = x(t) - A x(t-1) - B Delta_hat(t-1) u(t-1).
        self.bf = w - self._B @ (self.delta * u)
        self._hist.append((u, w, self.bf, self.delta.copy()))
        self._hist = self._hist[-self.config.window :]
        # Step 2, eqs. (10)-(11): min sum ||s_i||^2 + R ||gamma||^2 with the stored f_hat(t-i).
        Bs = self._B / self._s[:, None]
        H = np.diag(np.full(self._m, self.config.prior_weight_delta))
        g = np.zeros(self._m)
        for u_i, w_i, bf_i, _ in self._hist:
            Phi = Bs * u_i[None, :]
            r = (w_i - self._B @ (self.delta * u_i) - bf_i) / self._s
            H += Phi.T @ Phi
            g += Phi.T @ r
        gamma = np.linalg.solve(H, g)
        self.delta = np.clip(self.delta + gamma, 0.0, 1.0)
        return self.estimate()

    def estimate(self) -> Estimate:
        """The current estimate (copies)."""
        return Estimate(
            self.delta.copy(), self.bf.copy(), self._pinv @ self.bf, 0.0, len(self._hist)
        )
