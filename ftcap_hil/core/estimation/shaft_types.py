"""The drives' diagnosis, its types: what a drive is on its data sheet (:class:`DriveModel`),
what it reports (:class:`DriveReport`), the diagnosis settings (:class:`DiagnosisConfig`),
its hypotheses and its verdict per thruster (:class:`ShaftVerdict`). The diagnosis itself:
:mod:`ftcap_hil.core.estimation.shaft`."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray


class Hypothesis(enum.Enum):
    """What a thruster's drive says about it (module docstring)."""

    HEALTHY = "healthy"
    TELEMETRY_LOST = "telemetry-lost"
    DRIVE_DEAD = "drive-dead"
    JAMMED = "jammed"
    STUCK = "stuck"
    WEAK = "weak"
    LOAD_LOSS = "load-loss"
    LOAD_GAIN = "load-gain"
    VENTILATION = "ventilation"


# What the allocator may act on: a removal or a partial loss needs one of these.
# Wire codes (MAVLink, CSV): 0 means no drive diagnosis, then the hypotheses in order.
HYPOTHESIS_CODES = {h: i + 1 for i, h in enumerate(Hypothesis)}
HYPOTHESES_BY_CODE = {i: h for h, i in HYPOTHESIS_CODES.items()}

ACTIONABLE = frozenset(
    {Hypothesis.DRIVE_DEAD, Hypothesis.JAMMED, Hypothesis.STUCK, Hypothesis.WEAK,
     Hypothesis.LOAD_LOSS, Hypothesis.LOAD_GAIN}
)  # fmt: skip


LOAD = frozenset({Hypothesis.LOAD_LOSS, Hypothesis.LOAD_GAIN})


@dataclass(frozen=True)
class DriveModel:
    """One actuator as its data sheets give it. A shaft: ``k_thrust`` N/(rev/s)^2,
    ``k_torque`` N m/(rev/s)^2, ``watts_per_amp`` = efficiency x voltage, ``inflow_*`` =
    (1 - w) / (J_0 D) (0: in-flow not modelled), ``speed_loop`` the drive's kind; a servo
    (``is_shaft`` False): only ``full_force_n`` and ``time_constant_s`` matter."""

    full_force_n: float
    time_constant_s: float
    is_shaft: bool = True
    k_thrust: float = 1.0
    k_torque: float = 0.0
    watts_per_amp: float = 1.0
    idle_a: float = 0.0
    inflow_thrust: float = 0.0
    inflow_torque: float = 0.0
    # the drive closes a speed loop (a frequency converter, an ESC in rpm mode): its speed
    # follows the reference whatever the in-flow; False: a torque (duty-cycle) drive, whose
    # speed the in-flow shifts
    speed_loop: bool = False

    def __post_init__(self) -> None:
        for name in ("full_force_n", "k_thrust", "watts_per_amp"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"drive model: {name} must be > 0, got {getattr(self, name)}")
        if not self.time_constant_s >= 0.0:
            raise ValueError(
                f"drive model: time_constant_s must be >= 0, got {self.time_constant_s}"
            )


@fast_init  # one per drive report (core/frozen.py)
@dataclass(frozen=True)
class DriveReport:
    """One drive's telemetry as the allocator received it: at ``t_s`` (its clock, s),
    thruster ``index`` (0-based), ``speed`` rev/s (a servo: its deflection, fraction of
    full), ``current_a`` A (NaN: not reported)."""

    t_s: float
    index: int
    speed: float
    current_a: float = math.nan


@dataclass(frozen=True)
class DiagnosisConfig:
    """Bands, tests and decisions of the module docstring. The bands are residual
    standard deviations fitted on healthy data; ``cusum_*`` in band units."""

    enabled: bool = True  # judge the thrusters by their drives when the drives are known
    motion: bool = True  # False: the drives alone decide (the motion filter runs, unheard)
    # Dither a thruster whose drive reports fresh telemetry. Off: its drive judges it, and the
    # dither's only gain, shaft-invisible losses (hull, interaction), costs the boat its
    # motion on every healthy hour (CyberShip II: 3-5 mm in 120 s where CAP moves 0).
    dither: bool = False
    # The telemetry's speed resolution (rev/s; a servo: its fraction of full deflection), from
    # the drive's data sheet: DroneCAN esc.Status reports whole rpm (1/60 rev/s)
    speed_resolution: float = 1.0 / 60.0
    # A sample is judged when the whole predicted range turns one way by at least this many
    # bands (at the speed it runs: a DP thruster at 1 % of its rating is judged)
    floor_z: float = 4.0
    band_rel: float = 0.03  # the speed band: band_rel |n_p| + band_res speed_resolution
    band_res: float = 1.0
    servo_band_rel: float = 0.03  # a servo's deflection band, the same way
    servo_band_res: float = 1.0
    timing_s: float = 0.02  # the prediction's time is known to this (sampling)
    lag_uncertainty: float = 0.5  # the drive's time constant is known within x / (1 + this)
    current_rel: float = 0.03
    current_abs: float = 0.02
    load_snr: float = 5.0  # the load is judged only where full speed draws this many bands
    cusum_k: float = 1.0
    cusum_h: float = 12.0  # the speed test's threshold
    # the load test's: the load current drifts with the sea (inflow, ventilation) where the
    # speed does not, so it is calibrated on its own healthy peaks
    load_h: float = 12.0
    stall_rel: float = 0.1  # |n_m| below this share of the predicted speed: not turning
    jam_current_rel: float = 0.5  # drawn current (above idle) of the predicted: jammed
    stuck_window_s: float = 2.0
    stuck_hold_s: float = 0.5  # frozen (held while the command moved measurably) this long
    hold_s: float = 3.0
    clear_z: float = 2.5
    clear_s: float = 1.0
    telemetry_timeout_s: float = 0.5
    latency_s: float = 0.0  # the telemetry's known latency: samples are judged at t - latency
    cal_tau_s: float = 60.0  # online calibration of speed and current scales (0: off)
    # ... within this share of the data sheet: its tolerance. A deficit is named weak only
    # where the force the speed shows is down by more than this (within it, the sheet's error
    # and the loss cannot be told apart); the product's target is a loss of 30 %
    cal_limit: float = 0.15
    cal_samples: int = 20  # commanded samples that commission the model, before any test
    # The largest loss a healthy drive's amplitude (ratio_t) showed on the calibration runs
    # (bench/calibrate_shaft.py). A speed whose amplitude stays down by more than twice that
    # (and by more than cal_limit) for amplitude_hold_s of commanded time is named weak
    # without waiting for the speed test, whose residuals hide inside the lag's range while
    # the command swings (CyberShip II's propellers reversing twice a second: 5.5 s). The
    # default, uncalibrated, never trips (twice 0.5: no amplitude is down by all of it).
    amplitude_loss: float = 0.5
    amplitude_hold_s: float = 0.5
    motion_removal_s: float = 30.0  # a motion-only removal of a thruster whose drive shows
    # nothing wrong is acted upon only after it has held this long (hull or interaction loss)

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if isinstance(value, bool):
                continue
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"diagnosis.{name}: expected a finite number >= 0, got {value!r}")


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class ShaftVerdict:
    """Per thruster (m,): the hypothesis, the effectiveness its drive shows (1 where it
    shows nothing wrong), a stuck thruster's held force (N, NaN otherwise), the thrust the
    latest speed implies (N, NaN without telemetry), whether telemetry is fresh, whether a
    shaft alarm is up (no dither on it), and the latest normalised residuals."""

    hypothesis: tuple[Hypothesis, ...]
    delta: FloatArray
    held_n: FloatArray
    thrust_n: FloatArray
    fresh: BoolArray
    alarm: BoolArray
    r_thrust: FloatArray
    r_load: FloatArray

    @property
    def stuck(self) -> BoolArray:
        """(m,) a shaft or servo frozen where it was (its held force: ``held_n``)."""
        return np.array([h is Hypothesis.STUCK for h in self.hypothesis], dtype=bool)

    @property
    def actionable(self) -> BoolArray:
        """(m,) the drive itself shows a loss the allocator may act on."""
        return np.array([h in ACTIONABLE for h in self.hypothesis], dtype=bool)


def verdict_without_telemetry(m: int) -> ShaftVerdict:
    """The verdict when no drive reports at all (motion-only)."""
    nan = np.full(m, math.nan)
    return ShaftVerdict(
        (Hypothesis.TELEMETRY_LOST,) * m, np.ones(m), nan, nan.copy(), np.zeros(m, bool),
        np.zeros(m, bool), nan.copy(), nan.copy(),
    )  # fmt: skip
