"""The drives' diagnosis fused with the motion (core/cycle.py, core/evidence.py) on
CyberShip II station keeping: each thruster judged by its own shaft, the motion filter fed
the thrust the shafts show, side by side with motion only (the same run without telemetry)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

import ftcap_hil.data.scenarios as shipped
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.faults import Cause
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode
from tests.support.shaft_cases import cs2_case, deviation_max, flags, isolation_s

STARBOARD = 1  # the starboard main propeller


def test_healthy_raises_nothing_and_holds_station() -> None:
    rec = run_mode(cs2_case(STARBOARD, Cause.HEALTHY, 1.0), Mode.FTCAP)
    assert not flags(rec).any()
    assert deviation_max(rec) < 0.03


def test_no_dither_on_a_thruster_whose_drive_reports() -> None:
    """Healthy, every drive reporting: after the first second the allocation stays within
    0.1 % of each range of CAP's (what differs is the estimates' small corrections; the
    boat is not dithered), where the dither asked for (DiagnosisConfig.dither) moves each
    thruster by 1 % of its range and more (measured: 0.04 % and 7-20 %)."""
    sc = cs2_case(STARBOARD, Cause.HEALTHY, 1.0, duration_s=30.0)
    cap = run_mode(sc, Mode.CAP)
    diag = dataclasses.replace(sc.core.diagnosis, dither=True)
    dithered = run_mode(
        dataclasses.replace(sc, core=dataclasses.replace(sc.core, diagnosis=diag)), Mode.FTCAP
    )
    quiet = run_mode(sc, Mode.FTCAP)
    later = cap.t > 1.0
    for i, top in enumerate(sc.thrusters.u_max, start=1):
        ref = cap.columns[f"u_{i}"][later]
        assert np.abs(quiet.columns[f"u_{i}"][later] - ref).max() < 1e-3 * top, i
        assert np.abs(dithered.columns[f"u_{i}"][later] - ref).max() > 1e-2 * top, i


@pytest.mark.parametrize(
    ("cause", "delta", "within_s"),
    [(Cause.DRIVE_DEAD, 0.0, 1.0), (Cause.JAMMED, 0.0, 1.0), (Cause.STUCK, 1.0, 1.0),
     # A partial loss hides within the lag's uncertainty longer, and with no dither on a
     # thruster whose drive reports (DiagnosisConfig.dither) it shows only as the demand
     # moves its command: 8.7 s here, 4.3 s with the dither that moved the boat.
     (Cause.WEAK_MOTOR, 0.5, 10.0)],
)  # fmt: skip
def test_a_shaft_visible_fault_is_isolated_in_seconds(
    cause: Cause, delta: float, within_s: float
) -> None:
    shaft = run_mode(cs2_case(STARBOARD, cause, delta), Mode.FTCAP)
    motion = run_mode(cs2_case(STARBOARD, cause, delta, shaft=False), Mode.FTCAP)
    assert isolation_s(shaft, STARBOARD, 60.0) <= within_s
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


def test_a_drive_judging_its_thruster_healthy_leaves_the_motion_its_command(
    tmp_path: Path,
) -> None:
    """The drawn CyberShip II of seed 2 (its model turns the port propeller by 2.6 deg, 30 %
    of that propeller's yaw moment), healthy, 300 s: fed the thrust the measured speeds
    implied, the motion charged the model's error to the starboard propeller (0.57, flagged)
    while its drive judged it healthy. Fed the command there, as with no drives, it stays
    where the motion alone puts it (0.89 and 0.90)."""
    text = (Path(shipped.__file__).parent / "cybership2-station-drawn.toml").read_text()
    text = text.replace("seed = 0", "seed = 2").replace("duration = 120.0", "duration = 300.0")
    text = re.sub(r"\[\[fault\]\][^\[]*", "", text)  # healthy
    (tmp_path / "s2.toml").write_text(text)
    sc = load_scenario(tmp_path / "s2.toml")
    assert sc.seed == 2 and not sc.faults.events
    fused = run_mode(sc, Mode.FTCAP)
    no_drives = dataclasses.replace(sc.truth, feedback=None)
    motion = run_mode(dataclasses.replace(sc, truth=no_drives, drives=None), Mode.FTCAP)
    assert not flags(fused).any()
    final = fused.columns["delta_hat_2"][-1], motion.columns["delta_hat_2"][-1]
    assert abs(final[0] - final[1]) < 0.05, final
