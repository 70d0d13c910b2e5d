"""What the drives report: shaft speed (or a servo's deflection) and current, as a real
ESC or frequency converter measures them, from the thruster bank's state.

Per actuator ``i`` and sample, at true time ``t`` from the bank's output::

    speed_m   = (1 + e_n,i) speed + N(0, (speed_noise_rel |speed| + speed_noise_abs)^2)
    current_m = (1 + e_I,i) current + o_i(t) + N(0, current_noise_a^2)
    o_i(t + h) = o_i(t) + current_drift_a sqrt(h) N(0, 1)       offset random walk
    then speed_m rounded to speed_resolution, current_m to current_resolution_a

``e_n,i`` and ``e_I,i`` are per-seed calibration errors, drawn once from N(0, *_scale_std^2)
and unknown to the allocator (a current sense resistor's tolerance, a pole count). A
sample is taken every ``1 / rate_hz`` (the first at the first step; ``None``: every step)
and delivered ``latency_s`` later; an actuator whose drive does not report (``reports``
False: power or telemetry lost) sends nothing. Defaults: a model-scale ESC on DroneCAN
(ASSUMED: 10 Hz esc.Status, 20 ms on the bus, 1 rpm, current to 10 mA with 1 %
noise-level of 20 mA and a 5 % calibration error). Each random stream has its own
generator spawned from the seed. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FloatArray
from sim.sampling import RateSchedule
from sim.thrusters import BankOutput


@dataclass(frozen=True)
class FeedbackConfig:
    """The drives' telemetry settings (module docstring), the same for every actuator."""

    rate_hz: float | None = 10.0
    latency_s: float = 0.02
    speed_resolution: float = 1.0 / 60.0  # rev/s (1 rpm); a servo: its fraction
    current_resolution_a: float = 0.01
    speed_noise_rel: float = 0.005
    speed_noise_abs: float = 0.0
    current_noise_a: float = 0.02
    current_drift_a: float = 0.002  # A per sqrt(s)
    speed_scale_std: float = 0.0
    current_scale_std: float = 0.05
    seed: int = 0

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if name in ("rate_hz", "seed") or value is None:
                continue
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"feedback.{name}: expected a finite number >= 0, got {value!r}")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"feedback.rate_hz: expected > 0 or None, got {self.rate_hz}")


@dataclass(frozen=True)
class FeedbackSample:
    """One drive's report: measured at ``t_measured_s``, delivered at ``t_delivered_s``;
    ``speed`` rev/s for a shaft (a servo: its deflection), ``current_a`` A, ``voltage_v``."""

    t_measured_s: float
    t_delivered_s: float
    index: int
    speed: float
    current_a: float
    voltage_v: float
    is_shaft: bool = True

    @property
    def rpm(self) -> float:
        return 60.0 * self.speed


def _rounded(x: FloatArray, step: float) -> FloatArray:
    return x if step <= 0.0 else np.asarray(np.rint(x / step) * step)


class FeedbackSensor:
    """The telemetry of ``m`` drives; :meth:`step` once per truth step."""

    def __init__(self, config: FeedbackConfig, m: int) -> None:
        self.config = config
        self.m = m
        cal, noise, drift = np.random.SeedSequence(config.seed).spawn(3)
        rng_cal = np.random.default_rng(cal)
        self.speed_scale = 1.0 + config.speed_scale_std * rng_cal.standard_normal(m)
        self.current_scale = 1.0 + config.current_scale_std * rng_cal.standard_normal(m)
        self._rng_noise = np.random.default_rng(noise)
        self._rng_drift = np.random.default_rng(drift)
        self._offset = np.zeros(m)
        self._offset_t_s: float | None = None
        self._schedule = RateSchedule(config.rate_hz)
        self._pending: deque[FeedbackSample] = deque()

    def _measure(self, t_s: float, out: BankOutput) -> list[FeedbackSample]:
        cfg = self.config
        h = 0.0 if self._offset_t_s is None else t_s - self._offset_t_s
        self._offset = self._offset + cfg.current_drift_a * math.sqrt(h) * (
            self._rng_drift.standard_normal(self.m)
        )
        self._offset_t_s = t_s
        z = self._rng_noise.standard_normal((2, self.m))
        sd = cfg.speed_noise_rel * np.abs(out.speed) + cfg.speed_noise_abs
        speed = _rounded(self.speed_scale * out.speed + sd * z[0], cfg.speed_resolution)
        amps = self.current_scale * out.current_a + self._offset + cfg.current_noise_a * z[1]
        amps = _rounded(np.maximum(amps, 0.0), cfg.current_resolution_a)
        t_out = t_s + cfg.latency_s
        return [
            FeedbackSample(
                t_s,
                t_out,
                int(i),
                float(speed[i]),
                float(amps[i]),
                float(out.voltage_v[i]),
                bool(out.is_shaft[i]),
            )  # fmt: skip
            for i in np.flatnonzero(out.reports)
        ]

    def step(self, t_s: float, out: BankOutput) -> list[FeedbackSample]:
        """The bank's output ``out`` at true time ``t_s`` (s, non-decreasing); returns the
        samples delivered by ``t_s``, oldest first."""
        if self._schedule.due(t_s):
            self._pending.extend(self._measure(t_s, out))
        ready: list[FeedbackSample] = []
        while self._pending and self._pending[0].t_delivered_s <= t_s + 1e-12:
            ready.append(self._pending.popleft())
        return ready
