"""The drives' diagnosis fused with the motion (core/cycle.py, core/evidence.py) on
CyberShip II station keeping: each thruster judged by its own shaft, the motion filter fed
the thrust the shafts show, side by side with motion only (the same run without telemetry)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcap_hil.core.faults import Cause
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode
from tests.support.shaft_cases import cs2_case, deviation_max, flags, isolation_s

STARBOARD = 1  # the starboard main propeller


def test_healthy_raises_nothing_and_holds_station() -> None:
    rec = run_mode(cs2_case(STARBOARD, Cause.HEALTHY, 1.0), Mode.FTCAP)
    assert not flags(rec).any()
    assert deviation_max(rec) < 0.03


@pytest.mark.parametrize(
    ("cause", "delta"), [(Cause.DRIVE_DEAD, 0.0), (Cause.JAMMED, 0.0), (Cause.STUCK, 1.0),
                         (Cause.WEAK_MOTOR, 0.5)],
)  # fmt: skip
def test_a_shaft_visible_fault_is_isolated_within_a_second(cause: Cause, delta: float) -> None:
    shaft = run_mode(cs2_case(STARBOARD, cause, delta), Mode.FTCAP)
    motion = run_mode(cs2_case(STARBOARD, cause, delta, shaft=False), Mode.FTCAP)
    assert isolation_s(shaft, STARBOARD, 60.0) <= 1.0
    assert isolation_s(motion, STARBOARD, 60.0) > 3.0  # what the motion alone needs here
    assert not np.delete(flags(shaft), STARBOARD, axis=1).any()  # no healthy one flagged
    assert deviation_max(shaft) <= deviation_max(motion)


def test_a_partial_loss_is_estimated_to_within_a_tenth() -> None:
    for cause in (Cause.WEAK_MOTOR, Cause.LOST_BLADE):
        rec = run_mode(cs2_case(STARBOARD, cause, 0.5), Mode.FTCAP)
        assert rec.columns["delta_hat_2"][-1] == pytest.approx(0.5, abs=0.1), cause


def test_telemetry_lost_never_removes_a_working_thruster() -> None:
    rec = run_mode(cs2_case(STARBOARD, Cause.TELEMETRY_LOST, 1.0), Mode.FTCAP)
    assert not flags(rec).any() and not (rec.columns["dead_2"] > 0.5).any()


def test_power_lost_falls_back_to_the_motion() -> None:
    """A silent drive is not taken for a dead one; the motion still finds the loss."""
    rec = run_mode(cs2_case(STARBOARD, Cause.POWER_LOST, 0.0), Mode.FTCAP)
    assert 1.0 < isolation_s(rec, STARBOARD, 60.0) < math.inf
