"""Measured odometry from the true state: noise, drifting bias, rate, delay and dropouts.

Per sample, measured at true time ``t`` from the state ``x = [north, east, psi, u, v, r]``::

    y   = x + b(t) + w,    w ~ N(0, diag(noise_std^2))       (6,) white noise per axis
    psi = wrap(psi) to (-pi, pi]
    b(t + h) = exp(-h/tau) b(t) + sqrt(1 - exp(-2h/tau)) bias_std v,   v ~ N(0, I)

``b`` is a first-order Gauss-Markov bias per axis (Brown & Hwang, *Introduction to Random
Signals and Applied Kalman Filtering*, 4th ed., sec. 2.9), exact for any gap ``h`` between
samples: it starts at 0 (a freshly calibrated sensor) and its variance grows as
``bias_std^2 (1 - exp(-2t/tau))`` towards ``bias_std^2``; ``bias_std = 0`` turns it off.

Samples are taken every ``1 / rate_hz`` of true time (``None``: at every truth step) on the
truth steps (:meth:`OdometrySensor.step` decimates: a sample is due at the first step at or
after its time, and the next one is due a period after that time, so the mean rate holds).
A sample is lost with probability ``dropout_p``, and every sample measured during an
outage is lost; outages start as a Poisson process of rate ``outage_rate_hz`` and last an
exponential time of mean ``outage_mean_s`` (the long-run fraction of time in outage is
``mean / (1 / rate + mean)``). A kept sample is delivered ``delay_s`` after it was measured:
the step that reaches its delivery time returns it, carrying both times.

Each random stream (noise, bias, dropouts, outages) has its own generator spawned from the
seed, so turning one effect on does not change another's draws. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import wrap_angle
from sim.sampling import RateSchedule


def _axes(name: str, value: object) -> FloatArray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (6,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ValueError(f"sensors.{name}: expected 6 finite values >= 0, got {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class SensorConfig:
    """Odometry sensor settings; per-axis arrays are (6,) in the order of x (SI, rad)."""

    noise_std: FloatArray = field(default_factory=lambda: np.zeros(6))
    bias_std: FloatArray = field(default_factory=lambda: np.zeros(6))
    bias_tau_s: FloatArray = field(default_factory=lambda: np.full(6, 100.0))
    rate_hz: float | None = None
    delay_s: float = 0.0
    dropout_p: float = 0.0
    outage_rate_hz: float = 0.0
    outage_mean_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("noise_std", "bias_std", "bias_tau_s"):
            object.__setattr__(self, name, _axes(name, getattr(self, name)))
        if np.any((self.bias_std > 0.0) & (self.bias_tau_s <= 0.0)):
            raise ValueError(
                f"sensors.bias_tau_s: must be > 0 on biased axes, got {self.bias_tau_s}"
            )
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"sensors.rate_hz: expected > 0 or None, got {self.rate_hz}")
        if not 0.0 <= self.dropout_p <= 1.0:
            raise ValueError(f"sensors.dropout_p: expected a probability, got {self.dropout_p}")
        for name in ("delay_s", "outage_rate_hz", "outage_mean_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"sensors.{name}: expected a finite number >= 0, got {value!r}")
        if self.outage_rate_hz > 0.0 and self.outage_mean_s <= 0.0:
            raise ValueError("sensors.outage_mean_s: must be > 0 when outages are on")


@dataclass(frozen=True)
class Measurement:
    """One odometry sample: measured at true time ``t_measured_s``, delivered at
    ``t_delivered_s`` (s); ``eta`` = [north, east, psi] (m, m, rad), ``nu`` = [u, v, r]."""

    t_measured_s: float
    t_delivered_s: float
    eta: FloatArray
    nu: FloatArray


def gauss_markov_step(
    b: FloatArray, h_s: float, tau_s: FloatArray, std: FloatArray, v: FloatArray
) -> FloatArray:
    """First-order Gauss-Markov bias ``b`` advanced by ``h_s`` (s), exact; ``v`` ~ N(0, I)
    of ``b``'s shape; axes with ``std = 0`` stay at 0."""
    phi = np.exp(-h_s / np.where(tau_s > 0.0, tau_s, 1.0))
    return np.asarray(np.where(std > 0.0, phi * b + std * np.sqrt(1.0 - phi**2) * v, 0.0))


class OdometrySensor:
    """The sensor of the module docstring; :meth:`step` once per truth step."""

    def __init__(self, config: SensorConfig) -> None:
        self.config = config
        noise, bias, drop, outage = np.random.SeedSequence(config.seed).spawn(4)
        self._rng_noise = np.random.default_rng(noise)
        self._rng_bias = np.random.default_rng(bias)
        self._rng_drop = np.random.default_rng(drop)
        self._rng_outage = np.random.default_rng(outage)
        self._bias = np.zeros(6)
        self._bias_t_s = 0.0
        self._schedule = RateSchedule(config.rate_hz)
        self._outage = (math.inf, math.inf)  # [start, end) of the next or current outage
        self._pending: deque[Measurement] = deque()
        self.sent = 0  # samples measured
        self.lost = 0  # of which lost to dropouts and outages
        if config.outage_rate_hz > 0.0:
            self._outage = self._draw_outage(0.0)

    @property
    def bias(self) -> FloatArray:
        """(6,) the bias at the last sample."""
        return self._bias.copy()

    def _draw_outage(self, after_s: float) -> tuple[float, float]:
        cfg, rng = self.config, self._rng_outage
        start = after_s + rng.exponential(1.0 / cfg.outage_rate_hz)
        return start, start + rng.exponential(cfg.outage_mean_s)

    def _in_outage(self, t_s: float) -> bool:
        while t_s >= self._outage[1]:
            self._outage = self._draw_outage(self._outage[1])
        return self._outage[0] <= t_s

    def _measure(self, t_s: float, x: FloatArray) -> Measurement:
        cfg = self.config
        v = self._rng_bias.standard_normal(6)
        self._bias = gauss_markov_step(
            self._bias, t_s - self._bias_t_s, cfg.bias_tau_s, cfg.bias_std, v
        )
        self._bias_t_s = t_s
        y = x + self._bias + cfg.noise_std * self._rng_noise.standard_normal(6)
        if not -math.pi < y[2] <= math.pi:  # wrap only when needed: a perfect sensor is exact
            y[2] = float(wrap_angle(y[2]))
        return Measurement(t_s, t_s + cfg.delay_s, y[:3].copy(), y[3:].copy())

    def step(self, t_s: float, x: FloatArray) -> list[Measurement]:
        """The true state ``x`` (6,) at true time ``t_s`` (s, non-decreasing); returns the
        samples delivered by ``t_s``, oldest first (possibly none)."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (6,) or not np.all(np.isfinite(x)):
            raise ValueError(f"sensor: expected a finite state of 6, got {x.tolist()}")
        if self._schedule.due(t_s):
            sample = self._measure(t_s, x)
            self.sent += 1
            dropped = self._rng_drop.random() < self.config.dropout_p
            if dropped or self._in_outage(t_s):
                self.lost += 1
            else:
                self._pending.append(sample)
        out: list[Measurement] = []
        while self._pending and self._pending[0].t_delivered_s <= t_s + 1e-12:
            out.append(self._pending.popleft())
        return out
