"""One allocator cycle: estimate faults -> bounds -> allocate. Pure: no I/O, no clock.

Call order per cycle t (Algorithm 1 of the paper):

    w = plant.measured_wrench(x(t-1), x(t), dt)      # by the caller, from telemetry
    result = core.step(tau_d(t), w)                  # w = None when telemetry is stale
    send(result.u)

``step`` assumes that the command acting over the last estimation interval is the one it
returned last time (``u_sample`` overrides that: the daemon passes the time average of what
it sent). The centre of the rate box is always the last command (``reset_command`` sets it,
e.g. after the shell had to send zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ftcap_hil.core.allocator import Allocation, Allocator, AllocatorConfig
from ftcap_hil.core.estimator import (
    Estimate,
    EstimatorConfig,
    LiteralEstimator,
    WindowedEstimator,
    wrench_scale,
)
from ftcap_hil.core.excitation import Excitation, ExcitationConfig
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.geometry import ThrusterSet
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.status import Mode


@dataclass(frozen=True)
class CoreConfig:
    """Everything one :class:`FtcapCore` is built from: the mode (:class:`Mode`), the
    estimator, allocator and excitation settings, and the fault-flag thresholds (fractions
    of full effectiveness, 0 < fault_threshold <= fault_clear <= 1 in practice)."""

    mode: Mode = Mode.FTCAP
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    allocator: AllocatorConfig = field(default_factory=AllocatorConfig)
    excitation: ExcitationConfig = field(default_factory=ExcitationConfig)
    # Fault flags, with hysteresis: flagged when delta_hat drops below fault_threshold,
    # cleared when it rises above fault_clear. Flags only change on estimates the window
    # determines (window_len >= m + k): right after a restart the estimate explains one or
    # two samples by a minimum change and may dip transiently on healthy thrusters.
    fault_threshold: float = 0.85
    fault_clear: float = 0.95


@dataclass(frozen=True)
class CycleResult:
    """What one :meth:`FtcapCore.step` produced; per-thruster arrays are (m,)."""

    u: FloatArray  # (m,) command to send (N)
    estimate: Estimate
    allocation: Allocation
    faulty: BoolArray  # (m,), see CoreConfig.fault_threshold / fault_clear
    probing: BoolArray  # (m,), a recovery probe is active
    estimation_frozen: bool


class FtcapCore:
    """The allocator's cycle (module docstring): fault estimation, excitation, allocation.

    ``B`` (k, m): effectiveness matrix, k = 3 for a surface vessel (tau = [X (N), Y (N),
    N (N*m)], body frame) or 1 for the linear plant; ``thrusters``: the m thrusters' limits;
    ``dt_s``: the allocation period (s). The mode picks the estimator: ``FTCAP`` the windowed
    one, ``FTCAP_LITERAL`` the paper's literal one, ``ORACLE`` the truth handed in to
    :meth:`step`, ``CAP`` / ``NONE`` none (Delta_hat = I, f_hat = 0). Pure and
    single-threaded: the caller hands in measurements and times, the core reads no clock.
    ValueError if ``B`` and ``thrusters`` disagree on m.
    """

    def __init__(
        self, B: FloatArray, thrusters: ThrusterSet, dt_s: float, config: CoreConfig | None = None
    ):
        self.config = config or CoreConfig()
        self.B = np.array(B, dtype=np.float64)
        self.k, self.m = self.B.shape
        if thrusters.m != self.m:
            raise ValueError(f"B has {self.m} columns but the vessel has {thrusters.m} thrusters")
        self.scale = wrench_scale(self.B, thrusters.u_min, thrusters.u_max)
        self.allocator = Allocator(self.B, thrusters, dt_s, self.scale, self.config.allocator)
        u_range = np.maximum(np.abs(thrusters.u_min), np.abs(thrusters.u_max))
        self.excitation = Excitation(self.B, u_range, self.config.excitation)
        mode = self.config.mode
        self.estimator: WindowedEstimator | LiteralEstimator | None = None
        if mode is Mode.FTCAP:
            self.estimator = WindowedEstimator(self.B, self.scale, self.config.estimator)
        elif mode is Mode.FTCAP_LITERAL:
            self.estimator = LiteralEstimator(self.B, self.scale, self.config.estimator)
        self._pinv = np.linalg.pinv(self.B)
        self.u_prev = np.zeros(self.m)
        self._faulty = np.zeros(self.m, dtype=bool)
        self._estimate = Estimate(np.ones(self.m), np.zeros(self.k), np.zeros(self.m))

    def _estimate_for(
        self, w: FloatArray | None, applied: FloatArray, truth: Truth | None
    ) -> Estimate:
        """w: a finite sample, or None (no sample, or a non-finite one)."""
        mode = self.config.mode
        if mode is Mode.ORACLE:
            if truth is None:
                raise ValueError("oracle mode needs the true faults")
            bf = self.B @ truth.f
            return Estimate(truth.delta.copy(), bf, truth.f.copy())
        if self.estimator is None or w is None:
            return self._estimate  # CAP/NONE keep the identity; stale telemetry freezes
        return self.estimator.update(applied, w)

    def step(
        self,
        tau_d: FloatArray,
        w: FloatArray | None,
        truth: Truth | None = None,
        u_sample: FloatArray | None = None,
        dt_s: float | None = None,
        forced_dead: BoolArray | None = None,
    ) -> CycleResult:
        """One cycle; returns the command to send and what led to it.

        tau_d (k,): demanded wrench, body frame. w (k,): actuator wrench measured over the last
        estimation interval, or None when there is no new sample (estimates held; the
        excitation does not advance). u_sample (m,): the command that was acting over that
        interval (its time average); defaults to the last command. dt_s: time since the last
        cycle for the rate limits; defaults to the configured period. truth: the true faults,
        needed in ``ORACLE`` mode only (ValueError without). forced_dead (m,): thrusters known
        failed from outside (a silent ESC): allocated exactly 0, flagged faulty.
        """
        u_sample = self.u_prev if u_sample is None else u_sample
        if w is not None and not math.isfinite(w.sum()):
            w = None  # no sample: non-finite (or so large that its sum overflows)
        self._estimate = est = self._estimate_for(w, u_sample, truth)
        if forced_dead is not None and forced_dead.any():
            est = replace(est, delta_hat=np.where(forced_dead, 0.0, est.delta_hat))
        dead = est.delta_hat < self.config.allocator.dead_threshold
        if self.config.mode is Mode.FTCAP:
            exc = self.excitation(est.delta_hat, dead, advance=w is not None)
            u_pref, probe = exc.u_pref, exc.probe_limit
            if forced_dead is not None and forced_dead.any():
                # Known failed from outside (silent ESC): no probing, no dither, exactly 0.
                u_pref = np.where(forced_dead, 0.0, u_pref)
                probe = np.where(forced_dead, 0.0, probe)
        else:
            u_pref, probe = None, None
        alloc = self.allocator.allocate(
            tau_d, est.delta_hat, est.bf_hat, self.u_prev, u_pref, probe, dt_s
        )
        self.u_prev = alloc.u
        probing = np.zeros(self.m, dtype=bool) if probe is None else probe > 0
        return CycleResult(
            alloc.u,
            est,
            alloc,
            self._fault_flags(est, forced_dead),
            probing,
            estimation_frozen=self.config.mode.estimates and w is None,
        )

    def _fault_flags(self, est: Estimate, forced_dead: BoolArray | None) -> BoolArray:
        cfg = self.config
        determined = self.config.mode is Mode.ORACLE or est.window_len >= self.m + self.k
        if determined:
            d = est.delta_hat
            self._faulty = np.where(self._faulty, d < cfg.fault_clear, d < cfg.fault_threshold)
        flags = self._faulty.copy()
        if forced_dead is not None:
            flags |= forced_dead
        return flags

    def retune(
        self, allocator: AllocatorConfig | None = None, excitation: ExcitationConfig | None = None
    ) -> None:
        """Change allocation weights / excitation without touching the estimator's state."""
        if allocator is not None:
            self.allocator.retune(allocator)
            self.config = replace(self.config, allocator=allocator)
        if excitation is not None:
            self.excitation.config = excitation
            self.config = replace(self.config, excitation=excitation)

    def reset_command(self, u: FloatArray | None = None) -> None:
        """Tell the core what is on the actuators now (e.g. zero after a watchdog stop)."""
        self.u_prev = np.zeros(self.m) if u is None else np.array(u, dtype=np.float64)
