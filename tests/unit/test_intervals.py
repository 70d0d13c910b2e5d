"""Rates and shares with their 95 % intervals (report/intervals.py), against tabulated values."""

from __future__ import annotations

import math

import pytest

from ftcap_hil.report.intervals import hours_for_rate, poisson_rate, wilson_share


def test_poisson_interval_matches_the_tables() -> None:
    # Garwood 95 % limits for n events (e.g. Ulm 1990, Table 1): 0 -> [0, 3.689],
    # 3 -> [0.619, 8.767], 10 -> [4.795, 18.39]
    for n, low, high in ((0, 0.0, 3.689), (3, 0.619, 8.767), (10, 4.795, 18.39)):
        r = poisson_rate(n, 1.0)
        assert (r.low, r.high) == (pytest.approx(low, abs=1e-3), pytest.approx(high, abs=1e-2))
    # the figure: 0.86 /h over 3.5 h is 3 alarms: [0.18, 2.5] /h
    r = poisson_rate(3, 3.5)
    assert r.value == pytest.approx(0.857, abs=1e-3)
    assert (round(r.low, 2), round(r.high, 1)) == (0.18, 2.5)


def test_clean_hours_needed_to_show_a_rate() -> None:
    assert hours_for_rate(0.1) == pytest.approx(36.9, abs=0.1)  # "about 30 clean hours"


def test_wilson_share_at_the_edges() -> None:
    w = wilson_share(0, 10)
    assert w.value == 0.0 and w.low == 0.0 and w.high == pytest.approx(0.2775, abs=1e-4)
    full = wilson_share(20, 20)
    assert full.high == 1.0 and full.low == pytest.approx(0.8389, abs=1e-4)
    assert wilson_share(5, 10).low == pytest.approx(0.2366, abs=1e-4)


def test_nothing_measured_claims_nothing() -> None:
    assert math.isnan(poisson_rate(0, 0.0).value) and poisson_rate(0, 0.0).text() == "-"
    assert math.isnan(wilson_share(0, 0).high)
    assert poisson_rate(2, 4.0).text() == "0.50 [0.06, 1.81]"
    with pytest.raises(ValueError, match="share"):
        wilson_share(3, 2)
