"""The ground station's mission layer, without processes: mission files, the injection plan
that reproduces a fault schedule on the vessel, the wrench limit and the flight record."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.config.mission import load_mission, shipped_missions
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import Injection, injection_plan
from ftcap_hil.core.messages import FaultKind
from ftcap_hil.core.models.controllers import limit_wrench
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.report.flight import FlightRecorder
from ftcap_hil.report.records import column_names

W, B, S, OFF, OK = FaultKind.WEAK, FaultKind.BIAS, FaultKind.STUCK, FaultKind.OFF, FaultKind.OK


Row = tuple[float, int, FaultKind, float | None]


def _rows(plan: list[Injection]) -> list[Row]:
    return [(i.at_s, i.thruster, i.kind, None if math.isnan(i.value) else i.value) for i in plan]


def _plan(name: str | Path, *overrides: str) -> list[Row]:
    mission = load_mission(name, list(overrides))
    return _rows(injection_plan(mission.scenario.faults, mission.duration_s))


def test_shipped_missions() -> None:
    assert {"paper-4.2-ex1", "paper-4.2-ex1-short", "paper-4.2-ex2-bias008"} <= set(
        shipped_missions()
    )


def test_example_1_is_weak_then_bias_then_weak_and_stuck() -> None:
    # eqs. (27)-(28): WEAK clears the bias on the vessel, BIAS keeps delta
    assert _plan("paper-4.2-ex1") == [
        (12.0, 0, W, 0.9),
        (12.0, 0, B, 0.01),
        (200.0, 0, W, 0.8),
        (200.0, 2, S, 0.01),
    ]
    mission = load_mission("paper-4.2-ex1")
    assert (mission.duration_s, mission.period_s, mission.mode) == (700.0, 0.2827, None)
    assert mission.scenario.reference_at(250.0).tolist() == [2.0, 2.0, math.pi]


def test_short_example_1_compresses_the_schedule() -> None:
    assert [(t, i, k) for t, i, k, _ in _plan("paper-4.2-ex1-short")] == [
        (12.0, 0, W), (12.0, 0, B), (45.0, 0, W), (45.0, 2, S),
    ]  # fmt: skip
    mission = load_mission("paper-4.2-ex1-short")
    assert mission.duration_s == 140.0
    assert mission.scenario.name == "paper-4.2-ex1-short"
    assert mission.scenario.reference_at(50.0).tolist() == [2.0, 2.0, math.pi]


def test_a_cleared_fault_is_injected_as_ok_and_changes_after_the_end_are_dropped() -> None:
    assert _plan("paper-4.2-ex2-bias008") == [(12.0, 1, S, 0.08), (200.0, 1, OK, None)]
    assert _plan("paper-4.2-ex2-bias008", "mission.duration=100") == [(12.0, 1, S, 0.08)]
    assert _plan("paper-4.2-ex1", "mission.duration=30") == [(12.0, 0, W, 0.9), (12.0, 0, B, 0.01)]


def test_inline_faults_cover_off_and_bias_only_changes(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(
        '[mission]\nscenario = "paper-4.2-ex1"\nduration = 50.0\n'
        "[[fault]]\nfrom = 5.0\nthruster = 2\ndelta = 0.0\n"
        "[[fault]]\nfrom = 10.0\nthruster = 4\nbias = 0.02\n"
        "[[fault]]\nfrom = 20.0\nthruster = 4\ndelta = 0.5\nbias = 0.02\n"
    )
    assert _plan(path) == [
        (5.0, 1, OFF, None),
        (10.0, 3, B, 0.02),  # delta unchanged: BIAS alone
        (20.0, 3, W, 0.5),  # WEAK clears the bias on the vessel: BIAS again
        (20.0, 3, B, 0.02),
    ]


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("mission.mode=turbo", "[mission] mode: 'turbo' is not one of 'none', 'cap'"),
        ("mission.period=-1", "[mission] period: expected a finite number > 0, got -1"),
        ("gcs.wrench_limit=[1, 2]", "[gcs] wrench_limit: expected 3 finite numbers > 0"),
        ("gcs.colour=1", "[gcs] unknown key 'colour'; valid keys: clear_faults_at_end"),
        ("mission.scenario=nope", "[mission] scenario: scenario 'nope': no such file"),
    ],
)
def test_bad_values_name_their_key(override: str, key: str) -> None:
    with pytest.raises(ConfigError, match="paper-4.2-ex1.toml: " + re.escape(key)):
        load_mission("paper-4.2-ex1", [override])


def test_limit_wrench_keeps_the_direction() -> None:
    v = np.array([0.9, 0.3, 1.2])
    out = limit_wrench(v, (3.0, 3.0, 0.6))
    assert np.allclose(out, v / 2.0)
    small = np.array([0.1, 0.0, 0.1])
    assert limit_wrench(small, (3.0, 3.0, 0.6)) is small


_STATUS = AllocatorStatus(
    delta_hat=(0.9, 1.0, 1.0, 1.0), f_hat=(0.01, 0.0, 0.0, 0.0), degraded=True
)


def test_flight_record_has_the_simulator_columns_and_truth() -> None:
    mission = load_mission("paper-4.2-ex1", ["mission.duration=20"])
    rec = FlightRecorder(mission.scenario)
    u = np.array([0.05, 0.05, -0.05, -0.05])
    x0 = np.array([0.0, 0.0, 3.1, 0.0, 0.0, 0.0])
    x1 = np.array([0.1, 0.0, -3.1, 0.0, 0.0, 0.0])  # heading crossed +-pi
    rec.add(0.0, x0, np.zeros(3), np.zeros(3), None, None)
    rec.add(13.0, x1, np.array([2.0, 0, 0]), np.array([0.5, 0, 0]), _STATUS, u)
    run = rec.finish("ftcap", mission.period_s, source="test")
    assert list(run.columns) == column_names(mission.scenario)
    c = {k: v[1] for k, v in run.columns.items()}
    assert c["psi"] == pytest.approx(2 * math.pi - 3.1)  # unwrapped
    assert (c["delta_1"], c["f_1"], c["delta_hat_1"], c["fallback"]) == (0.9, 0.01, 0.9, 1.0)
    produced = np.array([0.9 * 0.05 + 0.01, 0.05, -0.05, -0.05])
    assert [c[f"tau_{i}"] for i in range(1, 5)] == pytest.approx(produced)
    v_ach = mission.scenario.B @ produced
    assert [c[f"v_ach_{j}"] for j in range(1, 4)] == pytest.approx(v_ach)
    assert math.isnan(run.columns["delta_hat_1"][0]) and math.isnan(c["solve_us"])
    assert run.scenario.duration_s == pytest.approx(13.0 + mission.period_s)  # cut short
