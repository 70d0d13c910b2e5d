"""Step 1-2 of a cycle, one strategy per mode: what the allocator is told about the faults.

Every stage turns an estimation sample into a :class:`StageOutput`: the estimate that is
reported (delta_hat, bias, their uncertainty), the effectiveness and bias the allocator uses
(``delta_alloc``, ``bf_alloc``), and the fault flags. A sample is an :class:`Observation`
(the measured plant state at both ends of an estimation interval) or, for the estimators
that work on it, the wrench ``w`` (k,) already inverted from it. ``None``: no new sample;
every stage then holds its last output (stale telemetry freezes estimation).

=================  ===================================================================
stage              used by
=================  ===================================================================
IdentityStage      ``none``, ``cap``: delta = 1, b = 0, never a flag
OracleStage        ``oracle``: the true faults
WindowedStage      ``ftcap`` with ``estimator.kind = "windowed"``; ``ftcap-literal``
KalmanStage        ``ftcap`` (default): core/estimation/kalman.py + core/estimation/decisions.py
=================  ===================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ftcap_hil.core.estimation.config import Estimate, EstimatorConfig
from ftcap_hil.core.estimation.decisions import Decision, FaultDecider
from ftcap_hil.core.estimation.kalman import KalmanEstimator
from ftcap_hil.core.estimation.windowed import LiteralEstimator, WindowedEstimator
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.models.vessel3dof import PlantModel


@fast_init  # built every estimation sample (core/frozen.py)
@dataclass(frozen=True)
class Observation:
    """The measured plant state at the start and the end of one estimation interval.

    x_prev, x_now: the plant's full state ([north, east, psi, u, v, r] for a vessel, NED /
    body frame, SI); dt_s: the interval (s) on the vessel's clock.
    """

    x_prev: FloatArray
    x_now: FloatArray
    dt_s: float

    def finite(self) -> bool:
        """Both states finite and dt a positive finite number."""
        total = _total(self.x_prev) + _total(self.x_now)
        return math.isfinite(total) and math.isfinite(self.dt_s) and self.dt_s > 0.0


def _total(x: FloatArray) -> float:
    """sum(x) (the method where it is an array: a third of np.sum's cost on a 6-vector)."""
    return float(x.sum() if isinstance(x, np.ndarray) else np.sum(x))


Sample = Observation | FloatArray


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class StageOutput:
    """One stage update: reported estimate, what the allocator uses, fault flags."""

    estimate: Estimate
    delta_alloc: FloatArray  # (m,)
    bf_alloc: FloatArray  # (k,)
    faulty: BoolArray  # (m,)
    decision: Decision | None = None  # the Kalman stage's full decision


class EstimationStage(Protocol):
    """A mode's estimation strategy (module docstring)."""

    def update(
        self, sample: Sample | None, u_sample: FloatArray, truth: Truth | None
    ) -> StageOutput:
        """One estimation sample (None: none new) with the command ``u_sample`` (m,) N that
        acted over it; ``truth``: the true faults (the oracle only)."""
        ...


def _identity(m: int, k: int) -> StageOutput:
    est = Estimate(np.ones(m), np.zeros(k), np.zeros(m), delta_std=np.zeros(m))
    return StageOutput(est, est.delta_hat, est.bf_hat, np.zeros(m, dtype=bool))


class IdentityStage:
    """CAP and the fault-free reference: the allocator assumes healthy thrusters."""

    def __init__(self, m: int, k: int) -> None:
        self._out = _identity(m, k)

    def update(
        self, sample: Sample | None, u_sample: FloatArray, truth: Truth | None
    ) -> StageOutput:
        """Always the identity (delta = 1, b = 0, no flag)."""
        return self._out


class OracleStage:
    """The true (delta, f) handed over (offline only); flags with the core's hysteresis."""

    def __init__(self, B: FloatArray, fault_threshold: float, fault_clear: float) -> None:
        self._B = B
        self._flags = _Hysteresis(B.shape[1], fault_threshold, fault_clear)

    def update(
        self, sample: Sample | None, u_sample: FloatArray, truth: Truth | None
    ) -> StageOutput:
        """The true faults as the estimate; ValueError without ``truth``."""
        if truth is None:
            raise ValueError("oracle mode needs the true faults")
        bf = self._B @ truth.f
        est = Estimate(truth.delta.copy(), bf, truth.f.copy(), delta_std=np.zeros(truth.f.size))
        return StageOutput(est, est.delta_hat, bf, self._flags.update(est.delta_hat))


class _Hysteresis:
    """Flag below ``on``, clear above ``off`` (> on): no flapping around one level."""

    def __init__(self, m: int, on: float, off: float) -> None:
        self._flags = np.zeros(m, dtype=bool)
        self._on, self._off = on, off

    def update(self, d: FloatArray) -> BoolArray:
        """New flags (m,) for the effectiveness ``d`` (m,)."""
        self._flags = np.where(self._flags, d < self._off, d < self._on)
        return self._flags.copy()

    @property
    def flags(self) -> BoolArray:
        """The current flags (a copy)."""
        return self._flags.copy()


class WindowedStage:
    """The windowed least-squares estimator (or the literal scheme) on the inverted wrench.

    Flags use the core's hysteresis and only change on estimates the window determines
    (window_len >= m + k): right after a restart the estimate explains one or two samples by
    a minimum change and may dip transiently on healthy thrusters.
    """

    def __init__(
        self,
        estimator: WindowedEstimator | LiteralEstimator,
        plant: PlantModel | None,
        fault_threshold: float,
        fault_clear: float,
    ) -> None:
        self._estimator = estimator
        self._plant = plant
        m, k = estimator.estimate().delta_hat.size, estimator.estimate().bf_hat.size
        self._flags = _Hysteresis(m, fault_threshold, fault_clear)
        self._determined = m + k
        self._out = _identity(m, k)

    def _wrench(self, sample: Sample) -> FloatArray | None:
        if isinstance(sample, Observation):
            if self._plant is None:
                raise ValueError("an Observation needs the plant model (FtcapCore(plant=...))")
            if not sample.finite():
                return None
            sample = self._plant.measured_wrench(sample.x_prev, sample.x_now, sample.dt_s)
        # non-finite, or so large that its sum overflows: no sample
        return sample if math.isfinite(float(np.sum(sample))) else None

    def update(
        self, sample: Sample | None, u_sample: FloatArray, truth: Truth | None
    ) -> StageOutput:
        """Fit one sample (an Observation is inverted to a wrench first); a missing or
        non-finite sample holds the last output."""
        w = None if sample is None else self._wrench(sample)
        if w is None:
            return self._out
        est = self._estimator.update(u_sample, w)
        flags = (
            self._flags.update(est.delta_hat)
            if est.window_len >= self._determined
            else self._flags.flags
        )
        self._out = StageOutput(est, est.delta_hat, est.bf_hat, flags)
        return self._out


class KalmanStage:
    """Kalman filter on the measured motion plus statistical decisions (core/estimation/kalman.py,
    core/estimation/decisions.py). Needs finite :class:`Observation` samples (FtcapCore.step drops
    the others)."""

    def __init__(
        self,
        B: FloatArray,
        scale: FloatArray,
        u_range: FloatArray,
        plant: PlantModel,
        config: EstimatorConfig,
        fault_threshold: float,
        fault_clear: float,
    ) -> None:
        self.filter = KalmanEstimator(B, scale, plant, config)
        self._decider = FaultDecider(B, u_range, config, fault_threshold, fault_clear)
        self._out = _identity(B.shape[1], B.shape[0])

    def forget(self, which: BoolArray) -> None:
        """What the motion learnt of the thrusters ``which`` (m,) dropped: their prior again,
        unflagged, in the allocation from the next sample on."""
        self.filter.forget(which)
        self._decider.forget(which)

    def update(
        self, sample: Sample | None, u_sample: FloatArray, truth: Truth | None
    ) -> StageOutput:
        """Filter one Observation and decide; ValueError for a bare wrench."""
        if sample is None:
            return self._out
        if not isinstance(sample, Observation):
            raise ValueError("the Kalman estimator needs an Observation, not a wrench")
        out = self.filter.update(u_sample, sample.x_now, sample.dt_s, sample.x_prev)
        dec = self._decider.update(out, sample.dt_s)
        self._out = StageOutput(out.estimate, dec.delta_alloc, dec.bf_alloc, dec.faulty, dec)
        return self._out
