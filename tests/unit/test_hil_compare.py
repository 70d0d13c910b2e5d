"""Live against offline metrics (report/hil_compare.py) and the mission a held vessel is
flown with (config/mission.py scenario_mission)."""

from __future__ import annotations

import numpy as np
import pytest

from ftcap_hil.config.mission import scenario_mission
from ftcap_hil.core.faults import FaultEvent, FaultSchedule
from ftcap_hil.report.hil_compare import CaseMetrics, comparison_lines, flag_metrics, onset

FAULTS = FaultSchedule(3, (FaultEvent(start=10.0, end=np.inf, thruster=1, delta=0.0, bias=None),))


def test_flags_give_detection_isolation_and_false_alarms() -> None:
    t = np.arange(0.0, 20.0, 0.5)
    flags = np.zeros((t.size, 3), dtype=bool)
    flags[0] = True  # the status before the first allocation: not a false alarm
    flags[(t >= 4.0) & (t < 5.0), 2] = True  # a false alarm on a healthy thruster
    flags[t >= 11.0, 0] = True  # detection: a healthy one first
    flags[t >= 12.5, 1] = True
    flags[t >= 14.0, 0] = False  # isolation: the faulty one alone
    assert onset(FAULTS) is not None and onset(FAULTS)[1].tolist() == [False, True, False]  # type: ignore[index]
    det, iso, fa = flag_metrics(FAULTS, t, flags)
    assert (det, iso, fa) == (1.0, 4.0, 2)  # thruster 1 at 11 s was a false alarm too


def test_comparison_targets() -> None:
    off = CaseMetrics(0.020, 5.0, 5.0, 0)
    same = comparison_lines(CaseMetrics(0.0215, 5.4, 5.3, 0), off, 0.1)
    assert same[-1] == "VERDICT: live as offline"
    late = comparison_lines(CaseMetrics(0.0215, 6.0, 6.0, 1), off, 0.1)
    assert "DIFFERS" in late[1] and "DIFFERS" in late[3] and "ok" in late[2]
    assert late[-1].startswith("VERDICT: live differs")
    assert "DIFFERS" in comparison_lines(CaseMetrics(0.030, 5.0, 5.0, 0), off, 0.1)[0]


def test_a_scenario_mission_flies_the_vessel_s_clock_and_injects_nothing() -> None:
    m = scenario_mission("cybership2-station", ["gcs.time_scale=2"])
    assert m.gcs.vessel_clock and m.gcs.time_scale == 2.0 and m.injections == []
    assert m.period_s == pytest.approx(0.1) and m.duration_s == 120.0
    assert m.scenario.truth is not None
