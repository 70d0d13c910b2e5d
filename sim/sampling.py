"""When a sensor of the truth model takes a sample: :class:`RateSchedule`.

A sensor sampling at ``rate_hz`` is stepped by the simulator at its own period, which need
not divide the sensor's. Sample k is due at ``t0 + k / rate_hz`` (t0: the first step asked);
a step that comes late takes one sample and skips the ones it missed, so samples never
bunch up. Written from the index k, not by adding periods, so no rounding accumulates over a
long run.
"""

from __future__ import annotations

import math


class RateSchedule:
    """Sample times at ``rate_hz`` (None: every step is a sample); :meth:`due` per step."""

    def __init__(self, rate_hz: float | None) -> None:
        if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz: expected a finite rate > 0 or None, got {rate_hz!r}")
        self.rate_hz = rate_hz
        self._t0_s: float | None = None  # time of the first sample
        self._k = 0  # index of the next sample due

    def due(self, t_s: float) -> bool:
        """Whether a sample is due at ``t_s`` (steps asked in increasing time)."""
        if self.rate_hz is None:
            return True
        if self._t0_s is None:
            self._t0_s = t_s
        period = 1.0 / self.rate_hz
        if t_s < self._t0_s + self._k * period - 1e-9 * period:
            return False
        # the next sample is the first one due after t_s (late steps skip samples)
        self._k = math.floor((t_s - self._t0_s) / period + 1e-9) + 1
        return True
