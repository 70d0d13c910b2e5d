"""Confidence intervals for the campaign's rates and shares, with the sample size beside them.

* A **rate** (events per hour over ``hours`` of exposure, e.g. false alarms per healthy
  hour): the exact Poisson interval (Garwood 1936) from chi-square quantiles,
  ``[chi2(a/2; 2n) / 2, chi2(1 - a/2; 2n + 2) / 2] / hours``; 0 events give an upper
  bound of 3.69 / hours at 95 % (one-sided 3.0 is the "rule of three").
* A **share** (k successes of n, e.g. faults isolated within 5 s): the Wilson score
  interval, which stays inside [0, 1] and is sane at k = 0 or k = n.

Both return NaN bounds for an empty sample (n = 0 or hours = 0): nothing measured, nothing
claimed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from scipy.stats import chi2, norm


@dataclass(frozen=True)
class Interval:
    """A point estimate with its two-sided interval at ``level`` and its sample size
    (``n``: events for a rate, trials for a share; ``exposure``: hours for a rate)."""

    value: float
    low: float
    high: float
    n: int
    exposure: float = math.nan
    level: float = 0.95

    def text(self, digits: int = 2) -> str:
        """``value [low, high]`` (``-`` when nothing was measured)."""
        if not math.isfinite(self.value):
            return "-"
        f = f"{{:.{digits}f}}"
        return f"{f.format(self.value)} [{f.format(self.low)}, {f.format(self.high)}]"


def poisson_rate(events: int, hours: float, level: float = 0.95) -> Interval:
    """Events per hour with the exact (Garwood) interval; module docstring."""
    if events < 0:
        raise ValueError(f"events: expected >= 0, got {events}")
    if not hours > 0.0:
        return Interval(math.nan, math.nan, math.nan, events, hours, level)
    a = 1.0 - level
    low = 0.0 if events == 0 else float(chi2.ppf(a / 2.0, 2 * events)) / 2.0
    high = float(chi2.ppf(1.0 - a / 2.0, 2 * events + 2)) / 2.0
    return Interval(events / hours, low / hours, high / hours, events, hours, level)


def wilson_share(successes: int, trials: int, level: float = 0.95) -> Interval:
    """successes / trials with the Wilson score interval; module docstring."""
    if not 0 <= successes <= max(trials, 0):
        raise ValueError(f"share: need 0 <= successes <= trials, got {successes}/{trials}")
    if trials == 0:
        return Interval(math.nan, math.nan, math.nan, 0, math.nan, level)
    z = float(norm.ppf(1.0 - (1.0 - level) / 2.0))
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = (
        z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    )
    return Interval(p, max(0.0, centre - half), min(1.0, centre + half), trials, math.nan, level)


def put_interval(row: dict[str, Any], name: str, iv: Interval) -> None:
    """``row[name]`` = the value, ``row[name_lo]`` / ``row[name_hi]`` its 95 % interval and
    ``row[name_n]`` its sample size (events or trials); None where nothing was measured."""

    def num(x: float) -> float | None:
        return x if math.isfinite(x) else None

    row[name], row[f"{name}_lo"], row[f"{name}_hi"] = num(iv.value), num(iv.low), num(iv.high)
    row[f"{name}_n"] = iv.n


def hours_for_rate(rate_per_h: float, level: float = 0.95) -> float:
    """Clean hours (0 events) needed for the interval's upper bound to reach ``rate_per_h``."""
    return float(chi2.ppf(level + (1.0 - level) / 2.0, 2)) / 2.0 / rate_per_h
