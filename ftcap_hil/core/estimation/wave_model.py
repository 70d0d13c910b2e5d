"""The first-order wave load as the estimator models it: a lightly damped oscillator per axis.

The wave load on a hull is a narrow-band force near the sea's peak frequency w0, far larger
than the thrusters (first-order loads of a few times their capacity in a moderate sea) and
zero-mean. Treated as white noise it would drown every thruster's effect; a filter that
knows its colour can predict it over the next sample and subtract it. Per axis (the linear
wave model of Fossen 2021, ch. 10.2.4, written as a force)::

    xi1' = xi2
    xi2' = -w0^2 xi1 - 2 zeta w0 xi2 + n,    n white, intensity q = 4 zeta w0 sigma^2
    force = xi2                              (stationary standard deviation sigma)

discretised exactly over each sample interval (Van Loan): the transition Phi, the process
noise Qd and the row c that gives the force's mean over the interval from the state at
its start (what the plant's one-step map takes as its constant input).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ftcap_hil.core.messages import FloatArray


@dataclass(frozen=True)
class WaveStep:
    """One interval's discrete wave model over all k axes (state [xi1, xi2] per axis,
    axis-major): ``phi`` (2k, 2k), ``q`` (2k, 2k) process noise, ``mean`` (k, 2k) the mean
    force over the interval from the state at its start."""

    phi: FloatArray
    q: FloatArray
    mean: FloatArray


class WaveModel:
    """Oscillators at ``omega_rad_s`` with damping ``damping`` and stationary force standard
    deviations ``force_std`` (k,) (N, N, N m). :meth:`step` is cached per interval length
    (to the microsecond)."""

    def __init__(self, omega_rad_s: float, damping: float, force_std: FloatArray) -> None:
        if not (omega_rad_s > 0 and damping > 0):
            raise ValueError(f"wave model: need w0, zeta > 0, got {omega_rad_s}, {damping}")
        self.omega, self.zeta = float(omega_rad_s), float(damping)
        self.force_std = np.asarray(force_std, dtype=np.float64)
        self.k = self.force_std.size
        self._cache: dict[int, WaveStep] = {}

    def stationary_cov(self) -> FloatArray:
        """The oscillators' stationary covariance (2k, 2k): var xi2 = sigma^2, var xi1 =
        sigma^2 / w0^2, uncorrelated."""
        var = np.square(self.force_std)
        diag = np.column_stack([var / self.omega**2, var]).ravel()
        out: FloatArray = np.diag(diag)
        return out

    def step(self, dt_s: float) -> WaveStep:
        """The discrete model over ``dt_s``."""
        key = int(round(dt_s * 1e6))
        hit = self._cache.get(key)
        if hit is None:
            hit = self._cache[key] = self._discretise(key * 1e-6)
            if len(self._cache) > 64:  # intervals jitter on a real clock: bound the cache
                self._cache.pop(next(iter(self._cache)))
        return hit

    def _discretise(self, dt: float) -> WaveStep:
        w, z = self.omega, self.zeta
        a = np.array([[0.0, 1.0], [-w * w, -2.0 * z * w]])
        k = self.k
        phis, qs, means = [], [], []
        for sigma in self.force_std:
            qc = np.array([[0.0, 0.0], [0.0, 4.0 * z * w * sigma * sigma]])
            # Van Loan: expm([[-A, Qc], [0, A^T]] dt) gives Phi and Qd
            vl = np.zeros((4, 4))
            vl[:2, :2], vl[:2, 2:], vl[2:, 2:] = -a, qc, a.T
            e = expm(vl * dt)
            phi = e[2:, 2:].T
            qd = phi @ e[:2, 2:]
            # the integral of Phi over the interval: expm([[A, I], [0, 0]] dt)[:2, 2:]
            it = np.zeros((4, 4))
            it[:2, :2], it[:2, 2:] = a, np.eye(2)
            integral = expm(it * dt)[:2, 2:]
            phis.append(phi)
            qs.append(0.5 * (qd + qd.T))
            means.append(integral[1] / dt)
        phi_all, q_all = np.zeros((2 * k, 2 * k)), np.zeros((2 * k, 2 * k))
        mean = np.zeros((k, 2 * k))
        for j in range(k):
            sl = slice(2 * j, 2 * j + 2)
            phi_all[sl, sl], q_all[sl, sl], mean[j, sl] = phis[j], qs[j], means[j]
        return WaveStep(phi_all, q_all, mean)
