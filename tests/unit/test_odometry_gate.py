"""Odometry the vessel cannot have produced is dropped and counted before the estimator
(runtime/estimation.py, PlausibilityGate); a genuine jump costs the re-fix time, never a
lock-out; a forged track that takes turns with the vessel's is never kept (issue 22)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcap_hil.config.daemon import OdometryLimits
from ftcap_hil.core.messages import Odometry
from ftcap_hil.runtime.estimation import MIN_INTERVAL, EstimationSampler, PlausibilityGate

DT = 0.1


def odo(k: int, north: float | None = None, u: float = 0.5) -> Odometry:
    """The vessel sailing north at u m/s, sample k at k DT of vessel time."""
    n = u * k * DT if north is None else north
    return Odometry(np.array([n, 0.0, 0.0]), np.array([u, 0.0, 0.0]), k * DT)


def ns(k: int) -> int:
    return int(k * DT * 1e9) + 1_000_000


@pytest.mark.parametrize(
    ("bad", "why"),
    [
        (Odometry(np.array([math.nan, 0, 0]), np.zeros(3), 0.5), "non-finite"),
        (Odometry(np.array([0.25, 0, 0]), np.array([1e6, 0, 0]), 0.5), "speed"),
        (Odometry(np.array([0.25, 0, 0]), np.array([0.5, 0, 40.0]), 0.5), "yaw rate"),
        (odo(5, north=1e4), "position jumped"),
        (Odometry(np.array([0.25, 0, 0]), np.array([0.5, 9.0, 0]), 0.5), "velocity jumped"),
    ],
)
def test_each_kind_of_implausible_sample_is_dropped_and_named(bad: Odometry, why: str) -> None:
    gate = PlausibilityGate()
    assert all(gate.check(odo(k), ns(k)) for k in range(5))
    assert not gate.check(bad, ns(5))
    assert gate.reason is not None and why in gate.reason and gate.rejected == 1


def test_a_genuine_jump_is_kept_once_it_held_for_the_refix_time() -> None:
    gate = PlausibilityGate(OdometryLimits(position_margin_m=1.0), refix_s=2.0)
    for k in range(5):
        assert gate.check(odo(k), ns(k))
    # 100 m: beyond what 15 m/s covers in the 2 s (a smaller jump becomes reachable sooner)
    refix = [odo(k, north=0.5 * k * DT + 100.0) for k in range(5, 40)]
    kept = [gate.check(o, ns(k)) for k, o in zip(range(5, 40), refix, strict=True)]
    # 2 s of the new track at 10 Hz: samples 5..24 dropped, 25 on kept
    assert kept == [False] * 20 + [True] * 15
    assert gate.reason is None and gate.rejected == 20


def test_a_forged_track_taking_turns_with_the_vessels_is_never_kept() -> None:
    """The old rule kept a sample that followed on from the dropped one before it: a steady
    forger (bursts between the vessel's samples, standing still 50 m away) won whenever two
    came in a row."""
    gate = PlausibilityGate(OdometryLimits(position_margin_m=1.0), refix_s=2.0)
    forged = lambda k: Odometry(np.array([50.0, 0, 0]), np.zeros(3), k * DT)  # noqa: E731
    kept_forged = 0
    for k in range(200):
        assert gate.check(odo(k), ns(k))
        for _ in range(3 if k % 4 else 1):  # bursts of three forged samples
            kept_forged += gate.check(forged(k), ns(k))
    assert kept_forged == 0


def test_absurd_samples_never_reach_the_estimator_and_sampling_goes_on() -> None:
    s = EstimationSampler(period_s=0.3, use_vessel_clock=True)
    s.command_sent(0, np.zeros(4))
    out = []
    for k in range(1, 60):
        absurd = k % 7 == 0  # a forger's sample every 0.7 s among the vessel's own
        o = Odometry(np.array([1e5, 0, 0]), np.array([1e6, 0, 0]), k * DT) if absurd else odo(k)
        got = s.sample(o, ns(k))
        if got is not None:
            out.append(got.observation)
    assert s.gate.rejected == 8
    assert len(out) >= 15  # the intervals go on across a dropped sample
    for obs in out:
        assert np.abs(obs.x_prev).max() < 10 and np.abs(obs.x_now).max() < 10
        # on the vessel's grid: a dropped sample moves one end to the next sample
        assert MIN_INTERVAL * 0.3 <= obs.dt_s < 0.45


def test_the_same_implausible_sample_seen_by_later_cycles_is_counted_once() -> None:
    s = EstimationSampler(period_s=0.3, use_vessel_clock=True)
    s.command_sent(0, np.zeros(4))
    bad = Odometry(np.array([0, 0, 0]), np.array([1e6, 0, 0]), 0.1)
    for _ in range(5):
        assert s.sample(bad, ns(1)) is None
    assert s.gate.rejected == 1 and s.gate.reason is not None
