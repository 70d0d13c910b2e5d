"""The estimators' settings and their common output: which estimator runs
(``EstimatorKind``), which bias the allocator compensates (``BiasCompensation``), the
tunables (``EstimatorConfig``), one estimate (``Estimate``) and the wrench scale S that makes
the axes commensurate."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.errors import require_member
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import FloatArray


class EstimatorKind(enum.Enum):
    """Which estimator mode ``ftcap`` runs (``ftcap-literal`` always runs the literal one)."""

    KALMAN = "kalman"  # core/estimation/kalman.py, core/estimation/decisions.py
    WINDOWED = "windowed"  # windowed least squares, core/estimation/windowed.py


class BiasCompensation(enum.Enum):
    """Which part of the estimated bias b the allocator compensates."""

    # only what core/estimation/decisions.py attributes to a thruster; the environment's
    # share is the controller's
    ATTRIBUTED = "attributed"
    ALL = "all"  # the paper's model: every bias is a thruster's


@dataclass(frozen=True)
class EstimatorConfig:
    """Tunables. Innovation and thresholds are normalized by S (fractions of max wrench)."""

    window: int = 20  # N of eq. (10), samples
    prior_weight_delta: float = 1e-5  # Lambda for delta (R of eq. 10); Q = 1 per sample
    prior_weight_bias: float = 1e-5  # Lambda for S^-1 b
    change_floor: float = 1e-3  # innovation above this (and above change_factor*RMS) restarts
    change_factor: float = 6.0
    holdoff: int = 0  # samples after a restart before another may happen (0: m + k)
    # Evict the sample that triggered a restart once a clean one arrives (it straddles the
    # onset on a continuous-time plant; a discrete-time plant has no such sample).
    evict_straddling: bool = True
    # Pole a of the first-order low-pass (1 - a) / (1 - a q^-1) applied alike to the command
    # and the measured wrench before the fit (0: off). Off by default: it also attenuates the
    # dither and probes against model error (docs/algorithm.md, the prefilter).
    prefilter: float = 0.0
    kind: EstimatorKind = EstimatorKind.KALMAN
    # --- kind = KALMAN (core/estimation/kalman.py, core/estimation/decisions.py) ---
    # Sensor noise std of the plant's dynamic state (u, v, r in m/s, m/s, rad/s for a
    # vessel), as the data sheet gives it; None: a noise-free world (1e-6).
    measurement_std: tuple[float, ...] | None = None
    model_error: float = 0.002  # process noise on s: this fraction of S, through G
    adapt_s: float = 10.0  # time constant of the process-noise scale learnt online (0: off)
    # The sea's first-order wave load as oscillator states (core/estimation/wave_model.py): its peak
    # period (s; 0: no wave states), damping, and standard deviation per axis (N, N, N m;
    # None: wave_force_rel of the largest achievable wrench S).
    wave_period_s: float = 0.0
    wave_damping: float = 0.1
    wave_force_std: tuple[float, ...] | None = None
    wave_force_rel: float = 0.3
    # The damping model's relative error per axis as states (truth = (1 + theta) x the
    # model's D(nu) nu): its prior standard deviation (0: no such states) and random walk
    # (per sqrt(s)). Only for a vessel whose model gives D(nu) nu (Vessel3DOF).
    damping_error_std: float = 0.0
    q_damping: float = 0.001
    bias_compensation: BiasCompensation = BiasCompensation.ATTRIBUTED
    q_delta: float = 0.002  # random walk of delta, per sqrt(s)
    q_bias_rel: float = 0.002  # random walk of b, fraction of S per sqrt(s)
    initial_delta_std: float = 0.05
    initial_bias_rel: float = 0.3
    reset_std: float = 0.3  # delta std after a change alarm
    reset_bias_rel: float = 0.3  # b std after a change alarm, fraction of S
    cusum_drift: float = 3.0  # CUSUM on nis - k: allowance per sample
    cusum_threshold: float = 25.0
    isolation_margin: float = 2.71  # suspects: within this log-likelihood of the best
    z_flag: float = 4.0  # one-sided confidence (in std) for a reported fault
    z_use: float = 2.0  # the allocator uses delta_hat + z_use std (capped at 1)
    practical_loss: float = 0.05  # 1 - delta_hat below this is never acted upon
    removal_threshold: float = 0.3  # a fault confidently below this is taken out
    observable_std: float = 0.1  # delta std the recent window alone must reach
    bias_min_rel: float = 0.03  # smallest thruster bias acted upon, fraction of its range
    bias_base_s: float = 60.0  # time constant of the healthy bias baseline (environment)

    def __post_init__(self) -> None:
        require_member("estimator.kind", self.kind, EstimatorKind)
        require_member("estimator.bias_compensation", self.bias_compensation, BiasCompensation)
        if self.window < 2:
            raise ValueError(f"estimator.window: need >= 2, got {self.window}")
        if not 0.0 <= self.prefilter < 1.0:
            raise ValueError(f"estimator.prefilter: need [0, 1), got {self.prefilter}")
        for key in ("prior_weight_delta", "prior_weight_bias", "change_floor", "change_factor"):
            if not getattr(self, key) > 0:
                raise ValueError(f"estimator.{key}: must be > 0, got {getattr(self, key)}")


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class Estimate:
    """One fault estimate: effectiveness, bias (as a wrench and per thruster) and window
    diagnostics (``innovation`` normalized by S; ``window_len`` samples in the window;
    ``restarted`` whether this sample restarted it)."""

    delta_hat: FloatArray  # (m,) effectiveness in [0, 1]
    bf_hat: FloatArray  # (k,) B f, generalized force (N, N, N*m)
    f_hat: FloatArray  # (m,) minimum-norm per-thruster bias (N)
    innovation: float = 0.0  # normalized one-step prediction error before the update
    window_len: int = 0
    restarted: bool = False
    delta_std: FloatArray | None = None  # (m,) standard deviation of delta_hat (None: unknown)


def wrench_scale(B: FloatArray, u_min: FloatArray, u_max: FloatArray) -> FloatArray:
    """S (k,): largest achievable |tau_j| per axis, sum_i |B_ji| max(|u_min_i|, |u_max_i|)."""
    return np.abs(B) @ np.maximum(np.abs(u_min), np.abs(u_max))
