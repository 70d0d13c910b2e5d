"""Excitation that keeps every delta_i identifiable without disturbing the vessel.

Two mechanisms, both expressed as a preferred command u_pref for the allocator (eq. 13's
effort term pulls u towards it; the slack term keeps the wrench unchanged):

* Null-space dither. With a constant command a thruster's delta_i u_i is indistinguishable
  from a bias. A pseudo-random binary sequence (PRBS, one +-1 level per null-space basis
  vector, held ``dither_period`` cycles) moves u inside the null space of the *estimated*
  effective matrix B Delta_hat restricted to the live thrusters. If the estimate is right the
  produced wrench does not change at all; if it is wrong the dither shows up in the residual,
  which is exactly the information the estimator needs.
* Recovery probe. A thruster the allocator has taken out (delta_hat < dead_threshold) gets no
  command, so nothing could ever show that it recovered. Every ``probe_interval`` cycles it
  gets a short zero-mean pulse train (+a, -a, ...) of ``probe_length`` cycles; outside those
  windows its command is exactly zero. Amplitude 0 or interval 0 disables either mechanism.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftcap_hil.messages import FloatArray


@dataclass(frozen=True)
class ExcitationConfig:
    dither_amplitude: float = 0.03  # fraction of each thruster's range, largest component
    dither_period: int = 2  # cycles per PRBS level
    probe_amplitude: float = 0.1  # fraction of the range
    probe_interval: int = 100  # cycles between probes of a dead thruster (0: never)
    probe_length: int = 4  # cycles per probe
    seed: int = 0

    def __post_init__(self) -> None:
        if self.dither_amplitude < 0 or self.probe_amplitude < 0:
            raise ValueError("excitation: amplitudes must be >= 0")
        if self.dither_period < 1 or self.probe_length < 1 or self.probe_interval < 0:
            raise ValueError("excitation: periods must be >= 1 (probe_interval >= 0)")


@dataclass(frozen=True)
class ExcitationOutput:
    u_pref: FloatArray  # (m,) preferred command (N)
    probe_limit: FloatArray  # (m,) amplitude a probed dead thruster may use (0: not probed)


class Excitation:
    def __init__(self, B: FloatArray, u_range: FloatArray, config: ExcitationConfig | None = None):
        self.config = config or ExcitationConfig()
        self._B = np.asarray(B, dtype=np.float64)
        self._range = np.asarray(u_range, dtype=np.float64)
        self._rng = np.random.default_rng(self.config.seed)
        self._levels = np.zeros(self._B.shape[1])
        self._cycle = 0

    def _null_dither(self, delta_hat: FloatArray, live: FloatArray) -> FloatArray:
        m = self._B.shape[1]
        out = np.zeros(m)
        idx = np.flatnonzero(live)
        if self.config.dither_amplitude == 0 or idx.size == 0:
            return out
        # Scale columns to the thruster ranges so the dither uses each range evenly.
        beff = self._B[:, idx] * (delta_hat[idx] * self._range[idx])[None, :]
        _, sv, vt = np.linalg.svd(beff)
        rank = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1.0)))
        basis = vt[rank:].T  # (live, nullity)
        if basis.shape[1] == 0:
            return out
        if self._cycle % self.config.dither_period == 0:
            self._levels = self._rng.choice([-1.0, 1.0], size=m)
        z = basis @ self._levels[: basis.shape[1]]
        peak = np.max(np.abs(z))
        if peak > 0:
            out[idx] = self.config.dither_amplitude * self._range[idx] * z / peak
        return out

    def __call__(self, delta_hat: FloatArray, dead: FloatArray) -> ExcitationOutput:
        """Excitation for this cycle; call once per cycle."""
        u_pref = self._null_dither(delta_hat, ~dead)
        limit = np.zeros_like(u_pref)
        cfg = self.config
        if cfg.probe_interval and cfg.probe_amplitude and np.any(dead):
            phase = self._cycle % cfg.probe_interval
            if phase < cfg.probe_length:
                sign = 1.0 if phase % 2 == 0 else -1.0
                amp = cfg.probe_amplitude * self._range
                u_pref = np.where(dead, sign * amp, u_pref)
                limit = np.where(dead, amp, 0.0)
        self._cycle += 1
        return ExcitationOutput(u_pref, limit)
