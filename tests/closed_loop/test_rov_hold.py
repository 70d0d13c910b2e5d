"""The BlueROV2 Heavy holds station in 6 DOF with a thruster dead when the allocation knows
it, and does not when it does not (bench/rov_hold.py gives the whole table)."""

from __future__ import annotations

import pytest

from ftcap_hil.config.underwater import load_vehicle
from ftcap_hil.runtime.rov_hold import hold

ROV = load_vehicle("bluerov2-heavy")


@pytest.mark.parametrize("dead", ["H3_aft_stbd", "V3_aft_stbd"])
def test_a_dead_thruster_told_to_the_allocation_is_held_through(dead: str) -> None:
    i = ROV.thrusters.names.index(dead)
    healthy = hold(ROV, "healthy")
    told = hold(ROV, "oracle", i)
    untold = hold(ROV, "cap", i)
    # told: as if nothing happened (the 7 others still span the 6 axes)
    assert told.depth_dev_max_m <= healthy.depth_dev_max_m + 0.002
    assert told.roll_pitch_max_deg < 0.1 and told.heading_dev_max_deg < 0.1
    assert told.unmet_rms < 1e-4
    # not told: the dead thruster's share is missing and the vehicle tilts or turns
    assert max(untold.roll_pitch_max_deg, untold.heading_dev_max_deg) > 5.0
    assert untold.unmet_rms > 10 * told.unmet_rms


def test_modes_and_faults_must_agree() -> None:
    with pytest.raises(ValueError, match="mode is one of"):
        hold(ROV, "ftcap", 0)
    with pytest.raises(ValueError, match="a dead thruster"):
        hold(ROV, "oracle")
