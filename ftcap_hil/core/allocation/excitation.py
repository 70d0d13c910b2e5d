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

from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray, IntArray


@dataclass(frozen=True)
class ExcitationConfig:
    """Dither and probe settings (module docstring); ValueError on construction if invalid."""

    dither_amplitude: float = 0.03  # fraction of each thruster's range, largest component
    dither_period: int = 2  # cycles per PRBS level
    probe_amplitude: float = 0.1  # fraction of the range
    probe_interval: int = 10  # cycles between probes of a dead thruster (0: never)
    probe_length: int = 4  # cycles per probe
    seed: int = 0
    # Sized to the noise (Kalman estimator): the dither and probe amplitudes are raised to
    # what brings each delta_i ``info_rate`` units of Fisher information per second at the
    # sensor's noise, up to ``amplitude_max`` (fractions of the range). 0: fixed amplitudes.
    info_rate: float = 40.0
    amplitude_max: float = 0.25

    def __post_init__(self) -> None:
        if self.info_rate < 0 or not 0 <= self.amplitude_max <= 1:
            raise ValueError("excitation: info_rate >= 0 and amplitude_max in [0, 1]")
        if self.dither_amplitude < 0 or self.probe_amplitude < 0:
            raise ValueError("excitation: amplitudes must be >= 0")
        if self.dither_period < 1 or self.probe_length < 1 or self.probe_interval < 0:
            raise ValueError("excitation: periods must be >= 1 (probe_interval >= 0)")


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class ExcitationOutput:
    """One cycle's excitation, per thruster (m,), in N."""

    u_pref: FloatArray  # (m,) preferred command (N)
    probe_limit: FloatArray  # (m,) amplitude a probed dead thruster may use (0: not probed)


class Excitation:
    """Null-space dither and recovery probes as a preferred command (module docstring).

    ``B`` (k, m) effectiveness matrix; ``u_range`` (m,) each thruster's range in N
    (max(|u_min|, |u_max|)), which the amplitudes are fractions of. Call once per cycle.
    """

    def __init__(self, B: FloatArray, u_range: FloatArray, config: ExcitationConfig | None = None):
        self.config = config or ExcitationConfig()
        self._B = np.asarray(B, dtype=np.float64)
        self._range = np.asarray(u_range, dtype=np.float64)
        m = self._B.shape[1]
        # A fixed PRBS table (one +-1 level per null-space direction and period), drawn
        # once: per-cycle random draws cost more than the rest of the excitation.
        rng = np.random.default_rng(self.config.seed)
        self._table = rng.integers(0, 2, size=(1024, m)) * 2.0 - 1.0
        self._zero = np.zeros(m)
        self._cached = np.zeros(m)
        self._cached_level = -1
        self._cycle = 0
        self._live_key = b""  # live mask (bytes) the basis was computed for
        self._delta_key = np.ones(m)  # delta_hat the basis was computed for
        self._idx: IntArray = np.zeros(0, dtype=np.intp)
        self._basis = np.zeros((0, 0))

    @property
    def cycle(self) -> int:
        """How many times the sequence has advanced (calls with ``advance``)."""
        return self._cycle

    def _null_basis(self, delta_hat: FloatArray, live: BoolArray) -> tuple[IntArray, FloatArray]:
        """Live thruster indices and the null space of the scaled live effective matrix;
        recomputed only when delta_hat moved by more than 1e-3 or the live set changed (an
        SVD per cycle is the dearest part of the excitation otherwise)."""
        mask = live.tobytes()
        if mask != self._live_key or np.abs(self._delta_key - delta_hat).max() > 1e-3:
            idx = np.flatnonzero(live)
            beff = self._B[:, idx] * (delta_hat[idx] * self._range[idx])[None, :]
            if idx.size:
                _, sv, vt = np.linalg.svd(beff)
                rank = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1.0)))
                self._basis = vt[rank:].T  # (live, nullity)
            else:
                self._basis = np.zeros((0, 0))
            self._idx = idx
            self._live_key, self._delta_key = mask, delta_hat.copy()
        return self._idx, self._basis

    def _null_dither(self, delta_hat: FloatArray, live: BoolArray) -> FloatArray:
        out = np.zeros(self._B.shape[1])
        if self.config.dither_amplitude == 0:
            return out
        # Columns are scaled to the thruster ranges so the dither uses each range evenly.
        idx, basis = self._null_basis(delta_hat, live)
        if basis.shape[1] == 0:
            return out
        level = self._cycle // self.config.dither_period
        z = basis @ self._table[level % self._table.shape[0], : basis.shape[1]]
        peak = np.abs(z).max()
        if peak > 0:
            out[idx] = self.config.dither_amplitude * self._range[idx] * z / peak
        return out

    def __call__(
        self, delta_hat: FloatArray, dead: BoolArray, advance: bool = True,
        still: BoolArray | None = None,
    ) -> ExcitationOutput:  # fmt: skip
        """Excitation for this cycle. ``advance``: a new estimation sample was taken, so the
        sequence moves on (levels are held for whole estimation samples, whatever the
        allocation rate). ``still`` (m,): thrusters left out of the dither (their drive
        alarms, or the motion alone suspects them) that still get probes if dead. The
        returned arrays are shared: treat them as read-only."""
        cfg = self.config
        level = self._cycle // cfg.dither_period
        quiet = dead if still is None else dead | still
        # The PRBS level only changes at period boundaries; a change of the dead set must
        # not leave a stale dither on a thruster that has just been taken out.
        if level != self._cached_level or (
            True in quiet.tolist() and (self._cached[quiet] != 0.0).any()
        ):
            self._cached = self._null_dither(delta_hat, ~quiet)
            self._cached_level = level
        u_pref, limit = self._cached, self._zero
        if cfg.probe_interval and cfg.probe_amplitude and True in dead.tolist():
            phase = self._cycle % cfg.probe_interval
            if phase < cfg.probe_length:
                sign = 1.0 if phase % 2 == 0 else -1.0
                amp = cfg.probe_amplitude * self._range
                u_pref = np.where(dead, sign * amp, u_pref)
                limit = np.where(dead, amp, 0.0)
        if advance:
            self._cycle += 1
        return ExcitationOutput(u_pref, limit)
